// The final surface fit (perch2/registration/surface_fit.hpp): a robust point-to-plane fit of observed
// readings onto a model's surface, on a frame with what a real sensor adds (depth noise, mixed-depth
// readings at the silhouette, a mask bleeding onto a surface just behind, clutter in front), against an
// independent long-double reference that minimises the same robust objective over exact point-to-triangle
// distances by brute force.
#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <omp.h>

#include "perch2/cpu/render.hpp"
#include "perch2/registration/surface_fit.hpp"
#include "render_fixtures.hpp"
#include "test_support.hpp"

using namespace perch2;
using perch2::test::vga_camera;

namespace {

constexpr float kDeg = 3.14159265f / 180.f;

/// A smooth bumpy ellipsoid (17 x 11 x 6 cm, ~4 mm triangles), like a scanned model's surface, with no
/// symmetry: every direction of the pose is constrained.
Mesh object() {
  Mesh m = perch2::test::lumpy_sphere(0.06f, 48, 48);
  for (auto& v : m.vertices) v = v.cwiseProduct(Eigen::Vector3f(1.4f, 0.9f, 0.5f));
  return m;
}

Pose true_pose() {
  Pose T = perch2::test::pose_at(0.03f, -0.02f, 0.7f, Eigen::Vector3f(1.f, 2.f, 0.5f), 40 * kDeg);
  return T;
}

/// Mean distance between the model's vertices at two poses (ADD), metres.
double add_m(const Mesh& m, const Pose& a, const Pose& b) {
  double sum = 0;
  for (const auto& v : m.vertices) sum += double((a * v - b * v).norm());
  return sum / double(m.vertices.size());
}

/// The readings of a mask around the object rendered at T: every `stride`-th pixel of the object dilated by
/// 3 px (the mask bleeds onto a surface 5 mm behind the object's silhouette), depth noise of 1 mm, readings
/// on the silhouette mixed half-way with that surface, and a quarter of the object hidden by clutter 6 mm in
/// front. Camera frame, metres, one cloud.
CloudBatch sensor_readings(const Mesh& m, const Pose& T, int stride, bool outliers, unsigned seed) {
  cpu::Renderer renderer({m});
  RenderSettings rs;
  rs.stride = 1;
  const CloudBatch r = renderer.render({Hypothesis{0, T}}, vga_camera(), rs);
  const Intrinsics K = vga_camera();
  std::vector<float> z(std::size_t(K.width * K.height), 0.f);
  for (std::size_t i = 0; i < r.size(); ++i) z[std::size_t(r.pixel[i])] = r.z[i];
  auto at = [&](int u, int v) {
    return u < 0 || v < 0 || u >= K.width || v >= K.height ? 0.f : z[std::size_t(v * K.width + u)];
  };
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.f, 0.001f);
  CloudBatch out;
  float u_min = 1e9f, u_max = -1e9f;
  for (std::size_t i = 0; i < r.size(); ++i) {
    const float u = float(r.pixel[i] % K.width);
    u_min = std::min(u_min, u), u_max = std::max(u_max, u);
  }
  for (int v = 0; v < K.height; v += stride)
    for (int u = 0; u < K.width; u += stride) {
      float d = at(u, v), behind = 0.f;  // the nearest object depth within 3 px, for the surface behind
      bool edge = false;
      for (int dv = -3; dv <= 3; ++dv)
        for (int du = -3; du <= 3; ++du) {
          const float n = at(u + du, v + dv);
          if (n > 0) behind = std::max(behind, n + 0.005f);
          if (std::abs(du) + std::abs(dv) == 1 && n == 0) edge = true;
        }
      if (d == 0 && behind == 0) continue;
      if (d == 0) {
        if (!outliers) continue;
        d = behind;  // the bled mask's readings of the surface behind
      } else if (outliers && edge) {
        d = 0.5f * (d + behind);  // a mixed-depth reading
      } else if (outliers && float(u) > u_max - 0.25f * (u_max - u_min)) {
        d -= 0.006f;  // clutter in front, touching
      }
      d += noise(rng);
      const Vec3f p = d * K.ray(float(u), float(v));
      out.x.push_back(p.x), out.y.push_back(p.y), out.z.push_back(p.z);
      out.rgb.push_back(0), out.pixel.push_back(v * K.width + u), out.cloud.push_back(0);
    }
  out.offsets.push_back(std::int64_t(out.size()));
  return out;
}

