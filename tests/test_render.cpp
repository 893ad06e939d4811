// Batch renderer: analytic renders, stride sampling, colours, occluders, cross-backend equality, bad input.
#include <omp.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <random>

#include "perch2/io/io.hpp"
#include "render_fixtures.hpp"
#include "test_support.hpp"

using namespace perch2;
using perch2::test::vga_camera;

namespace {

RenderSettings at_stride(int stride) {
  RenderSettings s;
  s.stride = stride;
  return s;
}

/// 2-D cross product sign of (b - a) x (p - a).
float cross2(Eigen::Vector2f a, Eigen::Vector2f b, Eigen::Vector2f p) {
  return (b - a).x() * (p - a).y() - (b - a).y() * (p - a).x();
}

/// Convex hull (Andrew's monotone chain), counter-clockwise.
std::vector<Eigen::Vector2f> convex_hull(std::vector<Eigen::Vector2f> p) {
  std::sort(p.begin(), p.end(),
            [](auto& a, auto& b) { return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y()); });
  std::vector<Eigen::Vector2f> h(2 * p.size());
  std::size_t k = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    while (k >= 2 && cross2(h[k - 2], h[k - 1], p[i]) <= 0) --k;
    h[k++] = p[i];
  }
  for (std::size_t i = p.size() - 1, t = k + 1; i > 0; --i) {
    while (k >= t && cross2(h[k - 2], h[k - 1], p[i - 1]) <= 0) --k;
    h[k++] = p[i - 1];
  }
  h.resize(k - 1);
  return h;
}

/// Signed distance (pixels, > 0 inside) from p to a counter-clockwise convex polygon.
float inside_distance(const std::vector<Eigen::Vector2f>& hull, Eigen::Vector2f p) {
  float d = 1e30f;
  for (std::size_t k = 0; k < hull.size(); ++k) {
    const Eigen::Vector2f a = hull[k], b = hull[(k + 1) % hull.size()];
    d = std::min(d, cross2(a, b, p) / (b - a).norm());
  }
  return d;
}

// The backends compared here promise bit-for-bit equal results (no FMA contraction; see system.hpp). A
// perch2::cuda built with PERCH2_CUDA_FMA=ON does not (Backend::bitwise_reproducible is false there).
static_assert(cpu::Backend::bitwise_reproducible && thrust_omp::Backend::bitwise_reproducible);

/// The Thrust renderer with the GPU's pass structure, run on OpenMP (checks the CUDA path's passes).
using PassesRenderer = thrust_backend::Renderer<thrust_backend::OmpPassesSystem>;

void require_equal_batches(const CloudBatch& a, const CloudBatch& b) {
  REQUIRE(a.offsets == b.offsets);
  REQUIRE(a.size() == b.size());
  // Same float operations in the same order on both backends: equality is exact. Whole arrays compare in
  // one assertion (the element-wise form dominated the suite's time); the first difference is reported.
  if (a.x == b.x && a.y == b.y && a.z == b.z && a.rgb == b.rgb && a.pixel == b.pixel && a.cloud == b.cloud)
    return;
  for (std::size_t i = 0; i < a.size(); ++i) {
    CAPTURE(i);
    REQUIRE(a.x[i] == b.x[i]);
    REQUIRE(a.y[i] == b.y[i]);
    REQUIRE(a.z[i] == b.z[i]);
    REQUIRE(a.rgb[i] == b.rgb[i]);
    REQUIRE(a.pixel[i] == b.pixel[i]);
    REQUIRE(a.cloud[i] == b.cloud[i]);
  }
}

}  // namespace

TEST_CASE_TEMPLATE("a fronto-parallel plane renders its exact depth on every covered sample", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  const Intrinsics K = vga_camera();
  typename B::Renderer renderer({test::make_quad(2.f)});  // 2 m square at 0.8 m: covers the whole image
  for (int stride : {1, 3, 8}) {
    const CloudBatch c = renderer.render({{0, test::pose_at(0, 0, 0.8f)}}, K, at_stride(stride));
    CHECK_NOTHROW(c.validate());
    REQUIRE(c.num_clouds() == 1);
    CHECK(c.size() == std::size_t(K.grid_width(stride) * K.grid_height(stride)));
    for (std::size_t i = 0; i < c.size(); ++i) REQUIRE(c.z[i] == doctest::Approx(0.8).epsilon(1e-6));
  }
}

