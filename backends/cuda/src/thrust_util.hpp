// Small helpers shared by the Thrust stage sources (private to the backend's .inl files).
#pragma once

#include <thrust/copy.h>
#include <thrust/device_ptr.h>
#include <thrust/device_vector.h>

#include <thrust/host_vector.h>

#if THRUST_DEVICE_SYSTEM == THRUST_DEVICE_SYSTEM_CUDA
#include <thrust/system/cuda/execution_policy.h>
#include <thrust/system/cuda/memory.h>
#endif

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <type_traits>
#include <vector>

#include "perch2/cuda/launch_plan.hpp"
#include "perch2/cuda/system.hpp"

#if THRUST_DEVICE_SYSTEM == THRUST_DEVICE_SYSTEM_OMP
#include <omp.h>
#endif

namespace perch2::thrust_backend {

/// Work items of a whole-unit pass on a CPU system (whole hypotheses or clouds, each item pulling units from
/// a shared counter until none is left): one per thread. GPU systems run such stages in passes instead.
inline int cpu_system_workers() {
#if THRUST_DEVICE_SYSTEM == THRUST_DEVICE_SYSTEM_OMP
  return omp_get_max_threads();
#else
  return 1;
#endif
}

/// Policy for launches the host need not wait for: on CUDA thrust::cuda::par_nosync (kernels stay ordered on
/// the default stream; the next copy to the host or synchronising algorithm waits for them), elsewhere
/// thrust::device (the OpenMP system runs each algorithm to completion anyway).
inline auto nosync() {
#if THRUST_DEVICE_SYSTEM == THRUST_DEVICE_SYSTEM_CUDA
  return thrust::cuda::par_nosync;
#else
  return thrust::device;
#endif
}

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

/// Resizes a reusable vector to n elements (contents unspecified), reallocating only when it must grow
/// (counted in `allocations`).
template <class T>
T* reuse(thrust::device_vector<T>& v, std::size_t n, std::int64_t& allocations) {
  if (v.capacity() < n) {
    v.clear();
    v.shrink_to_fit();
    v.reserve(n);
    ++allocations;
  }
  v.resize(n);
  return ptr(v);
}

/// Host -> device upload into a reusable vector (see reuse).
template <class T>
T* upload(thrust::device_vector<T>& dst, const std::vector<T>& src, std::int64_t& allocations) {
  T* p = reuse(dst, src.size(), allocations);
  if (!src.empty()) thrust::copy(src.begin(), src.end(), dst.begin());
  return p;
}

/// Bulk device -> host copy of n elements from a raw device pointer, appended to out.
template <class T>
void append_to_host(std::vector<T>& out, const T* device, std::size_t n) {
  if (n == 0) return;  // Thrust's cross-system copy takes &*out even for an empty range
  const std::size_t at = out.size();
  out.resize(at + n);
  const auto p = thrust::device_pointer_cast(device);
  thrust::copy(p, p + std::ptrdiff_t(n), out.begin() + std::ptrdiff_t(at));
}

#if THRUST_DEVICE_SYSTEM == THRUST_DEVICE_SYSTEM_CUDA
template <class T>
using PinnedAllocator = thrust::cuda::universal_host_pinned_allocator<T>;  // cudaMallocHost
#else
template <class T>
using PinnedAllocator = std::allocator<T>;  // no page-locked memory without the CUDA runtime
#endif

/// Host staging memory of a System (see System::pinned_host_buffers): pinned on CUDA, plain elsewhere.
template <class System, class T>
using HostBuffer = thrust::host_vector<
    T, std::conditional_t<System::pinned_host_buffers, PinnedAllocator<T>, std::allocator<T>>>;

/// Device -> host copy of n elements from a raw device pointer into out (resized to n). With pinned host
/// buffers the copy lands in `staging` (grown only; a growth counts in `allocations`: cudaMallocHost is as
/// costly as a device allocation) and is then copied into out; otherwise it goes straight into out.
template <class System, class T>
void download(const T* device, std::size_t n, std::vector<T>& out, HostBuffer<System, unsigned char>& staging,
              std::int64_t& allocations) {
  out.resize(n);
  if (n == 0) return;  // Thrust's cross-system copy takes &*out even for an empty range
  const auto p = thrust::device_pointer_cast(device);
  if constexpr (System::pinned_host_buffers) {
    const std::size_t bytes = n * sizeof(T);
    if (staging.capacity() < bytes) {
      staging.clear();
      staging.shrink_to_fit();
      staging.reserve(bytes);
      ++allocations;
    }
    staging.resize(bytes);
    T* host = reinterpret_cast<T*>(thrust::raw_pointer_cast(staging.data()));  // page-aligned
    thrust::copy(p, p + std::ptrdiff_t(n), host);
    std::copy(host, host + n, out.begin());
  } else {
    thrust::copy(p, p + std::ptrdiff_t(n), out.begin());
  }
}

/// One device allocation reused for a stage's per-chunk buffers: each chunk carves its arrays from it (in
/// a fixed order, 256-byte aligned), so a chunk's working memory is one figure (perch2/cuda/launch_plan.hpp)
/// the planner can hold to a budget, and repeated chunks and calls allocate nothing.
class DeviceArena {
 public:
  /// Makes the arena exactly `bytes` big if it is smaller, or larger than `max_bytes` (a smaller budget
  /// releases memory). Returns whether it allocated.
  bool reserve(std::size_t bytes, std::size_t max_bytes) {
    const std::size_t words = (bytes + 7) / 8;
    if (words <= storage_.size() && storage_.size() * 8 <= std::max(max_bytes, bytes)) return false;
    storage_.clear();
    storage_.shrink_to_fit();
    storage_.resize(words);
    return true;
  }
  std::size_t bytes() const { return storage_.size() * 8; }
  void rewind() { used_ = 0; }
  /// The next n elements of type T (uninitialised).
  template <class T>
  T* take(std::size_t n) {
    T* p = reinterpret_cast<T*>(reinterpret_cast<unsigned char*>(ptr(storage_)) + used_);
    used_ += arena_aligned(n * sizeof(T));
    return p;
  }

