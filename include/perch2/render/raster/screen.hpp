// Screening of a run's triangles before sampling: candidates from their corners' grid spans
// (grid_candidates), and the image-space pre-test of their samples (ScreenTriangle, ScreenBounds; four
// single-sample candidates at once with SSE2: screen_single_samples).
#pragma once

#include <cmath>
#include <cstdint>

#include "perch2/core/camera.hpp"
#include "perch2/core/device.hpp"
#include "perch2/render/raster/common.hpp"
#include "perch2/render/raster/grid.hpp"

namespace perch2 {

/// Triangles per batch of grid_candidates (a model's clusters hold at most this many).
constexpr int kCandidateBatch = 64;

/// Whether a triangle with corner spans sa, sb, sc may cover a sample of `roi`: its span (clamped to the
/// ROI) is not empty, or a corner is behind the near plane (whose span is the whole grid).
PERCH2_HD inline bool span_may_cover(const GridSpan& sa, const GridSpan& sb, const GridSpan& sc,
                                     const GridRoi& roi) {
  const int i0 = max_int(min3(sa.i_lo, sb.i_lo, sc.i_lo), roi.i0);
  const int j0 = max_int(min3(sa.j_lo, sb.j_lo, sc.j_lo), roi.j0);
  const int neg_i1 = max_int(min3(sa.neg_i_hi, sb.neg_i_hi, sc.neg_i_hi), 1 - roi.i0 - roi.width);
  const int neg_j1 = max_int(min3(sa.neg_j_hi, sb.neg_j_hi, sc.neg_j_hi), 1 - roi.j0 - roi.height);
  return (i0 + neg_i1 <= 0) & (j0 + neg_j1 <= 0);
}

/// A candidate triangle's samples: its span's grid box clamped to the ROI, the upper bounds negated.
struct GridCover {
  std::int16_t i0, j0, neg_i1, neg_j1;
  PERCH2_HD bool single() const { return (i0 + neg_i1 == 0) & (j0 + neg_j1 == 0); }
};

/// Writes the triangles of [first, last) (at most kCandidateBatch) that may cover a sample of `roi`
/// (span_may_cover) to `list` and their grid boxes (span_cover's) to `covers`, returns their count. At
/// stride >= 2 most of a model's triangles cover no sample: this filter is branch-free (no misprediction per
/// rejected triangle) and, with SSE2, tests two triangles' packed spans per instruction.
PERCH2_HD_FORCE_INLINE int grid_candidates(const std::int32_t* __restrict__ triangles,
                                           const GridSpan* __restrict__ span, int first, int last,
                                           const GridRoi& roi, int* __restrict__ list,
                                           GridCover* __restrict__ covers) {
  int n = 0, tri = first;
#if defined(PERCH2_RASTER_SSE2)
  const short i1 = short(roi.i0 + roi.width - 1), j1 = short(roi.j0 + roi.height - 1);
  const __m128i clip = _mm_setr_epi16(short(roi.i0), short(roi.j0), short(-i1), short(-j1), short(roi.i0),
                                      short(roi.j0), short(-i1), short(-j1));
  const __m128i zero = _mm_setzero_si128();
  auto corners_min = [span](const std::int32_t* f) {
    const __m128i a = _mm_loadl_epi64(reinterpret_cast<const __m128i*>(span + f[0]));
    const __m128i b = _mm_loadl_epi64(reinterpret_cast<const __m128i*>(span + f[1]));
    const __m128i c = _mm_loadl_epi64(reinterpret_cast<const __m128i*>(span + f[2]));
    return _mm_min_epi16(_mm_min_epi16(a, b), c);
  };
  for (; tri + 2 <= last; tri += 2) {
    const std::int32_t* f = triangles + 3 * tri;
    // Per triangle (i_lo, j_lo, -i_hi, -j_hi) clamped to the ROI: it may cover a sample iff lo + (-hi) <= 0
    // in i and in j.
    const __m128i m = _mm_max_epi16(_mm_unpacklo_epi64(corners_min(f), corners_min(f + 3)), clip);
    const __m128i hi = _mm_shufflehi_epi16(_mm_shufflelo_epi16(m, 0x4E), 0x4E);
    const int empty = _mm_movemask_epi8(_mm_cmpgt_epi16(_mm_adds_epi16(m, hi), zero));
    _mm_storel_epi64(reinterpret_cast<__m128i*>(covers + n), m);
    list[n] = tri, n += (empty & 0xF) == 0;
    _mm_storel_epi64(reinterpret_cast<__m128i*>(covers + n), _mm_unpackhi_epi64(m, m));
    list[n] = tri + 1, n += (empty & 0xF00) == 0;
  }
#endif
  for (; tri < last; ++tri) {
    const std::int32_t* f = triangles + 3 * tri;
    const GridSpan &sa = span[f[0]], &sb = span[f[1]], &sc = span[f[2]];
    covers[n] = {std::int16_t(max_int(min3(sa.i_lo, sb.i_lo, sc.i_lo), roi.i0)),
                 std::int16_t(max_int(min3(sa.j_lo, sb.j_lo, sc.j_lo), roi.j0)),
                 std::int16_t(max_int(min3(sa.neg_i_hi, sb.neg_i_hi, sc.neg_i_hi), 1 - roi.i0 - roi.width)),
                 std::int16_t(max_int(min3(sa.neg_j_hi, sb.neg_j_hi, sc.neg_j_hi), 1 - roi.j0 - roi.height))};
    list[n] = tri, n += span_may_cover(sa, sb, sc, roi);
  }
  return n;
}

/// Image-space pre-test of a triangle's samples: 2-D edge functions of its projected corners (pixels,
/// relative to the principal point), E_k(p) = (q_k+1 - q_k) x (p - q_k), oriented positive inside. For
/// exact values E_k is proportional to the edge plane's n_k . d (n . d = z_lo z_hi E / (fx fy)), so a sample
/// with E_k beyond +-margin on every edge is decided here: `margin` bounds the float error of E_k plus
/// the edge-plane test's own rounding mapped to E's units (ScreenBounds). Samples clearly inside need
/// only the triangle's plane for their depth; samples within the margin of an edge get covers_exactly.
struct ScreenTriangle {
#if defined(PERCH2_RASTER_SSE2)
  __m128 qx, qy, ex, ey;  ///< lanes 0-2: corner k and edge k (oriented); lane 3 unused
#else
  float qx[3], qy[3], ex[3], ey[3];
#endif
  float margin;      ///< pixels^2
  bool back_facing;  ///< clearly (area > margin): the edge-plane test culls it