TEST_CASE_TEMPLATE("a cube's silhouette is its projected convex polygon and its points lie on the cube", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  const Intrinsics K = vga_camera();
  const float side = 0.1f;
  typename B::Renderer renderer({test::make_box(side, side, side)});
  std::mt19937 rng(7);
  for (int trial = 0; trial < 5; ++trial) {
    const Pose T = test::random_pose(rng, 0.4f, 0.9f, 0.1f);
    const CloudBatch c = renderer.render({{0, T}}, K, at_stride(2));
    std::vector<Eigen::Vector2f> corners;
    for (int k = 0; k < 8; ++k) {
      const Eigen::Vector3f p = T * Eigen::Vector3f((k & 1 ? .5f : -.5f) * side, (k & 2 ? .5f : -.5f) * side,
                                                    (k & 4 ? .5f : -.5f) * side);
      corners.emplace_back(K.fx * p.x() / p.z() + K.cx, K.fy * p.y() / p.z() + K.cy);
    }
    const auto hull = convex_hull(corners);
    std::map<int, std::size_t> rendered;  // pixel -> point index
    for (std::size_t i = 0; i < c.size(); ++i) rendered[c.pixel[i]] = i;
    int checked = 0;
    for (int v = 0; v < K.height; v += 2)
      for (int u = 0; u < K.width; u += 2) {
        const float d = inside_distance(hull, Eigen::Vector2f(float(u), float(v)));
        if (std::abs(d) < 1e-2f) continue;  // on the silhouette edge: either answer is right
        ++checked;
        REQUIRE_MESSAGE((d > 0) == (rendered.count(v * K.width + u) == 1), "pixel " << u << "," << v);
      }
    CHECK(checked > 1000);
    const Pose T_obj_cam = T.inverse();
    for (std::size_t i = 0; i < c.size(); ++i) {
      const Eigen::Vector3f p = T_obj_cam * Eigen::Vector3f(c.x[i], c.y[i], c.z[i]);
      REQUIRE(p.cwiseAbs().maxCoeff() == doctest::Approx(0.5f * side).epsilon(1e-4));
    }
  }
}

TEST_CASE_TEMPLATE("pixel <-> 3-D round trip", B, PERCH2_CPU_RUNNABLE_BACKENDS) {
  const Intrinsics K = vga_camera();
  std::mt19937 rng(3);
  typename B::Renderer renderer({test::make_blob(rng, 0.08f)});
  std::vector<Hypothesis> hyps;
  for (int k = 0; k < 20; ++k) hyps.push_back({0, test::random_pose(rng, 0.3f, 1.2f)});
  const CloudBatch c = renderer.render(hyps, K, at_stride(1));
  REQUIRE(c.size() > 1000);
  for (std::size_t i = 0; i < c.size(); ++i) {
    const float u = float(c.pixel[i] % K.width), v = float(c.pixel[i] / K.width);
    // Projection passes through values of the principal point's magnitude, so 1e-5 relative is taken
    // against max(|u|, cx): float rounding there is ~1.5e-5 px at most.
    const Vec2f uv = K.project(c.point(i));
    REQUIRE(std::abs(uv.x - u) <= 1e-5f * std::max(u, K.cx));
    REQUIRE(std::abs(uv.y - v) <= 1e-5f * std::max(v, K.cy));
    const Vec3f p = K.backproject(u, v, c.z[i]);
    REQUIRE(std::sqrt(squared_norm(p - c.point(i))) <= 1e-5f * std::sqrt(squared_norm(c.point(i))));
  }
}

