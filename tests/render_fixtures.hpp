// Small analytic meshes and cameras for the renderer tests.
#pragma once

#include <Eigen/Geometry>
#include <random>
#include <vector>

#include "perch2/core/camera.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"

namespace perch2::test {

inline Intrinsics vga_camera() {
  return {615.f, 615.f, 319.5f, 239.5f, 640, 480};
}

/// Axis-aligned box centred at the origin, outward counter-clockwise winding, one colour per corner.
inline Mesh make_box(float sx, float sy, float sz) {
  Mesh m;
  m.name = "box";
  for (int k = 0; k < 8; ++k) {
    m.vertices.emplace_back((k & 1 ? 0.5f : -0.5f) * sx, (k & 2 ? 0.5f : -0.5f) * sy,
                            (k & 4 ? 0.5f : -0.5f) * sz);
    m.vertex_colors.push_back(
        {std::uint8_t(k & 1 ? 255 : 0), std::uint8_t(k & 2 ? 255 : 0), std::uint8_t(k & 4 ? 255 : 0)});
  }
  // Each face as a quad (a, b, c, d) counter-clockwise seen from outside.
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    m.triangles.emplace_back(q[0], q[1], q[2]);
    m.triangles.emplace_back(q[0], q[2], q[3]);
  }
  return m;
}

/// Square of side `size` in the object's z = 0 plane, facing -z (towards a camera looking along +z), with
/// texture coordinates (0,1) at (-x,-y) ... (1,0) at (+x,+y) if a texture is given: it appears upright.
inline Mesh make_quad(float size, ColorImage texture = {}) {
  Mesh m;
  m.name = "quad";
  const float h = 0.5f * size;
  m.vertices = {{-h, -h, 0}, {h, -h, 0}, {h, h, 0}, {-h, h, 0}};
  m.triangles = {{0, 3, 2}, {0, 2, 1}};  // counter-clockwise seen from -z
  if (texture.empty()) return m;
  m.texture = std::move(texture);
  const Eigen::Vector2f uv[4] = {{0, 1}, {1, 1}, {1, 0}, {0, 0}};
  for (const auto& t : m.triangles)
    for (int k = 0; k < 3; ++k) m.corner_uvs.push_back(uv[t[k]]);
  return m;
}

/// A closed, star-shaped random blob (a sphere with per-vertex random radius) with random vertex colours.
inline Mesh make_blob(std::mt19937& rng, float radius, int rings = 12, int segments = 16) {
  std::uniform_real_distribution<float> r(0.6f, 1.f);
  std::uniform_int_distribution<int> c(0, 255);
  Mesh m;
  m.name = "blob";
  const float pi = 3.14159265f;
  m.vertices.emplace_back(0, 0, radius * r(rng));  // north pole
  for (int i = 1; i < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      const float th = pi * i / rings, ph = 2 * pi * j / segments, rr = radius * r(rng);
      m.vertices.emplace_back(rr * std::sin(th) * std::cos(ph), rr * std::sin(th) * std::sin(ph),
                              rr * std::cos(th));
    }
  m.vertices.emplace_back(0, 0, -radius * r(rng));  // south pole
  const int south = int(m.vertices.size()) - 1;
  auto at = [&](int i, int j) { return 1 + (i - 1) * segments + (j % segments); };
  for (int j = 0; j < segments; ++j) m.triangles.emplace_back(0, at(1, j), at(1, j + 1));
  for (int i = 1; i + 1 < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      m.triangles.emplace_back(at(i, j), at(i + 1, j), at(i + 1, j + 1));
      m.triangles.emplace_back(at(i, j), at(i + 1, j + 1), at(i, j + 1));
    }
  for (int j = 0; j < segments; ++j) m.triangles.emplace_back(south, at(rings - 1, j + 1), at(rings - 1, j));
  for (std::size_t k = 0; k < m.vertices.size(); ++k)
    m.vertex_colors.push_back({std::uint8_t(c(rng)), std::uint8_t(c(rng)), std::uint8_t(c(rng))});
  return m;
}

/// The renderer benchmark's mesh: a sphere with sinusoidal bumps and vertex colours (rings x segments
/// quads; 0.06 m, 71, 72 gives 10,224 triangles).
inline Mesh lumpy_sphere(float radius_m, int rings, int segments) {
  Mesh m;
  m.name = "lumpy sphere";
  const float pi = 3.14159265f;
  for (int i = 0; i <= rings; ++i)
    for (int j = 0; j < segments; ++j) {
      const float th = pi * i / rings, ph = 2 * pi * j / segments;
      const float r = radius_m * (1.f + 0.1f * std::sin(5 * ph) * std::sin(3 * th));
      m.vertices.emplace_back(r * std::sin(th) * std::cos(ph), r * std::sin(th) * std::sin(ph),
                              r * std::cos(th));
      m.vertex_colors.push_back(
          {std::uint8_t(128 + 100 * std::sin(th)), std::uint8_t(128 + 100 * std::cos(ph)), 90});
    }
  auto at = [&](int i, int j) { return i * segments + (j % segments); };
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      m.triangles.emplace_back(at(i, j), at(i + 1, j), at(i + 1, j + 1));
      m.triangles.emplace_back(at(i, j), at(i + 1, j + 1), at(i, j + 1));
    }
  return m;
}

/// Texture whose texel (x, y) has colour (4x + 2, 4y + 2, 128): linear, so bilinear sampling is exact.
inline ColorImage make_ramp_texture(int size = 64) {
  ColorImage t(size, size);
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) t(x, y) = {std::uint8_t(4 * x + 2), std::uint8_t(4 * y + 2), 128};
  return t;
}

inline Pose pose_at(float x, float y, float z, const Eigen::Vector3f& axis = Eigen::Vector3f::UnitZ(),
                    float angle = 0) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisf(angle, axis.normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3f(x, y, z);
  return T;
}

inline Pose random_pose(std::mt19937& rng, float z_min, float z_max, float xy = 0.15f) {
  std::uniform_real_distribution<float> u(-1.f, 1.f), z(z_min, z_max);
  std::normal_distribution<float> g(0.f, 1.f);
  const Eigen::Quaternionf q = Eigen::Quaternionf{g(rng), g(rng), g(rng), g(rng)}.normalized();
  Pose T = Pose::Identity();
  T.linear() = q.toRotationMatrix();
  T.translation() = Eigen::Vector3f{xy * u(rng), xy * u(rng), z(rng)};
  return T;
}

}  // namespace perch2::test
