// Observed clouds: back-projection of an RGB-D frame, stride sampling, per-label segments, bad input, and
// the round trip render -> depth image -> observed cloud giving the renderer's points exactly.
#include <cmath>
#include <random>

#include "perch2/core/observed.hpp"
#include "render_fixtures.hpp"
#include "test_support.hpp"

using namespace perch2;
using perch2::test::vga_camera;

namespace {

ObservedCloudSettings every(int stride) {
  ObservedCloudSettings s;
  s.stride = stride;
  return s;
}

/// A frame seeing a fronto-parallel plane at depth_m with a hole (no reading) in the top-left 10x10 pixels.
RgbdFrame plane_frame(float depth_m) {
  RgbdFrame f;
  f.camera = vga_camera();
  f.depth_m = DepthImage(f.camera.width, f.camera.height, depth_m);
  f.rgb = ColorImage(f.camera.width, f.camera.height);
  for (int v = 0; v < f.camera.height; ++v)
    for (int u = 0; u < f.camera.width; ++u) {
      f.rgb(u, v) = Rgb8{std::uint8_t(u % 256), std::uint8_t(v % 256), 7};
      if (u < 10 && v < 10) f.depth_m(u, v) = 0.f;
    }
  return f;
}

/// The depth image (z of the visible surface) that a one-hypothesis render at stride 1 describes.
DepthImage depth_of(const CloudBatch& render, const Intrinsics& K) {
  DepthImage d(K.width, K.height, 0.f);
  for (std::size_t i = 0; i < render.size(); ++i) d.data[std::size_t(render.pixel[i])] = render.z[i];
  return d;
}

}  // namespace

TEST_CASE("observed_cloud back-projects every pixel with a reading through the camera") {
  const RgbdFrame f = plane_frame(0.8f);
  const CloudBatch c = observed_cloud(f);
  REQUIRE(c.num_clouds() == 1);
  CHECK(c.size() == std::size_t(640 * 480 - 100));  // the hole has no reading
  c.validate();
  for (std::size_t i = 0; i < c.size(); i += 997) {
    const int u = c.pixel[i] % 640, v = c.pixel[i] / 640;
    CHECK(c.z[i] == 0.8f);
    // Pinhole model u = fx x / z + cx, up to float rounding of the ray (~1e-4 px at u = 640).
    CHECK(std::abs(f.camera.fx * c.x[i] / c.z[i] + f.camera.cx - float(u)) < 1e-3f);
    CHECK(std::abs(f.camera.fy * c.y[i] / c.z[i] + f.camera.cy - float(v)) < 1e-3f);
    CHECK(c.rgb[i] == pack_rgb(f.rgb(u, v)));
    CHECK(c.cloud[i] == 0);
  }
  // Raster order, so consecutive pixels increase.
  for (std::size_t i = 1; i < c.size(); ++i) REQUIRE(c.pixel[i] > c.pixel[i - 1]);
}

TEST_CASE("observed_cloud at stride s keeps exactly the pixels at multiples of s") {
  const RgbdFrame f = plane_frame(1.2f);
  const CloudBatch full = observed_cloud(f, every(1)), s4 = observed_cloud(f, every(4));
  std::size_t expected = 0;
  for (std::size_t i = 0; i < full.size(); ++i) {
    const int u = full.pixel[i] % 640, v = full.pixel[i] / 640;
    if (u % 4 == 0 && v % 4 == 0) {
      REQUIRE(expected < s4.size());
      CHECK(s4.pixel[expected] == full.pixel[i]);
      CHECK(s4.x[expected] == full.x[i]);
      CHECK(s4.y[expected] == full.y[i]);
      ++expected;
    }
  }
  CHECK(s4.size() == expected);
  CHECK(expected == std::size_t(160 * 120 - 9));  // 3x3 samples of the stride-4 grid fall in the hole
}

TEST_CASE("observed_cloud without a colour image gives rgb 0") {
  RgbdFrame f = plane_frame(0.5f);
  f.rgb = ColorImage{};
  const CloudBatch c = observed_cloud(f, every(8));
  REQUIRE(c.size() > 0);
  for (auto rgb : c.rgb) REQUIRE(rgb == 0u);
}

TEST_CASE("observed_cloud keeps only readings inside the depth range") {
  RgbdFrame f = plane_frame(0.8f);
  for (int v = 0; v < 480; ++v)
    for (int u = 320; u < 640; ++u) f.depth_m(u, v) = 2.5f;  // right half: the wall behind the table
  ObservedCloudSettings s = every(4);
  s.max_depth_m = 2.f;
  const CloudBatch near = observed_cloud(f, s);
  CHECK(near.size() == std::size_t(80 * 120 - 9));  // left half of the grid, minus the hole
  for (std::size_t i = 0; i < near.size(); ++i) REQUIRE(near.z[i] == 0.8f);
  s.min_depth_m = 1.f, s.max_depth_m = 3.f;
  const CloudBatch far = observed_cloud(f, s);
  CHECK(far.size() == std::size_t(80 * 120));
  for (std::size_t i = 0; i < far.size(); ++i) REQUIRE(far.z[i] == 2.5f);
}

