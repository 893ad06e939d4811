// simplified() (perch2/render/simplify.hpp): the coarse copy of a mesh that the 6-DoF search renders at
// coarse strides. It must be much smaller, stay on the surface within a cell, render at stride 8 about
// as the full mesh does, keep a texture's corner coordinates and colours, and refuse bad cells.
#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "perch2/cpu/estimators.hpp"
#include "perch2/render/simplify.hpp"
#include "render_fixtures.hpp"
#include "test_support.hpp"

using namespace perch2;

TEST_CASE("simplified: a 10k-triangle mesh, a quarter of the triangles, on its surface within a cell") {
  const Mesh full = test::lumpy_sphere(0.06f, 71, 72);
  const float cell = 0.01f;
  const Mesh coarse = simplified(full, cell);
  coarse.validate();
  MESSAGE(full.triangles.size() << " -> " << coarse.triangles.size() << " triangles");
  CHECK(coarse.triangles.size() * 4 < full.triangles.size());
  CHECK(coarse.triangles.size() > 500);
  CHECK(coarse.vertex_colors.size() == coarse.vertices.size());
  // Every vertex is a mean of original vertices of one cell: within a cell's diagonal of one of them.
  for (const auto& v : coarse.vertices) {
    float nearest = INFINITY;
    for (const auto& w : full.vertices) nearest = std::min(nearest, (v - w).norm());
    CHECK(nearest <= cell * std::sqrt(3.f));
  }
  CHECK(coarse.bounds().min().isApprox(full.bounds().min(), 0.1f));

  // Rendered at stride 8 (where the search uses it), the same poses show about the same points at about
  // the same depth.
  const Intrinsics K = test::vga_camera();
  std::mt19937 rng(8);
  std::vector<Hypothesis> hyps;
  for (int k = 0; k < 60; ++k) hyps.push_back({0, test::random_pose(rng, 0.4f, 0.9f, 0.1f), -1});
  RenderSettings rs;
  rs.stride = 8;
  const CloudBatch a = cpu::Renderer({full}).render(hyps, K, rs);
  const CloudBatch b = cpu::Renderer({coarse}).render(hyps, K, rs);
  std::size_t shared = 0, close = 0;
  for (std::size_t h = 0; h < hyps.size(); ++h) {
    const auto na = double(a.cloud_size(h)), nb = double(b.cloud_size(h));
    CHECK(std::abs(na - nb) <= 0.1 * na + 2);
    for (auto i = std::size_t(a.offsets[h]); i < std::size_t(a.offsets[h + 1]); ++i)
      for (auto j = std::size_t(b.offsets[h]); j < std::size_t(b.offsets[h + 1]); ++j)
        if (a.pixel[i] == b.pixel[j]) {
          ++shared;
          close += std::abs(a.z[i] - b.z[j]) <= cell;
        }
  }
  CHECK(shared > 1000);
  CHECK(double(close) >= 0.95 * double(shared));
}

TEST_CASE("simplified: corner texture coordinates kept, the texture shrunk, colours averaged") {
  ColorImage tex(64, 32, Rgb8{0, 0, 0});
  for (int v = 0; v < 32; ++v)
    for (int u = 0; u < 64; ++u) tex(u, v) = Rgb8{std::uint8_t(4 * u), std::uint8_t(8 * v), 7};
  // A finely split quad: 40 x 40 vertices, two triangles per square, UVs of the plane.
  Mesh quad;
  const int n = 40;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      quad.vertices.emplace_back(0.1f * float(i) / (n - 1), 0.1f * float(j) / (n - 1), 0.f);
  auto uv = [&](int k) { return Eigen::Vector2f(float(k % n) / (n - 1), float(k / n) / (n - 1)); };
  for (int j = 0; j + 1 < n; ++j)
    for (int i = 0; i + 1 < n; ++i) {
      const int a = j * n + i, b = a + 1, c = a + n, d = c + 1;
      for (const Eigen::Vector3i t : {Eigen::Vector3i(a, c, d), Eigen::Vector3i(a, d, b)}) {
        quad.triangles.push_back(t);
        for (int k = 0; k < 3; ++k) quad.corner_uvs.push_back(uv(t[k]));
      }
    }
  quad.texture = tex;
  const Mesh coarse = simplified(quad, 0.01f, 2);
  coarse.validate();
  CHECK(coarse.triangles.size() * 4 < quad.triangles.size());
  CHECK(coarse.texture.width == 32);
  CHECK(coarse.texture.height == 16);
  CHECK(coarse.texture(0, 0).r == 2);  // mean of 0 and 4
  CHECK(coarse.texture(31, 15).g == 8 * 30 + 4);
  // Every corner's coordinates are an original corner's: no seam is averaged.
  for (const auto& t : coarse.corner_uvs) {
    const float i = t.x() * (n - 1), j = t.y() * (n - 1);
    CHECK(std::abs(i - std::round(i)) < 1e-4f);
    CHECK(std::abs(j - std::round(j)) < 1e-4f);
  }
  // Vertex colours: each vertex the mean of its cell's.
  Mesh two = test::make_box(0.002f, 0.002f, 0.002f);                       // all eight corners in one cell
  CHECK(simplified(two, 0.01f).triangles.size() == two.triangles.size());  // nothing left: returned as it is
  Mesh box = test::make_box(0.1f, 0.1f, 0.1f);
  const Mesh same = simplified(box, 0.01f);  // one corner per cell: the same box
  CHECK(same.triangles.size() == box.triangles.size());
  CHECK(same.vertex_colors.size() == 8);
}

TEST_CASE("simplified: a bad cell is refused by name, and bad 6-DoF coarse_mesh settings") {
  const Mesh box = test::make_box(0.1f, 0.1f, 0.1f);
  for (const float cell : {0.f, -1.f, NAN, INFINITY})
    CHECK_THROWS_WITH_AS(simplified(box, cell), doctest::Contains("cell_m"), InvalidInput);
  CHECK_THROWS_WITH_AS(simplified(box, 1e-9f), doctest::Contains("too small"), InvalidInput);
  SixDofModel model{test::lumpy_sphere(0.06f, 71, 72), {}};
  SixDofSettings s;
  s.coarse_mesh.cell_fraction = 0.f;
  CHECK_THROWS_WITH_AS(SixDofEstimator<cpu::Backend>({model}, s),
                       doctest::Contains("coarse_mesh.cell_fraction"), InvalidInput);
  s = SixDofSettings{};
  s.coarse_mesh.texture_factor = 0;
  CHECK_THROWS_WITH_AS(SixDofEstimator<cpu::Backend>({model}, s),
                       doctest::Contains("coarse_mesh.texture_factor"), InvalidInput);
  s = SixDofSettings{};
  s.coarse_mesh.min_stride = -1;
  CHECK_THROWS_WITH_AS(SixDofEstimator<cpu::Backend>({model}, s), doctest::Contains("coarse_mesh.min_stride"),
                       InvalidInput);
}
