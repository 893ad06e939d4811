// Device-callable rasterisation kernels shared by every backend (the algorithm text lives once).
//
// Homogeneous rasterisation (Olano & Greer 1997): each triangle (a, b, c) in the camera frame gets three
// edge planes through the camera centre; a pixel ray d = (x, y, 1) hits the triangle iff it lies on the
// inner side of all three. No screen-space clipping is needed: triangles crossing the near plane are
// handled per sample (z >= near).
//
// Conditioning. Scanned models have millimetre triangles a metre away, so every quantity is formed from
// vertex-relative (edge) vectors, never from triple products of the ~1 m position vectors, whose
// cancellation cost up to 3% of the depth in float:
// - edge plane of edge (p, q): p x (q - p) (= p x q), with (p, q) ordered canonically by coordinates, so the
//   two triangles sharing an edge compute the same bits with opposite signs (watertight: a sample on a
//   shared edge is covered by at least one of them);
// - plane normal N = (b - a) x (c - a); depth along d: z = (N . a) / (N . d);
// - barycentrics of the hit p = z d from q = p - a: w_b = (q x e2) . N / |N|^2, w_c = (e1 x q) . N / |N|^2.
#pragma once

#include <cmath>
#include <cstdint>

#include "perch2/core/camera.hpp"
#include "perch2/core/device.hpp"

#if defined(__SSE2__) && !defined(__CUDA_ARCH__)
#include <emmintrin.h>
#define PERCH2_RASTER_SSE2 1
#endif

// Forces inlining of the per-triangle set-up into the triangle loop (GCC stopped inlining it once it grew,
// costing ~10% of the raster time in a call that returns its result through memory).
#if defined(__CUDACC__)
#define PERCH2_HD_FORCE_INLINE __host__ __device__ __forceinline__
#elif defined(__GNUC__)
#define PERCH2_HD_FORCE_INLINE inline __attribute__((always_inline))
#else
#define PERCH2_HD_FORCE_INLINE inline
#endif

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

/// Per-triangle set-up: sign-normalised edge planes and plane (normal, offset) with the ray hitting the
/// front side where n[k] . d >= 0 for all k, depth = offset / (normal . d); and the grid samples to test.
struct TriangleRaster {
  Vec3f n[3];
  Vec3f normal;
  float offset = 0;
  GridRoi cover;
};

/// Lexicographic order of points: the canonical direction of an edge. Branch-free: the comparison is data
/// dependent and mispredicts half the time in a branchy form.
PERCH2_HD inline bool lex_less(Vec3f p, Vec3f q) {
  return (p.x < q.x) | ((p.x == q.x) & ((p.y < q.y) | ((p.y == q.y) & (p.z < q.z))));
}

