// The last refinement of a selected pose: a robust point-to-plane fit of the observed points onto the
// model's surface (observed -> model, not rendered -> observed as GICP does).
//
//   perch2::SurfaceFit<perch2::cpu::Backend> fit({mesh, ...});      // surface samples indexed once
//   perch2::SurfaceFitResult r = fit.fit(observed, {model, ...}, {T_cam_obj, ...},
//   perch2::SurfaceFitSettings{});
//
// Why this direction: every observed reading of the object lies on the model's surface (up to noise), while
// a rendered point at a silhouette or in a hole of the depth image has no true partner, and a rendered
// cloud on a stride grid carries its own sampling error. So each observed point o of cloud c (camera
// frame) is moved into the object frame, q = T^-1 o, and paired with the closest triangle of the model:
// the exact closest point on each triangle owning one of the `neighbours` nearest surface samples (samples
// ~1.5 mm apart, indexed once by the backend's KnnIndex) decides. The residual is r = d . (q - p) with p
// that closest point and d the smooth surface normal at p where p lies inside the triangle (corner normals
// averaged over the adjacent faces within smooth_angle_rad, interpolated), else (q - p) / |q - p| at an
// edge or corner (a reading beyond the silhouette is as far as it is). The pose minimises sum_i w_i r_i^2 by
// iteratively reweighted Gauss-Newton:
//   - a pair farther apart than max_distance_m, or whose triangle turns away from the camera at the current
//     pose (n . R^T o >= 0: the camera cannot see that surface, so the reading is not of it), is not used;
//   - w_i is Tukey's biweight of r_i / (tukey_c * s), s = max(1.4826 median |r_i|, min_scale_m): a robust
//     scale from the residuals themselves, so a reading that disagrees with the surface by more than a few
//     noise widths (a mask bled onto the table or a neighbour, clutter touching the object, a mixed-depth
//     edge pixel) gets no say, whatever the sensor's noise level;
//   - the step is T <- T * exp(delta) with delta in the object frame (pivot: the model origin), solved in
//     double on the eigenvectors of the normal equations (rotations scaled by the readings' RMS radius)
//     whose eigenvalue is at least min_curvature_ratio of the largest: a direction the geometry does not
//     constrain (a can's turn about its axis) does not move, so a turn found from colour is kept.
// Edge readings are not down-weighted on purpose: on a real Kinect the silhouette's readings are the only
// lateral constraint on a smooth object (measured on the LINEMOD cat frames: dropping readings within 2 px
// of a depth jump or hole moved the fitted poses 0.3 mm further from the ground truth, halving their weight
// 0.1 mm), and the robust weight already rejects the mixed ones that are off the surface.
#pragma once

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "perch2/core/cloud.hpp"
#include "perch2/core/error.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/knn/knn.hpp"

