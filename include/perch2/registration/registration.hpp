// The registration stage: batched point-to-point ICP (6-DoF or table x, y, yaw) and many-to-many GICP.
//
// Many source clouds (one per hypothesis, already posed in the camera frame, e.g. rendered clouds) are each
// aligned to one segment of a target cloud batch (the observed cloud, or its per-label segments). Backends
// implement `Registration` with this interface (perch2/cpu/registration.hpp, perch2/cuda/registration.hpp):
//   explicit Registration(const CloudBatch& targets);   // kd-trees / grids and target covariances built once
//   RegistrationResult icp(const CloudBatch& sources, const std::vector<std::int32_t>& source_segment,
//                          const IcpSettings&) const;
//   RegistrationResult gicp(const CloudBatch& sources, const std::vector<std::int32_t>& source_segment,
//                           const GicpSettings&) const;
//
// The algorithm (identical in every backend; the reference computes in double, the Thrust backend in float):
//   Each source point s_i is moved by the current correction T = (R, t): p_i = R s_i + t. Its correspondence
//   is the nearest target point q_i of its segment, if |q_i - p_i| <= max_correspondence_distance_m. The
//   residual d_i = q_i - p_i is weighted by W_i = (C_t,i + R C_s,i R^T)^-1 (GICP, Segal et al. 2009) or by
//   the identity (point-to-point ICP). The cost is sum_i d_i^T W_i d_i over the correspondences. The
//   increment is left-multiplied about a pivot c (the source centroid moved by T for 6-DoF; origin_cam for x,
//   y, yaw): p' = exp([w]x) (p - c) + c + v, i.e. T <- G(w, v) * T. Gauss-Newton normal equations H = sum J^T
//   W J, g = sum J^T W d with J = [[p - c]x, -I] are accumulated per hypothesis; for x, y, yaw they are
//   projected onto w = theta * up, v = a * e1 + b * e2 (e1, e2 span the table plane), so height along up,
//   roll and pitch never change. The damped system (H + lambda (diag(H) + floor)) x = -g is solved per
//   hypothesis (Levenberg-Marquardt): a step is accepted if the cost of the new pose over the *same*
//   correspondences and weights (W_i frozen at the accepted pose, as in fast_gicp: the cost the step
//   minimised) is not larger than the cost of the accepted pose; then lambda is multiplied by
//   lm.lambda_down, else the step is rejected and lambda multiplied by lm.lambda_up.
//   Correspondences are recomputed at every new pose (one pass per iteration).
//   A hypothesis converges when an accepted step rotates less than rotation_epsilon_rad and moves the pivot
//   less than translation_epsilon_m. It stops without converging when it has fewer than min_inliers
//   correspondences, when lambda exceeds lm.lambda_max, or at max_iterations. Every hypothesis returns its
//   last accepted pose, converged or not.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "perch2/core/cloud.hpp"
#include "perch2/core/error.hpp"
#include "perch2/core/pose.hpp"

