// A coarser copy of a mesh for coarse renders: vertex clustering (Rossignac & Borrel 1993). Every vertex
// moves to the mean of the vertices in its cell of a cell_m grid (their mean colour too); triangles whose
// corners fall in fewer than three cells vanish, and of triangles with the same three cells one is kept
// (with its own corner texture coordinates, so a texture seam is never averaged across). A render at a
// stride whose samples lie a centimetre apart on the object sees the same surface within about a cell,
// and a scan of 30k triangles costs its renderer's per-triangle set-up 30k times per hypothesis.
//
//   Mesh coarse = simplified(mesh, /*cell_m=*/0.004f, /*texture_factor=*/2);
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <set>
#include <string>
#include <unordered_map>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/mesh.hpp"

namespace perch2 {

/// The texture shrunk by an integer `factor` per axis (box filter over factor x factor texels; the last
/// row and column cover what is left). factor <= 1: a copy.
inline ColorImage shrunk_texture(const ColorImage& t, int factor) {
  if (factor <= 1 || t.empty()) return t;
  const int w = std::max(1, t.width / factor), h = std::max(1, t.height / factor);
  ColorImage out(w, h, Rgb8{0, 0, 0});
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const int u1 = u + 1 == w ? t.width : (u + 1) * factor, v1 = v + 1 == h ? t.height : (v + 1) * factor;
      std::array<std::uint32_t, 3> sum{0, 0, 0};
      std::uint32_t n = 0;
      for (int y = v * factor; y < v1; ++y)
        for (int x = u * factor; x < u1; ++x) {
          const Rgb8 c = t(x, y);
          sum[0] += c.r, sum[1] += c.g, sum[2] += c.b, ++n;
        }
      out(u, v) = Rgb8{std::uint8_t((sum[0] + n / 2) / n), std::uint8_t((sum[1] + n / 2) / n),
                       std::uint8_t((sum[2] + n / 2) / n)};
    }
  return out;
}

/// `m` with its vertices clustered on a cell_m grid (see the file comment) and its texture shrunk by
/// texture_factor. Throws InvalidInput on a non-positive or non-finite cell, or a bad mesh. A mesh that
/// clustering would leave without a triangle (smaller than a cell) is returned as it is.
inline Mesh simplified(const Mesh& m, float cell_m, int texture_factor = 1) {
  if (!(std::isfinite(cell_m) && cell_m > 0.f))
    throw InvalidInput("simplified: cell_m", "must be finite and > 0");
  m.validate();
  const Eigen::Vector3f lo = m.bounds().min();
  if (((m.bounds().max() - lo) / cell_m).maxCoeff() >= float(1 << 20))
    throw InvalidInput("simplified: cell_m",
                       "is too small for mesh '" + m.name + "' (over 2^20 cells across)");
  auto key = [&](const Eigen::Vector3f& v) {
    const Eigen::Vector3f c = ((v - lo) / cell_m).array().floor();
    return (std::int64_t(c.x()) << 42) | (std::int64_t(c.y()) << 21) | std::int64_t(c.z());
  };
  std::unordered_map<std::int64_t, int> cluster_of_key;
  std::vector<int> cluster(m.vertices.size());
  std::vector<Eigen::Vector3d> sum;
  std::vector<std::array<double, 3>> colour;
  std::vector<int> count;
  for (std::size_t i = 0; i < m.vertices.size(); ++i) {
    const auto [it, added] = cluster_of_key.emplace(key(m.vertices[i]), int(sum.size()));
    if (added) sum.emplace_back(0, 0, 0), colour.push_back({0, 0, 0}), count.push_back(0);
    const int c = it->second;
    cluster[i] = c;
    sum[std::size_t(c)] += m.vertices[i].cast<double>();
    if (m.has_vertex_colors()) {
      const Rgb8 rgb = m.vertex_colors[i];
      colour[std::size_t(c)][0] += rgb.r, colour[std::size_t(c)][1] += rgb.g,
          colour[std::size_t(c)][2] += rgb.b;
    }
    ++count[std::size_t(c)];
  }
  Mesh out;
  out.name = m.name;
  out.base_color = m.base_color;
  // Triangles spanning three cells, one per three cells and orientation (the first; keyed by the cyclic
  // rotation that starts at the least cell).
  std::set<std::array<int, 3>> seen;
  for (std::size_t t = 0; t < m.triangles.size(); ++t) {
    Eigen::Vector3i c(cluster[std::size_t(m.triangles[t][0])], cluster[std::size_t(m.triangles[t][1])],
                      cluster[std::size_t(m.triangles[t][2])]);
    if (c[0] == c[1] || c[1] == c[2] || c[0] == c[2]) continue;
    Eigen::Vector3i k = c;
    while (k[0] > k[1] || k[0] > k[2]) k = Eigen::Vector3i(k[1], k[2], k[0]);
    if (!seen.insert({k[0], k[1], k[2]}).second) continue;
    out.triangles.push_back(c);
    if (m.has_texture())
      for (int j = 0; j < 3; ++j) out.corner_uvs.push_back(m.corner_uvs[3 * t + std::size_t(j)]);
  }
  if (out.triangles.empty()) return m;
  if (m.has_texture()) out.texture = shrunk_texture(m.texture, texture_factor);
  // Only the clusters the triangles use, renumbered in order.
  std::vector<int> index(sum.size(), -1);
  for (Eigen::Vector3i& t : out.triangles)
    for (int k = 0; k < 3; ++k) {
      int& i = index[std::size_t(t[k])];
      if (i < 0) {
        const std::size_t c = std::size_t(t[k]);
        i = int(out.vertices.size());
        out.vertices.push_back((sum[c] / double(count[c])).cast<float>());
        if (m.has_vertex_colors())
          out.vertex_colors.push_back(Rgb8{std::uint8_t(std::lround(colour[c][0] / count[c])),
                                           std::uint8_t(std::lround(colour[c][1] / count[c])),
                                           std::uint8_t(std::lround(colour[c][2] / count[c]))});
      }
      t[k] = i;
    }
  return out;
}

}  // namespace perch2