TEST_CASE_TEMPLATE("rendering at stride s equals the full-resolution render sampled at multiples of s", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  const Intrinsics K = vga_camera();
  std::mt19937 rng(11);
  Mesh textured = test::make_box(0.12f, 0.08f, 0.05f);
  textured.vertex_colors.clear();
  textured.corner_uvs.assign(3 * textured.triangles.size(), Eigen::Vector2f(0.3f, 0.6f));
  for (std::size_t k = 0; k < textured.corner_uvs.size(); ++k)
    textured.corner_uvs[k] = Eigen::Vector2f(float(k % 3) * 0.4f + 0.1f, float(k % 5) * 0.2f + 0.05f);
  textured.texture = test::make_ramp_texture();
  typename B::Renderer renderer({test::make_blob(rng, 0.1f), textured});
  std::vector<Hypothesis> hyps;
  for (int k = 0; k < 12; ++k) hyps.push_back({k % 2, test::random_pose(rng, 0.3f, 1.0f)});
  const CloudBatch full = renderer.render(hyps, K, at_stride(1));
  for (int stride : {2, 3, 4, 8}) {
    const CloudBatch c = renderer.render(hyps, K, at_stride(stride));
    std::size_t expected = 0;
    for (std::size_t i = 0; i < full.size(); ++i) {
      const int u = full.pixel[i] % K.width, v = full.pixel[i] / K.width;
      if (u % stride || v % stride) continue;
      const std::size_t j = expected++;
      REQUIRE(j < c.size());
      REQUIRE(c.pixel[j] == full.pixel[i]);
      REQUIRE(c.cloud[j] == full.cloud[i]);
      REQUIRE(c.x[j] == full.x[i]);
      REQUIRE(c.y[j] == full.y[i]);
      REQUIRE(c.z[j] == full.z[i]);
      REQUIRE(c.rgb[j] == full.rgb[i]);
    }
    CHECK(c.size() == expected);
  }
}

TEST_CASE_TEMPLATE("colours come from the texture or interpolate the vertex colours", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  const Intrinsics K = vga_camera();
  const float size = 0.2f, z = 0.5f;
  SUBCASE("texture") {
    const Mesh quad = test::make_quad(size, test::make_ramp_texture(64));
    typename B::Renderer renderer({quad});
    const CloudBatch c = renderer.render({{0, test::pose_at(0, 0, z)}}, K, at_stride(2));
    REQUIRE(c.size() > 1000);
    int checked = 0;
    for (std::size_t i = 0; i < c.size(); ++i) {
      // Texture coordinates of the hit point: u runs with x, v against y (top of the quad is v = 1).
      const float tu = c.x[i] / size + 0.5f, tv = 0.5f - c.y[i] / size;
      if (tu < 0.05f || tu > 0.95f || tv < 0.05f || tv > 0.95f) continue;  // away from the wrap seam
      const Rgb8 rgb = unpack_rgb(c.rgb[i]);
      // Texel x has red 4x + 2, i.e. red = 4 * (tu * 64 - 0.5) + 2 = 256 tu; bilinear is exact on a ramp,
      // rounding to 8 bits gives +-1.
      REQUIRE(std::abs(float(rgb.r) - 256.f * tu) <= 1.01f);
      REQUIRE(std::abs(float(rgb.g) - 256.f * (1.f - tv)) <= 1.01f);
      REQUIRE(rgb.b == 128);
      ++checked;
    }
    CHECK(checked > 1000);
  }
  SUBCASE("vertex colours, perspective-correct on a slanted plane") {
    Mesh quad = test::make_quad(size);
    quad.vertex_colors = {{0, 0, 0}, {250, 0, 0}, {250, 0, 0}, {0, 0, 0}};  // red grows with object x
    typename B::Renderer renderer({quad});
    const Pose T = test::pose_at(0, 0, z, Eigen::Vector3f::UnitY(), 0.6f);  // slanted: depth varies with x
    const CloudBatch c = renderer.render({{0, T}}, K, at_stride(2));
    REQUIRE(c.size() > 500);
    const Pose T_obj_cam = T.inverse();
    for (std::size_t i = 0; i < c.size(); ++i) {
      const Eigen::Vector3f p = T_obj_cam * Eigen::Vector3f(c.x[i], c.y[i], c.z[i]);
      const float expected = 250.f * (p.x() / size + 0.5f);  // linear in the object frame, not the image
      REQUIRE(std::abs(float(unpack_rgb(c.rgb[i]).r) - expected) <= 1.01f);
    }
  }
  SUBCASE("base colour when the mesh has neither") {
    Mesh quad = test::make_quad(size);
    quad.base_color = {10, 20, 30};
    typename B::Renderer renderer({quad});
    const CloudBatch c = renderer.render({{0, test::pose_at(0, 0, z)}}, K, at_stride(4));
    REQUIRE(c.size() > 0);
    for (auto rgb : c.rgb) REQUIRE(rgb == pack_rgb({10, 20, 30}));
  }
}

