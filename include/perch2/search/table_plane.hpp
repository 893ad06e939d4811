// The table frame from a depth image: the dominant plane by RANSAC, refined by least squares on its inliers,
// oriented with z towards the camera (BOP world convention: z up, table top at z = 0).
#pragma once

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/pose.hpp"

namespace perch2 {

struct TablePlaneSettings {
  int stride = 4;                   ///< depth pixels sampled every stride pixels in u and v (>= 1)
  int iterations = 300;             ///< RANSAC plane hypotheses (>= 1)
  float inlier_distance_m = 0.01f;  ///< a point within this of the plane supports it, metres
  /// The plane must hold at least this fraction of the sampled readings, else there is "no table".
  float min_inlier_fraction = 0.2f;
  int min_inliers = 50;        ///< ... and at least this many sampled readings
  std::uint32_t seed = 12345;  ///< RANSAC random seed (results are deterministic)
};

struct TablePlane {
  Eigen::Vector3f normal_cam = Eigen::Vector3f::UnitZ();  ///< unit normal towards the camera side
  float offset_m = 0;  ///< plane: normal_cam . p + offset_m = 0 (offset_m > 0: camera above the plane)
  /// Table frame -> camera: z = normal_cam, origin = the inliers' centroid projected onto the plane, x = the
  /// camera's x axis projected onto the plane.
  Pose T_cam_world = Pose::Identity();
  int inliers = 0;  ///< sampled readings within inlier_distance_m
  int samples = 0;  ///< sampled readings
};

namespace table_detail {

/// Least-squares plane (normal, offset) through points; the normal is the covariance's smallest eigenvector.
inline void fit_plane(const std::vector<Eigen::Vector3f>& pts, Eigen::Vector3f& n, float& d) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : pts) mean += p.cast<double>();
  mean /= double(pts.size());
  Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
  for (const auto& p : pts) {
    const Eigen::Vector3d q = p.cast<double>() - mean;
    C += q * q.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
  n = es.eigenvectors().col(0).cast<float>().normalized();
  d = -n.dot(mean.cast<float>());
}

inline std::vector<Eigen::Vector3f> inliers_of(const std::vector<Eigen::Vector3f>& pts,
                                               const Eigen::Vector3f& n, float d, float tol) {
  std::vector<Eigen::Vector3f> out;
  for (const auto& p : pts)
    if (std::abs(n.dot(p) + d) <= tol) out.push_back(p);
  return out;
}

/// The sampled readings (every stride pixels in u and v), camera frame, metres.
inline std::vector<Eigen::Vector3f> sampled_points(const RgbdFrame& frame, int stride) {
  std::vector<Eigen::Vector3f> pts;
  for (int v = 0; v < frame.camera.height; v += stride)
    for (int u = 0; u < frame.camera.width; u += stride)
      if (const float z = frame.depth_m(u, v); z > 0) {
        const Vec3f p = z * frame.camera.ray(float(u), float(v));
        pts.emplace_back(p.x, p.y, p.z);
      }
  return pts;
}

/// The plane RANSAC finds among `pts` (iterations draws from `rng`), refined twice by least squares on its
/// inliers and oriented towards the camera; `inliers` = 0 if no draw gave a plane.
inline TablePlane ransac_plane(const std::vector<Eigen::Vector3f>& pts, const TablePlaneSettings& s,
                               std::mt19937& rng) {
  TablePlane out;
  out.samples = int(pts.size());
  if (pts.size() < 3) return out;
  std::uniform_int_distribution<std::size_t> pick(0, pts.size() - 1);
  std::size_t best = 0;
  Eigen::Vector3f best_n = Eigen::Vector3f::UnitZ();
  float best_d = 0;
  for (int it = 0; it < s.iterations; ++it) {
    const std::size_t i = pick(rng);
    const std::size_t j = pick(rng);
    const std::size_t k = pick(rng);
    const Eigen::Vector3f n = (pts[j] - pts[i]).cross(pts[k] - pts[i]);
    if (!(n.norm() > 1e-9f)) continue;
    const Eigen::Vector3f u = n.normalized();
    const float d = -u.dot(pts[i]);
    std::size_t count = 0;
    for (const auto& p : pts) count += std::abs(u.dot(p) + d) <= s.inlier_distance_m;
    if (count > best) best = count, best_n = u, best_d = d;
  }
  if (best < 3) return out;
  std::vector<Eigen::Vector3f> in = inliers_of(pts, best_n, best_d, s.inlier_distance_m);
  for (int pass = 0; pass < 2; ++pass) {  // least squares, then once more on the refined inlier set
    fit_plane(in, out.normal_cam, out.offset_m);
    in = inliers_of(pts, out.normal_cam, out.offset_m, s.inlier_distance_m);
  }
  if (out.offset_m < 0) out.normal_cam = -out.normal_cam, out.offset_m = -out.offset_m;  // camera side
  out.inliers = int(in.size());
  Eigen::Vector3f centroid = Eigen::Vector3f::Zero();
  for (const auto& p : in) centroid += p;
  centroid /= float(std::max<std::size_t>(in.size(), 1));
  const Eigen::Vector3f z = out.normal_cam;
  Eigen::Vector3f x = Eigen::Vector3f::UnitX() - z.dot(Eigen::Vector3f::UnitX()) * z;
  if (x.norm() < 1e-3f) x = Eigen::Vector3f::UnitZ() - z.dot(Eigen::Vector3f::UnitZ()) * z;
  x.normalize();
  out.T_cam_world.linear().col(0) = x;
  out.T_cam_world.linear().col(1) = z.cross(x);
  out.T_cam_world.linear().col(2) = z;
  out.T_cam_world.translation() = centroid - (z.dot(centroid) + out.offset_m) * z;
  return out;
}

inline void check(const TablePlaneSettings& s) {
  if (s.stride < 1 || s.iterations < 1 || s.min_inliers < 3 || !(s.inlier_distance_m > 0) ||
      !(s.min_inlier_fraction >= 0 && s.min_inlier_fraction <= 1))
    throw InvalidInput("TablePlaneSettings",
                       "needs stride >= 1, iterations >= 1, min_inliers >= 3, "
                       "inlier_distance_m > 0 and min_inlier_fraction in [0, 1]");
}

/// The readings a plane must hold: min_inliers and min_inlier_fraction of the samples.
inline std::size_t needed_inliers(const TablePlaneSettings& s, std::size_t samples) {
  return std::max(std::size_t(s.min_inliers), std::size_t(std::ceil(s.min_inlier_fraction * float(samples))));
}

}  // namespace table_detail

