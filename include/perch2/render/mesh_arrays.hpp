// Host-side flattening of a Mesh into the arrays a MeshView points at (both backends start from this).
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/render/raster.hpp"

namespace perch2 {

struct MeshArrays {
  std::vector<Vec3f> vertices;
  std::vector<std::int32_t> triangles;
  std::vector<Rgb8> vertex_colors, texture;
  std::vector<Vec2f> corner_uvs;
  int texture_width = 0, texture_height = 0;
  Rgb8 base_color{200, 200, 200};
  Vec3f box_min{0, 0, 0}, box_max{0, 0, 0};

  /// Takes the mesh's texture and colours without copying them (a texture can be 50 MB).
  explicit MeshArrays(Mesh&& mesh) {
    mesh.validate();
    vertices.reserve(mesh.vertices.size());
    for (const auto& v : mesh.vertices) vertices.push_back({v.x(), v.y(), v.z()});
    triangles.reserve(3 * mesh.triangles.size());
    for (const auto& t : mesh.triangles) triangles.insert(triangles.end(), {t[0], t[1], t[2]});
    vertex_colors = std::move(mesh.vertex_colors);
    if (mesh.has_texture()) {
      texture = std::move(mesh.texture.data);
      texture_width = mesh.texture.width, texture_height = mesh.texture.height;
      corner_uvs.reserve(mesh.corner_uvs.size());
      for (const auto& uv : mesh.corner_uvs) corner_uvs.push_back({uv.x(), uv.y()});
    }
    base_color = mesh.base_color;
    const auto box = mesh.bounds();
    mesh = Mesh{};
    box_min = to_vec3(box.min()), box_max = to_vec3(box.max());
  }

  /// A view whose pointers address the given (host or device) copies of these arrays.
  MeshView view(const Vec3f* v, const std::int32_t* t, const Rgb8* vc, const Vec2f* uv,
                const Rgb8* tex) const {
    MeshView m;
    m.vertices = v, m.triangles = t;
    m.vertex_colors = vertex_colors.empty() ? nullptr : vc;
    m.corner_uvs = corner_uvs.empty() ? nullptr : uv;
    m.texture = texture.empty() ? nullptr : tex;
    m.num_vertices = int(vertices.size()), m.num_triangles = int(triangles.size() / 3);
    m.texture_width = texture_width, m.texture_height = texture_height;
    m.base_color = base_color, m.box_min = box_min, m.box_max = box_max;
    return m;
  }
  MeshView host_view() const {
    return view(vertices.data(), triangles.data(), vertex_colors.data(), corner_uvs.data(), texture.data());
  }
};

}  // namespace perch2