Pose perturbed(const Pose& T, float angle, float dist) {
  Pose D = Pose::Identity();
  D.linear() = Eigen::AngleAxisf(angle, Eigen::Vector3f(0.3f, -1.f, 0.6f).normalized()).toRotationMatrix();
  D.translation() = dist * Eigen::Vector3f(-0.5f, 0.4f, 0.77f).normalized();
  Pose out = T * D;
  return out;
}

using Ld = long double;
using V3 = Eigen::Matrix<Ld, 3, 1>;

/// Closest point of triangle (a, b, c) to p (Ericson, Real-Time Collision Detection, 5.1.5).
V3 closest_on_triangle(const V3& p, const V3& a, const V3& b, const V3& c) {
  const V3 ab = b - a, ac = c - a, ap = p - a;
  const Ld d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const V3 bp = p - b;
  const Ld d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const Ld vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + ab * (d1 / (d1 - d3));
  const V3 cp = p - c;
  const Ld d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const Ld vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + ac * (d2 / (d2 - d6));
  const Ld va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
  const Ld denom = 1 / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

/// The fit's objective minimised independently: exact distances to the closest triangle (brute force over
/// all triangles, long double; a reading whose closest triangle faces away is not used), the same gate,
/// robust scale and Tukey weights, Gauss-Newton on SE(3) until the step is below 1e-12 (or 60 steps).
Pose reference_fit(const Mesh& m, const CloudBatch& obs, Pose start, const SurfaceFitSettings& s) {
  Eigen::Matrix<Ld, 3, 3> R = start.linear().cast<Ld>();
  V3 t = start.translation().cast<Ld>();
  // Corner normals: the area-weighted normals of the faces at the vertex within 30 deg of the face.
  std::vector<V3> area(m.triangles.size());
  std::vector<std::vector<std::size_t>> at(m.vertices.size());
  for (std::size_t f = 0; f < m.triangles.size(); ++f) {
    const auto& tri = m.triangles[f];
    const V3 a = m.vertices[std::size_t(tri[0])].cast<Ld>();
    area[f] = (m.vertices[std::size_t(tri[1])].cast<Ld>() - a)
                  .cross(m.vertices[std::size_t(tri[2])].cast<Ld>() - a);
    for (int k = 0; k < 3; ++k) at[std::size_t(tri[k])].push_back(f);
  }
  const Ld smooth_cos = std::cos(Ld(30) * Ld(3.14159265358979323846L) / 180);
  auto corner_normal = [&](std::size_t f, int vertex) {
    V3 sum = V3::Zero();
    for (const std::size_t g : at[std::size_t(vertex)])
      if (area[g].norm() > 0 && area[g].normalized().dot(area[f].normalized()) >= smooth_cos) sum += area[g];
    return V3(sum.normalized());
  };
  std::vector<V3> A, B, C, N, centre;
  std::vector<Ld> radius;  // bounding spheres: a triangle farther than the best so far is skipped
  for (const auto& tri : m.triangles) {
    A.push_back(m.vertices[std::size_t(tri[0])].cast<Ld>()),
        B.push_back(m.vertices[std::size_t(tri[1])].cast<Ld>());
    C.push_back(m.vertices[std::size_t(tri[2])].cast<Ld>());
    N.push_back((B.back() - A.back()).cross(C.back() - A.back()).normalized());
    centre.push_back((A.back() + B.back() + C.back()) / 3);
    radius.push_back(std::max({(A.back() - centre.back()).norm(), (B.back() - centre.back()).norm(),
                               (C.back() - centre.back()).norm()}));
  }
  for (int it = 0; it < 60; ++it) {
    struct Pair {
      V3 q, n;
      Ld r;
    };
    std::vector<Pair> pairs;
    for (std::size_t i = 0; i < obs.size(); ++i) {
      const V3 o(obs.x[i], obs.y[i], obs.z[i]);
      const V3 q = R.transpose() * (o - t), view = R.transpose() * o;
      Ld best = 1e30L;
      std::size_t bt = 0;
      V3 foot;
      for (std::size_t f = 0; f < A.size(); ++f) {
        if ((q - centre[f]).norm() - radius[f] > best) continue;
        const V3 c = closest_on_triangle(q, A[f], B[f], C[f]);
        if (const Ld d = (q - c).norm(); d < best) best = d, bt = f, foot = c;
      }
      if (best > Ld(s.max_distance_m) || N[bt].dot(view) >= 0) continue;  // too far, or an unseen surface
      // Inside the triangle: along the interpolated vertex normal; at an edge or corner: the distance.
      const V3 e = q - foot;
      const bool inside = (e - N[bt].dot(e) * N[bt]).norm() <= 1e-9L * std::max(e.norm(), Ld(1e-3));
      V3 n = e.norm() > 0 ? V3(e / e.norm()) : N[bt];
      if (inside || e.norm() == 0) {
        const auto& tri = m.triangles[bt];
        const V3 v0 = B[bt] - A[bt], v1 = C[bt] - A[bt], v2 = foot - A[bt];
        const Ld d00 = v0.dot(v0), d01 = v0.dot(v1), d11 = v1.dot(v1), d20 = v2.dot(v0), d21 = v2.dot(v1);
        const Ld den = d00 * d11 - d01 * d01, v = (d11 * d20 - d01 * d21) / den,
                 w = (d00 * d21 - d01 * d20) / den;
        const V3 s = (1 - v - w) * corner_normal(bt, tri[0]) + v * corner_normal(bt, tri[1]) +
                     w * corner_normal(bt, tri[2]);
        n = s.norm() > 0 && s.normalized().dot(N[bt]) > Ld(0.1) ? V3(s.normalized()) : N[bt];
      }
      pairs.push_back({q, n, n.dot(e)});
    }
    std::vector<Ld> ar;
    for (const auto& p : pairs) ar.push_back(std::abs(p.r));
    std::nth_element(ar.begin(), ar.begin() + std::ptrdiff_t(ar.size() / 2), ar.end());
    const Ld cut = Ld(s.tukey_c) * std::max(Ld(1.4826) * ar[ar.size() / 2], Ld(s.min_scale_m));
    Eigen::Matrix<Ld, 6, 6> H = Eigen::Matrix<Ld, 6, 6>::Zero();
    Eigen::Matrix<Ld, 6, 1> g = Eigen::Matrix<Ld, 6, 1>::Zero();
    for (const auto& p : pairs) {
      const Ld u = p.r / cut;
      if (std::abs(u) >= 1) continue;
      const Ld w = (1 - u * u) * (1 - u * u);
      Eigen::Matrix<Ld, 6, 1> J;
      J << -p.q.cross(p.n), -p.n;
      H += w * J * J.transpose(), g += w * J * p.r;
    }
    const Eigen::Matrix<Ld, 6, 1> d = -H.ldlt().solve(g);
    const V3 w = d.head<3>(), v = d.tail<3>();
    Eigen::Matrix<Ld, 3, 3> Rd = Eigen::Matrix<Ld, 3, 3>::Identity();
    if (w.norm() > 0) Rd = Eigen::AngleAxis<Ld>(w.norm(), w.normalized()).toRotationMatrix();
    t = t + R * (Rd * v), R = R * Rd;
    if (w.norm() < 1e-12L && v.norm() < 1e-12L) break;
  }
  Pose out = Pose::Identity();
  out.linear() = R.cast<float>(), out.translation() = t.cast<float>();
  return out;
}

/// The readings of the outlier cases (a quarter of them 6 mm off, see sensor_readings) and a start 2 deg and
/// 4 mm from the truth.
struct OutlierCase {
  Mesh m = object();
  Pose T = true_pose();
  CloudBatch obs = sensor_readings(m, T, 2, /*outliers=*/true, 3);
  Pose start = perturbed(T, 2.f * kDeg, 0.004f);
};

}  // namespace

