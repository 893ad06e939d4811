// Device queries for perch2::cuda (host code only). A failed query clears CUDA's last-error state, so it
// never surfaces later as the error of an unrelated call.
#include <cuda_runtime_api.h>

#include "perch2/cuda/device.hpp"

namespace perch2::cuda {

namespace {
cudaError_t count_devices(int& n) {
  n = 0;
  const cudaError_t e = cudaGetDeviceCount(&n);
  if (e != cudaSuccess) n = 0, (void)cudaGetLastError();
  return e;
}
}  // namespace

int device_count() noexcept {
  int n = 0;
  count_devices(n);
  return n;
}

std::string device_summary() {
  int n = 0;
  const cudaError_t e = count_devices(n);
  if (e != cudaSuccess)
    return std::string("no CUDA device visible (cudaGetDeviceCount: ") + cudaGetErrorString(e) + ")";
  if (n == 0) return "no CUDA device visible (cudaGetDeviceCount found 0 devices)";
  std::string out = std::to_string(n) + (n == 1 ? " CUDA device:" : " CUDA devices:");
  for (int d = 0; d < n; ++d) {
    cudaDeviceProp p{};
    if (cudaGetDeviceProperties(&p, d) != cudaSuccess) {
      (void)cudaGetLastError();
      continue;
    }
    out += " [" + std::to_string(d) + "] " + p.name + " (sm_" + std::to_string(p.major) +
           std::to_string(p.minor) + ")";
  }
  return out;
}

}  // namespace perch2::cuda
