// Reference registration: OpenMP over source clouds, FLANN kd-trees, Eigen (double) for the small solves.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "perch2/core/export.hpp"
#include "perch2/registration/registration.hpp"

namespace perch2::cpu {

class PERCH2_API Registration {
 public:
  /// Keeps the target segments (camera frame, metres) and builds one kd-tree per non-empty segment.
  /// Target covariances are computed once per GicpSettings::k_neighbors value, on first use.
  /// Throws InvalidInput if the batch is malformed, non-finite or has no segments.
  explicit Registration(const CloudBatch& targets);
  ~Registration();
  Registration(Registration&&) noexcept;
  Registration& operator=(Registration&&) noexcept;

  /// Point-to-point ICP of every source cloud c against target segment source_segment[c].
  RegistrationResult icp(const CloudBatch& sources, const std::vector<std::int32_t>& source_segment,
                         const IcpSettings& settings) const;
  /// Generalized ICP of every source cloud c against target segment source_segment[c].
  RegistrationResult gicp(const CloudBatch& sources, const std::vector<std::int32_t>& source_segment,
                          const GicpSettings& settings) const;

  std::size_t num_segments() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace perch2::cpu
