// Thrust registration: batched ICP / GICP as per-iteration passes over all (hypothesis, point) pairs —
// correspondences by the uniform-grid search, per-point normal equations summed per block of points, and a
// per-hypothesis functor that sums its blocks, solves the damped 6x6 (or 3x3) system and updates its pose
// and convergence flag. No host round trip per iteration. On CPU systems (OmpSystem) each thread runs the
// same functors over whole source clouds pulled from a counter: one parallel region per call. Algorithm:
// perch2/registration/registration.hpp.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "perch2/cuda/system.hpp"
#include "perch2/registration/registration.hpp"

namespace perch2::thrust_backend {

template <class System>
class PERCH2_API Registration {
 public:
  /// Uploads the target segments once and builds their uniform grid. Target covariances are computed once
  /// per GicpSettings::k_neighbors value, on first use. Throws InvalidInput on a bad batch.
  explicit Registration(const CloudBatch& targets);
  ~Registration();
  Registration(Registration&&) noexcept;
  Registration& operator=(Registration&&) noexcept;

  RegistrationResult icp(const CloudBatch& sources, const std::vector<std::int32_t>& source_segment,
                         const IcpSettings& settings) const;
  RegistrationResult gicp(const CloudBatch& sources, const std::vector<std::int32_t>& source_segment,
                          const GicpSettings& settings) const;

  std::size_t num_segments() const;

  /// Passes, work items and device allocations of the last icp()/gicp() run (for gicp with an ICP warm-up:
  /// its GICP stage). Iterations stop once no hypothesis is active (checked every few iterations).
  LaunchShape last_launch_shape() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

extern template class Registration<CudaSystem>;
extern template class Registration<OmpSystem>;
extern template class Registration<OmpPassesSystem>;

}  // namespace perch2::thrust_backend
