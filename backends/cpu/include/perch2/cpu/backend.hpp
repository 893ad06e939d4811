// The reference backend as a policy: every stage type a pipeline templated on a Backend needs.
#pragma once

#include "perch2/cpu/cost.hpp"
#include "perch2/cpu/knn.hpp"
#include "perch2/cpu/registration.hpp"
#include "perch2/cpu/render.hpp"

namespace perch2::cpu {

struct Backend {
  static constexpr const char* name = "cpu";
  static constexpr bool bitwise_reproducible = true;  ///< the reference itself
  using Renderer = cpu::Renderer;
  using KnnIndex = cpu::KnnIndex;
  using Registration = cpu::Registration;
  using Cost = cpu::Cost;
};

}  // namespace perch2::cpu