namespace perch2 {

/// Degrees of freedom of the correction.
enum class Dof : std::uint8_t {
  Six,         ///< full SE(3)
  TableXYYaw,  ///< translation in the table plane and rotation about the table normal (the 3-DoF mode)
};

/// Levenberg-Marquardt damping shared by ICP and GICP. The damped system is (H + lambda (diag(H) + floor)) x
/// = -g.
struct LmSettings {
  float lambda_initial = 1e-4f;  ///< damping of the first step (dimensionless, relative to diag(H))
  float lambda_up = 10.f;        ///< factor applied to lambda after a rejected step (> 1)
  float lambda_down = 0.1f;      ///< factor applied to lambda after an accepted step (in (0, 1])
  float lambda_min = 1e-7f;      ///< lambda never drops below this
  float lambda_max = 1e4f;       ///< a hypothesis whose lambda grows above this stops (not converged)
  float diagonal_floor =
      1e-6f;  ///< added to diag(H) before damping, in units of H (keeps empty directions solvable)
};

/// Point-to-point ICP (the correspondence weight is the identity).
struct IcpSettings {
  int max_iterations = 30;  ///< correspondence passes per hypothesis (>= 1)
  float max_correspondence_distance_m =
      0.02f;  ///< pairs farther apart than this are not correspondences, metres
  /// Converged when an accepted step moves the pivot less than this, metres. 1e-4 is the knee measured with
  /// bench_registration on the cat and the banana (600 starts up to 10 deg / 2 cm): the same accuracy as
  /// 1e-5 (median point displacement 0.26 / 1.7 mm) in 3-5% fewer passes; 1e-3 ends 0.66 / 2.2 mm off.
  float translation_epsilon_m = 1e-4f;
  float rotation_epsilon_rad = 1e-4f;  ///< ... and rotates less than this, radians
  int min_inliers = 3;                 ///< fewer correspondences than this: stop, not converged
  Dof dof = Dof::Six;
  /// TableXYYaw only: the table normal in the camera frame (need not be unit length; must be non-zero).
  Eigen::Vector3f up_cam = Eigen::Vector3f(0.f, -1.f, 0.f);
  /// TableXYYaw only: a point of the rotation axis (e.g. on the table), camera frame, metres. Yaw steps
  /// rotate about the line through it along up_cam.
  Eigen::Vector3f origin_cam = Eigen::Vector3f::Zero();
  LmSettings lm;
};

/// How source covariances are estimated.
enum class SourceCovariance : std::uint8_t {
  FromKnn,                 ///< k nearest neighbours within the same source cloud
  FromPixelNeighbourhood,  ///< points of the same cloud whose render pixels are near (needs
                           ///< CloudBatch::pixel)
};

/// Largest GicpSettings::k_neighbors (device code keeps the neighbour list in fixed-size local arrays).
constexpr int kMaxCovarianceNeighbors = 32;

/// Generalized ICP (Segal, Haehnel, Thrun 2009) with plane-like covariances.
struct GicpSettings {
  int k_neighbors =
      10;  ///< points (including the point itself) used for each covariance, 3..kMaxCovarianceNeighbors
  /// Segal's regularisation: a covariance's eigenvalues are replaced by (epsilon, 1, 1) (smallest first),
  /// i.e. C = I - (1 - epsilon) n n^T with n the estimated surface normal (dimensionless, in (0, 1]).
  float covariance_epsilon = 1e-3f;
  SourceCovariance source_covariance = SourceCovariance::FromKnn;
  /// FromPixelNeighbourhood only: width of the full-resolution image the pixel indices refer to
  /// (CloudBatch::pixel = v * width + u), pixels. Must be set (> 0) to use that mode.
  int image_width_px = 0;
  /// FromPixelNeighbourhood only: neighbours are points whose pixel lies within this many full-resolution
  /// pixels in u and in v (e.g. 8 at render stride 4 is a 5 x 5 window of rendered pixels), pixels.
  int pixel_radius_px = 8;
  /// FromPixelNeighbourhood only: neighbours farther than this in 3-D are ignored (depth edges), metres.
  float pixel_neighbour_max_distance_m = 0.02f;
  int max_iterations = 30;  ///< correspondence passes per hypothesis (>= 1)
  float max_correspondence_distance_m =
      0.02f;  ///< pairs farther apart than this are not correspondences, metres
  /// Converged when an accepted step moves the pivot less than this, metres. 1e-4 is the knee measured with
  /// bench_registration on the cat and the banana (600 starts up to 10 deg / 2 cm): the same accuracy as
  /// 1e-5 (median point displacement 0.022 / 0.029 mm, all within 1 mm) in 26-31% fewer passes (4.3 / 6.2
  /// instead of 6.2 / 8.3); looser settings save up to 25% more passes but drift (0.034 / 0.087 mm at 1e-3).
  float translation_epsilon_m = 1e-4f;
  float rotation_epsilon_rad = 1e-4f;  ///< ... and rotates less than this, radians
  int min_inliers = 6;                 ///< fewer correspondences than this: stop, not converged
  Dof dof = Dof::Six;  ///< TableXYYaw restricts GICP like ICP (up_cam, origin_cam as in IcpSettings)
  Eigen::Vector3f up_cam = Eigen::Vector3f(0.f, -1.f, 0.f);
  Eigen::Vector3f origin_cam = Eigen::Vector3f::Zero();
  LmSettings lm;
  /// Point-to-point ICP passes run before GICP (same distance cap, epsilons, DoF and damping), for starts
  /// far from the optimum: GICP's plane-like weights let a source slide along wrong planes while most
  /// correspondences are wrong. Measured on the LINEMOD cat (200 random starts 15 deg off, 10 cm cap): GICP
  /// alone recovers 99% of 3 cm starts and 80% of 5 cm starts; with 20 warm-up passes, all of both (ICP
  /// alone: all). Costs up to that many ICP passes; counted in RegistrationResult::iterations.
  int icp_warmup_iterations = 0;
};

/// Per source cloud: the correction and how it was reached.
struct RegistrationResult {
  /// The correction in the camera frame: refined T_cam_obj = T_corr * T_cam_obj. The last accepted
  /// iterate, whether or not the hypothesis converged (identity only if no step was ever accepted).
  std::vector<Pose> T_corr;
  std::vector<int> iterations;  ///< correspondence passes used
  std::vector<int> inliers;     ///< correspondences at the returned pose
  /// RMS distance of the correspondences at the returned pose, metres; +infinity if there are none.
  std::vector<float> final_error;
  std::vector<std::uint8_t> converged;  ///< 1 if the convergence test passed, else 0

