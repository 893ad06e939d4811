// The 6-DoF and 3-DoF estimators over the reference backend, compiled once into perch2::cpu
// (src/estimators_*.cpp). Include this instead of instantiating them in every translation unit that uses
// them: each such unit then compiles in seconds instead of the ~30-70 s an instantiation takes.
//
//   #include "perch2/cpu/estimators.hpp"
//   perch2::SixDofEstimator<perch2::cpu::Backend> estimator(models);  // defined in libperch2_cpu
#pragma once

#include "perch2/core/export.hpp"
#include "perch2/cpu/backend.hpp"
#include "perch2/search/sixdof.hpp"
#include "perch2/search/tabletop.hpp"

namespace perch2 {
extern template class PERCH2_API SixDofEstimator<cpu::Backend>;
extern template class PERCH2_API TabletopEstimator<cpu::Backend>;
}  // namespace perch2