TEST_CASE("texture lookups repeat the texture outside [0, 1] and blend the four nearest texels") {
  // A 5 x 3 texture (sizes that are not powers of two) with distinct texels; the lookup is compared with
  // the textbook bilinear formula, wrapping texel indices with a true modulo, at coordinates inside, on
  // the borders, just outside and several periods away.
  const int W = 5, H = 3;
  std::vector<Rgb8> texels;
  for (int k = 0; k < W * H; ++k)
    texels.push_back({std::uint8_t(17 * k), std::uint8_t(255 - 11 * k), std::uint8_t((k * 97) % 256)});
  MeshView m;
  m.texture = texels.data(), m.texture_width = W, m.texture_height = H;
  auto wrap = [](int i, int n) { return ((i % n) + n) % n; };
  auto reference = [&](float u, float v) {
    const double x = (double(u) - std::floor(double(u))) * W - 0.5;
    const double y = (1.0 - (double(v) - std::floor(double(v)))) * H - 0.5;
    const int xi = int(std::floor(x)), yi = int(std::floor(y));
    const double wx = x - xi, wy = y - yi;
    auto at = [&](int i, int j) { return texels[std::size_t(wrap(j, H) * W + wrap(i, W))]; };
    auto mix = [&](auto channel) {
      return (1 - wy) * ((1 - wx) * channel(at(xi, yi)) + wx * channel(at(xi + 1, yi))) +
             wy * ((1 - wx) * channel(at(xi, yi + 1)) + wx * channel(at(xi + 1, yi + 1)));
    };
    return std::array<double, 3>{mix([](Rgb8 c) { return double(c.r); }),
                                 mix([](Rgb8 c) { return double(c.g); }),
                                 mix([](Rgb8 c) { return double(c.b); })};
  };
  int checked = 0;
  for (float u :
       {-2.31f, -1.f, -0.5f, -1e-7f, 0.f, 0.05f, 0.1f, 0.37f, 0.5f, 0.9f, 0.95f, 0.9999f, 1.f, 1.63f, 7.02f})
    for (float v : {-3.4f, -1e-7f, 0.f, 0.1f, 0.2f, 0.5f, 0.83f, 0.99f, 1.f, 2.5f}) {
      const Rgb8 got = sample_texture(m, u, v);
      const std::array<double, 3> want = reference(u, v);
      // Float weights against double ones, then rounding to 8 bits: within 1.
      CHECK(std::abs(double(got.r) - want[0]) <= 1.01);
      CHECK(std::abs(double(got.g) - want[1]) <= 1.01);
      CHECK(std::abs(double(got.b) - want[2]) <= 1.01);
      ++checked;
    }
  CHECK(checked == 150);
}