namespace perch2 {

struct SurfaceFitSettings {
  int iterations = 20;  ///< Gauss-Newton steps per pose (>= 0; 0 = no fit)
  /// Observed points farther than this from the model's surface (at the current pose) are not used,
  /// metres. Covers the selected pose's error (a few millimetres) with margin.
  float max_distance_m = 0.01f;
  /// Tukey's constant in units of the robust scale s (4.685: 95% efficiency under Gaussian noise).
  float tukey_c = 4.685f;
  /// Floor of the robust scale s, metres (below the sensor's noise: keeps the weights finite on clean data).
  float min_scale_m = 0.0005f;
  int neighbours = 8;   ///< nearest surface samples per point whose triangles are tried (1..64)
  int min_points = 12;  ///< fewer usable pairs: the pose is left as it is (>= 6)
  /// Directions of the step whose curvature (eigenvalue of the scaled normal equations) is below this times
  /// the largest are not moved (in (0, 1)).
  float min_curvature_ratio = 1e-3f;
  float translation_epsilon_m = 1e-5f;  ///< converged when a step moves less than this, metres ...
  /// ... and turns less than this, radians (1e-4 rad moves a 6 cm radius by 6 um: below the jitter of
  /// correspondences switching triangles)
  float rotation_epsilon_rad = 1e-4f;
  /// Largest step per iteration (a bad start cannot jump away), metres and radians.
  float max_step_m = 0.005f, max_step_rad = 0.05f;
};

/// Per observed cloud: the fitted pose and how it was reached.
struct SurfaceFitResult {
  std::vector<Pose> T_cam_obj;          ///< the fitted pose (the start if the fit had too few pairs)
  std::vector<int> iterations;          ///< Gauss-Newton steps taken
  std::vector<int> inliers;             ///< pairs with a non-zero weight at the last step
  std::vector<float> scale_m;           ///< the robust residual scale s at the last step, metres
  std::vector<std::uint8_t> converged;  ///< 1 if the last step was below the epsilons
};

namespace surface_fit_detail {

/// Points on every triangle of `mesh` about `spacing_m` apart, with the triangle's index: with a the
/// corner opposite the longest edge, the centres a + s (b - a) + r (c - a) of an n_b x n_c grid
/// (n = ceil(edge length / spacing)) that lie inside the triangle, or its centroid when none does. Long thin
/// triangles (a can's sides) get samples along their length only. Degenerate triangles give none.
inline void sample_surface(const Mesh& mesh, float spacing_m, std::vector<Eigen::Vector3f>& points,
                           std::vector<std::int32_t>& triangle) {
  for (std::size_t f = 0; f < mesh.triangles.size(); ++f) {
    const Eigen::Vector3i& t = mesh.triangles[f];
    Eigen::Vector3f v[3] = {mesh.vertices[std::size_t(t[0])], mesh.vertices[std::size_t(t[1])],
                            mesh.vertices[std::size_t(t[2])]};
    const Eigen::Vector3f cross = (v[1] - v[0]).cross(v[2] - v[0]);
    const float norm = cross.norm();
    if (!(norm > 0.f)) continue;
    int apex = 0;  // opposite the longest edge
    float longest = -1.f;
    for (int k = 0; k < 3; ++k)
      if (const float e = (v[(k + 1) % 3] - v[(k + 2) % 3]).norm(); e > longest) longest = e, apex = k;
    const Eigen::Vector3f a = v[apex], ab = v[(apex + 1) % 3] - a, ac = v[(apex + 2) % 3] - a;
    const int nb = std::max(1, int(std::ceil(ab.norm() / spacing_m)));
    const int nc = std::max(1, int(std::ceil(ac.norm() / spacing_m)));
    const std::size_t before = points.size();
    for (int i = 0; i < nb; ++i)
      for (int j = 0; j < nc; ++j) {
        const float s = (float(i) + 0.5f) / float(nb), r = (float(j) + 0.5f) / float(nc);
        if (s + r >= 1.f) continue;
        points.push_back(a + s * ab + r * ac);
        triangle.push_back(std::int32_t(f));
      }
    if (points.size() == before) points.push_back(a + (ab + ac) / 3.f), triangle.push_back(std::int32_t(f));
  }
}

inline void check(const SurfaceFitSettings& s) {
  const std::string who = "SurfaceFitSettings";
  if (s.iterations < 0) throw InvalidInput(who + "::iterations", "must be >= 0");
  auto positive = [&](float v, const char* name) {
    if (!(std::isfinite(v) && v > 0)) throw InvalidInput(who + "::" + name, "must be finite and > 0");
  };
  positive(s.max_distance_m, "max_distance_m");
  positive(s.tukey_c, "tukey_c");
  positive(s.min_scale_m, "min_scale_m");
  if (!(s.min_curvature_ratio > 0 && s.min_curvature_ratio < 1))
    throw InvalidInput(who + "::min_curvature_ratio", "must be in (0, 1)");
  positive(s.max_step_m, "max_step_m");
  positive(s.max_step_rad, "max_step_rad");
  if (!(std::isfinite(s.translation_epsilon_m) && s.translation_epsilon_m >= 0) ||
      !(std::isfinite(s.rotation_epsilon_rad) && s.rotation_epsilon_rad >= 0))
    throw InvalidInput(who + "::*_epsilon_*", "must be finite and >= 0");
  if (s.neighbours < 1 || s.neighbours > 64) throw InvalidInput(who + "::neighbours", "must be in [1, 64]");
  if (s.min_points < 6) throw InvalidInput(who + "::min_points", "must be >= 6 (six unknowns)");
}

/// Tukey's biweight of residual r at cut-off c.
inline double tukey_weight(double r, double c) {
  const double u = r / c;
  return std::abs(u) < 1.0 ? (1.0 - u * u) * (1.0 - u * u) : 0.0;
}

/// Closest point of triangle (a, b, c) to p (Ericson, Real-Time Collision Detection, 5.1.5).
inline Eigen::Vector3d closest_on_triangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                           const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + ab * (d1 / (d1 - d3));
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + ac * (d2 / (d2 - d6));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
  const double denom = 1 / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

/// A model triangle in double: corners, unit normal and the smooth normals at its corners (object frame).
struct Triangle {
  Eigen::Vector3d a, b, c, n;
  Eigen::Vector3d na = Eigen::Vector3d::Zero(), nb = Eigen::Vector3d::Zero(), nc = Eigen::Vector3d::Zero();
};

/// The direction in which the distance from the surface grows at q, given its closest point p on triangle
/// t: where p is inside t, the smooth normal there (its corner normals interpolated: a faceted can is
/// fitted as the cylinder it stands for, whose turn about its axis changes no distance); where an edge or
/// corner is closest, (q - p) / |q - p|, so the residual is the whole distance (a reading beyond the
/// silhouette would nearly satisfy a plane through the edge).
inline Eigen::Vector3d distance_direction(const Eigen::Vector3d& q, const Eigen::Vector3d& p,
                                          const Triangle& t) {
  const Eigen::Vector3d e = q - p;
  const double norm = e.norm();
  if (norm > 0.0 && (e - t.n.dot(e) * t.n).norm() > 1e-9 * std::max(norm, 1e-3)) return e / norm;
  // Barycentric coordinates of p (Ericson 3.4).
  const Eigen::Vector3d v0 = t.b - t.a, v1 = t.c - t.a, v2 = p - t.a;
  const double d00 = v0.dot(v0), d01 = v0.dot(v1), d11 = v1.dot(v1), d20 = v2.dot(v0), d21 = v2.dot(v1);
  const double den = d00 * d11 - d01 * d01;
  const double v = (d11 * d20 - d01 * d21) / den, w = (d00 * d21 - d01 * d20) / den;
  const Eigen::Vector3d n = (1.0 - v - w) * t.na + v * t.nb + w * t.nc;
  return n.norm() > 0 && n.normalized().dot(t.n) > 0.1 ? Eigen::Vector3d(n.normalized()) : t.n;
}

}  // namespace surface_fit_detail

template <class Backend>
class SurfaceFit {
 public:
  /// Samples every model's surface about `sample_spacing_m` apart (metres; finer than the sensor's pixel
  /// footprint: 1.5 mm is ~1 px at 0.9 m) and indexes the samples once, one segment per model. Throws
  /// InvalidInput on no models, a bad mesh or a spacing that is not > 0.
  /// Faces meeting at less than `smooth_angle_rad` (default 30 deg: a 64-sided can's facets, 5.6 deg, are
  /// one smooth side; a box's faces, 90 deg, stay flat) share their corner normals.
  explicit SurfaceFit(const std::vector<Mesh>& models, float sample_spacing_m = 0.0015f,
                      float smooth_angle_rad = 0.5235988f)
      : index_(samples_of(models, sample_spacing_m, smooth_angle_rad)) {}

