// Host-side flattening of a Mesh into the arrays a MeshView points at (both backends start from this).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <utility>
#include <vector>

#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/render/raster.hpp"

namespace perch2 {

struct MeshArrays {
  std::vector<Vec3f> vertices;
  std::vector<float>
      vertex_xyz;  ///< the vertices as x of every vertex, then y, then z (MeshView::vertex_xyz)
  std::vector<std::int32_t> triangles;
  std::vector<Rgb8> vertex_colors, texture;
  std::vector<Vec2f> corner_uvs;
  std::vector<TriangleCluster> clusters;      ///< cover the triangles in order (see cluster_triangles)
  std::vector<VertexBlockMask> vertex_masks;  ///< per cluster, the vertex blocks it uses (see block_vertices)
  int texture_width = 0, texture_height = 0;
  Rgb8 base_color{200, 200, 200};
  Vec3f box_min{0, 0, 0}, box_max{0, 0, 0};
  float max_edge_m = 0.f;  ///< longest triangle edge, metres (see MeshView::max_edge_m)

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
    cluster_triangles();
    block_vertices();
  }

  /// A view whose pointers address the given (host or device) copies of these arrays (`cl`: of clusters;
  /// null renders without cluster culling, with identical results on well-conditioned meshes).
  /// `masks`: of vertex_masks; null poses every vertex.
  MeshView view(const Vec3f* v, const float* xyz, const std::int32_t* t, const Rgb8* vc, const Vec2f* uv,
                const Rgb8* tex, const TriangleCluster* cl = nullptr,
                const VertexBlockMask* masks = nullptr) const {
    MeshView m;
    m.clusters = clusters.empty() ? nullptr : cl;
    m.num_clusters = m.clusters ? int(clusters.size()) : 0;
    m.vertex_masks = m.clusters && !vertex_masks.empty() ? masks : nullptr;
    m.vertices = v, m.vertex_xyz = xyz, m.triangles = t;
    m.vertex_colors = vertex_colors.empty() ? nullptr : vc;
    m.corner_uvs = corner_uvs.empty() ? nullptr : uv;
    m.texture = texture.empty() ? nullptr : tex;
    m.num_vertices = int(vertices.size()), m.num_triangles = int(triangles.size() / 3);
    m.texture_width = texture_width, m.texture_height = texture_height;
    m.base_color = base_color, m.box_min = box_min, m.box_max = box_max, m.max_edge_m = max_edge_m;
    return m;
  }
  MeshView host_view() const {
    return view(vertices.data(), vertex_xyz.data(), triangles.data(), vertex_colors.data(), corner_uvs.data(),
                texture.data(), clusters.data(), vertex_masks.data());
  }

  /// Triangles per cluster: enough to amortise the cone test, few enough for tight cones and spheres.
  static constexpr int kClusterTriangles = 64;

