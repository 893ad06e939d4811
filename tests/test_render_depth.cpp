// Rendered depth against an independent double-precision ray caster (Möller–Trumbore per triangle).
//
// The contract (issue "renderer depth"): every rendered sample lies within 1e-4 x depth of the nearest
// front-facing surface hit by the same pixel ray in double precision, except where that ray meets a triangle
// within 1 degree of grazing or passes within kEdgePx of a triangle's edge (there the float and double
// answers may legitimately pick different triangles). Samples the reference sees robustly must be
// rendered (no holes), and nothing may be rendered where the reference sees no surface at all.
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "perch2/io/io.hpp"
#include "render_fixtures.hpp"
#include "test_support.hpp"

using namespace perch2;

namespace {

constexpr double kRelTol = 1e-4;     // depth error bound, relative to depth
constexpr double kEdgePx = 0.001;    // samples this close (pixels) to a triangle edge are not judged
constexpr double kGrazingDeg = 1.0;  // rays this close to a triangle's plane are not judged
constexpr double kInf = std::numeric_limits<double>::infinity();

/// Per stride-grid sample: nearest robust hit and nearest hit that cannot be judged (edge or grazing).
struct ReferenceSample {
  double robust = kInf, excluded = kInf;
};

/// Double-precision ray cast of one posed mesh over the stride grid, with the renderer's culling rule
/// (triangles whose plane faces away from the camera are skipped).
std::vector<ReferenceSample> reference_cast(const Mesh& mesh, const Pose& T_cam_obj, const Intrinsics& K,
                                            int stride, double near_m) {
  const int gw = K.grid_width(stride), gh = K.grid_height(stride);
  std::vector<ReferenceSample> out(std::size_t(gw) * gh);
  const Eigen::Matrix3d R = T_cam_obj.linear().cast<double>();
  const Eigen::Vector3d t = T_cam_obj.translation().cast<double>();
  std::vector<Eigen::Vector3d> p(mesh.vertices.size());
  for (std::size_t k = 0; k < p.size(); ++k) p[k] = R * mesh.vertices[k].cast<double>() + t;
  const double fx = K.fx, fy = K.fy, cx = K.cx, cy = K.cy;
  const double sin_grazing = std::sin(kGrazingDeg * M_PI / 180.0);
  for (const auto& f : mesh.triangles) {
    const Eigen::Vector3d a = p[f[0]], b = p[f[1]], c = p[f[2]];
    if (a.z() < near_m || b.z() < near_m || c.z() < near_m) continue;  // test poses keep meshes in front
    const Eigen::Vector3d e1 = b - a, e2 = c - a, n = e1.cross(e2);
    if (!(n.dot(a) < 0)) continue;  // back-facing or degenerate: culled, as in the renderer
    Eigen::Vector2d q[3];
    const Eigen::Vector3d v[3] = {a, b, c};
    for (int k = 0; k < 3; ++k) q[k] = {fx * v[k].x() / v[k].z() + cx, fy * v[k].y() / v[k].z() + cy};
    const double u0 = std::min({q[0].x(), q[1].x(), q[2].x()}) - 1,
                 u1 = std::max({q[0].x(), q[1].x(), q[2].x()}) + 1;
    const double v0 = std::min({q[0].y(), q[1].y(), q[2].y()}) - 1,
                 v1 = std::max({q[0].y(), q[1].y(), q[2].y()}) + 1;
    const int i0 = std::max(0, int(std::ceil(u0 / stride))),
              i1 = std::min(gw - 1, int(std::floor(u1 / stride)));
    const int j0 = std::max(0, int(std::ceil(v0 / stride))),
              j1 = std::min(gh - 1, int(std::floor(v1 / stride)));
    // Image-space orientation: inside is where every edge distance has the sign of the triangle's area.
    const double area = (q[1] - q[0]).x() * (q[2] - q[0]).y() - (q[1] - q[0]).y() * (q[2] - q[0]).x();
    if (area == 0) continue;
    const double orient = area > 0 ? 1 : -1;
    for (int j = j0; j <= j1; ++j)
      for (int i = i0; i <= i1; ++i) {
        const double u = double(stride) * i, w = double(stride) * j;
        double edge_px = kInf;
        for (int k = 0; k < 3; ++k) {
          const Eigen::Vector2d s = q[k], e = q[(k + 1) % 3];
          const double len = (e - s).norm();
          edge_px = std::min(edge_px, orient * ((e - s).x() * (w - s.y()) - (e - s).y() * (u - s.x())) / len);
        }
        if (edge_px < -kEdgePx) continue;  // clearly outside
        const Eigen::Vector3d d((u - cx) / fx, (w - cy) / fy, 1.0);
        const double depth = n.dot(a) / n.dot(d);  // plane hit along d, z = depth since d.z = 1
        if (!(depth >= near_m)) continue;
        const bool grazing = std::abs(n.dot(d)) < sin_grazing * n.norm() * d.norm();
        ReferenceSample& r = out[std::size_t(j) * gw + i];
        if (edge_px > kEdgePx && !grazing)
          r.robust = std::min(r.robust, depth);
        else
          r.excluded = std::min(r.excluded, depth);
      }
  }
  return out;
}

struct DepthReport {
  std::size_t judged = 0, excluded = 0, wrong = 0, holes = 0, spurious = 0;
  double worst_rel = 0, worst_abs_m = 0;
};

/// Renders every pose with backend B and compares each sample with the reference ray cast.
template <class B>
DepthReport compare_with_reference(const Mesh& mesh, const std::vector<Pose>& poses, int stride) {
  const Intrinsics K = test::vga_camera();
  typename B::Renderer renderer({mesh});
  std::vector<Hypothesis> hyps;
  for (const Pose& T : poses) hyps.push_back({0, T});
  RenderSettings settings;
  settings.stride = stride;
  const CloudBatch clouds = renderer.render(hyps, K, settings);
  DepthReport rep;
  const int gw = K.grid_width(stride);
  for (std::size_t h = 0; h < poses.size(); ++h) {
    const auto ref = reference_cast(mesh, poses[h], K, stride, settings.near_m);
    std::vector<char> rendered(ref.size(), 0);
    for (std::int64_t k = clouds.offsets[h]; k < clouds.offsets[h + 1]; ++k) {
      const int u = clouds.pixel[k] % K.width, v = clouds.pixel[k] / K.width;
      const std::size_t s = std::size_t(v / stride) * gw + std::size_t(u / stride);
      rendered[s] = 1;
      const ReferenceSample& r = ref[s];
      if (!(r.robust < r.excluded)) {  // nearest surface is an edge or grazing hit, or nothing at all
        if (r.excluded == kInf) ++rep.spurious;
        ++rep.excluded;
        continue;
      }
      ++rep.judged;
      const double err = std::abs(double(clouds.z[k]) - r.robust);
      rep.worst_abs_m = std::max(rep.worst_abs_m, err);
      rep.worst_rel = std::max(rep.worst_rel, err / r.robust);
      if (err > kRelTol * r.robust) ++rep.wrong;
    }
    for (std::size_t s = 0; s < ref.size(); ++s)
      if (!rendered[s] && ref[s].robust < ref[s].excluded) ++rep.holes;
  }
  return rep;
}

void check_report(const DepthReport& r) {
  MESSAGE("judged " << r.judged << " samples (" << r.excluded << " on edges or grazing): " << r.wrong
                    << " off by more than 1e-4 x depth, worst " << r.worst_abs_m * 1e3 << " mm ("
                    << r.worst_rel << " x depth), " << r.holes << " holes, " << r.spurious << " spurious");
  CHECK(r.judged > 0);
  CHECK(r.wrong == 0);
  CHECK(r.holes == 0);
  CHECK(r.spurious == 0);
  CHECK(r.excluded < r.judged / 50);  // exclusions stay a small minority (< 1% seen)
}

/// Random poses `z_min..z_max` away with the model's centre near the optical axis.
std::vector<Pose> random_poses(const Mesh& mesh, int n, float z_min, float z_max, unsigned seed) {
  std::mt19937 rng(seed);
  std::vector<Pose> out;
  const Eigen::Vector3f centre = mesh.bounds().center();
  for (int k = 0; k < n; ++k) {
    Pose T = test::random_pose(rng, z_min, z_max, 0.f);
    std::uniform_real_distribution<float> u(-0.2f, 0.2f);
    const Eigen::Vector3f shift{u(rng) * T.translation().z(), u(rng) * T.translation().z(), 0.f};
    T.translation() += shift - T.linear() * centre;
    out.push_back(T);
  }
  return out;
}

}  // namespace