  std::size_t size() const { return T_corr.size(); }
};

// ---- validation shared by every backend (same inputs rejected with the same messages) ------------------

namespace registration_detail {

inline void check_lm(const LmSettings& lm, const std::string& who) {
  if (!(std::isfinite(lm.lambda_initial) && lm.lambda_initial >= 0))
    throw InvalidInput(who + "::lm.lambda_initial", "must be finite and >= 0");
  if (!(std::isfinite(lm.lambda_up) && lm.lambda_up > 1))
    throw InvalidInput(who + "::lm.lambda_up", "must be > 1");
  if (!(lm.lambda_down > 0 && lm.lambda_down <= 1))
    throw InvalidInput(who + "::lm.lambda_down", "must be in (0, 1]");
  if (!(std::isfinite(lm.lambda_min) && lm.lambda_min >= 0))
    throw InvalidInput(who + "::lm.lambda_min", "must be finite and >= 0");
  if (!(lm.lambda_max >= lm.lambda_min)) throw InvalidInput(who + "::lm.lambda_max", "must be >= lambda_min");
  if (!(std::isfinite(lm.diagonal_floor) && lm.diagonal_floor > 0))
    throw InvalidInput(who + "::lm.diagonal_floor", "must be finite and > 0");
}

template <class S>
void check_common(const S& s, const std::string& who) {
  if (s.max_iterations < 1) throw InvalidInput(who + "::max_iterations", "must be >= 1");
  if (!(std::isfinite(s.max_correspondence_distance_m) && s.max_correspondence_distance_m > 0))
    throw InvalidInput(who + "::max_correspondence_distance_m", "must be finite and > 0");
  if (!(std::isfinite(s.translation_epsilon_m) && s.translation_epsilon_m >= 0))
    throw InvalidInput(who + "::translation_epsilon_m", "must be finite and >= 0");
  if (!(std::isfinite(s.rotation_epsilon_rad) && s.rotation_epsilon_rad >= 0))
    throw InvalidInput(who + "::rotation_epsilon_rad", "must be finite and >= 0");
  if (s.min_inliers < 1) throw InvalidInput(who + "::min_inliers", "must be >= 1");
  if (s.dof == Dof::TableXYYaw) {
    if (!s.up_cam.allFinite() || !(s.up_cam.norm() > 1e-6f))
      throw InvalidInput(who + "::up_cam", "must be finite and non-zero");
    if (!s.origin_cam.allFinite()) throw InvalidInput(who + "::origin_cam", "must be finite");
  } else if (s.dof != Dof::Six) {
    throw InvalidInput(who + "::dof", "unknown value");
  }
  check_lm(s.lm, who);
}

}  // namespace registration_detail

inline void validate(const IcpSettings& s) {
  registration_detail::check_common(s, "IcpSettings");
}

inline void validate(const GicpSettings& s) {
  registration_detail::check_common(s, "GicpSettings");
  if (s.k_neighbors < 3 || s.k_neighbors > kMaxCovarianceNeighbors)
    throw InvalidInput("GicpSettings::k_neighbors", "must be in [3, " +
                                                        std::to_string(kMaxCovarianceNeighbors) + "], got " +
                                                        std::to_string(s.k_neighbors));
  if (!(s.covariance_epsilon > 0 && s.covariance_epsilon <= 1))
    throw InvalidInput("GicpSettings::covariance_epsilon", "must be in (0, 1]");
  if (s.icp_warmup_iterations < 0) throw InvalidInput("GicpSettings::icp_warmup_iterations", "must be >= 0");
  if (s.source_covariance == SourceCovariance::FromPixelNeighbourhood) {
    if (s.image_width_px <= 0)
      throw InvalidInput("GicpSettings::image_width_px",
                         "must be > 0 for FromPixelNeighbourhood covariances");
    if (s.pixel_radius_px < 1) throw InvalidInput("GicpSettings::pixel_radius_px", "must be >= 1");
    if (!(std::isfinite(s.pixel_neighbour_max_distance_m) && s.pixel_neighbour_max_distance_m > 0))
      throw InvalidInput("GicpSettings::pixel_neighbour_max_distance_m", "must be finite and > 0");
  } else if (s.source_covariance != SourceCovariance::FromKnn) {
    throw InvalidInput("GicpSettings::source_covariance", "unknown value");
  }
}

/// Throws InvalidInput if a cloud batch is malformed or holds non-finite coordinates.
inline void validate_registration_cloud(const CloudBatch& c, const std::string& name) {
  c.validate(name);
  for (std::size_t i = 0; i < c.size(); ++i)
    if (!(std::isfinite(c.x[i]) && std::isfinite(c.y[i]) && std::isfinite(c.z[i])))
      throw InvalidInput(name, "point " + std::to_string(i) + " is not finite");
}

/// Throws InvalidInput unless the targets have at least one segment and are finite.
inline void validate_registration_targets(const CloudBatch& targets) {
  validate_registration_cloud(targets, "registration targets");
  if (targets.num_clouds() == 0) throw InvalidInput("registration targets", "has no segments");
}

/// Throws InvalidInput if the sources are malformed or a segment index is out of range.
inline void validate_registration_sources(const CloudBatch& sources,
                                          const std::vector<std::int32_t>& source_segment,
                                          std::size_t num_target_segments, bool need_pixels = false) {
  validate_registration_cloud(sources, "registration sources");
  if (source_segment.size() != sources.num_clouds())
    throw InvalidInput("source_segment", "has " + std::to_string(source_segment.size()) + " entries for " +
                                             std::to_string(sources.num_clouds()) + " source clouds");
  for (std::size_t c = 0; c < source_segment.size(); ++c)
    if (source_segment[c] < 0 || std::size_t(source_segment[c]) >= num_target_segments)
      throw InvalidInput("source_segment", "entry " + std::to_string(c) + " is " +
                                               std::to_string(source_segment[c]) + ", but the targets have " +
                                               std::to_string(num_target_segments) + " segments");
  if (need_pixels)
    for (std::size_t i = 0; i < sources.size(); ++i)
      if (sources.pixel[i] < 0)
        throw InvalidInput(
            "registration sources",
            "point " + std::to_string(i) + " has no pixel index (FromPixelNeighbourhood covariances)");
}

/// An orthonormal basis (e1, e2) of the plane perpendicular to unit vector u (deterministic).
inline void plane_basis(const Eigen::Vector3f& u, Eigen::Vector3f& e1, Eigen::Vector3f& e2) {
  const Eigen::Vector3f a = std::abs(u.x()) < 0.9f ? Eigen::Vector3f::UnitX() : Eigen::Vector3f::UnitY();
  e1 = (a - a.dot(u) * u).normalized();
  e2 = u.cross(e1);
}

/// The point-to-point ICP passes of GicpSettings::icp_warmup_iterations: same cap, epsilons, DoF, damping.
inline IcpSettings icp_warmup_settings(const GicpSettings& s) {
  IcpSettings warm;
  warm.max_iterations = s.icp_warmup_iterations;
  warm.max_correspondence_distance_m = s.max_correspondence_distance_m;
  warm.translation_epsilon_m = s.translation_epsilon_m, warm.rotation_epsilon_rad = s.rotation_epsilon_rad;
  warm.min_inliers = s.min_inliers;
  warm.dof = s.dof, warm.up_cam = s.up_cam, warm.origin_cam = s.origin_cam, warm.lm = s.lm;
  return warm;
}

/// GicpSettings::icp_warmup_iterations > 0: runs the warm-up ICP, moves each source by its correction, runs
/// GICP on the moved sources and composes the two corrections (one host pass over the points between the
/// two batched calls). `icp` and `gicp` are the backend's own batched calls (gicp with warm-up 0).
template <class Icp, class Gicp>
RegistrationResult gicp_after_icp_warmup(const CloudBatch& sources, const GicpSettings& s, Icp&& icp,
                                         Gicp&& gicp) {
  const RegistrationResult first = icp(sources, icp_warmup_settings(s));

  CloudBatch moved = sources;
  for (std::size_t c = 0; c < moved.num_clouds(); ++c) {
    const Pose& T = first.T_corr[c];
    for (auto i = moved.offsets[c]; i < moved.offsets[c + 1]; ++i) {
      const Eigen::Vector3f p = T * Eigen::Vector3f(moved.x[i], moved.y[i], moved.z[i]);
      moved.x[i] = p.x(), moved.y[i] = p.y(), moved.z[i] = p.z();
    }
  }
  GicpSettings rest = s;
  rest.icp_warmup_iterations = 0;
  RegistrationResult r = gicp(moved, rest);
  for (std::size_t c = 0; c < r.size(); ++c) {
    r.T_corr[c] = r.T_corr[c] * first.T_corr[c];
    r.iterations[c] += first.iterations[c];
  }
  return r;
}

}  // namespace perch2
