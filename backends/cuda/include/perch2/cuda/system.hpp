// The Thrust backend is one source compiled for two Thrust device systems. Each stage is a class template
// over a system tag, explicitly instantiated in the library built for that system:
//   perch2::cuda        nvcc, THRUST_DEVICE_SYSTEM_CUDA (production, GPUs)
//   perch2::thrust_omp  g++,  THRUST_DEVICE_SYSTEM_OMP  (checked against the reference on every CI run)
#pragma once

#include <cstddef>

#include "perch2/core/export.hpp"

namespace perch2::thrust_backend {

struct PERCH2_API CudaSystem {
  static constexpr const char* name = "cuda";
  static constexpr std::size_t default_chunk_bytes = std::size_t(256) << 20;  ///< fills a GPU
};
struct PERCH2_API OmpSystem {
  static constexpr const char* name = "thrust_omp";
  static constexpr std::size_t default_chunk_bytes = std::size_t(4) << 20;  ///< stays in cache
};

}  // namespace perch2::thrust_backend
