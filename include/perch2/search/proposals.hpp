// 6-DoF pose proposals from an instance mask and box (PERCH 2.0, Section V-B, after SSD-6D):
//   rotations    = viewpoints spread evenly on the sphere (or the upper hemisphere of the object frame)
//                  x in-plane rotations about the viewing ray, with rotations that a symmetry of the model
//                  makes equivalent removed (no two proposals within symmetry_threshold_rad of each other
//                  under any symmetry);
//   translations = points on the ray through the box centre, at planar depths z from the mask's nearest
//                  observed depth to its farthest plus half the object's thickness, every depth_step_m.
//
//   perch2::ProposalSettings s;                         // 40 viewpoints x 4 in-plane x <= 3 depths, 0.02 m
//   auto R = perch2::rotation_proposals(s, symmetries);          // object -> "view" rotations
//   auto z = perch2::proposal_depths(frame.depth_m, mask, mesh, s);
//   auto T = perch2::pose_proposals(frame.camera, box_centre_px, R, z);   // T_cam_obj
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "perch2/core/camera.hpp"
#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"

namespace perch2 {

/// Symmetries of a model as in BOP's models_info.json (object frame): transforms T_obj_obj' that map the
/// model onto itself (the identity need not be listed) and axes of continuous rotational symmetry.
/// Proposals only compare rotations, so translations of the discrete symmetries and the offsets of the
/// continuous axes are not needed here.
struct ModelSymmetries {
  std::vector<Pose> discrete;
  std::vector<Eigen::Vector3f> continuous_axes;  ///< object frame, any non-zero length
  bool empty() const { return discrete.empty() && continuous_axes.empty(); }

