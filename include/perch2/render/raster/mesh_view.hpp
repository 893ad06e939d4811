// A model as the kernels see it (MeshView): flat arrays, its triangle clusters and vertex blocks, and the
// culling of clusters that face away from a camera pose (cluster_faces_away, front_clusters).
#pragma once

#include <cmath>
#include <cstdint>

#include "perch2/core/camera.hpp"
#include "perch2/core/device.hpp"

namespace perch2 {

/// A run of nearby, similarly oriented triangles with a bounding sphere and a cone holding their normals
/// (object frame), precomputed once per model: a cluster that faces away from the camera as a whole is
/// skipped without touching its triangles (back-face culling per cluster rather than per triangle).
struct TriangleCluster {
  int first = 0, count = 0;  ///< triangles [first, first + count)
  Vec3f axis{0, 0, 1};       ///< unit cone axis
  float cos_half = -1.f;     ///< cone half-angle; cos_half <= 0 (a cone of 90 deg or wider): never culled
  float sin_half = 1.f;
  Vec3f center{0, 0, 0};  ///< bounding sphere of the triangles, metres
  float radius = 0.f;
  float max_edge_m = 0.f;  ///< longest triangle edge (bounds the rounding of the image-space test)
  /// The vertex blocks its triangles use: MeshView::vertex_masks[first_mask, first_mask + num_masks).
  int first_mask = 0, num_masks = 0;
};

/// Vertices are posed in blocks of kPoseBlock (the posing loop's SIMD width): vertices [kPoseBlock b,
/// kPoseBlock (b + 1)) form block b.
constexpr int kPoseBlock = 4;

/// 64 vertex blocks as bits: bit k of `bits` is block 64 word + k.
struct VertexBlockMask {
  std::uint64_t bits;
  std::int32_t word;
};

/// 64-bit words of a bit set over a model's vertex blocks.
PERCH2_HD inline int vertex_block_words(int num_vertices) {
  return (num_vertices + 64 * kPoseBlock - 1) / (64 * kPoseBlock);
}

/// True if every triangle of the cluster faces away from a camera at `cam_obj` (object frame), with a
/// margin that makes the verdict agree with the per-triangle float test (so culling never changes a
/// render): every point p of the sphere and normal n of the cone satisfy n . (p - cam) > margin.
PERCH2_HD inline bool cluster_faces_away(const TriangleCluster& c, Vec3f cam_obj) {
  if (c.cos_half <= 0.f) return false;
  const Vec3f v = c.center - cam_obj;
  const float dist2 = dot(v, v), along = dot(c.axis, v);
  const float across = sqrtf(max_f(dist2 - along * along, 0.f));
  const float margin = 1e-5f * sqrtf(dist2) + 1e-6f;  // >> the float error of a posed triangle's offset
  return along * c.cos_half - across * c.sin_half > c.radius + margin;
}

/// A model as the kernels see it: flat arrays (host or device memory) owned by the backend.
struct MeshView {
  const Vec3f* vertices = nullptr;          ///< object frame, metres
  const float* vertex_xyz = nullptr;        ///< the same, as x of every vertex, then y, then z (posing loop)
  const std::int32_t* triangles = nullptr;  ///< 3 vertex indices per triangle
  const Rgb8* vertex_colors = nullptr;      ///< null, or one per vertex
  const Vec2f* corner_uvs = nullptr;        ///< null, or 3 per triangle
  const Rgb8* texture = nullptr;            ///< null, or texture_width x texture_height, top row first
  int num_vertices = 0, num_triangles = 0;
  int texture_width = 0, texture_height = 0;
  Rgb8 base_color{200, 200, 200};
  Vec3f box_min{0, 0, 0}, box_max{0, 0, 0};   ///< object-frame bounds
  float max_edge_m = 0.f;                     ///< longest triangle edge, metres
  const TriangleCluster* clusters = nullptr;  ///< null (no cluster culling), or num_clusters covering all
  int num_clusters = 0;                       ///< triangles in order
  /// Null (every vertex is posed), or the vertex blocks of each cluster (TriangleCluster::first_mask): a
  /// hypothesis then poses only the blocks of its clusters that face the camera.
  const VertexBlockMask* vertex_masks = nullptr;
};

/// The camera centre in the object frame: -R^T t.
PERCH2_HD inline Vec3f camera_in_object(const Rigid3f& T_cam_obj) {
  const float* R = T_cam_obj.R.m;
  const Vec3f t = T_cam_obj.t;
  return {-(R[0] * t.x + R[3] * t.y + R[6] * t.z), -(R[1] * t.x + R[4] * t.y + R[7] * t.z),
          -(R[2] * t.x + R[5] * t.y + R[8] * t.z)};
}

/// Depth (z, metres) of object-frame point p in the camera frame.
PERCH2_HD inline float depth_in_camera(const Rigid3f& T_cam_obj, Vec3f p) {
  const float* R = T_cam_obj.R.m;
  return R[6] * p.x + R[7] * p.y + R[8] * p.z + T_cam_obj.t.z;
}

/// A lower bound on the depths of a cluster's triangles: its bounding sphere's nearest depth.
PERCH2_HD inline float cluster_min_depth(const TriangleCluster& c, const Rigid3f& T_cam_obj) {
  return depth_in_camera(T_cam_obj, c.center) - c.radius;
}

/// The clusters of a model that face a camera at T_cam_obj, in order (their indices into `front`; returns
/// how many), and the vertex blocks their triangles use (`blocks`: a bit set over the model's vertex blocks,
/// vertex_block_words(m.num_vertices) words; needs MeshView::vertex_masks).
PERCH2_HD inline int front_clusters(const MeshView& m, const Rigid3f& T_cam_obj, std::int32_t* front,
                                    std::uint64_t* blocks) {
  for (int k = 0; k < vertex_block_words(m.num_vertices); ++k) blocks[k] = 0;
  const Vec3f cam_obj = camera_in_object(T_cam_obj);
  int n = 0;
  for (int c = 0; c < m.num_clusters; ++c) {
    const TriangleCluster& cluster = m.clusters[c];
    if (cluster_faces_away(cluster, cam_obj)) continue;
    front[n++] = c;
    for (int k = cluster.first_mask; k < cluster.first_mask + cluster.num_masks; ++k)
      blocks[m.vertex_masks[k].word] |= m.vertex_masks[k].bits;
  }
  return n;
}

}  // namespace perch2
