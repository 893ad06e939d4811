// Thrust cost stage: one thread per rendered point (J_r) and per (hypothesis, observed point in its volume)
// pair (J_o), each visiting the other cloud's uniform grid within delta; per-hypothesis sums on the device.
// CPU systems (System::cost_whole_hypotheses) classify the rendered points of whole hypotheses per work
// item instead (see cost.inl).
#pragma once

#include <memory>

#include "perch2/cost/cost.hpp"
#include "perch2/cuda/system.hpp"

namespace perch2::thrust_backend {

template <class System>
class PERCH2_API Cost {
 public:
  /// Uploads the observed segments once, builds their grid and CIELAB colours. Throws InvalidInput on a
  /// malformed or non-finite batch or one without segments.
  explicit Cost(const CloudBatch& observed);
  ~Cost();
  Cost(Cost&&) noexcept;
  Cost& operator=(Cost&&) noexcept;

  /// Scores every rendered cloud (see perch2/cost/cost.hpp); the counts equal the reference's exactly.
  CostResult evaluate(const CloudBatch& rendered, const CostRequest& request,
                      const CostSettings& settings = {}) const;

  std::size_t num_segments() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

extern template class Cost<CudaSystem>;
extern template class Cost<OmpSystem>;
extern template class Cost<OmpPassesSystem>;

}  // namespace perch2::thrust_backend