/// Fits the table plane to the frame's depth. Throws InvalidInput on a malformed frame or bad settings, and
/// when no plane holds enough readings ("no table visible").
inline TablePlane estimate_table_plane(const RgbdFrame& frame, const TablePlaneSettings& s = {}) {
  frame.validate("table plane frame");
  table_detail::check(s);
  const std::vector<Eigen::Vector3f> pts = table_detail::sampled_points(frame, s.stride);
  const std::size_t needed = table_detail::needed_inliers(s, pts.size());
  if (pts.size() < needed || pts.size() < 3)
    throw InvalidInput("table plane", "no table visible: only " + std::to_string(pts.size()) +
                                          " depth readings sampled (need " + std::to_string(needed) + ")");
  std::mt19937 rng(s.seed);
  const TablePlane plane = table_detail::ransac_plane(pts, s, rng);
  if (std::size_t(plane.inliers) < needed)
    throw InvalidInput("table plane",
                       "no table visible: the best plane holds " + std::to_string(plane.inliers) + " of " +
                           std::to_string(pts.size()) + " readings (need " + std::to_string(needed) + ")");
  return plane;
}

/// Up to max_planes planes, largest first: each is RANSAC's plane among the sampled readings that no earlier
/// one holds (within inlier_distance_m), kept while it holds enough of all the samples (min_inliers,
/// min_inlier_fraction). The first is estimate_table_plane()'s. Empty: no plane. Throws InvalidInput on a
/// malformed frame or bad settings.
inline std::vector<TablePlane> estimate_planes(const RgbdFrame& frame, const TablePlaneSettings& s,
                                               int max_planes) {
  frame.validate("plane frame");
  table_detail::check(s);
  std::vector<Eigen::Vector3f> pts = table_detail::sampled_points(frame, s.stride);
  const std::size_t samples = pts.size(), needed = table_detail::needed_inliers(s, samples);
  std::vector<TablePlane> planes;
  std::mt19937 rng(s.seed);
  while (int(planes.size()) < max_planes && pts.size() >= needed && pts.size() >= 3) {
    TablePlane plane = table_detail::ransac_plane(pts, s, rng);
    if (std::size_t(plane.inliers) < needed) break;
    plane.samples = int(samples);
    std::vector<Eigen::Vector3f> rest;  // the readings no plane holds yet
    for (const auto& p : pts)
      if (std::abs(plane.normal_cam.dot(p) + plane.offset_m) > s.inlier_distance_m) rest.push_back(p);
    pts = std::move(rest);
    planes.push_back(plane);
  }
  return planes;
}

}  // namespace perch2
