// One hypothesis rendered start to end in one thread (render_hypothesis: pose, rasterise, resolve, shade),
// with its parameters (RenderParams) and scratch (HypothesisScratch).
#pragma once

#include <cstdint>

#include "perch2/core/camera.hpp"
#include "perch2/core/device.hpp"
#include "perch2/render/raster/grid.hpp"
#include "perch2/render/raster/mesh_view.hpp"
#include "perch2/render/raster/pose_vertices.hpp"
#include "perch2/render/raster/rasterize.hpp"
#include "perch2/render/raster/resolve.hpp"

namespace perch2 {

/// What a render needs besides the model and the pose (device-callable copy of RenderSettings' fields).
struct RenderParams {
  Intrinsics K;
  int stride;
  float near_m;
  bool cull_back_faces;
  OccluderView occ;
};

/// Scratch for rendering one hypothesis in one thread: posed vertices and spans (room for the model's
/// vertices) and a z-buffer (room for the ROI).
struct HypothesisScratch {
  PosedPoint* p_cam;
  GridSpan* span;
  DepthTriangle* zbuf;
  std::int32_t* front_clusters;  ///< room for the model's clusters
  std::uint64_t* vertex_blocks;  ///< vertex_block_words(num_vertices) words
};

/// Poses the vertex blocks of the clusters that face the camera, then rasterises those clusters (back faces
/// culled; the model has MeshView::vertex_masks). A triangle reads only its own corners, so this is the
/// z-buffer of posing every vertex; on the benchmark's closed models it poses 68-72% of them.
template <class Plot>
PERCH2_HD void pose_and_rasterize_front_clusters(const MeshView& m, const Rigid3f& T_cam_obj,
                                                 const GridRoi& roi, const RenderParams& p,
                                                 const HypothesisScratch& s, Plot& plot) {
  const int n = front_clusters(m, T_cam_obj, s.front_clusters, s.vertex_blocks);
  pose_vertex_blocks(VertexPoser(m, T_cam_obj, p.K, p.stride, p.near_m), s.vertex_blocks, m.num_vertices,
                     s.p_cam, s.span);
  const PosedVertices posed{s.p_cam, s.span};
  for (int k = 0; k < n; ++k) {
    const TriangleCluster& c = m.clusters[s.front_clusters[k]];
    rasterize_triangle_run(m, posed, c.first, c.first + c.count, T_cam_obj, p.K, p.stride, p.near_m, roi,
                           true, c.max_edge_m, cluster_min_depth(c, T_cam_obj), plot);
  }
}

/// Renders one hypothesis start to end in one thread: poses the model (only the clusters that face the
/// camera when back faces are culled by clusters), rasterises it into the ROI z-buffer and resolves the
/// visible samples, in raster order of the stride grid, into out (room for roi.size()). Returns their count.
/// The reference backend and the Thrust backend on CPU systems render this way (each hypothesis' working set
/// stays in cache); on GPUs the Thrust backend runs the same steps as passes.
PERCH2_HD inline int render_hypothesis(const MeshView& m, const Rigid3f& T_cam_obj, std::int32_t label,
                                       const GridRoi& roi, const RenderParams& p, const HypothesisScratch& s,
                                       RenderedSample* out) {
  if (roi.size() == 0) return 0;
  for (int k = 0; k < roi.size(); ++k) s.zbuf[k] = kEmptyPixel;
  const PosedVertices posed{s.p_cam, s.span};
  DepthTriangle* const zbuf = s.zbuf;
  auto plot = [zbuf](int idx, DepthTriangle w) { zbuf[idx] = zbuf[idx] < w ? zbuf[idx] : w; };
  if (p.cull_back_faces && m.clusters && m.vertex_masks) {
    pose_and_rasterize_front_clusters(m, T_cam_obj, roi, p, s, plot);
  } else {
    pose_vertices(m, T_cam_obj, p.K, p.stride, p.near_m, 0, m.num_vertices, s.p_cam, s.span);
    rasterize_triangles(m, posed, 0, m.num_triangles, T_cam_obj, p.K, p.stride, p.near_m, roi,
                        p.cull_back_faces, plot);
  }
  const GridRays rays(p.K, p.stride);
  int n = 0;
  for (int j = 0; j < roi.height; ++j)
    for (int i = 0; i < roi.width; ++i)
      n += resolve_point(zbuf[j * roi.width + i], p.K, rays, roi.i0 + i, roi.j0 + j, p.occ, label, out[n]);
  shade_samples(m, posed, out, n);
  return n;
}

}  // namespace perch2