  /// Regroups the triangles (and their corner UVs) into clusters: triangles are binned by normal direction
  /// (6 cube faces x 4 x 4 cells, ~12 deg wide) and ordered along a Morton curve of their centroids inside a
  /// bin, then cut into runs of kClusterTriangles. Each cluster gets the tightest cone around its unit
  /// normals (about their mean) and a bounding sphere. Degenerate triangles never render and do not widen
  /// cones.
  void cluster_triangles() {
    const int n = int(triangles.size() / 3);
    std::vector<std::uint64_t> key(static_cast<std::size_t>(n), 0);
    std::vector<Vec3f> unit_normal(static_cast<std::size_t>(n), Vec3f{0, 0, 0});
    const Vec3f extent = box_max - box_min;
    const float scale = 1023.f / std::max(std::max(extent.x, extent.y), std::max(extent.z, 1e-12f));
    for (int t = 0; t < n; ++t) {
      const Vec3f a = corner(t, 0), b = corner(t, 1), c = corner(t, 2);
      const Vec3f nrm = cross(b - a, c - a);
      const float len = std::sqrt(dot(nrm, nrm));
      if (len > 0.f) unit_normal[std::size_t(t)] = (1.f / len) * nrm;
      const Vec3f centroid = (1.f / 3.f) * (a + b + c) - box_min;
      key[std::size_t(t)] =
          (std::uint64_t(direction_bin(unit_normal[std::size_t(t)])) << 30) |
          morton3(unsigned(centroid.x * scale), unsigned(centroid.y * scale), unsigned(centroid.z * scale));
    }
    std::vector<int> order(static_cast<std::size_t>(n));
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(), [&](int p, int q) { return key[p] < key[q]; });
    permute_triangles(order);
    std::vector<Vec3f> sorted_normal(static_cast<std::size_t>(n));
    for (int t = 0; t < n; ++t) sorted_normal[std::size_t(t)] = unit_normal[std::size_t(order[t])];
    clusters.clear();
    max_edge_m = 0.f;
    for (int begin = 0; begin < n;) {
      int end = begin + 1;
      while (end < n && end - begin < kClusterTriangles &&
             (key[order[end]] >> 30) == (key[order[begin]] >> 30))
        ++end;
      clusters.push_back(bound_cluster(begin, end, sorted_normal));
      max_edge_m = std::max(max_edge_m, clusters.back().max_edge_m);
      begin = end;
    }
  }

  /// Renumbers the vertices in the order the (clustered) triangles first use them, so that a cluster's
  /// vertices fill few blocks of kPoseBlock, records each cluster's blocks (vertex_masks) and builds
  /// vertex_xyz. Vertices no triangle uses go last, in no block. Posing only the blocks of the clusters that
  /// face the camera then poses 68-72% of the vertices of the benchmark's closed models (the vertices their
  /// front-facing triangles use: 65-68%).
  void block_vertices() {
    const std::size_t nv = vertices.size();
    std::vector<std::int32_t> new_index(nv, -1);
    std::vector<std::size_t> order;  // old index of each new vertex
    order.reserve(nv);
    for (std::int32_t& v : triangles) {
      if (new_index[std::size_t(v)] < 0)
        new_index[std::size_t(v)] = std::int32_t(order.size()), order.push_back(std::size_t(v));
      v = new_index[std::size_t(v)];
    }
    for (std::size_t v = 0; v < nv; ++v)
      if (new_index[v] < 0) new_index[v] = std::int32_t(order.size()), order.push_back(v);
    permute(vertices, order);
    if (!vertex_colors.empty()) permute(vertex_colors, order);
    vertex_xyz.resize(3 * nv);
    for (std::size_t k = 0; k < nv; ++k)
      vertex_xyz[k] = vertices[k].x, vertex_xyz[nv + k] = vertices[k].y,
      vertex_xyz[2 * nv + k] = vertices[k].z;
    vertex_masks.clear();
    for (TriangleCluster& c : clusters) {
      c.first_mask = int(vertex_masks.size());
      for (int t = c.first; t < c.first + c.count; ++t)
        for (int k = 0; k < 3; ++k) {
          const int block = triangles[std::size_t(3 * t + k)] / kPoseBlock, word = block / 64;
          std::size_t at = std::size_t(c.first_mask);
          while (at < vertex_masks.size() && vertex_masks[at].word != word) ++at;
          if (at == vertex_masks.size()) vertex_masks.push_back({0, word});
          vertex_masks[at].bits |= std::uint64_t(1) << (block % 64);
        }
      c.num_masks = int(vertex_masks.size()) - c.first_mask;
    }
  }

 private:
  Vec3f corner(int t, int k) const { return vertices[std::size_t(triangles[std::size_t(3 * t + k)])]; }

  static unsigned direction_bin(Vec3f d) {  // 96 bins: cube face of the dominant axis x 4 x 4 cells
    const float ax = std::abs(d.x), ay = std::abs(d.y), az = std::abs(d.z);
    int face;
    float u, v, m;
    if (ax >= ay && ax >= az)
      face = d.x >= 0 ? 0 : 1, u = d.y, v = d.z, m = ax;
    else if (ay >= az)
      face = d.y >= 0 ? 2 : 3, u = d.x, v = d.z, m = ay;
    else
      face = d.z >= 0 ? 4 : 5, u = d.x, v = d.y, m = az;
    if (m == 0.f) return 0;
    auto cell = [m](float w) { return std::min(3, int((w / m + 1.f) * 2.f)); };
    return unsigned(face * 16 + cell(u) * 4 + cell(v));
  }

  static std::uint64_t morton3(unsigned x, unsigned y, unsigned z) {  // 10 bits each
    std::uint64_t out = 0;
    for (int b = 0; b < 10; ++b)
      out |= std::uint64_t((x >> b) & 1u) << (3 * b) | std::uint64_t((y >> b) & 1u) << (3 * b + 1) |
             std::uint64_t((z >> b) & 1u) << (3 * b + 2);
    return out;
  }

  template <class T>
  static void permute(std::vector<T>& v, const std::vector<std::size_t>& order) {
    std::vector<T> out;
    out.reserve(order.size());
    for (const std::size_t k : order) out.push_back(v[k]);
    v = std::move(out);
  }

  void permute_triangles(const std::vector<int>& order) {
    std::vector<std::int32_t> tri(triangles.size());
    std::vector<Vec2f> uv(corner_uvs.size());
    for (std::size_t t = 0; t < order.size(); ++t)
      for (int k = 0; k < 3; ++k) {
        tri[3 * t + k] = triangles[std::size_t(3 * order[t] + k)];
        if (!uv.empty()) uv[3 * t + k] = corner_uvs[std::size_t(3 * order[t] + k)];
      }
    triangles = std::move(tri);
    corner_uvs = std::move(uv);
  }

  TriangleCluster bound_cluster(int begin, int end, const std::vector<Vec3f>& normal) const {
    TriangleCluster c;
    c.first = begin, c.count = end - begin;
    Vec3f lo{1e30f, 1e30f, 1e30f}, hi{-1e30f, -1e30f, -1e30f}, sum{0, 0, 0};
    for (int t = begin; t < end; ++t) {
      sum = sum + normal[std::size_t(t)];
      for (int k = 0; k < 3; ++k) {
        const Vec3f p = corner(t, k);
        lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
        hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
      }
    }
    c.center = 0.5f * (lo + hi);
    for (int t = begin; t < end; ++t)
      for (int k = 0; k < 3; ++k) {
        const Vec3f d = corner(t, k) - c.center;
        c.radius = std::max(c.radius, std::sqrt(dot(d, d)));
      }
    c.radius *= 1.0001f;  // rounding of the sphere itself
    for (int t = begin; t < end; ++t)
      for (int k = 0; k < 3; ++k) {
        const Vec3f e = corner(t, (k + 1) % 3) - corner(t, k);
        c.max_edge_m = std::max(c.max_edge_m, float(1.0001 * std::sqrt(double(dot(e, e)))));
      }
    const float len = std::sqrt(dot(sum, sum));
    if (!(len > 0.f)) return c;  // all degenerate, or normals cancel: never culled
    c.axis = (1.f / len) * sum;
    float cos_half = 1.f;
    for (int t = begin; t < end; ++t)
      if (dot(normal[std::size_t(t)], normal[std::size_t(t)]) > 0.f)
        cos_half = std::min(cos_half, dot(c.axis, normal[std::size_t(t)]));
    // Widen by 0.01 rad for the rounding of unit normals; a cone of 90 deg or more is never culled.
    const double half = std::acos(std::max(-1.0, std::min(1.0, double(cos_half)))) + 0.01;
    c.cos_half = half < 1.5707963 ? float(std::cos(half)) : -1.f;
    c.sin_half = float(std::sin(std::min(half, 1.5707963)));
    return c;
  }
};

}  // namespace perch2