TEST_CASE_TEMPLATE("surface fit: outliers and edge readings cost little", B, PERCH2_CPU_RUNNABLE_BACKENDS) {
  const OutlierCase c;
  const Mesh& m = c.m;
  const Pose& T = c.T;
  REQUIRE(c.obs.size() > 1000);
  REQUIRE(add_m(m, c.start, T) > 0.004);
  SurfaceFit<B> fit({m});
  const SurfaceFitSettings s;
  const SurfaceFitResult r = fit.fit(c.obs, {0}, {c.start}, s);
  CHECK(r.converged[0] == 1);
  CHECK(r.inliers[0] > 500);
  const double robust = add_m(m, r.T_cam_obj[0], T);
  MESSAGE("ADD to the truth: start " << 1e3 * add_m(m, c.start, T) << " mm, fitted " << 1e3 * robust
                                     << " mm, robust scale " << 1e3 * r.scale_m[0] << " mm");
  CHECK(robust < 0.8e-3);  // a quarter of the readings are 6 mm off
  // Without the robust weights the same readings pull the pose away: the weights are what keeps it.
  SurfaceFitSettings plain = s;
  plain.tukey_c = 1e6f;
  const double not_robust = add_m(m, fit.fit(c.obs, {0}, {c.start}, plain).T_cam_obj[0], T);
  MESSAGE("without robust weights: " << 1e3 * not_robust << " mm");
  CHECK(not_robust > 3 * robust);
}