/// Normal of the plane through the camera centre and edge (p, q), pointing to the left of p -> q seen from
/// the camera (as p x q). Computed from the lexicographically smaller endpoint and the edge vector, so the
/// reversed edge gives exactly the negated bits.
PERCH2_HD inline Vec3f edge_plane(Vec3f p, Vec3f q) {
  const bool swap = lex_less(q, p);
  const Vec3f lo{swap ? q.x : p.x, swap ? q.y : p.y, swap ? q.z : p.z};
  const Vec3f hi{swap ? p.x : q.x, swap ? p.y : q.y, swap ? p.z : q.z};
  const Vec3f n = cross(lo, hi - lo);
  const float sign = swap ? -1.f : 1.f;
  return sign * n;
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

PERCH2_HD inline int min3(int a, int b, int c) {
  return min_int(min_int(a, b), c);
}
PERCH2_HD inline int max3(int a, int b, int c) {
  return max_int(max_int(a, b), c);
}

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

/// Branch-free select: a float comparison in a conditional expression keeps the loop from vectorising
/// (the comparison may trap, so the compiler will not if-convert it).
PERCH2_HD inline int select_int(bool c, int a, int b) {
  const int mask = -int(c);
  return (a & mask) | (b & ~mask);
}

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

/// The plane of camera-frame triangle (a, b, c) into t.normal, t.offset, sign-normalised (s: the sign
/// applied) so that a ray d hits its front where t.normal . d > 0, at depth t.offset / (t.normal . d).
/// Returns false if the triangle is degenerate or culled as a back face.
PERCH2_HD_FORCE_INLINE bool triangle_plane(Vec3f a, Vec3f b, Vec3f c, bool cull_back_faces, TriangleRaster& t,
                                           float& s) {
  const Vec3f normal = cross(b - a, c - a);
  const float offset = dot(normal, a);  // = a . (b x c), without the cancellation
  // offset < 0: counter-clockwise winding faces the camera (outward normal points at the origin).
  if (offset == 0.f || !(offset == offset) || (cull_back_faces && offset > 0.f)) return false;
  s = offset < 0.f ? -1.f : 1.f;
  t.normal = s * normal, t.offset = s * offset;
  return true;
}

/// Returns false if the triangle covers no sample of `roi` (degenerate, culled, behind the near plane).
/// `sa, sb, sc` are the corners' grid spans (used when all corners are in front of the near plane).
PERCH2_HD_FORCE_INLINE bool setup_triangle(const PosedVertices& p_cam, const std::int32_t* f,
                                           const GridSpan& sa, const GridSpan& sb, const GridSpan& sc,
                                           const Intrinsics& K, int stride, float near_m, const GridRoi& roi,
                                           bool cull_back_faces, TriangleRaster& t) {
  if (min3(sa.i_lo, sb.i_lo, sc.i_lo) != kBehindNear) {
    t.cover = span_cover(sa, sb, sc, roi);
    if (t.cover.size() == 0) return false;
  } else {
    PixelBounds bounds;
    const Vec3f v[3] = {p_cam[f[0]], p_cam[f[1]], p_cam[f[2]]};
    for (int k = 0; k < 3; ++k) {  // clip the polygon against z >= near, projecting what remains
      const Vec3f p = v[k], q = v[(k + 1) % 3];
      if (p.z >= near_m) bounds.add(K, p);
      if ((p.z >= near_m) != (q.z >= near_m)) {
        const float w = (near_m - p.z) / (q.z - p.z);
        Vec3f x = p + w * (q - p);
        x.z = near_m;
        bounds.add(K, x);
      }
    }
    t.cover = grid_cover(bounds, stride, roi);
    if (t.cover.size() == 0) return false;
  }
  const Vec3f a = p_cam[f[0]], b = p_cam[f[1]], c = p_cam[f[2]];
  float s;
  if (!triangle_plane(a, b, c, cull_back_faces, t, s)) return false;
  t.n[0] = s * edge_plane(b, c), t.n[1] = s * edge_plane(c, a), t.n[2] = s * edge_plane(a, b);
  return true;
}

/// The depth (z, metres) of the triangle's plane along a ray, and whether the ray meets its front side
/// beyond the near plane.
PERCH2_HD inline bool sample_plane(const TriangleRaster& t, Vec3f ray, float near_m, float& depth_m) {
  const float along_normal = dot(t.normal, ray);
  depth_m = t.offset / along_normal;
  return (along_normal > 0.f) & (depth_m >= near_m);
}

/// Edge-function test of one ray: on a hit, the depth (z, metres) of the triangle along it. Branch-free
/// (the depth is computed for every ray, its value only used on a hit): whether a candidate triangle hits
/// its sample is close to a coin toss at stride >= 2, which branches would mispredict.
PERCH2_HD inline bool sample_triangle(const TriangleRaster& t, Vec3f ray, float near_m, float& depth_m) {
  return (dot(t.n[0], ray) >= 0.f) & (dot(t.n[1], ray) >= 0.f) & (dot(t.n[2], ray) >= 0.f) &
         sample_plane(t, ray, near_m, depth_m);
}

PERCH2_HD inline std::uint8_t to_u8(float c) {
  return std::uint8_t(min_f(max_f(c + 0.5f, 0.f), 255.f));
}

/// The four texels and weights of a bilinear texture lookup at (u, v): OBJ convention (v = 0 at the image
/// bottom), repeating outside [0, 1]. sample_texture in two steps, so that a caller can fetch the texels of
/// many lookups at once (the texture is often far larger than the caches).
struct TexelQuad {
  int i00, i10, i01, i11;  ///< texel indices: (x0, y0), (x1, y0), (x0, y1), (x1, y1)
  float wx, wy;
};
PERCH2_HD inline TexelQuad texel_quad(const MeshView& m, float u, float v) {
  const float x = (u - floorf(u)) * float(m.texture_width) - 0.5f;
  const float y = (1.f - (v - floorf(v))) * float(m.texture_height) - 0.5f;
  const float xf = floorf(x), yf = floorf(y);
  const int W = m.texture_width, H = m.texture_height;
  // x is in [-0.5, W - 0.5], so floor(x) in [-1, W - 1]: wrap without integer division (the clamp only
  // keeps a non-finite coordinate inside the texture).
  const int x0 = min_int(max_int(select_int(xf < 0.f, W - 1, int(xf)), 0), W - 1);
  const int y0 = min_int(max_int(select_int(yf < 0.f, H - 1, int(yf)), 0), H - 1);
  const int x1 = select_int(x0 + 1 == W, 0, x0 + 1), y1 = select_int(y0 + 1 == H, 0, y0 + 1);
  return {y0 * W + x0, y0 * W + x1, y1 * W + x0, y1 * W + x1, x - xf, y - yf};
}
PERCH2_HD inline Rgb8 mix_texels(const MeshView& m, const TexelQuad& q) {
  const Rgb8 c00 = m.texture[q.i00], c10 = m.texture[q.i10], c01 = m.texture[q.i01], c11 = m.texture[q.i11];
  const float wx = q.wx, wy = q.wy;
  auto mix = [&](float p00, float p10, float p01, float p11) {
    return to_u8((1 - wy) * ((1 - wx) * p00 + wx * p10) + wy * ((1 - wx) * p01 + wx * p11));
  };
  return {mix(c00.r, c10.r, c01.r, c11.r), mix(c00.g, c10.g, c01.g, c11.g), mix(c00.b, c10.b, c01.b, c11.b)};
}
/// Bilinear texture lookup (texel_quad, then mix_texels).
PERCH2_HD inline Rgb8 sample_texture(const MeshView& m, float u, float v) {
  return mix_texels(m, texel_quad(m, u, v));
}

/// Barycentrics (w0, w1, w2) of camera-frame point `hit` in triangle (a, b, c): of the 3-D hit, so
/// perspective-correct by construction.
PERCH2_HD inline Vec3f barycentrics(Vec3f a, Vec3f b, Vec3f c, Vec3f hit) {
  const Vec3f e1 = b - a, e2 = c - a, q = hit - a, normal = cross(e1, e2);
  const float inv = 1.f / dot(normal, normal);
  const float w1 = dot(cross(q, e2), normal) * inv, w2 = dot(cross(e1, q), normal) * inv;
  return {1.f - w1 - w2, w1, w2};
}

/// Texture coordinates of triangle `tri` at barycentrics w (a textured model).
PERCH2_HD inline Vec2f texture_uv(const MeshView& m, int tri, Vec3f w) {
  const Vec2f t0 = m.corner_uvs[3 * tri], t1 = m.corner_uvs[3 * tri + 1], t2 = m.corner_uvs[3 * tri + 2];
  return {w.x * t0.x + w.y * t1.x + w.z * t2.x, w.x * t0.y + w.y * t1.y + w.z * t2.y};
}

PERCH2_HD inline bool textured(const MeshView& m) {
  return m.texture && m.corner_uvs;
}

/// Colour of triangle `tri` (camera-frame corners a, b, c) at its camera-frame point `hit`: texture, else
/// interpolated vertex colours, else the model's base colour.
PERCH2_HD inline Rgb8 shade(const MeshView& m, int tri, Vec3f a, Vec3f b, Vec3f c, Vec3f hit) {
  const Vec3f w = barycentrics(a, b, c, hit);
  if (textured(m)) {
    const Vec2f uv = texture_uv(m, tri, w);
    return sample_texture(m, uv.x, uv.y);
  }
  if (m.vertex_colors) {
    const std::int32_t* f = m.triangles + 3 * tri;
    const Rgb8 c0 = m.vertex_colors[f[0]], c1 = m.vertex_colors[f[1]], c2 = m.vertex_colors[f[2]];
    return {to_u8(w.x * c0.r + w.y * c1.r + w.z * c2.r), to_u8(w.x * c0.g + w.y * c1.g + w.z * c2.g),
            to_u8(w.x * c0.b + w.y * c1.b + w.z * c2.b)};
  }
  return m.base_color;
}

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

/// Double-precision 3-vectors for the exact coverage test (covers_exactly).
struct Vec3d {
  double x, y, z;
};
PERCH2_HD inline Vec3d operator-(Vec3d a, Vec3d b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}
PERCH2_HD inline double dot(Vec3d a, Vec3d b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
PERCH2_HD inline Vec3d cross(Vec3d a, Vec3d b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}

/// Whether the ray through pixel (u, v) passes inside triangle f of the model posed by T_cam_obj, decided
/// in double precision: corners posed in double (the float posing is off by ~1e-7 of the distance, ~1e-4
/// px), edge planes in edge_plane's canonical order (the two triangles of an edge get exactly negated
/// planes: watertight), ray (u - cx) / fx, (v - cy) / fy. Float decisions can differ within ~1e-5 px of an
/// edge, which at a silhouette lets a triangle in front claim a sample whose ray misses it; this test is
/// run only there (ScreenTriangle's margin), so it costs little.
PERCH2_HD inline bool covers_exactly(const MeshView& m, const std::int32_t* f, const Rigid3f& T,
                                     const Intrinsics& K, float u_px, float v_px) {
  Vec3d p[3];
  for (int k = 0; k < 3; ++k) {
    const Vec3f q = m.vertices[f[k]];
    const double x = q.x, y = q.y, z = q.z;
    p[k] = {T.R.m[0] * x + T.R.m[1] * y + T.R.m[2] * z + T.t.x,
            T.R.m[3] * x + T.R.m[4] * y + T.R.m[5] * z + T.t.y,
            T.R.m[6] * x + T.R.m[7] * y + T.R.m[8] * z + T.t.z};
  }
  const Vec3d d{(double(u_px) - K.cx) / K.fx, (double(v_px) - K.cy) / K.fy, 1.0};
  const double det = dot(cross(p[1] - p[0], p[2] - p[0]), p[0]);
  if (!(det != 0.0)) return false;
  const double s = det < 0.0 ? -1.0 : 1.0;
  for (int k = 0; k < 3; ++k) {
    const Vec3d a = p[k == 2 ? 0 : k + 1], b = p[k == 0 ? 2 : k - 1];  // the edge opposite corner k
    const bool swap = (b.x < a.x) | ((b.x == a.x) & ((b.y < a.y) | ((b.y == a.y) & (b.z < a.z))));
    const Vec3d lo = swap ? b : a, hi = swap ? a : b;
    const double e = dot(cross(lo, hi - lo), d);
    if (!((swap ? -s : s) * e >= 0.0)) return false;
  }
  return true;
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

/// C-PERCH occluder test for a rendered depth at one full-resolution pixel.
PERCH2_HD inline bool is_occluded(float rendered_depth_m, float observed_depth_m, bool has_labels,
                                  std::int32_t observed_label, std::int32_t hypothesis_label,
                                  float margin_m) {
  if (!(observed_depth_m > 0.f)) return false;  // no reading: cannot occlude
  if (observed_depth_m >= rendered_depth_m - margin_m) return false;
  return !has_labels || observed_label != hypothesis_label;
}

/// Observed images for occluder marking, as raw full-resolution arrays (null: none).
struct OccluderView {
  const float* depth_m = nullptr;
  const std::int32_t* labels = nullptr;
  float margin_m = 0.f;
};

/// One visible rendered sample: camera-frame point, colour and full-resolution pixel index.
struct RenderedSample {
  Vec3f p_cam;
  std::uint32_t rgb;
  std::int32_t pixel;
};

/// Resolve pass for one z-buffer word of grid sample (i, j), before shading: decode the winning triangle,
/// drop the sample if an observed occluder hides it, else set its point and pixel and keep its triangle in
/// out.rgb for shade_sample(s). Returns false for empty or occluded samples.
PERCH2_HD inline bool resolve_point(DepthTriangle word, const Intrinsics& K, const GridRays& rays, int i,
                                    int j, const OccluderView& occ, std::int32_t hypothesis_label,
                                    RenderedSample& out) {
  if (word == kEmptyPixel) return false;
  const float depth_m = unpack_depth(word);
  const int u = rays.stride * i, v = rays.stride * j;
  out.pixel = v * K.width + u;
  if (occ.depth_m && is_occluded(depth_m, occ.depth_m[out.pixel], occ.labels != nullptr,
                                 occ.labels ? occ.labels[out.pixel] : 0, hypothesis_label, occ.margin_m))
    return false;
  out.p_cam = depth_m * rays(i, j);
  out.rgb = unpack_triangle(word);
  return true;
}

/// Colours a resolved sample (its triangle in s.rgb).
PERCH2_HD inline void shade_sample(const MeshView& m, const PosedVertices& verts_cam, RenderedSample& s) {
  const int tri = int(s.rgb);
  const std::int32_t* f = m.triangles + 3 * tri;
  s.rgb = pack_rgb(shade(m, tri, verts_cam[f[0]], verts_cam[f[1]], verts_cam[f[2]], s.p_cam));
}

/// resolve_point, then shade_sample.
PERCH2_HD inline bool resolve_sample(const MeshView& m, const PosedVertices& verts_cam, DepthTriangle word,
                                     const Intrinsics& K, const GridRays& rays, int i, int j,
                                     const OccluderView& occ, std::int32_t hypothesis_label,
                                     RenderedSample& out) {
  if (!resolve_point(word, K, rays, i, j, occ, hypothesis_label, out)) return false;
  shade_sample(m, verts_cam, out);
  return true;
}

/// Colours n resolved samples. With a texture, a sample's texels are requested kTexelLookahead samples
/// before they are mixed: the lookups of a large texture miss the caches, and one after another each would
/// wait for memory (on the YCB banana's 4096^2 texture ~40% of the render; the same colours either way).
constexpr int kTexelLookahead = 8;
PERCH2_HD inline void shade_samples(const MeshView& m, const PosedVertices& verts_cam, RenderedSample* s,
                                    int n) {
  if (!textured(m)) {
    for (int k = 0; k < n; ++k) shade_sample(m, verts_cam, s[k]);
    return;
  }
  TexelQuad q[kTexelLookahead];
  for (int k = 0; k < n + kTexelLookahead; ++k) {
    const int slot = k % kTexelLookahead;
    if (k >= kTexelLookahead) s[k - kTexelLookahead].rgb = pack_rgb(mix_texels(m, q[slot]));
    if (k >= n) continue;
    const int tri = int(s[k].rgb);
    const std::int32_t* f = m.triangles + 3 * tri;
    const Vec2f uv =
        texture_uv(m, tri, barycentrics(verts_cam[f[0]], verts_cam[f[1]], verts_cam[f[2]], s[k].p_cam));
    q[slot] = texel_quad(m, uv.x, uv.y);
#if defined(PERCH2_RASTER_SSE2)
    for (const int t : {q[slot].i00, q[slot].i10, q[slot].i01, q[slot].i11})
      _mm_prefetch(reinterpret_cast<const char*>(m.texture + t), _MM_HINT_T0);
#endif
  }
}

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
