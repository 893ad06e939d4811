// SE(3) at the host API (Eigen) and its POD twin for device code.
#pragma once

#include <Eigen/Geometry>
#include <cmath>

#include "perch2/core/device.hpp"

namespace perch2 {

using Pose = Eigen::Isometry3f;  ///< e.g. T_cam_obj: object frame -> camera frame

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
