#include "demo_scene.hpp"

#include <cmath>

namespace perch2::demo {
namespace {

constexpr float kPi = 3.14159265358979f;

/// Stripes and a band: an asymmetric label so the can's yaw is visible.
ColorImage can_label() {
  ColorImage t(256, 128);
  for (int y = 0; y < t.height; ++y)
    for (int x = 0; x < t.width; ++x) {
      const bool band = y > 40 && y < 88;
      const bool logo = x < 64 && band;
      t(x, y) = logo ? Rgb8{250, 220, 40} : band ? Rgb8{230, 230, 230} : Rgb8{200, 30, 30};
    }
  return t;
}

/// T_table_cam from an eye position looking at a target (OpenCV camera frame, table z up).
Pose look_at(const Eigen::Vector3f& eye, const Eigen::Vector3f& target) {
  const Eigen::Vector3f z = (target - eye).normalized();
  const Eigen::Vector3f x = z.cross(Eigen::Vector3f::UnitZ()).normalized();
  const Eigen::Vector3f y = z.cross(x);
  Pose T = Pose::Identity();
  T.linear().col(0) = x, T.linear().col(1) = y, T.linear().col(2) = z;
  T.translation() = eye;
  return T;
}

}  // namespace

Mesh make_cylinder(float radius_m, float height_m, int segments, ColorImage label_texture) {
  Mesh m;
  m.name = "can";
  // Side: a ring of (bottom, top) vertex pairs; the seam vertex is duplicated so u runs 0..1.
  for (int k = 0; k <= segments; ++k) {
    const float a = 2 * kPi * k / segments;
    m.vertices.emplace_back(radius_m * std::cos(a), radius_m * std::sin(a), 0.f);
    m.vertices.emplace_back(radius_m * std::cos(a), radius_m * std::sin(a), height_m);
  }
  const int bottom = int(m.vertices.size()), top = bottom + 1;
  m.vertices.emplace_back(0.f, 0.f, 0.f);
  m.vertices.emplace_back(0.f, 0.f, height_m);
  auto uv = [&](int k, bool up) { return Eigen::Vector2f(float(k) / segments, up ? 1.f : 0.f); };
  const Eigen::Vector2f lid(0.5f, 0.3f);  // a grey-ish texel of the band for both lids
  for (int k = 0; k < segments; ++k) {
    const int b0 = 2 * k, t0 = 2 * k + 1, b1 = 2 * k + 2, t1 = 2 * k + 3;
    m.triangles.emplace_back(b0, b1, t1),
        m.corner_uvs.insert(m.corner_uvs.end(), {uv(k, 0), uv(k + 1, 0), uv(k + 1, 1)});
    m.triangles.emplace_back(b0, t1, t0),
        m.corner_uvs.insert(m.corner_uvs.end(), {uv(k, 0), uv(k + 1, 1), uv(k, 1)});
    m.triangles.emplace_back(top, t0, t1), m.corner_uvs.insert(m.corner_uvs.end(), {lid, lid, lid});
    m.triangles.emplace_back(bottom, b1, b0), m.corner_uvs.insert(m.corner_uvs.end(), {lid, lid, lid});
  }
  m.texture = std::move(label_texture);
  return m;
}

Mesh make_box(float sx, float sy, float sz) {
  Mesh m;
  m.name = "box";
  for (int k = 0; k < 8; ++k) {
    m.vertices.emplace_back((k & 1 ? 0.5f : -0.5f) * sx, (k & 2 ? 0.5f : -0.5f) * sy, (k & 4 ? sz : 0.f));
    m.vertex_colors.push_back(
        {std::uint8_t(k & 1 ? 240 : 40), std::uint8_t(k & 2 ? 160 : 60), std::uint8_t(k & 4 ? 220 : 30)});
  }
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads)
    m.triangles.emplace_back(q[0], q[1], q[2]), m.triangles.emplace_back(q[0], q[2], q[3]);
  return m;
}

/// A lumpy ball with smoothly varying vertex colours.
Mesh make_blob(float radius_m, int rings, int segments) {
  Mesh m;
  m.name = "blob";
  for (int i = 0; i <= rings; ++i)
    for (int j = 0; j < segments; ++j) {
      const float th = kPi * i / rings, ph = 2 * kPi * j / segments;
      const float r = radius_m * (1.f + 0.15f * std::sin(3 * ph) * std::sin(th));
      m.vertices.emplace_back(r * std::sin(th) * std::cos(ph), r * std::sin(th) * std::sin(ph),
                              radius_m + r * std::cos(th));
      m.vertex_colors.push_back(
          {std::uint8_t(60 + 150 * std::sin(th)), std::uint8_t(120 + 100 * std::cos(ph)), 200});
    }
  auto at = [&](int i, int j) { return i * segments + (j % segments); };
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      m.triangles.emplace_back(at(i, j), at(i + 1, j), at(i + 1, j + 1));
      m.triangles.emplace_back(at(i, j), at(i + 1, j + 1), at(i, j + 1));
    }
  return m;
}

Pose on_table(float x_m, float y_m, float yaw_rad, float z_m) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisf(yaw_rad, Eigen::Vector3f::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3f(x_m, y_m, z_m);
  return T;
}

Scene make_scene() {
  Scene s;
  s.camera = {615.f, 615.f, 319.5f, 239.5f, 640, 480};
  s.T_cam_table = look_at({0.f, -0.55f, 0.5f}, {0.f, 0.05f, 0.05f}).inverse();
  Mesh table = make_box(1.2f, 0.9f, 0.02f);
  table.name = "table";
  table.vertex_colors.assign(table.vertices.size(), Rgb8{150, 110, 70});
  s.models = {table, make_cylinder(0.035f, 0.12f, 48, can_label()), make_box(0.05f, 0.14f, 0.2f),
              make_blob(0.045f, 24, 32)};
  s.T_table_obj = {on_table(0, 0, 0, -0.02f), on_table(-0.12f, 0.02f, 0.4f), on_table(0.1f, 0.08f, 0.5f),
                   on_table(-0.02f, 0.18f, 0.f)};
  return s;
}

}  // namespace perch2::demo
