// The Thrust backend as a policy, once per device system (see system.hpp).
#pragma once

#include "perch2/cuda/cost.hpp"
#include "perch2/cuda/knn.hpp"
#include "perch2/cuda/registration.hpp"
#include "perch2/cuda/render.hpp"
#include "perch2/cuda/system.hpp"

namespace perch2::thrust_backend {

template <class System>
struct Backend {
  static constexpr const char* name = System::name;
  /// Same results as perch2::cpu bit for bit (same float operations in the same order, no FMA).
  static constexpr bool bitwise_reproducible = System::bitwise_reproducible;
  using Renderer = thrust_backend::Renderer<System>;
  using KnnIndex = thrust_backend::KnnIndex<System>;
  using Registration = thrust_backend::Registration<System>;
  using Cost = thrust_backend::Cost<System>;
};

}  // namespace perch2::thrust_backend

namespace perch2::cuda {
using Backend = thrust_backend::Backend<thrust_backend::CudaSystem>;
}
namespace perch2::thrust_omp {
using Backend = thrust_backend::Backend<thrust_backend::OmpSystem>;
}