  std::size_t num_samples(int model) const {
    return std::size_t(offsets_[std::size_t(model) + 1] - offsets_[std::size_t(model)]);
  }

  /// Fits cloud c of `observed` (camera frame, metres) onto model[c] from T_cam_obj[c]. Throws InvalidInput
  /// on mismatched sizes, an unknown model, a non-finite point or start pose, or bad settings.
  SurfaceFitResult fit(const CloudBatch& observed, const std::vector<int>& model, std::vector<Pose> T_cam_obj,
                       const SurfaceFitSettings& s) const {
    using namespace surface_fit_detail;
    check(s);
    validate_knn_cloud(observed, "surface fit: observed clouds");
    const std::size_t C = observed.num_clouds();
    if (model.size() != C || T_cam_obj.size() != C)
      throw InvalidInput("surface fit", "needs one model and one start pose per observed cloud (" +
                                            std::to_string(C) + "), got " + std::to_string(model.size()) +
                                            " and " + std::to_string(T_cam_obj.size()));
    for (std::size_t c = 0; c < C; ++c) {
      if (model[c] < 0 || std::size_t(model[c]) + 1 >= offsets_.size())
        throw InvalidInput("surface fit",
                           "cloud " + std::to_string(c) + ": unknown model " + std::to_string(model[c]));
      if (!is_valid_pose(T_cam_obj[c]))
        throw InvalidInput("surface fit",
                           "cloud " + std::to_string(c) + ": start pose is not rigid and finite");
    }
    SurfaceFitResult out;
    out.iterations.assign(C, 0), out.inliers.assign(C, 0), out.scale_m.assign(C, 0.f);
    out.converged.assign(C, 0);
    std::vector<Eigen::Isometry3d> T(C);
    for (std::size_t c = 0; c < C; ++c) T[c] = T_cam_obj[c].cast<double>();
    std::vector<bool> active(C, true);
    KnnSettings ks;
    ks.k = s.neighbours;
    ks.max_distance_m = s.max_distance_m;
    for (int it = 0; it < s.iterations; ++it) {
      CloudBatch queries;  // the active clouds' points in their object frames
      std::vector<std::int32_t> segment;
      std::vector<std::size_t> which;
      for (std::size_t c = 0; c < C; ++c) {
        if (!active[c]) continue;
        const Eigen::Isometry3d inv = T[c].inverse();
        for (auto i = observed.offsets[c]; i < observed.offsets[c + 1]; ++i) {
          const Eigen::Vector3d q = inv * Eigen::Vector3d(observed.x[i], observed.y[i], observed.z[i]);
          queries.x.push_back(float(q.x())), queries.y.push_back(float(q.y())),
              queries.z.push_back(float(q.z()));
        }
        queries.offsets.push_back(std::int64_t(queries.x.size()));
        segment.push_back(model[c]);
        which.push_back(c);
      }
      if (which.empty()) break;
      const KnnResult nn = index_.knn(queries, segment, ks);
      for (std::size_t a = 0; a < which.size(); ++a) {
        const std::size_t c = which[a];
        if (!step(observed, c, queries, a, nn, s, T[c], out)) active[c] = false;
      }
    }
    out.T_cam_obj.resize(C);
    for (std::size_t c = 0; c < C; ++c) {
      Pose P = T[c].cast<float>();
      P.linear() = Eigen::Quaternionf(P.linear()).normalized().toRotationMatrix();
      out.T_cam_obj[c] = P;
    }
    return out;
  }