// One test for both CPU backends: the brute-force reference is the suite's slow part, computed once here.
TEST_CASE("surface fit: cpu and thrust_omp equal a long-double reference on readings with outliers") {
  const OutlierCase c;
  const SurfaceFitSettings s;
  // The reference minimises the same objective over every triangle (the fit: the nearest samples' ones).
  const Pose ref = reference_fit(c.m, c.obs, c.start, s);
  const Pose cpu = SurfaceFit<cpu::Backend>({c.m}).fit(c.obs, {0}, {c.start}, s).T_cam_obj[0];
  const Pose omp = SurfaceFit<thrust_omp::Backend>({c.m}).fit(c.obs, {0}, {c.start}, s).T_cam_obj[0];
  MESSAGE("fit vs long-double reference: cpu " << 1e3 * add_m(c.m, cpu, ref) << " mm, thrust_omp "
                                               << 1e3 * add_m(c.m, omp, ref) << " mm");
  CHECK(add_m(c.m, cpu, ref) < 0.05e-3);
  CHECK(add_m(c.m, omp, ref) < 0.05e-3);
}

TEST_CASE("surface fit: the same pose bit for bit on one thread and on all (pairs found in parallel)") {
  const OutlierCase c;
  REQUIRE(c.obs.size() >= 512);  // large enough for the parallel pairing
  const SurfaceFit<thrust_omp::Backend> fit({c.m});
  const SurfaceFitResult all = fit.fit(c.obs, {0}, {c.start}, SurfaceFitSettings{});
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  const SurfaceFitResult one = fit.fit(c.obs, {0}, {c.start}, SurfaceFitSettings{});
  omp_set_num_threads(threads);
  CHECK(one.iterations[0] == all.iterations[0]);
  CHECK(one.inliers[0] == all.inliers[0]);
  CHECK(one.T_cam_obj[0].matrix() == all.T_cam_obj[0].matrix());
}

TEST_CASE("surface fit: readings without outliers give the true pose, a can's turn about its axis stays") {
  const Mesh m = object();
  const Pose T = true_pose();
  SurfaceFit<cpu::Backend> fit({m}, 0.001f);
  const CloudBatch clean = sensor_readings(m, T, 2, false, 1);
  const SurfaceFitResult r = fit.fit(clean, {0}, {perturbed(T, 1.5f * kDeg, 0.003f)}, SurfaceFitSettings{});
  CHECK(add_m(m, r.T_cam_obj[0], T) < 0.1e-3);  // 1 mm noise on ~2,300 readings
  // A closed cylinder (360 sides: facets 1 deg apart) turned about its axis fits its readings equally well:
  // the fit must not move it.
  Mesh can;
  const int sides = 360;
  for (int k = 0; k < sides; ++k) {
    const float a = 2 * 3.14159265f * float(k) / float(sides);
    can.vertices.emplace_back(0.033f * std::cos(a), 0.033f * std::sin(a), -0.06f);
    can.vertices.emplace_back(0.033f * std::cos(a), 0.033f * std::sin(a), 0.06f);
  }
  can.vertices.emplace_back(0.f, 0.f, -0.06f), can.vertices.emplace_back(0.f, 0.f, 0.06f);
  const int bottom = 2 * sides, top = bottom + 1;
  for (int k = 0; k < sides; ++k) {
    const int a = 2 * k, b = 2 * ((k + 1) % sides);
    can.triangles.emplace_back(a, b, b + 1), can.triangles.emplace_back(a, b + 1, a + 1);
    can.triangles.emplace_back(bottom, b, a), can.triangles.emplace_back(top, a + 1, b + 1);
  }
  const Pose Tc = perch2::test::pose_at(0.f, 0.f, 0.6f, Eigen::Vector3f::UnitX(), 120 * kDeg);
  const CloudBatch readings = sensor_readings(can, Tc, 2, false, 2);
  Pose turned = Tc;
  turned.linear() = Tc.linear() * Eigen::AngleAxisf(0.5f, Eigen::Vector3f::UnitZ()).toRotationMatrix();
  const Pose start = turned;
  SurfaceFit<cpu::Backend> can_fit({can}, 0.001f);
  const Pose f = can_fit.fit(readings, {0}, {start}, SurfaceFitSettings{}).T_cam_obj[0];
  CHECK((f.translation() - Tc.translation()).norm() < 0.2e-3f);
  const Eigen::Vector3f x_turned = turned.linear().col(0), x_fit = f.linear().col(0);
  CHECK(std::acos(std::min(1.f, x_turned.dot(x_fit))) < 0.5f * kDeg);  // the turn stays
}

