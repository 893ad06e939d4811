// Vertex posing: a model's vertices into the camera frame with their grid spans (VertexPoser, SSE2 four at
// a time), all of them (pose_vertices) or only some vertex blocks (pose_vertex_blocks).
#pragma once

#include <cstdint>

#include "perch2/core/camera.hpp"
#include "perch2/core/device.hpp"
#include "perch2/render/raster/common.hpp"
#include "perch2/render/raster/grid.hpp"
#include "perch2/render/raster/mesh_view.hpp"

namespace perch2 {

/// A posed vertex: camera-frame point padded to 16 bytes (the posing loop's four-float stores vectorise, and
/// a triangle set-up reads each corner from one cache line).
struct PosedPoint {
  float x, y, z, pad;
};

/// A posed model's vertices and their grid spans (meaningful where z >= near).
struct PosedVertices {
  const PosedPoint* p_cam;
  const GridSpan* span;
  PERCH2_HD Vec3f operator[](int k) const { return {p_cam[k].x, p_cam[k].y, p_cam[k].z}; }
};

#if defined(PERCH2_RASTER_SSE2)
/// The pose, intrinsics and grid of a VertexPoser in four lanes each.
struct PoseLanes {
  __m128 R[9], t[3], fx, fy, cx, cy, near_m, inv_stride, width, height;
};
#endif

/// Poses a model's vertices into the camera frame (p_cam[k]) and computes their grid spans: any ranges of
/// them for one pose, its constants computed (and broadcast) once, so that a short range costs little.
struct VertexPoser {
  const float *vx, *vy, *vz;  ///< MeshView::vertex_xyz's three arrays
  Rigid3f T;
  Intrinsics K;
  StrideGrid g;
  float near_m;
#if defined(PERCH2_RASTER_SSE2)
  PoseLanes lanes;
#endif
  PERCH2_HD VertexPoser(const MeshView& m, const Rigid3f& T_cam_obj, const Intrinsics& K_, int stride,
                        float near_m_)
      : vx(m.vertex_xyz),
        vy(m.vertex_xyz + m.num_vertices),
        vz(m.vertex_xyz + 2 * m.num_vertices),
        T(T_cam_obj),
        K(K_),
        g(K_, stride),
        near_m(near_m_) {
#if defined(PERCH2_RASTER_SSE2)
    for (int k = 0; k < 9; ++k) lanes.R[k] = _mm_set1_ps(T.R.m[k]);
    lanes.t[0] = _mm_set1_ps(T.t.x), lanes.t[1] = _mm_set1_ps(T.t.y), lanes.t[2] = _mm_set1_ps(T.t.z);
    lanes.fx = _mm_set1_ps(K.fx), lanes.fy = _mm_set1_ps(K.fy), lanes.cx = _mm_set1_ps(K.cx);
    lanes.cy = _mm_set1_ps(K.cy), lanes.near_m = _mm_set1_ps(near_m);
    lanes.inv_stride = _mm_set1_ps(g.inv_stride), lanes.width = _mm_set1_ps(g.width);
    lanes.height = _mm_set1_ps(g.height);
#endif
  }
  PERCH2_HD void pose(int begin, int end, PosedPoint* __restrict__ p_cam, GridSpan* __restrict__ span) const;
};

/// Vertices [begin, end). Branch-free, reading structure-of-arrays input: compilers vectorise it (SSE2: four
/// vertices per instruction, with divps for the one division per vertex).
PERCH2_HD inline void VertexPoser::pose(int begin, int end, PosedPoint* __restrict__ p_cam,
                                        GridSpan* __restrict__ span) const {
  const float* __restrict__ vx = this->vx;
  const float* __restrict__ vy = this->vy;
  const float* __restrict__ vz = this->vz;
  constexpr float kEps = 1e-3f;  // pixels; spans are a superset filter, the edge test is exact
  auto clamp = [](float x, float hi) { return min_f(max_f(x, -1.f), hi); };
  int k = begin;
#if defined(PERCH2_RASTER_SSE2)
  // Four vertices per step in the same float operations as the loop below (which does the rest): g++'s
  // vectorisation of that loop spent ~50 instructions per vertex on the interleaved stores.
  const PoseLanes& c = lanes;
  const auto mul = [](__m128 a, __m128 b) { return _mm_mul_ps(a, b); };
  const auto add = [](__m128 a, __m128 b) { return _mm_add_ps(a, b); };
  const auto set = [](float a) { return _mm_set1_ps(a); };
  const auto row = [&](int r, __m128 X, __m128 Y, __m128 Z) {
    return add(add(add(mul(c.R[3 * r], X), mul(c.R[3 * r + 1], Y)), mul(c.R[3 * r + 2], Z)), c.t[r]);
  };
  const auto clamp4 = [](__m128 x, __m128 hi) { return _mm_min_ps(_mm_max_ps(x, _mm_set1_ps(-1.f)), hi); };
  const auto ceil4 = [](__m128 x) {  // ceil_int: i + (x > i)
    const __m128i i = _mm_cvttps_epi32(x);
    return _mm_sub_epi32(i, _mm_castps_si128(_mm_cmpgt_ps(x, _mm_cvtepi32_ps(i))));
  };
  const auto floor4 = [](__m128 x) {  // floor_int: i - (x < i)
    const __m128i i = _mm_cvttps_epi32(x);
    return _mm_add_epi32(i, _mm_castps_si128(_mm_cmplt_ps(x, _mm_cvtepi32_ps(i))));
  };
  const auto select = [](__m128i mask, __m128i a, __m128i b) {
    return _mm_or_si128(_mm_and_si128(mask, a), _mm_andnot_si128(mask, b));
  };
  for (; k + 4 <= end; k += 4) {
    const __m128 X = _mm_loadu_ps(vx + k), Y = _mm_loadu_ps(vy + k), Z = _mm_loadu_ps(vz + k);
    const __m128 x = row(0, X, Y, Z), y = row(1, X, Y, Z), z = row(2, X, Y, Z);
    const __m128 inv_z = _mm_div_ps(set(1.f), z);
    const __m128 du = mul(mul(c.fx, x), inv_z), dv = mul(mul(c.fy, y), inv_z);
    const __m128 u = add(du, c.cx), v = add(dv, c.cy);
    const __m128i in_front = _mm_castps_si128(_mm_cmpge_ps(z, c.near_m));
    const __m128 s = c.inv_stride, eps = set(kEps);
    const __m128i i_lo =
        select(in_front, ceil4(clamp4(mul(_mm_sub_ps(u, eps), s), c.width)), _mm_set1_epi32(kBehindNear));
    const __m128i j_lo =
        select(in_front, ceil4(clamp4(mul(_mm_sub_ps(v, eps), s), c.height)), _mm_set1_epi32(kBehindNear));
    const __m128i zero = _mm_setzero_si128();
    const __m128i neg_i_hi =
        select(in_front, _mm_sub_epi32(zero, floor4(clamp4(mul(add(u, eps), s), c.width))),
               _mm_set1_epi32(-kMaxGridSize));
    const __m128i neg_j_hi =
        select(in_front, _mm_sub_epi32(zero, floor4(clamp4(mul(add(v, eps), s), c.height))),
               _mm_set1_epi32(-kMaxGridSize));
    const __m128i nan = _mm_set1_epi32(0x7fc00000);
    const __m128 du_s = _mm_castsi128_ps(select(in_front, _mm_castps_si128(du), nan));
    const __m128 dv_s = _mm_castsi128_ps(select(in_front, _mm_castps_si128(dv), nan));
    // GridSpan records: (i_lo, j_lo, -i_hi, -j_hi) as int16 (all within int16), then du, dv.
    const __m128i a = _mm_packs_epi32(i_lo, neg_i_hi), b = _mm_packs_epi32(j_lo, neg_j_hi);
    const __m128i lo = _mm_unpacklo_epi16(a, b), hi = _mm_unpackhi_epi16(a, b);  // (i, j) and (-i, -j) pairs
    const __m128i s01 = _mm_unpacklo_epi32(lo, hi), s23 = _mm_unpackhi_epi32(lo, hi);
    const __m128i d01 = _mm_castps_si128(_mm_unpacklo_ps(du_s, dv_s)),
                  d23 = _mm_castps_si128(_mm_unpackhi_ps(du_s, dv_s));
    __m128i* out = reinterpret_cast<__m128i*>(span + k);
    _mm_storeu_si128(out, _mm_unpacklo_epi64(s01, d01)),
        _mm_storeu_si128(out + 1, _mm_unpackhi_epi64(s01, d01));
    _mm_storeu_si128(out + 2, _mm_unpacklo_epi64(s23, d23)),
        _mm_storeu_si128(out + 3, _mm_unpackhi_epi64(s23, d23));
    // Posed points (x, y, z, 0).
    const __m128 xy_lo = _mm_unpacklo_ps(x, y), xy_hi = _mm_unpackhi_ps(x, y);
    const __m128 z0_lo = _mm_unpacklo_ps(z, _mm_setzero_ps()), z0_hi = _mm_unpackhi_ps(z, _mm_setzero_ps());
    float* p = &p_cam[k].x;
    _mm_storeu_ps(p, _mm_movelh_ps(xy_lo, z0_lo)), _mm_storeu_ps(p + 4, _mm_movehl_ps(z0_lo, xy_lo));
    _mm_storeu_ps(p + 8, _mm_movelh_ps(xy_hi, z0_hi)), _mm_storeu_ps(p + 12, _mm_movehl_ps(z0_hi, xy_hi));
  }
#endif
  for (; k < end; ++k) {
    const float X = vx[k], Y = vy[k], Z = vz[k];
    const float x = T.R.m[0] * X + T.R.m[1] * Y + T.R.m[2] * Z + T.t.x;
    const float y = T.R.m[3] * X + T.R.m[4] * Y + T.R.m[5] * Z + T.t.y;
    const float z = T.R.m[6] * X + T.R.m[7] * Y + T.R.m[8] * Z + T.t.z;
    p_cam[k].x = x, p_cam[k].y = y, p_cam[k].z = z, p_cam[k].pad = 0.f;
    // Behind the near plane the span is computed from garbage (clamped, never UB) and marked.
    const float inv_z = 1.f / z;
    const float du = K.fx * x * inv_z, dv = K.fy * y * inv_z;
    const float u = du + K.cx, v = dv + K.cy;
    const bool in_front = z >= near_m;
    const int i_lo = ceil_int(clamp((u - kEps) * g.inv_stride, g.width));
    const int j_lo = ceil_int(clamp((v - kEps) * g.inv_stride, g.height));
    const int i_hi = floor_int(clamp((u + kEps) * g.inv_stride, g.width));
    const int j_hi = floor_int(clamp((v + kEps) * g.inv_stride, g.height));
    span[k].i_lo = std::int16_t(select_int(in_front, i_lo, kBehindNear));
    span[k].j_lo = std::int16_t(select_int(in_front, j_lo, kBehindNear));
    span[k].neg_i_hi = std::int16_t(select_int(in_front, -i_hi, -kMaxGridSize));
    span[k].neg_j_hi = std::int16_t(select_int(in_front, -j_hi, -kMaxGridSize));
    constexpr int kNaN = 0x7fc00000;
    span[k].du_px = bits_float(std::uint32_t(select_int(in_front, int(float_bits(du)), kNaN)));
    span[k].dv_px = bits_float(std::uint32_t(select_int(in_front, int(float_bits(dv)), kNaN)));
  }
}

/// Poses vertices [begin, end) of a model (VertexPoser).
PERCH2_HD inline void pose_vertices(const MeshView& m, const Rigid3f& T_cam_obj, const Intrinsics& K,
                                    int stride, float near_m, int begin, int end, PosedPoint* p_cam,
                                    GridSpan* span) {
  VertexPoser(m, T_cam_obj, K, stride, near_m).pose(begin, end, p_cam, span);
}

/// Index of the lowest set bit of x != 0.
PERCH2_HD inline int lowest_bit(std::uint64_t x) {
#if defined(__CUDA_ARCH__)
  return __ffsll(static_cast<long long>(x)) - 1;
#else
  return __builtin_ctzll(x);
#endif
}

/// Poses the vertex blocks in `blocks` (a bit set over the model's vertex blocks): each run of consecutive
/// blocks in one pose().
PERCH2_HD inline void pose_vertex_blocks(const VertexPoser& poser, const std::uint64_t* blocks,
                                         int num_vertices, PosedPoint* p_cam, GridSpan* span) {
  for (int w = 0; w < vertex_block_words(num_vertices); ++w)
    for (std::uint64_t todo = blocks[w]; todo;) {
      // todo + its lowest bit: the lowest run of ones carried into the bit above it (0 if it ends at bit 63).
      const std::uint64_t carried = todo + (todo & (~todo + 1));
      const int first = 64 * w + lowest_bit(todo), last = 64 * w + (carried ? lowest_bit(carried) : 64);
      poser.pose(kPoseBlock * first, min_int(kPoseBlock * last, num_vertices), p_cam, span);
      todo &= carried;
    }
}

}  // namespace perch2
