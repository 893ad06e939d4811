// Rendered depth against an independent double-precision ray caster (Möller–Trumbore per triangle).
//
// The contract (issue "renderer depth"): every rendered sample whose ray, cast in double precision, first
// hits a front-facing triangle at a regular point — more than kEdgePx inside its edges and more than 1 degree
// from grazing — lies within 1e-4 x depth of that hit. Samples whose first hit is irregular are not judged
// (there float and double may legitimately pick different triangles), but a triangle that the double ray
// misses, even by a hair, must not claim a sample in front of a regular hit. Samples the reference sees
// regularly must be rendered (no holes), and nothing may be rendered where the reference sees no surface
// within kEdgePx.
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
constexpr double kEdgePx = 0.001;    // hits this close (pixels) to a triangle edge are not regular
constexpr double kGrazingDeg = 1.0;  // hits this close to a triangle's plane are not regular
constexpr double kInf = std::numeric_limits<double>::infinity();

/// Per stride-grid sample: the nearest hit (the ray inside a triangle's edges), whether it is regular, and
/// the nearest triangle the ray misses by less than kEdgePx.
struct ReferenceSample {
  double hit = kInf, near_miss = kInf;
  bool regular = false;
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
        ReferenceSample& r = out[std::size_t(j) * gw + i];
        if (edge_px < 0) {
          r.near_miss = std::min(r.near_miss, depth);
        } else if (depth < r.hit) {
          r.hit = depth;
          r.regular = edge_px > kEdgePx && std::abs(n.dot(d)) >= sin_grazing * n.norm() * d.norm();
        }
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
      if (!r.regular) {  // the first hit is on an edge or grazing, or there is none
        if (r.hit == kInf && r.near_miss == kInf) ++rep.spurious;
        ++rep.excluded;
        continue;
      }
      ++rep.judged;
      const double err = std::abs(double(clouds.z[k]) - r.hit);
      rep.worst_abs_m = std::max(rep.worst_abs_m, err);
      rep.worst_rel = std::max(rep.worst_rel, err / r.hit);
      if (err > kRelTol * r.hit) {
        ++rep.wrong;
        MESSAGE("pose " << h << " (centre " << poses[h].translation().z() << " m), pixel (" << u << ", " << v
                        << "): rendered " << clouds.z[k] << " m, first regular hit " << r.hit << " m");
      }
    }
    for (std::size_t s = 0; s < ref.size(); ++s)
      if (!rendered[s] && ref[s].regular) ++rep.holes;
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

/// A model stored in millimetres (the LINEMOD meshes), in metres.
Mesh load_mm_mesh(const std::string& path) {
  io::MeshLoadOptions mm;
  mm.scale = 0.001f;
  return io::load_mesh(path, mm);
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

// 400 poses, as the outside check of issue 22 used: pose 16 of seed 1039 holds a sample that float edge tests
// gave to a grazing silhouette triangle 19.9 mm in front of the surface its ray hits (now decided exactly).
TEST_CASE_TEMPLATE("rendered depth matches a double-precision ray cast on the scanned LINEMOD cat", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/linemod_obj_06/obj_06.ply");
  const Mesh cat = load_mm_mesh(path);
  check_report(compare_with_reference<B>(cat, random_poses(cat, 400, 0.35f, 1.6f, 1039), 2));
}

// The same sample with its pose written out (random_poses' sequence depends on the standard library): at
// pixel (374, 184) the ray passes 1e-6 px outside a triangle seen 0.27 deg from edge-on and hits the cat
// 19.9 mm behind it at 45 deg; float edge planes put the sample inside the grazing triangle.
TEST_CASE_TEMPLATE("a grazing silhouette triangle does not claim a sample its edges miss (LINEMOD cat)", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/linemod_obj_06/obj_06.ply");
  const Mesh cat = load_mm_mesh(path);
  Pose T = Pose::Identity();
  T.matrix().topRows<3>() << 0x1.6888bcp-1f, -0x1.6831bcp-1f, 0x1.897c84p-4f, 0x1.7b961ap-4f,  //
      -0x1.4c94b8p-1f, -0x1.62c5f4p-1f, -0x1.406fdcp-2f, -0x1.5a5c2cp-4f,                      //
      0x1.259794p-2f, 0x1.437bf4p-3f, -0x1.e3cadp-1f, 0x1.a1b54ap-1f;
  typename B::Renderer renderer({cat});
  RenderSettings stride2;
  stride2.stride = 2;
  const CloudBatch cloud = renderer.render({{0, T}}, test::vga_camera(), stride2);
  const int pixel = 184 * 640 + 374;
  const auto at = std::find(cloud.pixel.begin(), cloud.pixel.end(), pixel);
  REQUIRE(at != cloud.pixel.end());
  CHECK(cloud.z[std::size_t(at - cloud.pixel.begin())] == doctest::Approx(0.829473).epsilon(1e-5));
  check_report(compare_with_reference<B>(cat, {T}, 2));
}

// 400 poses, as for the cat and the outside check of issue 22.
TEST_CASE_TEMPLATE("rendered depth matches a double-precision ray cast on the scanned YCB banana", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/ycb_011_banana/textured_simple.obj");
  const Mesh banana = io::load_mesh(path);
  check_report(compare_with_reference<B>(banana, random_poses(banana, 400, 0.35f, 1.6f, 5), 2));
}