  /// From any pair of BOP-like lists (perch2::dataset::ModelInfo, perch2::synth::Symmetries): `continuous`
  /// elements need an `axis` member.
  template <class Continuous>
  static ModelSymmetries from(const std::vector<Pose>& discrete, const std::vector<Continuous>& continuous) {
    ModelSymmetries s;
    s.discrete = discrete;
    for (const auto& c : continuous) s.continuous_axes.push_back(c.axis);
    return s;
  }
};

struct ProposalSettings {
  /// Viewpoints (camera directions seen from the object) on the Fibonacci sphere, >= 1. Authors: 80 with
  /// 1-4 in-plane angles. Default 40 x 4 in-plane: the same number of rotations as 80 x 2 but spread more
  /// evenly over SO(3) (nearest rotation at most ~45 deg in-plane and ~16 deg in viewpoint away, instead of
  /// 90 deg in-plane), which GICP with the ICP warm-up closes. With max_depths 3 that is at most 480
  /// hypotheses per instance, ~2,400 for a scene of 5 objects as in the paper (fewer for symmetric models).
  int viewpoints = 40;
  /// Only viewpoints with a non-negative object-frame z (the camera above the object's natural top), for
  /// objects that are never seen from below. Authors: used for many YCB objects.
  bool hemisphere = false;
  /// In-plane rotations about the viewing ray per viewpoint, evenly over [0, 2 pi), >= 1. Authors: 1-4.
  int inplane_rotations = 4;
  /// Two rotations closer than this (geodesic angle, after any symmetry of the model) are one proposal,
  /// radians. < 0 (default): automatic, 0.95 x the smallest angle between two proposals of an asymmetric
  /// model (0.47 rad for 40 viewpoints x 4, 0.33 for 80), so an asymmetric model keeps every proposal and a
  /// symmetric one drops the copies its symmetries make (see symmetry_threshold()).
  float symmetry_threshold_rad = -1.f;
  /// Step between proposal depths along the ray, metres. Authors: 0.02.
  float depth_step_m = 0.02f;
  /// Robust nearest and farthest mask depths: these quantiles of the mask's valid depths (in [0, 1]), so a
  /// few stray readings (mask bleeding onto the table or a neighbour's edge) do not stretch the range.
  float depth_quantile_near = 0.05f, depth_quantile_far = 0.95f;
  /// Most depths per instance (>= 1): a deeper range is sampled with a larger step so that a bad mask
  /// cannot blow up the hypothesis count; GICP closes the remaining depth error (its cap is 0.04 m).
  int max_depths = 3;
};

/// Throws InvalidInput naming the field unless the settings are usable.
inline void validate(const ProposalSettings& s) {
  if (s.viewpoints < 1) throw InvalidInput("ProposalSettings::viewpoints", "must be >= 1");
  if (s.inplane_rotations < 1) throw InvalidInput("ProposalSettings::inplane_rotations", "must be >= 1");
  if (!(s.symmetry_threshold_rad < 3.1416f))
    throw InvalidInput("ProposalSettings::symmetry_threshold_rad", "must be < pi (< 0: automatic)");
  if (!(std::isfinite(s.depth_step_m) && s.depth_step_m > 0))
    throw InvalidInput("ProposalSettings::depth_step_m", "must be finite and > 0");
  if (!(s.depth_quantile_near >= 0 && s.depth_quantile_near <= s.depth_quantile_far &&
        s.depth_quantile_far <= 1))
    throw InvalidInput("ProposalSettings::depth_quantile_*", "need 0 <= near <= far <= 1");
  if (s.max_depths < 1) throw InvalidInput("ProposalSettings::max_depths", "must be >= 1");
}

/// n directions evenly spread over the unit sphere (Fibonacci / golden-angle spiral; equal-area bands), or
/// over the upper (z >= 0) hemisphere.
inline std::vector<Eigen::Vector3f> fibonacci_directions(int n, bool hemisphere = false) {
  std::vector<Eigen::Vector3f> out;
  const double golden = 3.141592653589793 * (3.0 - std::sqrt(5.0));
  for (int i = 0; i < n; ++i) {
    const double t = (double(i) + 0.5) / double(n);
    const double z = hemisphere ? 1.0 - t : 1.0 - 2.0 * t;
    const double r = std::sqrt(std::max(0.0, 1.0 - z * z)), phi = golden * double(i);
    out.emplace_back(float(r * std::cos(phi)), float(r * std::sin(phi)), float(z));
  }
  return out;
}

/// Geodesic angle between two rotations, radians.
inline float rotation_angle(const Eigen::Matrix3f& A, const Eigen::Matrix3f& B) {
  const float c = 0.5f * ((A.transpose() * B).trace() - 1.f);
  return std::acos(std::clamp(c, -1.f, 1.f));
}

/// The smallest angle between R_cam_obj and any pose equivalent to A_cam_obj under the symmetries (R and
/// A * S render identically for a symmetry S): min over S of angle(R, A S); with a continuous axis a the
/// rotations about it are free, leaving the angle between the axis as posed by R and by A S.
inline float symmetric_rotation_distance(const Eigen::Matrix3f& R, const Eigen::Matrix3f& A,
                                         const ModelSymmetries& sym) {
  std::vector<Eigen::Matrix3f> group{Eigen::Matrix3f::Identity()};
  for (const auto& S : sym.discrete) group.push_back(S.linear());
  // Two independent continuous axes (a sphere-like model): every rotation is equivalent.
  for (std::size_t i = 0; i < sym.continuous_axes.size(); ++i)
    for (std::size_t j = 0; j < i; ++j)
      if (sym.continuous_axes[i].normalized().cross(sym.continuous_axes[j].normalized()).norm() > 1e-3f)
        return 0.f;
  float best = 4.f;
  for (const auto& S : group) {
    const Eigen::Matrix3f AS = A * S;
    if (sym.continuous_axes.empty()) {
      best = std::min(best, rotation_angle(R, AS));
    } else {
      const Eigen::Vector3f a = sym.continuous_axes.front().normalized();
      best = std::min(best, std::acos(std::clamp((R * a).dot(AS * a), -1.f, 1.f)));
    }
  }
  return best;
}

/// Every viewpoint x in-plane rotation R_view_obj, before symmetry de-duplication (see rotation_proposals).
/// Viewpoint v's in-plane angles are inplane_offset(R0) + 2 pi k / inplane_rotations, R0 its rotation at
/// angle 0 (radians about the view's z axis).
template <class Offset>
std::vector<Eigen::Matrix3f> view_rotations(const ProposalSettings& s, Offset&& inplane_offset) {
  validate(s);
  std::vector<Eigen::Matrix3f> out;
  for (const Eigen::Vector3f& v : fibonacci_directions(s.viewpoints, s.hemisphere)) {
    // R_obj_view columns: x, y, z of the view frame in object coordinates; z looks at the object (-v).
    const Eigen::Vector3f z = -v;
    const Eigen::Vector3f helper =
        std::abs(z.z()) < 0.9f ? Eigen::Vector3f::UnitZ() : Eigen::Vector3f::UnitX();
    const Eigen::Vector3f x = helper.cross(z).normalized(), y = z.cross(x);
    Eigen::Matrix3f R_obj_view;
    R_obj_view << x, y, z;
    const float offset = inplane_offset(Eigen::Matrix3f(R_obj_view.transpose()));
    for (int k = 0; k < s.inplane_rotations; ++k) {
      const float theta = offset + 6.2831853f * float(k) / float(s.inplane_rotations);
      out.push_back(Eigen::AngleAxisf(theta, Eigen::Vector3f::UnitZ()).toRotationMatrix() *
                    R_obj_view.transpose());
    }
  }
  return out;
}

inline std::vector<Eigen::Matrix3f> view_rotations(const ProposalSettings& s) {
  return view_rotations(s, [](const Eigen::Matrix3f&) { return 0.f; });
}

/// The threshold rotation_proposals() uses: settings.symmetry_threshold_rad, or if that is < 0, 0.95 x the
/// smallest angle between two of `all` (the view rotations).
inline float symmetry_threshold(const ProposalSettings& s, const std::vector<Eigen::Matrix3f>& all) {
  if (s.symmetry_threshold_rad >= 0) return s.symmetry_threshold_rad;
  float spacing = 3.1415927f;
  for (std::size_t i = 0; i < all.size(); ++i)
    for (std::size_t j = 0; j < i; ++j) spacing = std::min(spacing, rotation_angle(all[i], all[j]));
  return 0.95f * spacing;
}

namespace proposal_detail {

inline void check_symmetries(const ModelSymmetries& symmetries) {
  for (const auto& a : symmetries.continuous_axes)
    if (!a.allFinite() || !(a.norm() > 1e-6f))
      throw InvalidInput("ModelSymmetries::continuous_axes", "an axis is zero or not finite");
  for (const auto& S : symmetries.discrete)
    if (!is_valid_pose(S))
      throw InvalidInput("ModelSymmetries::discrete", "a symmetry is not a rigid transform");
}

/// `all` in order without a rotation within `threshold` of a kept one under the symmetries.
inline std::vector<Eigen::Matrix3f> distinct_rotations(const std::vector<Eigen::Matrix3f>& all,
                                                       float threshold, const ModelSymmetries& symmetries) {
  std::vector<Eigen::Matrix3f> kept;
  for (const Eigen::Matrix3f& R : all) {
    const bool duplicate = std::any_of(kept.begin(), kept.end(), [&](const Eigen::Matrix3f& A) {
      return symmetric_rotation_distance(R, A, symmetries) < threshold;
    });
    if (!duplicate) kept.push_back(R);
  }
  return kept;
}

}  // namespace proposal_detail

/// Rotation proposals R_view_obj: object -> a "view" frame whose z axis is the viewing ray (OpenCV: x right,
/// y down). Viewpoint v (object frame, from the object towards the camera) puts the camera's z along -v;
/// in-plane rotation k turns it about z by 2 pi k / inplane_rotations. Kept in order, a rotation is dropped
/// when it lies within symmetry_threshold() of a kept one under the model's symmetries.
/// pose_proposals() turns the view frame onto each instance's ray.
inline std::vector<Eigen::Matrix3f> rotation_proposals(const ProposalSettings& s,
                                                       const ModelSymmetries& symmetries = {}) {
  validate(s);
  proposal_detail::check_symmetries(symmetries);
  const std::vector<Eigen::Matrix3f> all = view_rotations(s);
  return proposal_detail::distinct_rotations(all, symmetry_threshold(s, all), symmetries);
}

/// Second moments of a mesh's surface about its area-weighted centre, object frame (m^2): its triangles'
/// centroids weighted by their areas (a mesh's vertices crowd where its detail is, not where its surface is).
inline Eigen::Matrix3f surface_second_moments(const Mesh& mesh) {
  Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
  Eigen::Vector3d first = Eigen::Vector3d::Zero();
  double area = 0;
  for (const Eigen::Vector3i& t : mesh.triangles) {
    const Eigen::Vector3d a = mesh.vertices[std::size_t(t[0])].cast<double>(),
                          b = mesh.vertices[std::size_t(t[1])].cast<double>(),
                          c = mesh.vertices[std::size_t(t[2])].cast<double>();
    const double w = 0.5 * (b - a).cross(c - a).norm();
    const Eigen::Vector3d m = (a + b + c) / 3.0;
    sum += w * m * m.transpose(), first += w * m, area += w;
  }
  if (!(area > 0)) return Eigen::Matrix3f::Zero();
  const Eigen::Vector3d mean = first / area;
  return Eigen::Matrix3f((sum / area - mean * mean.transpose()).cast<float>());
}

/// The long axis of 2-D second moments (sxx, sxy, syy), radians from the x axis towards y, in (-pi/2, pi/2].
inline float principal_angle(double sxx, double sxy, double syy) {
  return float(0.5 * std::atan2(2.0 * sxy, sxx - syy));
}

/// rotation_proposals() whose in-plane angles start, per viewpoint, where the model's long axis as the
/// view projects it (from `moments_obj`, surface_second_moments()) lies along `image_angle_rad` (the long
/// axis of the instance's pixels, principal_angle()): two in-plane angles then cover an elongated object
/// seen side-on in any orientation, which 2 fixed ones (0 and 180 deg) leave up to 90 deg off. The
/// de-duplication threshold is rotation_proposals()'s.
inline std::vector<Eigen::Matrix3f> aligned_rotation_proposals(const ProposalSettings& s,
                                                               const ModelSymmetries& symmetries,
                                                               const Eigen::Matrix3f& moments_obj,
                                                               float image_angle_rad) {
  validate(s);
  proposal_detail::check_symmetries(symmetries);
  if (!std::isfinite(image_angle_rad)) throw InvalidInput("aligned proposals", "image angle is not finite");
  const std::vector<Eigen::Matrix3f> all = view_rotations(s, [&](const Eigen::Matrix3f& R_view_obj) {
    const Eigen::Matrix3f m = R_view_obj * moments_obj * R_view_obj.transpose();
    return image_angle_rad - principal_angle(m(0, 0), m(0, 1), m(1, 1));
  });
  return proposal_detail::distinct_rotations(all, symmetry_threshold(s, view_rotations(s)), symmetries);
}

/// proposal_depths() from a mask's valid depth readings, ascending (not empty), metres.
inline std::vector<float> proposal_depths_sorted(const std::vector<float>& z, const Mesh& mesh,
                                                 const ProposalSettings& s) {
  auto quantile = [&](float q) { return z[std::size_t(std::lround(q * float(z.size() - 1)))]; };
  const float z_near = quantile(s.depth_quantile_near), z_far = quantile(s.depth_quantile_far);
  const Eigen::Vector3f size = mesh.bounds().sizes();
  float sides[3] = {size.x(), size.y(), size.z()};
  std::sort(sides, sides + 3);
  float radius = 0;
  for (const auto& p : mesh.vertices) radius = std::max(radius, p.norm());
  const float hi = std::max(z_near, std::min(z_far + 0.5f * sides[1], z_near + radius));
  const float span = hi - z_near;
  int n = int(std::floor(span / s.depth_step_m + 1e-4f)) + 1;
  n = std::min(n, s.max_depths);
  std::vector<float> out;
  // Evenly over the range, centred when the step does not divide it.
  const float step = n > 1 ? std::min(s.depth_step_m, span / float(n - 1)) : 0.f;
  const float start = z_near + 0.5f * (span - step * float(n - 1));
  for (int i = 0; i < n; ++i) out.push_back(start + step * float(i));
  return out;
}

/// Depths (planar z, metres) of an object's centre seen in `mask` (non-zero = inside): from the robust
/// nearest observed depth z_near to the robust farthest z_far plus half the model's thickness, every
/// depth_step_m (a wider range is sampled with max_depths evenly spaced values).
/// Why the extra half thickness: the depth image sees the object's front surface, and its centre (the
/// model origin: BOP models are centred on their bounding box) lies behind that surface by about half the
/// object's extent along the ray; z_far alone would miss it for a thick object seen face-on (z_near ~
/// z_far). The thickness is the middle bounding-box side (a robust guess for the extent along an unknown
/// viewing direction). The range is capped at z_near + the model's radius (no model point is farther from
/// the centre, so the centre is at most that far behind the nearest point of the object).
/// Throws InvalidInput for an empty mask, a mask of the wrong size or a mask without valid depth.
inline std::vector<float> proposal_depths(const DepthImage& depth_m, const Image<std::uint8_t>& mask,
                                          const Mesh& mesh, const ProposalSettings& s,
                                          const std::string& who = "instance mask") {
  validate(s);
  check_size(mask, depth_m.width, depth_m.height, who);
  std::vector<float> z;
  bool any = false;
  for (std::size_t i = 0; i < mask.data.size(); ++i) {
    if (!mask.data[i]) continue;
    any = true;
    if (depth_m.data[i] > 0 && std::isfinite(depth_m.data[i])) z.push_back(depth_m.data[i]);
  }
  if (!any) throw InvalidInput(who, "is empty (no pixel inside)");
  if (z.empty()) throw InvalidInput(who, "has no valid depth reading inside it");
  std::sort(z.begin(), z.end());
  return proposal_depths_sorted(z, mesh, s);
}

/// The pixel centre of a box (x, y, w, h) as BOP writes it (w = x_max - x_min), pixels.
inline Eigen::Vector2f box_centre_px(const Eigen::Vector4i& box_xywh) {
  return {float(box_xywh[0]) + 0.5f * float(box_xywh[2]), float(box_xywh[1]) + 0.5f * float(box_xywh[3])};
}

/// The rotation taking the camera's optical axis (z) onto the ray through pixel `centre_px` by the
/// smallest turn: a proposal seen through an off-centre box keeps its viewpoint relative to the line of
/// sight.
inline Eigen::Matrix3f ray_alignment(const Intrinsics& camera, const Eigen::Vector2f& centre_px) {
  const Vec3f r = camera.ray(centre_px.x(), centre_px.y());
  const Eigen::Vector3f ray = Eigen::Vector3f(r.x, r.y, r.z).normalized();
  return Eigen::Quaternionf::FromTwoVectors(Eigen::Vector3f::UnitZ(), ray).toRotationMatrix();
}

/// Every rotation x depth combination as T_cam_obj: the object's centre on the ray through centre_px at
/// planar depth z, rotated by ray_alignment * R_view_obj. Depth-major within a rotation (rotation r,
/// depth d at index r * depths.size() + d).
inline std::vector<Pose> pose_proposals(const Intrinsics& camera, const Eigen::Vector2f& centre_px,
                                        const std::vector<Eigen::Matrix3f>& rotations,
                                        const std::vector<float>& depths) {
  camera.validate("proposal camera");
  if (!centre_px.allFinite()) throw InvalidInput("proposal box centre", "is not finite");
  const Eigen::Matrix3f align = ray_alignment(camera, centre_px);
  const Vec3f r = camera.ray(centre_px.x(), centre_px.y());
  const Eigen::Vector3f ray(r.x, r.y, r.z);  // z = 1: t = z * ray has planar depth z
  std::vector<Pose> out;
  out.reserve(rotations.size() * depths.size());
  for (const auto& R : rotations)
    for (const float z : depths) {
      Pose T = Pose::Identity();
      T.linear() = align * R;
      T.translation() = z * ray;
      out.push_back(T);
    }
  return out;
}

}  // namespace perch2