TEST_CASE_TEMPLATE("observed depth and labels occlude rendered pixels", B, PERCH2_CPU_RUNNABLE_BACKENDS) {
  const Intrinsics K = vga_camera();
  typename B::Renderer renderer({test::make_quad(4.f)});  // fills the image at 1 m
  const Hypothesis hyp{0, test::pose_at(0, 0, 1.f), /*label=*/7};
  RenderSettings s = at_stride(4);
  s.occlusion_margin_m = 0.01f;
  Occluders occ;
  occ.depth_m = DepthImage(K.width, K.height, 2.f);  // behind the quad: occludes nothing
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width / 2; ++u) occ.depth_m(u, v) = 0.5f;  // left half in front of the quad
  for (int v = 0; v < K.height / 2; ++v) occ.depth_m(K.width - 1 - v, v) = 0.995f;  // nearer, within margin
  occ.depth_m(K.width - 4, K.height - 4) = 0.f;                                     // no reading
  auto count_left = [&](const CloudBatch& c) {
    return std::count_if(c.pixel.begin(), c.pixel.end(), [&](int p) { return p % K.width < K.width / 2; });
  };
  const std::size_t all = std::size_t(K.grid_width(4) * K.grid_height(4));
  const std::size_t left = std::size_t(K.grid_width(4) / 2) * std::size_t(K.grid_height(4));

  SUBCASE("depth only: everything nearer by more than the margin occludes") {
    const CloudBatch c = renderer.render({hyp}, K, s, &occ);
    CHECK(count_left(c) == 0);
    CHECK(c.size() == all - left);
  }
  SUBCASE("labels: the hypothesis' own pixels never occlude it, others and background do") {
    occ.labels = LabelImage(K.width, K.height, 0);
    for (int v = 0; v < K.height / 2; ++v)
      for (int u = 0; u < K.width / 2; ++u) occ.labels(u, v) = 7;  // top-left: the object itself
    for (int v = K.height / 2; v < K.height; ++v)
      for (int u = 0; u < K.width / 4; ++u) occ.labels(u, v) = 3;  // another object
    const CloudBatch c = renderer.render({hyp}, K, s, &occ);
    for (std::size_t i = 0; i < c.size(); ++i) {
      const int u = c.pixel[i] % K.width, v = c.pixel[i] / K.width;
      if (u < K.width / 2) REQUIRE(occ.labels(u, v) == 7);
    }
    CHECK(std::size_t(count_left(c)) == left / 2);
    CHECK(c.size() == all - left + left / 2);
  }
}

TEST_CASE_TEMPLATE("near-plane clipping keeps exactly the surface in front of the near plane", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  const Intrinsics K = vga_camera();
  RenderSettings s = at_stride(4);
  s.near_m = 0.3f;
  SUBCASE("a slanted wall crossing the near plane") {
    typename B::Renderer renderer({test::make_quad(4.f)});
    // Turned 1.2 rad about y: depth falls from 2.4 m (left) through the near plane (u ~ 477) to behind
    // the camera.
    const Pose T = test::pose_at(0, 0, 0.5f, Eigen::Vector3f::UnitY(), 1.2f);
    const CloudBatch c = renderer.render({{0, T}}, K, s);
    REQUIRE(c.size() > 1000);
    for (float zi : c.z) REQUIRE(zi >= s.near_m);
    CHECK(*std::min_element(c.z.begin(), c.z.end()) < 0.31f);  // it really reaches the near plane
    const int max_u = *std::max_element(c.pixel.begin(), c.pixel.end(), [&](int a, int b) {
      return a % K.width < b % K.width;
    }) % K.width;
    CHECK(max_u > 460);
    CHECK(max_u < 490);
  }
  SUBCASE("camera inside a box sees its inner walls when culling is off") {
    s.cull_back_faces = false;
    typename B::Renderer renderer({test::make_box(2.f, 2.f, 2.f)});
    const CloudBatch c = renderer.render({{0, Pose::Identity()}}, K, s);
    CHECK(c.size() == std::size_t(K.grid_width(4) * K.grid_height(4)));
    for (float zi : c.z) REQUIRE(zi == doctest::Approx(1.f).epsilon(1e-5));  // the far wall at z = +1
    s.cull_back_faces = true;
    CHECK(renderer.render({{0, Pose::Identity()}}, K, s).size() == 0);
  }
  SUBCASE("an object entirely behind the camera renders nothing") {
    typename B::Renderer renderer({test::make_box(0.1f, 0.1f, 0.1f)});
    const CloudBatch c = renderer.render({{0, test::pose_at(0, 0, -1.f)}}, K, s);
    CHECK(c.size() == 0);
    CHECK(c.num_clouds() == 1);
  }
}