TEST_CASE("surface fit rejects bad input with a clear error") {
  const Mesh m = object();
  CHECK_THROWS_WITH_AS(SurfaceFit<cpu::Backend>({}), doctest::Contains("no models"), InvalidInput);
  CHECK_THROWS_WITH_AS(SurfaceFit<cpu::Backend>({m}, 0.f), doctest::Contains("sample_spacing_m"),
                       InvalidInput);
  CHECK_THROWS_WITH_AS(SurfaceFit<cpu::Backend>({m}, 0.0015f, -0.1f), doctest::Contains("smooth_angle_rad"),
                       InvalidInput);
  CHECK_THROWS_WITH_AS(SurfaceFit<cpu::Backend>({m}, 0.0015f, 4.f), doctest::Contains("smooth_angle_rad"),
                       InvalidInput);
  Mesh flat = m;
  for (auto& v : flat.vertices) v.z() = 0.f, v.y() = 0.f;  // every triangle degenerate
  CHECK_THROWS_WITH_AS(SurfaceFit<cpu::Backend>({flat}), doctest::Contains("no triangle with an area"),
                       InvalidInput);
  SurfaceFit<cpu::Backend> fit({m});
  const CloudBatch obs = sensor_readings(m, true_pose(), 4, false, 1);
  const SurfaceFitSettings s;
  CHECK_THROWS_WITH_AS(fit.fit(obs, {0, 0}, {true_pose()}, s), doctest::Contains("one model and one start"),
                       InvalidInput);
  CHECK_THROWS_WITH_AS(fit.fit(obs, {1}, {true_pose()}, s), doctest::Contains("unknown model"), InvalidInput);
  Pose bad = true_pose();
  bad.linear() *= 2.f;
  CHECK_THROWS_WITH_AS(fit.fit(obs, {0}, {bad}, s), doctest::Contains("not rigid"), InvalidInput);
  CloudBatch nan = obs;
  nan.x[3] = std::nanf("");
  CHECK_THROWS_WITH_AS(fit.fit(nan, {0}, {true_pose()}, s), doctest::Contains("non-finite"), InvalidInput);
  SurfaceFitSettings wrong = s;
  wrong.tukey_c = 0.f;
  CHECK_THROWS_WITH_AS(fit.fit(obs, {0}, {true_pose()}, wrong), doctest::Contains("tukey_c"), InvalidInput);
  wrong = s, wrong.min_points = 3;
  CHECK_THROWS_WITH_AS(fit.fit(obs, {0}, {true_pose()}, wrong), doctest::Contains("min_points"),
                       InvalidInput);
  // Too few readings: the start pose comes back unchanged.
  CloudBatch few;
  for (int i = 0; i < 5; ++i)
    few.x.push_back(obs.x[std::size_t(i)]), few.y.push_back(obs.y[std::size_t(i)]),
        few.z.push_back(obs.z[std::size_t(i)]);
  few.rgb.assign(5, 0), few.pixel.assign(5, -1), few.cloud.assign(5, 0), few.offsets = {0, 5};
  const SurfaceFitResult r = fit.fit(few, {0}, {true_pose()}, s);
  CHECK(r.iterations[0] == 0);
  CHECK(r.T_cam_obj[0].isApprox(true_pose()));
}
