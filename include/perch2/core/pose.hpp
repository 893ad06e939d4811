// SE(3) at the host API (Eigen) and its POD twin for device code.
#pragma once

#include <Eigen/Geometry>
#include <cmath>

#include "perch2/core/device.hpp"

namespace perch2 {

/// A rigid transform, e.g. T_cam_obj: object frame -> camera frame. Used like Eigen::Isometry3f (and
/// converts to and from it implicitly), but stored unaligned (Eigen::DontAlign): Eigen aligns a 4x4 float
/// matrix to 16, 32 or 64 bytes depending on the vectorisation flags (SSE, AVX, AVX-512), so an aligned
/// member would sit at a different offset in a consumer built with -march=native than in the library.
/// Unaligned, every struct holding a Pose (Hypothesis, RegistrationResult::T_corr) has one layout
/// whatever flags either side uses. Poses are converted to Rigid3f before any hot loop, so the unaligned
/// loads cost nothing measurable.
using Pose = Eigen::Transform<float, 3, Eigen::Isometry, Eigen::DontAlign>;
static_assert(alignof(Pose) == alignof(float) && sizeof(Pose) == 16 * sizeof(float),
              "perch2::Pose must not depend on the vectorisation flags");
// The other fixed-size Eigen types in API structs (Mesh, IcpSettings, GicpSettings) are 8 or 12 bytes:
// Eigen over-aligns only sizes that are multiples of 16 bytes, so these are never over-aligned either.
static_assert(alignof(Eigen::Vector3f) == alignof(float) && alignof(Eigen::Vector2f) == alignof(float) &&
                  alignof(Eigen::Vector3i) == alignof(int),
              "Eigen types in perch2's API structs must not depend on the vectorisation flags");

inline Rigid3f to_rigid(const Pose& T) {
  Rigid3f out{};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out.R.m[3 * r + c] = T.linear()(r, c);
  out.t = {T.translation().x(), T.translation().y(), T.translation().z()};
  return out;
}

inline Pose to_pose(const Rigid3f& T) {
  Pose out = Pose::Identity();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out.linear()(r, c) = T.R.m[3 * r + c];
  out.translation() = Eigen::Vector3f(T.t.x, T.t.y, T.t.z);
  return out;
}

/// True if the pose has a finite translation and an orthonormal rotation (det +1) to within tol.
inline bool is_valid_pose(const Pose& T, float tol = 1e-3f) {
  if (!T.matrix().allFinite()) return false;
  const Eigen::Matrix3f R = T.linear();
  return (R * R.transpose() - Eigen::Matrix3f::Identity()).cwiseAbs().maxCoeff() < tol &&
         std::abs(R.determinant() - 1.f) < tol;
}

inline Vec3f to_vec3(const Eigen::Vector3f& v) {
  return {v.x(), v.y(), v.z()};
}

}  // namespace perch2
