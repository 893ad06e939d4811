// Triangle meshes with per-vertex colours and/or a texture, in metres, in the object frame.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <vector>

#include "perch2/core/device.hpp"
#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"

namespace perch2 {

struct Mesh {
  std::vector<Eigen::Vector3f> vertices;   ///< object frame, metres
  std::vector<Eigen::Vector3i> triangles;  ///< vertex indices, counter-clockwise seen from outside
  std::vector<Rgb8> vertex_colors;         ///< empty, or one per vertex
  /// Texture coordinates per triangle corner (3 per triangle; OBJ convention: v = 0 at the image bottom).
  std::vector<Eigen::Vector2f> corner_uvs;
  ColorImage texture;              ///< empty, or the diffuse texture sampled through corner_uvs
  Rgb8 base_color{200, 200, 200};  ///< used when there are neither vertex colours nor a texture
  std::string name;

  bool has_texture() const { return !texture.empty() && !corner_uvs.empty(); }
  bool has_vertex_colors() const { return !vertex_colors.empty(); }

  /// Throws InvalidInput naming the mesh if indices, colours or UVs are inconsistent or non-finite.
  void validate() const {
    const std::string who = "mesh '" + name + "'";
    if (vertices.empty() || triangles.empty()) throw InvalidInput(who, "has no vertices or no triangles");
    for (const auto& v : vertices)
      if (!v.allFinite()) throw InvalidInput(who, "has a non-finite vertex");
    const int n = int(vertices.size());
    for (const auto& t : triangles)
      for (int k = 0; k < 3; ++k)
        if (t[k] < 0 || t[k] >= n)
          throw InvalidInput(
              who, "triangle references vertex " + std::to_string(t[k]) + " of " + std::to_string(n));
    if (!vertex_colors.empty() && vertex_colors.size() != vertices.size())
      throw InvalidInput(who, "has " + std::to_string(vertex_colors.size()) + " vertex colours for " +
                                  std::to_string(n) + " vertices");
    if (!corner_uvs.empty() && corner_uvs.size() != 3 * triangles.size())
      throw InvalidInput(who, "needs 3 texture coordinates per triangle");
    if (!corner_uvs.empty() && texture.empty())
      throw InvalidInput(who, "has texture coordinates but no texture");
    if (!texture.empty()) check_size(texture, texture.width, texture.height, who + " texture");
  }

  /// Axis-aligned bounds in the object frame.
  Eigen::AlignedBox3f bounds() const {
    Eigen::AlignedBox3f box;
    for (const auto& v : vertices) box.extend(v);
    return box;
  }
};

}  // namespace perch2