TEST_CASE("both backends render identical batches for random meshes and poses") {
  const Intrinsics K = vga_camera();
  std::mt19937 rng(2026);
  std::vector<Mesh> models;
  for (int m = 0; m < 3; ++m)
    models.push_back(test::make_blob(rng, 0.05f + 0.03f * m, 10 + 4 * m, 12 + 6 * m));
  Mesh textured = test::make_box(0.1f, 0.2f, 0.05f);
  textured.corner_uvs.resize(3 * textured.triangles.size());
  std::uniform_real_distribution<float> uv(-0.5f, 1.5f);
  for (auto& t : textured.corner_uvs) t = Eigen::Vector2f{uv(rng), uv(rng)};
  textured.texture = test::make_ramp_texture(32);
  models.push_back(textured);

  std::vector<Hypothesis> hyps;
  std::uniform_int_distribution<int> which(0, int(models.size()) - 1);
  for (int k = 0; k < 200; ++k)
    hyps.push_back({which(rng), test::random_pose(rng, -0.2f, 1.5f, 0.4f), k % 3});
  Occluders occ;
  occ.depth_m = DepthImage(K.width, K.height, 0.f);
  occ.labels = LabelImage(K.width, K.height, 0);
  std::uniform_real_distribution<float> depth(0.f, 1.5f);
  for (auto& d : occ.depth_m.data) d = depth(rng);
  for (std::size_t k = 0; k < occ.labels.data.size(); ++k) occ.labels.data[k] = int(k / 97) % 3;

  const cpu::Renderer reference(models);
  const thrust_omp::Backend::Renderer thrust_renderer(models);
  const PassesRenderer passes_renderer(models);
  for (int stride : {1, 4}) {
    for (bool cull : {true, false}) {
      RenderSettings s = at_stride(stride);
      s.cull_back_faces = cull;
      s.near_m = 0.05f;
      CAPTURE(stride);
      CAPTURE(cull);
      const CloudBatch a = reference.render(hyps, K, s), occluded = reference.render(hyps, K, s, &occ);
      CHECK(a.size() > 1000);
      require_equal_batches(a, thrust_renderer.render(hyps, K, s));
      require_equal_batches(occluded, thrust_renderer.render(hyps, K, s, &occ));
      s.memory_budget_bytes = std::size_t(1) << 16;  // one or two hypotheses per chunk in passes
      require_equal_batches(a, passes_renderer.render(hyps, K, s));
      require_equal_batches(occluded, passes_renderer.render(hyps, K, s, &occ));
    }
  }
}

TEST_CASE("real scanned models render identically on both backends, in their own colours") {
  PERCH2_REQUIRE_SHARED_DATA(banana_path, "models/ycb_011_banana/textured_simple.obj");
  PERCH2_REQUIRE_SHARED_DATA(cat_path, "models/linemod_obj_06/obj_06.ply");
  io::MeshLoadOptions mm;
  mm.scale = 0.001f;
  std::vector<Mesh> models{io::load_mesh(banana_path), io::load_mesh(cat_path, mm)};
  const Intrinsics K = vga_camera();
  std::mt19937 rng(5);
  std::vector<Hypothesis> hyps;
  for (int k = 0; k < 40; ++k) hyps.push_back({k % 2, test::random_pose(rng, 0.4f, 0.9f, 0.1f)});
  RenderSettings s = at_stride(2);
  const cpu::Renderer reference(models);
  const thrust_omp::Backend::Renderer thrust_renderer(models);
  const CloudBatch a = reference.render(hyps, K, s);
  require_equal_batches(a, thrust_renderer.render(hyps, K, s));
  require_equal_batches(a, PassesRenderer(models).render(hyps, K, s));

  // The banana's texture is mostly yellow (red and green well above blue); the cat's vertex colours are
  // mostly pink-brown (red above green and blue). Shading is unlit, so colours are the model's own.
  int yellow = 0, banana = 0, reddish = 0, cat = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const Rgb8 c = unpack_rgb(a.rgb[i]);
    if (a.cloud[i] % 2 == 0) {
      ++banana;
      yellow += c.r > c.b + 40 && c.g > c.b + 40;
    } else {
      ++cat;
      reddish += c.r > c.g && c.r > c.b;
    }
  }
  REQUIRE(banana > 5000);
  REQUIRE(cat > 5000);
  CHECK(yellow > 0.7 * banana);
  CHECK(reddish > 0.7 * cat);
}