 private:
  /// One IRLS Gauss-Newton step of cloud c (its queries are query cloud a). Returns false once the cloud
  /// is done (converged or too few pairs).
  bool step(const CloudBatch& observed, std::size_t c, const CloudBatch& queries, std::size_t a,
            const KnnResult& nn, const SurfaceFitSettings& s, Eigen::Isometry3d& T,
            SurfaceFitResult& out) const {
    using namespace surface_fit_detail;
    const Eigen::Matrix3d Rt = T.linear().transpose();
    struct Pair {
      Eigen::Vector3d q, n;
      double r;
    };
    const auto begin = queries.offsets[a], end = queries.offsets[a + 1];
    const std::int64_t first_observed = observed.offsets[c];
    // Each point's pair on its own (exact closest points in double: most of a step's time), in parallel;
    // gathered in point order below, so the sums are the same whatever the threads.
    std::vector<Pair> slot(std::size_t(end - begin));
    std::vector<char> paired(slot.size(), 0);
#ifdef _OPENMP
#pragma omp parallel for schedule(static) if (end - begin >= 512)
#endif
    for (auto i = begin; i < end; ++i) {
      const Eigen::Vector3d q(queries.x[i], queries.y[i], queries.z[i]);
      const std::int64_t o = first_observed + (i - begin);
      const Eigen::Vector3d view = Rt * Eigen::Vector3d(observed.x[o], observed.y[o], observed.z[o]);
      double best = double(s.max_distance_m);
      const Triangle* closest = nullptr;
      Eigen::Vector3d foot;
      for (int k = 0; k < nn.k; ++k) {  // the closest of the nearest samples' triangles
        const std::int32_t j = nn.index[std::size_t(i) * std::size_t(nn.k) + std::size_t(k)];
        if (j < 0) break;
        const Triangle& t = triangles_[std::size_t(sample_triangle_[std::size_t(j)])];
        const Eigen::Vector3d c = closest_on_triangle(q, t.a, t.b, t.c);
        if (const double d = (q - c).norm(); d <= best) best = d, closest = &t, foot = c;
      }
      if (closest && closest->n.dot(view) < 0.0) {  // a surface the camera cannot see explains no reading
        const Eigen::Vector3d n = distance_direction(q, foot, *closest);
        slot[std::size_t(i - begin)] = {q, n, n.dot(q - foot)}, paired[std::size_t(i - begin)] = 1;
      }
    }
    std::vector<Pair> pairs;
    for (std::size_t k = 0; k < slot.size(); ++k)
      if (paired[k]) pairs.push_back(slot[k]);
    if (int(pairs.size()) < s.min_points) return false;
    std::vector<double> abs_r(pairs.size());
    for (std::size_t p = 0; p < pairs.size(); ++p) abs_r[p] = std::abs(pairs[p].r);
    std::nth_element(abs_r.begin(), abs_r.begin() + std::ptrdiff_t(abs_r.size() / 2), abs_r.end());
    const double scale = std::max(1.4826 * abs_r[abs_r.size() / 2], double(s.min_scale_m));
    const double cut = double(s.tukey_c) * scale;
    Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> g = Eigen::Matrix<double, 6, 1>::Zero();
    int inliers = 0;
    for (const Pair& p : pairs) {
      const double w = tukey_weight(p.r, cut);
      if (w <= 0.0) continue;
      ++inliers;
      // q' = exp(-delta) q ~ q - w x q - v, so dr/dw = -(q x n), dr/dv = -n.
      Eigen::Matrix<double, 6, 1> J;
      J << -p.q.cross(p.n), -p.n;
      H += w * J * J.transpose();
      g += w * J * p.r;
    }
    out.inliers[c] = inliers, out.scale_m[c] = float(scale);
    if (inliers < s.min_points) return false;
    // Rotations in units of the displacement they cause (times the readings' RMS radius about the pivot,
    // metres like the translations), then solved on the constrained eigen-directions only.
    double r2 = 0;
    for (const Pair& p : pairs) r2 += p.q.squaredNorm();
    const double L = std::max(std::sqrt(r2 / double(pairs.size())), 1e-6);
    Eigen::Matrix<double, 6, 1> unit;
    unit << 1 / L, 1 / L, 1 / L, 1, 1, 1;  // a turn of w moves the readings by ~ L w
    const Eigen::Matrix<double, 6, 6> Hs = unit.asDiagonal() * H * unit.asDiagonal();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eig(Hs);
    const Eigen::Matrix<double, 6, 1> gs = unit.asDiagonal() * g;
    Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
    const double floor = double(s.min_curvature_ratio) * eig.eigenvalues()(5);
    for (int e = 0; e < 6; ++e)
      if (eig.eigenvalues()(e) > floor && eig.eigenvalues()(e) > 0)
        delta -= eig.eigenvectors().col(e) * (eig.eigenvectors().col(e).dot(gs) / eig.eigenvalues()(e));
    delta = unit.asDiagonal() * delta;
    if (!delta.allFinite()) return false;
    Eigen::Vector3d w = delta.head<3>(), v = delta.tail<3>();
    if (w.norm() > double(s.max_step_rad)) w *= double(s.max_step_rad) / w.norm();
    if (v.norm() > double(s.max_step_m)) v *= double(s.max_step_m) / v.norm();
    // q' = Rd^T q - v, i.e. T' = T * [Rd | Rd v].
    Eigen::Isometry3d step = Eigen::Isometry3d::Identity();
    if (w.norm() > 0) step.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
    step.translation() = step.linear() * v;
    T = T * step;
    ++out.iterations[c];
    const bool done = w.norm() < double(s.rotation_epsilon_rad) && v.norm() < double(s.translation_epsilon_m);
    out.converged[c] = done;
    return !done;
  }

