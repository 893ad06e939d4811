// Reference cost stage: FLANN radius searches (cpu::KnnIndex) in both directions, OpenMP over points.
#pragma once

#include <memory>

#include "perch2/core/export.hpp"
#include "perch2/cost/cost.hpp"

namespace perch2::cpu {

class PERCH2_API Cost {
 public:
  /// Keeps the observed segments (camera frame, metres, rgb), builds their kd-trees and CIELAB colours.
  /// Throws InvalidInput on a malformed or non-finite batch or one without segments.
  explicit Cost(const CloudBatch& observed);
  ~Cost();
  Cost(Cost&&) noexcept;
  Cost& operator=(Cost&&) noexcept;

  /// Scores every rendered cloud (one per hypothesis; see perch2/cost/cost.hpp for the definitions).
  CostResult evaluate(const CloudBatch& rendered, const CostRequest& request,
                      const CostSettings& settings = {}) const;

  std::size_t num_segments() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace perch2::cpu
