// Small helpers shared by the Thrust stage sources (private to the backend's .inl files).
#pragma once

#include <thrust/copy.h>
#include <thrust/device_vector.h>

#include <cstddef>
#include <vector>

namespace perch2::thrust_backend {

template <class T>
T* ptr(thrust::device_vector<T>& v) {
  return thrust::raw_pointer_cast(v.data());
}
template <class T>
const T* ptr(const thrust::device_vector<T>& v) {
  return thrust::raw_pointer_cast(v.data());
}

/// Bulk device -> host copy (element-wise device_reference reads are slow on CUDA, and on the OpenMP
/// system they bind a reference through a null policy pointer, which UBSan rightly reports).
template <class T>
std::vector<T> to_host(const thrust::device_vector<T>& v) {
  std::vector<T> out(v.size());
  if (!v.empty()) thrust::copy(v.begin(), v.end(), out.begin());  // &*out.begin() must be valid
  return out;
}

/// Bulk host -> device copy (an empty input gives an empty vector without touching its null data()).
template <class T>
thrust::device_vector<T> to_device(const std::vector<T>& v) {
  thrust::device_vector<T> out(v.size());
  if (!v.empty()) thrust::copy(v.begin(), v.end(), out.begin());
  return out;
}

/// One element, device -> host.
template <class T>
T read_at(const thrust::device_vector<T>& v, std::size_t i) {
  T out;
  thrust::copy_n(v.begin() + std::ptrdiff_t(i), 1, &out);
  return out;
}

/// One element, host -> device.
template <class T>
void write_at(thrust::device_vector<T>& v, std::size_t i, const T& value) {
  thrust::copy_n(&value, 1, v.begin() + std::ptrdiff_t(i));
}

}  // namespace perch2::thrust_backend
