// What the rasterisation kernels share: the SSE2 switch (host builds on x86), the force-inline qualifier
// and small branch-free integer helpers.
#pragma once

#include <cstdint>

#include "perch2/core/device.hpp"

#if defined(__SSE2__) && !defined(__CUDA_ARCH__)
#include <emmintrin.h>
#define PERCH2_RASTER_SSE2 1
#endif

// Forces inlining of the per-triangle set-up into the triangle loop (GCC stopped inlining it once it grew,
// costing ~10% of the raster time in a call that returns its result through memory).
#if defined(__CUDACC__)
#define PERCH2_HD_FORCE_INLINE __host__ __device__ __forceinline__
#elif defined(__GNUC__)
#define PERCH2_HD_FORCE_INLINE inline __attribute__((always_inline))
#else
#define PERCH2_HD_FORCE_INLINE inline
#endif

namespace perch2 {

PERCH2_HD inline int min3(int a, int b, int c) {
  return min_int(min_int(a, b), c);
}
PERCH2_HD inline int max3(int a, int b, int c) {
  return max_int(max_int(a, b), c);
}

/// Branch-free select: a float comparison in a conditional expression keeps the loop from vectorising
/// (the comparison may trap, so the compiler will not if-convert it).
PERCH2_HD inline int select_int(bool c, int a, int b) {
  const int mask = -int(c);
  return (a & mask) | (b & ~mask);
}

}  // namespace perch2