TEST_CASE_TEMPLATE("bad render inputs raise InvalidInput naming the input", B, PERCH2_CPU_RUNNABLE_BACKENDS) {
  const Intrinsics K = vga_camera();
  typename B::Renderer renderer({test::make_box(0.1f, 0.1f, 0.1f)});
  const Hypothesis ok{0, test::pose_at(0, 0, 0.5f)};
  const RenderSettings s;
  CHECK_THROWS_WITH_AS(renderer.render({}, K, s), doctest::Contains("no hypotheses"), InvalidInput);
  CHECK_THROWS_WITH_AS(renderer.render({{3, ok.T_cam_obj}}, K, s),
                       doctest::Contains("hypothesis 0: model index 3"), InvalidInput);
  Pose nan_pose = ok.T_cam_obj;
  nan_pose.translation().x() = std::nanf("");
  CHECK_THROWS_WITH_AS(renderer.render({ok, {0, nan_pose}}, K, s), doctest::Contains("hypothesis 1"),
                       InvalidInput);
  Pose scaled = ok.T_cam_obj;
  scaled.linear() *= 2.f;
  CHECK_THROWS_AS(renderer.render({{0, scaled}}, K, s), InvalidInput);
  RenderSettings bad = s;
  bad.stride = 0;
  CHECK_THROWS_WITH_AS(renderer.render({ok}, K, bad), doctest::Contains("stride"), InvalidInput);
  Intrinsics bad_K = K;
  bad_K.fx = 0;
  CHECK_THROWS_WITH_AS(renderer.render({ok}, bad_K, s), doctest::Contains("focal"), InvalidInput);
  Occluders occ;
  occ.depth_m = DepthImage(K.width / 2, K.height, 1.f);
  CHECK_THROWS_WITH_AS(renderer.render({ok}, K, s, &occ),
                       doctest::Contains("occluder depth: expected 640x480"), InvalidInput);
  occ.depth_m = DepthImage(K.width, K.height, 1.f);
  occ.depth_m(5, 6) = std::nanf("");
  CHECK_THROWS_WITH_AS(renderer.render({ok}, K, s, &occ), doctest::Contains("pixel (5, 6)"), InvalidInput);
  occ.depth_m(5, 6) = 1.f;
  occ.labels = LabelImage(3, 3, 0);
  CHECK_THROWS_WITH_AS(renderer.render({ok}, K, s, &occ), doctest::Contains("occluder labels"), InvalidInput);

  Mesh broken = test::make_box(0.1f, 0.1f, 0.1f);
  broken.triangles[2] = Eigen::Vector3i(0, 1, 99);
  CHECK_THROWS_WITH_AS(typename B::Renderer({broken}), doctest::Contains("vertex 99"), InvalidInput);
  CHECK_THROWS_WITH_AS(typename B::Renderer({Mesh{}}), doctest::Contains("no vertices"), InvalidInput);
  CHECK_THROWS_WITH_AS(typename B::Renderer(std::vector<Mesh>{}), doctest::Contains("no models"),
                       InvalidInput);
}

TEST_CASE(
    "thrust renderer in passes: chunk device memory stays within memory_budget_bytes, outputs included") {
  // The chunk planner counts every device array of a chunk, including the compacted outputs (24 bytes per
  // visible sample) and the scan's temporaries; LaunchShape::peak_chunk_bytes is what the backend actually
  // allocated for chunks (its arena and temporary blocks), not an estimate.
  std::mt19937 rng(41);
  std::vector<Mesh> models{test::make_blob(rng, 0.08f, 16, 24), test::make_box(0.12f, 0.1f, 0.08f)};
  const Intrinsics K = vga_camera();
  std::vector<Hypothesis> hyps;
  for (int k = 0; k < 60; ++k) hyps.push_back({k % 2, test::random_pose(rng, 0.8f, 1.2f, 0.1f)});
  const PassesRenderer renderer(models);
  RenderSettings s = at_stride(1);
  s.memory_budget_bytes = std::size_t(1) << 30;
  const CloudBatch whole = renderer.render(hyps, K, s);
  REQUIRE(renderer.last_launch_shape().find("rasterize")->launches == 1);  // one chunk
  CHECK(whole.size() > 60 * 4000);  // > 4,000 visible samples per hypothesis (ROIs ~10^4): outputs matter
  for (std::size_t budget : {std::size_t(3) << 20, std::size_t(5) << 20, std::size_t(16) << 20}) {
    CAPTURE(budget);
    s.memory_budget_bytes = budget;
    require_equal_batches(whole, renderer.render(hyps, K, s));  // chunking never changes the result
    const thrust_backend::LaunchShape shape = renderer.last_launch_shape();
    CHECK(shape.find("rasterize")->launches > 1);
    CHECK(shape.peak_chunk_bytes <= budget);
    CHECK(shape.peak_chunk_bytes > budget / 2);  // chunks are filled, not tiny
    // The workspace is warm: the same call again allocates nothing on the device.
    renderer.render(hyps, K, s);
    CHECK(renderer.last_launch_shape().device_allocations == 0);
  }
}