TEST_CASE_TEMPLATE("rendered depth matches a double-precision ray cast on random blobs", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  std::mt19937 rng(11);
  for (int k = 0; k < 3; ++k) {
    const Mesh blob = test::make_blob(rng, 0.05f, 40, 60);  // 4,680 triangles of a few mm
    check_report(compare_with_reference<B>(blob, random_poses(blob, 20, 0.35f, 1.6f, 100 + k), 2));
  }
}

TEST_CASE_TEMPLATE("rendered depth matches a double-precision ray cast on the bench's lumpy sphere", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  const Mesh sphere = test::lumpy_sphere(0.06f, 71, 72);
  check_report(compare_with_reference<B>(sphere, random_poses(sphere, 40, 0.5f, 1.0f, 7), 4));
}

TEST_CASE_TEMPLATE("rendered depth matches a double-precision ray cast on the scanned LINEMOD cat", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/linemod_obj_06/obj_06.ply");
  io::MeshLoadOptions mm;
  mm.scale = 0.001f;
  const Mesh cat = io::load_mesh(path, mm);
  check_report(compare_with_reference<B>(cat, random_poses(cat, 100, 0.35f, 1.6f, 3), 2));
}

TEST_CASE_TEMPLATE("rendered depth matches a double-precision ray cast on the scanned YCB banana", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/ycb_011_banana/textured_simple.obj");
  const Mesh banana = io::load_mesh(path);
  check_report(compare_with_reference<B>(banana, random_poses(banana, 100, 0.35f, 1.6f, 5), 2));
}
