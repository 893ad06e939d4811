// Geometry of the stride grid: ROIs (GridRoi), the z-buffer word (DepthTriangle), rays through the grid's
// samples (GridRays), screen bounds -> grid samples (grid_cover, model_roi), and a posed vertex's grid span
// (GridSpan, span_cover).
#pragma once

#include <cstdint>

#include "perch2/core/camera.hpp"
#include "perch2/core/device.hpp"
#include "perch2/render/raster/common.hpp"
#include "perch2/render/raster/mesh_view.hpp"

namespace perch2 {

/// Axis-aligned block of the stride grid: samples (i, j) with i0 <= i < i0 + width, j0 <= j < j0 + height.
struct GridRoi {
  int i0 = 0, j0 = 0, width = 0, height = 0;
  PERCH2_HD int size() const { return width * height; }
};

/// The z-buffer word: depth bits (positive floats order like their bit patterns) above the triangle id,
/// so one 64-bit atomic min keeps the nearest surface and breaks exact ties by the smaller triangle id.
using DepthTriangle = std::uint64_t;
constexpr DepthTriangle kEmptyPixel = ~DepthTriangle(0);

PERCH2_HD inline DepthTriangle pack_depth_triangle(float depth_m, std::uint32_t triangle) {
  return (DepthTriangle(float_bits(depth_m)) << 32) | triangle;
}
PERCH2_HD inline float unpack_depth(DepthTriangle w) {
  return bits_float(std::uint32_t(w >> 32));
}
PERCH2_HD inline std::uint32_t unpack_triangle(DepthTriangle w) {
  return std::uint32_t(w & 0xFFFFFFFFu);
}

/// Rays (z = 1) through the stride grid's samples, full-resolution pixel (u, v) = (stride * i, stride * j):
/// Intrinsics::ray's float operations at every stride, so a stride-s render equals the full-resolution one
/// sampled at multiples of s. 1/fx and 1/fy are computed once here: per ray they cost a divide per sample
/// (g++ did not hoist it out of the resolve loop, ~40% of that loop in the Thrust build).
struct GridRays {
  float cx, cy, inv_fx, inv_fy;
  int stride;
  PERCH2_HD GridRays(const Intrinsics& K, int stride_)
      : cx(K.cx), cy(K.cy), inv_fx(1.f / K.fx), inv_fy(1.f / K.fy), stride(stride_) {}
  PERCH2_HD Vec3f operator()(int i, int j) const {
    return {(float(stride * i) - cx) * inv_fx, (float(stride * j) - cy) * inv_fy, 1.f};
  }
};

/// Conservative float -> grid index conversions that never overflow int.
PERCH2_HD inline int grid_floor(float u_px, float inv_stride) {
  return floor_int(min_f(max_f(u_px * inv_stride, -1e8f), 1e8f));
}
PERCH2_HD inline int grid_ceil(float u_px, float inv_stride) {
  return ceil_int(min_f(max_f(u_px * inv_stride, -1e8f), 1e8f));
}

/// Screen bounds of camera-frame points, in full-resolution pixels.
struct PixelBounds {
  float u0 = 1e30f, v0 = 1e30f, u1 = -1e30f, v1 = -1e30f;
  PERCH2_HD void add(Vec2f q) {
    u0 = min_f(u0, q.x), v0 = min_f(v0, q.y), u1 = max_f(u1, q.x), v1 = max_f(v1, q.y);
  }
  PERCH2_HD void add(const Intrinsics& K, Vec3f p) { add(K.project(p)); }
  PERCH2_HD bool empty() const { return u0 > u1 || v0 > v1; }
};

/// Grid samples inside `bounds` (widened by a small epsilon) and inside `clip`.
PERCH2_HD inline GridRoi grid_cover(const PixelBounds& b, int stride, const GridRoi& clip) {
  constexpr float kEps = 1e-3f;  // pixels; bounds are a superset filter, the edge test is exact
  GridRoi r;
  if (b.empty()) return r;
  const float inv = 1.f / float(stride);
  const int i0 = max_int(grid_ceil(b.u0 - kEps, inv), clip.i0);
  const int j0 = max_int(grid_ceil(b.v0 - kEps, inv), clip.j0);
  const int i1 = min_int(grid_floor(b.u1 + kEps, inv), clip.i0 + clip.width - 1);
  const int j1 = min_int(grid_floor(b.v1 + kEps, inv), clip.j0 + clip.height - 1);
  if (i1 < i0 || j1 < j0) return r;
  return {i0, j0, i1 - i0 + 1, j1 - j0 + 1};
}

/// The part of the stride grid a posed model can cover: its transformed bounding box, projected.
PERCH2_HD inline GridRoi model_roi(const MeshView& m, const Rigid3f& T_cam_obj, const Intrinsics& K,
                                   int stride, float near_m) {
  const GridRoi full{0, 0, K.grid_width(stride), K.grid_height(stride)};
  PixelBounds b;
  int in_front = 0;
  for (int k = 0; k < 8; ++k) {
    const Vec3f p_obj{(k & 1) ? m.box_max.x : m.box_min.x, (k & 2) ? m.box_max.y : m.box_min.y,
                      (k & 4) ? m.box_max.z : m.box_min.z};
    const Vec3f p = T_cam_obj * p_obj;
    if (p.z >= near_m) ++in_front, b.add(K, p);
  }
  if (in_front == 0) return GridRoi{};
  if (in_front < 8) return full;  // box crosses the near plane: its projection is unbounded
  return grid_cover(b, stride, full);
}

/// The grid samples a projected vertex bounds from each side: i_lo = ceil((u - eps) / s), i_hi =
/// floor((u + eps) / s) (likewise j), clamped to [-1, grid size]. A triangle's samples lie within the min of
/// its corners' lo and the max of their hi, so the per-triangle bound needs integer min/max only. The upper
/// bounds are stored negated (-i_hi, -j_hi), so one packed 16-bit min over the corners bounds all four
/// (grid_candidates). 16-bit (grids are at most 32767 samples wide); a vertex nearer than the near plane
/// has the whole grid as its span, with i_lo = kBehindNear marking it. With the span, the vertex's projection
/// as an offset from the principal point, fx x / z and fy y / z (pixels; NaN behind the near plane), for the
/// image-space pre-test (ScreenTriangle).
struct GridSpan {
  std::int16_t i_lo, j_lo, neg_i_hi, neg_j_hi;
  float du_px, dv_px;
};
static_assert(sizeof(GridSpan) == 16, "pose_vertices and screen_single_samples read GridSpan as 4 floats");
constexpr std::int16_t kBehindNear = -32768;
constexpr int kMaxGridSize = 32767;

/// The stride grid's constants, computed once per pass rather than per vertex (two divisions).
struct StrideGrid {
  float inv_stride, width, height;  ///< 1 / stride; grid size in samples
  PERCH2_HD StrideGrid(const Intrinsics& K, int stride)
      : inv_stride(1.f / float(stride)),
        width(float(K.grid_width(stride))),
        height(float(K.grid_height(stride))) {}
};

/// The samples of `roi` inside a triangle's grid span: the packed min of its corners' spans.
PERCH2_HD inline GridRoi span_cover(const GridSpan& sa, const GridSpan& sb, const GridSpan& sc,
                                    const GridRoi& roi) {
  const int i0 = max_int(min3(sa.i_lo, sb.i_lo, sc.i_lo), roi.i0);
  const int i1 = min_int(-min3(sa.neg_i_hi, sb.neg_i_hi, sc.neg_i_hi), roi.i0 + roi.width - 1);
  const int j0 = max_int(min3(sa.j_lo, sb.j_lo, sc.j_lo), roi.j0);
  const int j1 = min_int(-min3(sa.neg_j_hi, sb.neg_j_hi, sc.neg_j_hi), roi.j0 + roi.height - 1);
  if (i1 < i0 || j1 < j0) return GridRoi{};
  return {i0, j0, i1 - i0 + 1, j1 - j0 + 1};
}

}  // namespace perch2
