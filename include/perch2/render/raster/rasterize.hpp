// The triangle-run rasteriser: a run of posed triangles into an ROI z-buffer through a backend's plot
// (rasterize_triangle_run), and over a model's triangles, skipping clusters that face away
// (rasterize_triangles).
#pragma once

#include <cmath>
#include <cstdint>

#include "perch2/core/camera.hpp"
#include "perch2/core/device.hpp"
#include "perch2/render/raster/common.hpp"
#include "perch2/render/raster/grid.hpp"
#include "perch2/render/raster/mesh_view.hpp"
#include "perch2/render/raster/pose_vertices.hpp"
#include "perch2/render/raster/screen.hpp"
#include "perch2/render/raster/triangle.hpp"

namespace perch2 {

/// Rasterise triangles [begin, end) of a model posed by T_cam_obj into an ROI z-buffer: calls
/// plot(roi_index, packed_word) for every covered sample. The backend's plot does the z-test (plain min in
/// the reference, a 64-bit atomic min in the Thrust backend). Inputs are copied to locals so that plot's
/// stores (an atomic is a compiler barrier) do not force reloads of the mesh, camera and ROI. Coverage: the
/// pre-test (ScreenTriangle) decides samples away from edges, covers_exactly the others; triangles reaching
/// the near plane use the float edge planes. `z_min_m`: a lower bound on the triangles' depths.
template <class Plot>
PERCH2_HD void rasterize_triangle_run(const MeshView& m, PosedVertices v, int begin, int end,
                                      const Rigid3f& T_cam_obj, const Intrinsics& K, int stride, float near_m,
                                      const GridRoi& roi, bool cull_back_faces, float max_edge_m,
                                      float z_min_m, Plot& plot) {
  const std::int32_t* const triangles = m.triangles;
  const Intrinsics K_local = K;
  const GridRays rays(K, stride);
  const GridRoi roi_local = roi;
  const ScreenBounds bounds(K, stride, roi, max_edge_m, z_min_m, near_m);
  // Plots triangle tri's depth at sample (i, j) if it covers it (`exact`: decided by covers_exactly);
  // false if the triangle is degenerate or culled (then it covers nothing). `t`: the plane, once set up.
  const auto sample = [&](TriangleRaster& t, bool& plane, int tri, int i, int j, bool exact) {
    const std::int32_t* f = triangles + 3 * tri;
    float s;
    if (!plane && !(plane = triangle_plane(v[f[0]], v[f[1]], v[f[2]], cull_back_faces, t, s))) return false;
    float depth_m;
    const bool hit =
        sample_plane(t, rays(i, j), near_m, depth_m) &&
        (!exact || covers_exactly(m, f, T_cam_obj, K_local, float(stride * i), float(stride * j)));
    if (hit)
      plot((j - roi_local.j0) * roi_local.width + (i - roi_local.i0),
           pack_depth_triangle(depth_m, std::uint32_t(tri)));
    return true;
  };
  // One candidate triangle and its cover, sample by sample.
  const auto rasterize = [&](int tri, const GridCover& c) {
    const std::int32_t* f = triangles + 3 * tri;
    const GridSpan &sa = v.span[f[0]], &sb = v.span[f[1]], &sc = v.span[f[2]];
    const int i0 = c.i0, i1 = -c.neg_i1, j0 = c.j0, j1 = -c.neg_j1;
    TriangleRaster t;
    bool plane = false;
    if (min3(sa.i_lo, sb.i_lo, sc.i_lo) == kBehindNear) {  // reaches the near plane: float edge planes
      if (!setup_triangle(v, f, sa, sb, sc, K_local, stride, near_m, roi_local, cull_back_faces, t)) return;
      for (int j = t.cover.j0; j < t.cover.j0 + t.cover.height; ++j)
        for (int i = t.cover.i0; i < t.cover.i0 + t.cover.width; ++i) {
          float depth_m;
          const bool hit = sample_triangle(t, rays(i, j), near_m, depth_m);
          // A miss plots the empty word, which never wins the z-test (a select, not a branch).
          plot((j - roi_local.j0) * roi_local.width + (i - roi_local.i0),
               hit ? pack_depth_triangle(depth_m, std::uint32_t(tri)) : kEmptyPixel);
        }
      return;
    }
    ScreenTriangle screen;
    if (!screen_triangle(sa, sb, sc, K_local, bounds, screen)) {  // image-degenerate: exact test everywhere
      for (int j = j0; j <= j1; ++j)
        for (int i = i0; i <= i1; ++i)
          if (!sample(t, plane, tri, i, j, true)) return;
      return;
    }
    if (cull_back_faces && screen.back_facing) return;
    for (int j = j0; j <= j1; ++j)
      for (int i = i0; i <= i1; ++i) {
        const int verdict = screen.classify(float(stride * i) - K_local.cx, float(stride * j) - K_local.cy);
        if (verdict >= 0 && !sample(t, plane, tri, i, j, verdict == 0)) return;
      }
  };
  int list[kCandidateBatch];
  GridCover covers[kCandidateBatch];
  for (int first = begin; first < end; first += kCandidateBatch) {
    const int n = grid_candidates(triangles, v.span, first, min_int(end, first + kCandidateBatch), roi_local,
                                  list, covers);
#if defined(PERCH2_RASTER_SSE2)
    // Candidates with one sample, four at a time through screen_single_samples; the others one by one.
    int single[kCandidateBatch + 3], ns = 0;
    for (int k = 0; k < n; ++k) {
      const bool one = covers[k].single();
      single[ns] = k, ns += one;
      if (!one) rasterize(list[k], covers[k]);
    }
    for (int q = ns; q < ns + 3; ++q) single[q] = single[0];  // padding lanes, ignored
    for (int q = 0; q < ns; q += 4) {
      const std::int32_t* f[4];
      int i[4], j[4];
      for (int l = 0; l < 4; ++l) {
        const int k = single[q + l];
        f[l] = triangles + 3 * list[k], i[l] = covers[k].i0, j[l] = covers[k].j0;
      }
      const ScreenVerdicts sv = screen_single_samples(f, v.span, i, j, K_local, stride, bounds);
      for (int l = 0; l < min_int(4, ns - q); ++l) {
        const int k = single[q + l], bit = 1 << l;
        if (sv.general & bit) {
          rasterize(list[k], covers[k]);
        } else if (!(sv.out & bit) && !(cull_back_faces && (sv.back & bit))) {
          TriangleRaster t;
          bool plane = false;
          sample(t, plane, list[k], i[l], j[l], !(sv.in & bit));
        }
      }
    }
#else
    for (int k = 0; k < n; ++k) rasterize(list[k], covers[k]);
#endif
  }
}

/// rasterize_triangle_run over [begin, end), skipping the model's clusters that face away from the camera
/// as a whole when back faces are culled.
template <class Plot>
PERCH2_HD void rasterize_triangles(const MeshView& m, PosedVertices v, int begin, int end,
                                   const Rigid3f& T_cam_obj, const Intrinsics& K, int stride, float near_m,
                                   const GridRoi& roi, bool cull_back_faces, Plot&& plot) {
  if (!cull_back_faces || !m.clusters) {
    const Vec3f half = 0.5f * (m.box_max - m.box_min), centre = m.box_min + half;
    const float z_min = depth_in_camera(T_cam_obj, centre) - 1.0001f * sqrtf(dot(half, half));  // its sphere
    rasterize_triangle_run(m, v, begin, end, T_cam_obj, K, stride, near_m, roi, cull_back_faces, m.max_edge_m,
                           z_min, plot);
    return;
  }
  const Vec3f cam_obj = camera_in_object(T_cam_obj);
  int lo = 0, hi = m.num_clusters;  // first cluster that ends after `begin`
  while (lo < hi) {
    const int mid = (lo + hi) / 2;
    if (m.clusters[mid].first + m.clusters[mid].count <= begin)
      lo = mid + 1;
    else
      hi = mid;
  }
  for (int c = lo; c < m.num_clusters && m.clusters[c].first < end; ++c) {
    const TriangleCluster cluster = m.clusters[c];
    if (cluster_faces_away(cluster, cam_obj)) continue;
    rasterize_triangle_run(m, v, max_int(begin, cluster.first), min_int(end, cluster.first + cluster.count),
                           T_cam_obj, K, stride, near_m, roi, cull_back_faces, cluster.max_edge_m,
                           cluster_min_depth(cluster, T_cam_obj), plot);
  }
}

}  // namespace perch2
