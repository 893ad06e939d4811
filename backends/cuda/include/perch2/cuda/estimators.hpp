// The 6-DoF and 3-DoF estimators over the Thrust backend, compiled once into its libraries:
// perch2::thrust_omp (src/estimators_*_omp.cpp) and, in an nvcc build, perch2::cuda (src/estimators_cuda.cpp,
// host code built by the C++ compiler). Include this instead of instantiating them in every translation unit
// that uses them: each such unit then compiles in seconds instead of the ~30-70 s an instantiation takes.
//
//   #include "perch2/cuda/estimators.hpp"
//   perch2::SixDofEstimator<perch2::thrust_omp::Backend> estimator(models);  // defined in
//   libperch2_thrust_omp
#pragma once

#include "perch2/core/export.hpp"
#include "perch2/cuda/backend.hpp"
#include "perch2/search/sixdof.hpp"
#include "perch2/search/tabletop.hpp"

namespace perch2 {
extern template class PERCH2_API SixDofEstimator<thrust_omp::Backend>;
extern template class PERCH2_API TabletopEstimator<thrust_omp::Backend>;
extern template class PERCH2_API SixDofEstimator<cuda::Backend>;  // libperch2_cuda
extern template class PERCH2_API TabletopEstimator<cuda::Backend>;
}  // namespace perch2