TEST_CASE("thrust renderer in passes: launch shape counts every pass's work items") {
  std::mt19937 rng(43);
  const std::vector<Mesh> models{test::make_blob(rng, 0.06f, 10, 12)};
  std::vector<Hypothesis> hyps;
  for (int k = 0; k < 7; ++k) hyps.push_back({0, test::random_pose(rng, 0.5f, 0.8f, 0.1f)});
  const PassesRenderer renderer(models);
  renderer.render(hyps, vga_camera(), at_stride(2));
  const thrust_backend::LaunchShape shape = renderer.last_launch_shape();
  const int block = thrust_backend::OmpPassesSystem::render_elements_per_item;
  const std::int64_t tri = std::int64_t(models[0].triangles.size());
  const auto* raster = shape.find("rasterize");
  REQUIRE(raster != nullptr);
  CHECK(raster->elements_per_item == block);
  CHECK(raster->items == 7 * ((tri + block - 1) / block));  // one chunk: every hypothesis' triangles
  CHECK(shape.find("roi")->items == 7);
  CHECK(shape.device_allocations > 0);  // the first call builds the workspace
}

TEST_CASE("thrust renderer on CPU systems: two parallel passes per chunk, within memory_budget_bytes") {
  // Whole hypotheses per work item (OmpSystem::render_whole_hypotheses): a call launches the ROI pass and,
  // per chunk, one rendering and one compaction pass, so few parallel regions (each a barrier that waits
  // for a descheduled thread on a shared CPU) whatever the batch size.
  std::mt19937 rng(47);
  std::vector<Mesh> models{test::make_blob(rng, 0.08f, 16, 24), test::make_box(0.12f, 0.1f, 0.08f)};
  const Intrinsics K = vga_camera();
  std::vector<Hypothesis> hyps;
  for (int k = 0; k < 300; ++k) hyps.push_back({k % 2, test::random_pose(rng, 0.8f, 1.2f, 0.1f)});
  const thrust_omp::Backend::Renderer renderer(models);
  const CloudBatch whole = renderer.render(hyps, K, at_stride(4));
  const thrust_backend::LaunchShape shape = renderer.last_launch_shape();
  CHECK(shape.chunks == 1);  // the default budget holds 300 hypotheses at stride 4
  REQUIRE(shape.passes.size() == 3);
  CHECK(shape.find("roi")->launches == 1);
  CHECK(shape.find("render_hypotheses")->launches == 1);
  CHECK(shape.find("render_hypotheses")->items == omp_get_max_threads());
  CHECK(shape.find("scatter")->items == omp_get_max_threads());  // pulls the 300 hypotheses
  CHECK(shape.peak_chunk_bytes <= thrust_backend::OmpSystem::default_chunk_bytes);
  RenderSettings s = at_stride(4);
  s.memory_budget_bytes = std::size_t(1) << 20;
  require_equal_batches(whole, renderer.render(hyps, K, s));  // chunking never changes the result
  const thrust_backend::LaunchShape chunked = renderer.last_launch_shape();
  CHECK(chunked.chunks > 1);
  CHECK(chunked.find("render_hypotheses")->launches == chunked.chunks);
  CHECK(chunked.find("scatter")->launches == chunked.chunks);
  CHECK(chunked.peak_chunk_bytes <= s.memory_budget_bytes);
  CHECK(chunked.peak_chunk_bytes > s.memory_budget_bytes / 2);  // chunks are filled, not tiny
  renderer.render(hyps, K, s);
  CHECK(renderer.last_launch_shape().device_allocations == 0);  // the workspace is warm
}