 private:
  thrust::device_vector<std::uint64_t> storage_;
  std::size_t used_ = 0;
};

/// Temporary storage for Thrust algorithms (thrust::device(allocator)): one cached block, grown when a
/// request does not fit, so a scan per chunk allocates once per stage object, not once per chunk.
class TempAllocator {
 public:
  using value_type = char;
  char* allocate(std::ptrdiff_t n) {
    const std::size_t bytes = std::size_t(n);
    if (in_use_ || bytes > block_.size()) {
      if (in_use_) {  // a second live request (not made by the algorithms used here): a one-off block
        ++allocations;
        extra_.emplace_back(bytes);
        return ptr(extra_.back());
      }
      block_.clear();
      block_.shrink_to_fit();
      block_.resize(bytes);
      ++allocations;
    }
    peak_bytes = std::max(peak_bytes, bytes);
    in_use_ = true;
    return ptr(block_);
  }
  void deallocate(char* p, std::size_t) {
    if (!block_.empty() && p == ptr(block_)) {
      in_use_ = false;
      return;
    }
    for (auto it = extra_.begin(); it != extra_.end(); ++it)
      if (ptr(*it) == p) {
        extra_.erase(it);
        return;
      }
  }
  std::size_t bytes() const { return block_.size(); }
  std::int64_t allocations = 0;  ///< device allocations made (the caller resets it per call)
  std::size_t peak_bytes = 0;    ///< largest request

 private:
  thrust::device_vector<char> block_;
  std::vector<thrust::device_vector<char>> extra_;
  bool in_use_ = false;
};

}  // namespace perch2::thrust_backend
