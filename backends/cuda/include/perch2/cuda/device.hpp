// Which CUDA devices this process can use. Defined in perch2::cuda (the nvcc build): link that library to
// call these. Tests and benchmarks ask here before running their perch2::cuda instances, so a build with
// nvcc on a machine without a GPU skips them with a reason instead of failing.
#pragma once

#include <string>

#include "perch2/core/export.hpp"

namespace perch2::cuda {

/// Number of CUDA devices visible to this process (cudaGetDeviceCount): 0 when there is no GPU, no driver,
/// an old driver, or CUDA_VISIBLE_DEVICES hides them all. Never throws.
PERCH2_API int device_count() noexcept;

/// One line for logs and skip messages: the visible devices ("1 CUDA device: [0] NVIDIA H100 (sm_90)") or
/// why there is none ("no CUDA device visible (cudaGetDeviceCount: CUDA driver version is insufficient for
/// CUDA runtime version)").
PERCH2_API std::string device_summary();

}  // namespace perch2::cuda