  /// -1: outside, +1: inside, 0: within the margin of an edge. (x, y): sample pixel - principal point.
  PERCH2_HD int classify(float x, float y) const {
#if defined(PERCH2_RASTER_SSE2)
    const __m128 E = _mm_sub_ps(_mm_mul_ps(ex, _mm_sub_ps(_mm_set1_ps(y), qy)),
                                _mm_mul_ps(ey, _mm_sub_ps(_mm_set1_ps(x), qx)));
    const int out = _mm_movemask_ps(_mm_cmplt_ps(E, _mm_set1_ps(-margin))) & 7;
    const int in = _mm_movemask_ps(_mm_cmpgt_ps(E, _mm_set1_ps(margin))) & 7;
    return out ? -1 : in == 7 ? 1 : 0;
#else
    bool out = false, in = true;
    for (int k = 0; k < 3; ++k) {
      const float E = ex[k] * (y - qy[k]) - ey[k] * (x - qx[k]);
      out |= E<-margin, in &= E> margin;
    }
    return out ? -1 : in ? 1 : 0;
#endif
  }
};

/// Per-run constants of the pre-test's margin: the edge-plane test's rounding in E's units (pixels^2) for
/// triangles whose edges are at most `max_edge_m` long and lie at least `z_min_m` deep, and bounds on the
/// samples' offsets from the principal point. The float edge plane n = lo x (hi - lo) and the ray d are
/// off by ~3 and ~2 ulps, the dot product by ~3 more: |n . d error| <= ~14 u |lo| |hi - lo| |d| (u =
/// 2^-24), i.e. <= ~14 u |d|^2 fy L (f + L) in E with L = f max_edge / z_min the longest edge in pixels
/// (the L^2 part bounds the triangle's orientation); 2^-19 is twice that. Infinite (no pre-test) when the
/// triangles may reach the near plane.
struct ScreenBounds {
  float rounding_px2;  ///< times |d|^2
  float roi_px;        ///< >= |u - cx|, |v - cy| of the ROI's samples
  float inv_f2;        ///< 1/fx^2 + 1/fy^2: |d|^2 <= 1 + r^2 inv_f2 for offsets up to r
  PERCH2_HD ScreenBounds(const Intrinsics& K, int stride, const GridRoi& roi, float max_edge_m, float z_min_m,
                         float near_m) {
    const float f = max_f(K.fx, K.fy), L = f * max_edge_m / z_min_m;
    rounding_px2 = z_min_m >= near_m ? 0x1p-19f * L * (f + L) : 1e30f;
    const float u0 = float(stride * roi.i0) - K.cx, u1 = float(stride * (roi.i0 + roi.width)) - K.cx;
    const float v0 = float(stride * roi.j0) - K.cy, v1 = float(stride * (roi.j0 + roi.height)) - K.cy;
    roi_px = max_f(max_f(fabsf(u0), fabsf(u1)), max_f(fabsf(v0), fabsf(v1)));
    inv_f2 = 1.f / (K.fx * K.fx) + 1.f / (K.fy * K.fy);
  }
};

/// Sets up the pre-test of a triangle whose corners are all in front of the near plane and whose spans
/// cover a sample of the ROI; false if it is too close to degenerate in the image (sign of area uncertain).
PERCH2_HD_FORCE_INLINE bool screen_triangle(const GridSpan& sa, const GridSpan& sb, const GridSpan& sc,
                                            const Intrinsics& K, const ScreenBounds& bounds,
                                            ScreenTriangle& t) {
  const float qx[3] = {sa.du_px, sb.du_px, sc.du_px};
  const float qy[3] = {sa.dv_px, sb.dv_px, sc.dv_px};
  const float ex[3] = {qx[1] - qx[0], qx[2] - qx[1], qx[0] - qx[2]};
  const float ey[3] = {qy[1] - qy[0], qy[2] - qy[1], qy[0] - qy[2]};
  const float area = ex[2] * ey[0] - ey[2] * ex[0];  // E_0(q_2) = e_0 x (q_2 - q_0), q_2 - q_0 = -e_2
  // Extent: >= bounding box width + height (two edges span it), + the span filter's epsilon.
  const float span = fabsf(ex[0]) + fabsf(ex[1]) + fabsf(ey[0]) + fabsf(ey[1]) + 0.01f;
  // A covered sample lies within `span` of every corner, so r bounds the corners' and samples' offsets.
  const float r = bounds.roi_px + span;
  // Offsets q = fx x (1/z) are off by <= 3 u r each (u = 2^-24), the samples' s - cx by u r, moving E by
  // <= 14 u r span; E's products and differences round by <= 6 u span^2. 2^-18 is > 4x their sum.
  t.margin = 0x1p-18f * (r + span) * span + (1.f + r * r * bounds.inv_f2) * bounds.rounding_px2;
  if (!(fabsf(area) > t.margin)) return false;  // also NaN
  const float o = area > 0.f ? 1.f : -1.f;
  t.back_facing = area > 0.f;  // a . (b x c) has the sign of the projected area (fx, fy > 0)
#if defined(PERCH2_RASTER_SSE2)
  t.qx = _mm_setr_ps(qx[0], qx[1], qx[2], 0.f), t.qy = _mm_setr_ps(qy[0], qy[1], qy[2], 0.f);
  t.ex = _mm_mul_ps(_mm_set1_ps(o), _mm_setr_ps(ex[0], ex[1], ex[2], 0.f));
  t.ey = _mm_mul_ps(_mm_set1_ps(o), _mm_setr_ps(ey[0], ey[1], ey[2], 0.f));
#else
  for (int k = 0; k < 3; ++k) t.qx[k] = qx[k], t.qy[k] = qy[k], t.ex[k] = o * ex[k], t.ey[k] = o * ey[k];
#endif
  return true;
}

#if defined(PERCH2_RASTER_SSE2)
/// ScreenTriangle's set-up and verdict for four candidates at once, each with the one sample (i[l], j[l])
/// its cover holds (the common case at stride >= 2), in the same float operations. Bit l of `general`: lane
/// l needs the per-triangle path (image-degenerate, or a corner behind the near plane: NaN offsets); of the
/// others, `back` are clearly back-facing, `out` clearly miss, `in` clearly hit.
struct ScreenVerdicts {
  int general, back, out, in;
};
inline ScreenVerdicts screen_single_samples(const std::int32_t* const* f, const GridSpan* span, const int* i,
                                            const int* j, const Intrinsics& K, int stride,
                                            const ScreenBounds& bounds) {
  __m128 qx[3], qy[3];
  for (int c = 0; c < 3; ++c) {  // corner c of the four triangles: (du, dv) are floats 2, 3 of a GridSpan
    const auto load = [&](int l) { return _mm_loadu_ps(reinterpret_cast<const float*>(span + f[l][c])); };
    const __m128 a = _mm_unpackhi_ps(load(0), load(1)), b = _mm_unpackhi_ps(load(2), load(3));
    qx[c] = _mm_movelh_ps(a, b), qy[c] = _mm_movehl_ps(b, a);
  }
  const __m128 x =
      _mm_sub_ps(_mm_cvtepi32_ps(_mm_setr_epi32(stride * i[0], stride * i[1], stride * i[2], stride * i[3])),
                 _mm_set1_ps(K.cx));
  const __m128 y =
      _mm_sub_ps(_mm_cvtepi32_ps(_mm_setr_epi32(stride * j[0], stride * j[1], stride * j[2], stride * j[3])),
                 _mm_set1_ps(K.cy));
  __m128 ex[3], ey[3];
  for (int c = 0; c < 3; ++c)
    ex[c] = _mm_sub_ps(qx[c == 2 ? 0 : c + 1], qx[c]), ey[c] = _mm_sub_ps(qy[c == 2 ? 0 : c + 1], qy[c]);
  const __m128 area = _mm_sub_ps(_mm_mul_ps(ex[2], ey[0]), _mm_mul_ps(ey[2], ex[0]));
  const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
  const auto abs = [&](__m128 v) { return _mm_and_ps(v, abs_mask); };
  const __m128 span_px = _mm_add_ps(
      _mm_add_ps(_mm_add_ps(abs(ex[0]), abs(ex[1])), _mm_add_ps(abs(ey[0]), abs(ey[1]))), _mm_set1_ps(0.01f));
  const __m128 r = _mm_add_ps(_mm_set1_ps(bounds.roi_px), span_px);
  const __m128 margin = _mm_add_ps(
      _mm_mul_ps(_mm_mul_ps(_mm_set1_ps(0x1p-18f), _mm_add_ps(r, span_px)), span_px),
      _mm_mul_ps(_mm_add_ps(_mm_set1_ps(1.f), _mm_mul_ps(_mm_mul_ps(r, r), _mm_set1_ps(bounds.inv_f2))),
                 _mm_set1_ps(bounds.rounding_px2)));
  const __m128 flip = _mm_andnot_ps(abs_mask, area);  // the sign of the area: orients E positive inside
  const __m128 neg_margin = _mm_sub_ps(_mm_setzero_ps(), margin);
  __m128 out = _mm_setzero_ps(), in = _mm_castsi128_ps(_mm_set1_epi32(-1));
  for (int c = 0; c < 3; ++c) {
    const __m128 E = _mm_xor_ps(
        flip, _mm_sub_ps(_mm_mul_ps(ex[c], _mm_sub_ps(y, qy[c])), _mm_mul_ps(ey[c], _mm_sub_ps(x, qx[c]))));
    out = _mm_or_ps(out, _mm_cmplt_ps(E, neg_margin)), in = _mm_and_ps(in, _mm_cmpgt_ps(E, margin));
  }
  return {~_mm_movemask_ps(_mm_cmpgt_ps(abs(area), margin)) & 15,
          _mm_movemask_ps(_mm_cmpgt_ps(area, _mm_setzero_ps())), _mm_movemask_ps(out), _mm_movemask_ps(in)};
}
#endif

}  // namespace perch2
