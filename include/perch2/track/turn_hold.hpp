// Holding the turn that the geometry cannot see. A printed can or bottle fits its readings equally well
// turned about its axis, so GICP lets the turn wander with the sensor's noise, and the constant-velocity
// prediction repeats every wander: within a few frames the label faces the wrong way. Each frame the
// tracked objects whose model is printed are turned about their flat axes (flat_axes(): the model axes
// about which the mesh looks the same turned) by +-step, halving over `levels`, and the turn whose rendered
// colours correlate best with the frame's (perch2/cost/appearance.hpp, weighted where the print varies) is
// kept. The same measure as the 6-DoF search's local search, over a few degrees instead of a full turn.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "perch2/core/image.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/cost/appearance.hpp"
#include "perch2/registration/surface_fit.hpp"
#include "perch2/render/render.hpp"

namespace perch2 {
namespace track_detail {

/// The model axes (0 = x, 1 = y, 2 = z, through the model origin) about which the mesh looks the same
/// turned by 10 and 25 degrees: its surface samples (1/50 of its size apart) land within a sample spacing of
/// the surface, on average. A can's or bottle's axis; none for a box or a scanned animal.
inline std::vector<int> flat_axes(const Mesh& mesh) {
  if (mesh.vertices.empty()) return {};
  const float size = mesh.bounds().sizes().maxCoeff();
  if (!(size > 0.f)) return {};
  const float spacing = size / 50.f;
  std::vector<Eigen::Vector3f> points;
  std::vector<std::int32_t> triangle;
  surface_fit_detail::sample_surface(mesh, spacing, points, triangle);
  if (points.empty()) return {};
  // A hash grid of the samples (cell = spacing) for nearest-sample queries within two cells.
  auto key = [&](const Eigen::Vector3f& p, int dx, int dy, int dz) {
    const auto c = [&](float x, int d) { return std::int64_t(std::floor(x / spacing)) + d; };
    return (c(p.x(), dx) * 73856093) ^ (c(p.y(), dy) * 19349663) ^ (c(p.z(), dz) * 83492791);
  };
  std::unordered_multimap<std::int64_t, std::size_t> grid;
  for (std::size_t i = 0; i < points.size(); ++i) grid.emplace(key(points[i], 0, 0, 0), i);
  auto nearest = [&](const Eigen::Vector3f& q) {
    float best = 2.f * spacing;  // farther counts as 2 spacings
    for (int dx = -2; dx <= 2; ++dx)
      for (int dy = -2; dy <= 2; ++dy)
        for (int dz = -2; dz <= 2; ++dz) {
          const auto range = grid.equal_range(key(q, dx, dy, dz));
          for (auto it = range.first; it != range.second; ++it)
            best = std::min(best, (points[it->second] - q).norm());
        }
    return best;
  };
  const std::size_t step = std::max<std::size_t>(1, points.size() / 2000);  // enough queries to average
  std::vector<int> out;
  for (int axis = 0; axis < 3; ++axis) {
    bool flat = true;
    for (const float degrees : {10.f, 25.f}) {
      const Eigen::Matrix3f R =
          Eigen::AngleAxisf(degrees * 3.14159265f / 180.f, Eigen::Vector3f::Unit(axis)).toRotationMatrix();
      double sum = 0;
      std::size_t n = 0;
      for (std::size_t i = 0; i < points.size(); i += step, ++n) sum += double(nearest(R * points[i]));
      flat = flat && sum / double(n) < double(spacing);
    }
    if (flat) out.push_back(axis);
  }
  return out;
}

/// Whether a model shows a print or colours (the appearance can see its turn).
inline bool printed(const Mesh& mesh) {
  return mesh.has_texture() || mesh.has_vertex_colors();
}

/// T_cam_obj moved to `T_new` without the turn about the model's `axis` that the move holds: the geometry
/// cannot see that turn, so a registration's turn about it is the sensor's noise (swing-twist
/// decomposition of the move in the model frame; the model origin stays where T_new puts it).
inline Pose without_turn(const Pose& T, const Pose& T_new, int axis) {
  const Eigen::Quaternionf q(Eigen::Matrix3f(T.linear().transpose() * T_new.linear()));  // model frame
  const Eigen::Vector3f e = Eigen::Vector3f::Unit(axis);
  Eigen::Quaternionf twist(q.w(), 0.f, 0.f, 0.f);
  twist.vec() = q.vec().dot(e) * e;
  if (twist.norm() < 1e-9f) return T_new;  // a half turn about a perpendicular axis: no twist to remove
  twist.normalize();
  const Eigen::Quaternionf swing = q * twist.conjugate();
  Pose out = T_new;
  out.linear() = T.linear() * swing.normalized().toRotationMatrix();
  return out;
}

/// The pose turned by `angle_rad` about the model's own `axis`.
inline Pose turned(Pose T, int axis, float angle_rad) {
  T.linear() = T.linear() * Eigen::AngleAxisf(angle_rad, Eigen::Vector3f::Unit(axis)).toRotationMatrix();
  return T;
}

}  // namespace track_detail
}  // namespace perch2