TEST_CASE("observed_segments splits the points by label and keeps empty labels as empty clouds") {
  const RgbdFrame f = plane_frame(0.7f);
  LabelImage labels(640, 480, 0);
  for (int v = 0; v < 480; ++v)
    for (int u = 0; u < 640; ++u) labels(u, v) = u < 320 ? 3 : (v < 240 ? 5 : 0);
  const CloudBatch c = observed_segments(f, labels, {5, 9, 3}, every(2));
  c.validate();
  REQUIRE(c.num_clouds() == 3);
  CHECK(c.cloud_size(0) == std::size_t(160 * 120));       // u >= 320, v < 240
  CHECK(c.cloud_size(1) == 0);                            // label 9 is not in the image
  CHECK(c.cloud_size(2) == std::size_t(160 * 240 - 25));  // u < 320, minus the hole's 5x5 samples
  for (std::size_t s = 0; s < 3; ++s)
    for (auto i = c.offsets[s]; i < c.offsets[s + 1]; ++i) {
      const int u = c.pixel[std::size_t(i)] % 640, v = c.pixel[std::size_t(i)] / 640;
      REQUIRE(c.cloud[std::size_t(i)] == int(s));
      REQUIRE(labels(u, v) == (s == 0 ? 5 : 3));
    }
}

TEST_CASE("on_stride_grid thins each segment to the coarser grid, keeping small segments whole") {
  const RgbdFrame f = plane_frame(0.7f);
  LabelImage labels(640, 480, 0);
  for (int v = 0; v < 480; ++v)
    for (int u = 0; u < 640; ++u) labels(u, v) = u < 320 ? 1 : (u < 340 && v < 20 ? 2 : 0);
  CloudBatch c = observed_segments(f, labels, {1, 2}, every(2));
  const CloudBatch s4 = on_stride_grid(c, 640, 4, 30), s8 = observed_segments(f, labels, {1, 2}, every(8));
  s4.validate();
  REQUIRE(s4.num_clouds() == 2);
  // Segment 0 is observed_segments at stride 4 exactly; segment 1 (10 x 10 = 100 points, 25 on the
  // stride-4 grid, fewer than 30) keeps all its points.
  const CloudBatch direct4 = observed_segments(f, labels, {1}, every(4));
  REQUIRE(s4.cloud_size(0) == direct4.size());
  for (std::size_t i = 0; i < direct4.size(); ++i)
    REQUIRE((s4.pixel[i] == direct4.pixel[i] && s4.x[i] == direct4.x[i] && s4.rgb[i] == direct4.rgb[i]));
  CHECK(s4.cloud_size(1) == c.cloud_size(1));
  CHECK(c.cloud_size(1) == 100);
  CHECK(on_stride_grid(c, 640, 8, 0).cloud_size(1) == s8.cloud_size(1));  // min_points 0: always thinned
  CHECK(on_stride_grid(c, 640, 1, 0).size() == c.size());
  // A cloud with a point without a pixel (a rendered piece, say) is kept whole.
  c.pixel[std::size_t(c.offsets[0])] = -1;
  CHECK(on_stride_grid(c, 640, 4, 0).cloud_size(0) == c.cloud_size(0));
  CHECK_THROWS_WITH_AS(on_stride_grid(c, 640, 0, 0), doctest::Contains("stride must be >= 1"), InvalidInput);
}

TEST_CASE_TEMPLATE("a rendered depth image turns back into the renderer's points exactly", Backend,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  std::mt19937 rng(7);
  const Intrinsics K = vga_camera();
  const typename Backend::Renderer renderer({test::make_blob(rng, 0.08f)});
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisf(0.7f, Eigen::Vector3f(1, 2, 3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3f(0.03f, -0.02f, 0.7f);
  const std::vector<Hypothesis> hyp{{0, T}};
  RgbdFrame f;
  f.camera = K;
  RenderSettings s;
  s.stride = 1;
  f.depth_m = depth_of(renderer.render(hyp, K, s), K);
  for (int stride : {1, 3, 4}) {
    s.stride = stride;
    const CloudBatch rendered = renderer.render(hyp, K, s), observed = observed_cloud(f, every(stride));
    CAPTURE(stride);
    REQUIRE(rendered.size() > 50);
    REQUIRE(observed.size() == rendered.size());
    for (std::size_t i = 0; i < rendered.size(); ++i) {  // same rays, same depths: bit-identical
      REQUIRE(observed.pixel[i] == rendered.pixel[i]);
      REQUIRE(observed.x[i] == rendered.x[i]);
      REQUIRE(observed.y[i] == rendered.y[i]);
      REQUIRE(observed.z[i] == rendered.z[i]);
    }
  }
}

TEST_CASE("observed clouds reject bad frames, labels and strides with a clear message") {
  RgbdFrame f = plane_frame(0.6f);
  CHECK_THROWS_WITH_AS(observed_cloud(f, every(0)), doctest::Contains("stride must be >= 1"), InvalidInput);
  ObservedCloudSettings range;
  range.min_depth_m = 1.f, range.max_depth_m = 0.5f;
  CHECK_THROWS_WITH_AS(observed_cloud(f, range), doctest::Contains("depth range"), InvalidInput);
  range.min_depth_m = std::nanf(""), range.max_depth_m = 2.f;
  CHECK_THROWS_WITH_AS(observed_cloud(f, range), doctest::Contains("depth range"), InvalidInput);
  LabelImage small(320, 240, 1);
  CHECK_THROWS_WITH_AS(observed_segments(f, small, {1}), doctest::Contains("observed label image"),
                       InvalidInput);
  LabelImage labels(640, 480, 1);
  CHECK_THROWS_WITH_AS(observed_segments(f, labels, {1, 2, 1}), doctest::Contains("listed twice"),
                       InvalidInput);
  f.depth_m(100, 200) = std::nanf("");
  CHECK_THROWS_WITH_AS(observed_cloud(f), doctest::Contains("(100, 200)"), InvalidInput);
  f = plane_frame(0.6f);
  f.depth_m = DepthImage(640, 479, 1.f);
  CHECK_THROWS_WITH_AS(observed_cloud(f), doctest::Contains("observed frame depth"), InvalidInput);
}