  CloudBatch samples_of(const std::vector<Mesh>& models, float spacing_m, float smooth_angle_rad) {
    if (models.empty()) throw InvalidInput("surface fit", "no models given");
    if (!(std::isfinite(spacing_m) && spacing_m > 0))
      throw InvalidInput("surface fit sample_spacing_m", "must be finite and > 0");
    if (!(smooth_angle_rad >= 0 && smooth_angle_rad <= 3.1415927f))
      throw InvalidInput("surface fit smooth_angle_rad", "must be in [0, pi]");
    CloudBatch b;
    for (std::size_t m = 0; m < models.size(); ++m) {
      models[m].validate();
      const std::size_t before = points_.size(), first_triangle = triangles_.size();
      const Mesh& mesh = models[m];
      // Area-weighted face normals (the cross product is twice the area) and the faces at each vertex.
      std::vector<Eigen::Vector3d> face(mesh.triangles.size());
      std::vector<std::vector<std::int32_t>> faces_at(mesh.vertices.size());
      for (std::size_t f = 0; f < mesh.triangles.size(); ++f) {
        const Eigen::Vector3i& t = mesh.triangles[f];
        const Eigen::Vector3d a = mesh.vertices[std::size_t(t[0])].cast<double>();
        face[f] = (mesh.vertices[std::size_t(t[1])].cast<double>() - a)
                      .cross(mesh.vertices[std::size_t(t[2])].cast<double>() - a);
        for (int k = 0; k < 3; ++k) faces_at[std::size_t(t[k])].push_back(std::int32_t(f));
      }
      const double smooth_cos = std::cos(double(smooth_angle_rad));
      // A corner's normal: the faces at the vertex within smooth_angle_rad of this face (a crease stays
      // sharp).
      auto corner = [&](std::size_t f, int vertex) {
        const Eigen::Vector3d own = face[f].normalized();
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        for (const std::int32_t g : faces_at[std::size_t(vertex)])
          if (face[std::size_t(g)].norm() > 0 && face[std::size_t(g)].normalized().dot(own) >= smooth_cos)
            sum += face[std::size_t(g)];
        return sum.norm() > 0 ? Eigen::Vector3d(sum.normalized()) : own;
      };
      for (std::size_t f = 0; f < mesh.triangles.size(); ++f) {
        const Eigen::Vector3i& t = mesh.triangles[f];
        surface_fit_detail::Triangle d;
        d.a = mesh.vertices[std::size_t(t[0])].cast<double>();
        d.b = mesh.vertices[std::size_t(t[1])].cast<double>();
        d.c = mesh.vertices[std::size_t(t[2])].cast<double>();
        const Eigen::Vector3d n = (d.b - d.a).cross(d.c - d.a);
        d.n = n.norm() > 0 ? Eigen::Vector3d(n.normalized()) : Eigen::Vector3d::Zero();
        if (face[f].norm() > 0) d.na = corner(f, t[0]), d.nb = corner(f, t[1]), d.nc = corner(f, t[2]);
        triangles_.push_back(d);
      }
      std::vector<std::int32_t> local;
      surface_fit_detail::sample_surface(models[m], spacing_m, points_, local);
      for (const std::int32_t f : local) sample_triangle_.push_back(std::int32_t(first_triangle) + f);
      if (points_.size() == before)
        throw InvalidInput("surface fit model " + std::to_string(m), "has no triangle with an area");
      offsets_.push_back(std::int64_t(points_.size()));
    }
    for (const auto& p : points_) b.x.push_back(p.x()), b.y.push_back(p.y()), b.z.push_back(p.z());
    b.offsets = offsets_;
    return b;
  }

  std::vector<Eigen::Vector3f> points_;                  ///< surface samples (object frames), models in order
  std::vector<std::int32_t> sample_triangle_;            ///< per sample: its triangle (into triangles_)
  std::vector<surface_fit_detail::Triangle> triangles_;  ///< every model's triangles, models in order
  std::vector<std::int64_t> offsets_{0};                 ///< per model: samples [offsets[m], offsets[m + 1])
  typename Backend::KnnIndex index_;
};

}  // namespace perch2
