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
};

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
  const TriangleCluster* clusters = nullptr;  ///< null (no cluster culling), or num_clusters covering all
  int num_clusters = 0;                       ///< triangles in order
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
/// has the whole grid as its span, with i_lo = kBehindNear marking it.
struct GridSpan {
  std::int16_t i_lo, j_lo, neg_i_hi, neg_j_hi;
};
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

/// Poses vertices [begin, end) of a model into the camera frame (p_cam[k]) and computes their grid spans.
/// Inputs are copied to locals first (the compiler would reload the pose and intrinsics after every store
/// otherwise); the body is branch-free and reads structure-of-arrays input, so compilers vectorise it
/// (SSE2: four vertices per instruction, with divps for the one division per vertex).
PERCH2_HD inline void pose_vertices(const MeshView& m, const Rigid3f& T_cam_obj, const Intrinsics& K,
                                    int stride, float near_m, int begin, int end,
                                    PosedPoint* __restrict__ p_cam, GridSpan* __restrict__ span) {
  const float* __restrict__ vx = m.vertex_xyz;
  const float* __restrict__ vy = m.vertex_xyz + m.num_vertices;
  const float* __restrict__ vz = m.vertex_xyz + 2 * m.num_vertices;
  const Rigid3f T = T_cam_obj;
  const Intrinsics K_local = K;
  const StrideGrid g(K, stride);
  constexpr float kEps = 1e-3f;  // pixels; spans are a superset filter, the edge test is exact
  auto clamp = [](float x, float hi) { return min_f(max_f(x, -1.f), hi); };
  for (int k = begin; k < end; ++k) {
    const float X = vx[k], Y = vy[k], Z = vz[k];
    const float x = T.R.m[0] * X + T.R.m[1] * Y + T.R.m[2] * Z + T.t.x;
    const float y = T.R.m[3] * X + T.R.m[4] * Y + T.R.m[5] * Z + T.t.y;
    const float z = T.R.m[6] * X + T.R.m[7] * Y + T.R.m[8] * Z + T.t.z;
    p_cam[k].x = x, p_cam[k].y = y, p_cam[k].z = z, p_cam[k].pad = 0.f;
    // Behind the near plane the span is computed from garbage (clamped, never UB) and marked.
    const float inv_z = 1.f / z;
    const float u = K_local.fx * x * inv_z + K_local.cx, v = K_local.fy * y * inv_z + K_local.cy;
    const bool in_front = z >= near_m;
    const int i_lo = ceil_int(clamp((u - kEps) * g.inv_stride, g.width));
    const int j_lo = ceil_int(clamp((v - kEps) * g.inv_stride, g.height));
    const int i_hi = floor_int(clamp((u + kEps) * g.inv_stride, g.width));
    const int j_hi = floor_int(clamp((v + kEps) * g.inv_stride, g.height));
    span[k].i_lo = std::int16_t(select_int(in_front, i_lo, kBehindNear));
    span[k].j_lo = std::int16_t(select_int(in_front, j_lo, kBehindNear));
    span[k].neg_i_hi = std::int16_t(select_int(in_front, -i_hi, -kMaxGridSize));
    span[k].neg_j_hi = std::int16_t(select_int(in_front, -j_hi, -kMaxGridSize));
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
  const Vec3f normal = cross(b - a, c - a);
  const float offset = dot(normal, a);  // = a . (b x c), without the cancellation
  // offset < 0: counter-clockwise winding faces the camera (outward normal points at the origin).
  if (offset == 0.f || !(offset == offset) || (cull_back_faces && offset > 0.f)) return false;
  const float s = offset < 0.f ? -1.f : 1.f;
  t.n[0] = s * edge_plane(b, c), t.n[1] = s * edge_plane(c, a), t.n[2] = s * edge_plane(a, b);
  t.normal = s * normal, t.offset = s * offset;
  return true;
}

/// Edge-function test of one ray: on a hit, the depth (z, metres) of the triangle along it. Branch-free
/// (the depth is computed for every ray, its value only used on a hit): whether a candidate triangle hits
/// its sample is close to a coin toss at stride >= 2, which branches would mispredict.
PERCH2_HD inline bool sample_triangle(const TriangleRaster& t, Vec3f ray, float near_m, float& depth_m) {
  const float along_normal = dot(t.normal, ray);
  depth_m = t.offset / along_normal;
  return (dot(t.n[0], ray) >= 0.f) & (dot(t.n[1], ray) >= 0.f) & (dot(t.n[2], ray) >= 0.f) &
         (along_normal > 0.f) & (depth_m >= near_m);
}

PERCH2_HD inline std::uint8_t to_u8(float c) {
  return std::uint8_t(min_f(max_f(c + 0.5f, 0.f), 255.f));
}

/// Bilinear texture lookup; OBJ convention (v = 0 at the image bottom), repeating outside [0, 1].
PERCH2_HD inline Rgb8 sample_texture(const MeshView& m, float u, float v) {
  const float x = (u - floorf(u)) * float(m.texture_width) - 0.5f;
  const float y = (1.f - (v - floorf(v))) * float(m.texture_height) - 0.5f;
  const float xf = floorf(x), yf = floorf(y);
  const float wx = x - xf, wy = y - yf;
  const int W = m.texture_width, H = m.texture_height;
  // x is in [-0.5, W - 0.5], so floor(x) in [-1, W - 1]: wrap without integer division (the clamp only
  // keeps a non-finite coordinate inside the texture).
  const int x0 = min_int(max_int(select_int(xf < 0.f, W - 1, int(xf)), 0), W - 1);
  const int y0 = min_int(max_int(select_int(yf < 0.f, H - 1, int(yf)), 0), H - 1);
  const int x1 = select_int(x0 + 1 == W, 0, x0 + 1), y1 = select_int(y0 + 1 == H, 0, y0 + 1);
  const Rgb8 c00 = m.texture[y0 * W + x0], c10 = m.texture[y0 * W + x1];
  const Rgb8 c01 = m.texture[y1 * W + x0], c11 = m.texture[y1 * W + x1];
  auto mix = [&](float p00, float p10, float p01, float p11) {
    return to_u8((1 - wy) * ((1 - wx) * p00 + wx * p10) + wy * ((1 - wx) * p01 + wx * p11));
  };
  return {mix(c00.r, c10.r, c01.r, c11.r), mix(c00.g, c10.g, c01.g, c11.g), mix(c00.b, c10.b, c01.b, c11.b)};
}

/// Colour of triangle `tri` (camera-frame corners a, b, c) at its camera-frame point `hit`: texture, else
/// interpolated vertex colours, else the model's base colour.
PERCH2_HD inline Rgb8 shade(const MeshView& m, int tri, Vec3f a, Vec3f b, Vec3f c, Vec3f hit) {
  const Vec3f e1 = b - a, e2 = c - a, q = hit - a, normal = cross(e1, e2);
  const float inv = 1.f / dot(normal, normal);
  const float w1 = dot(cross(q, e2), normal) * inv, w2 = dot(cross(e1, q), normal) * inv;
  const float w0 = 1.f - w1 - w2;  // barycentrics of the 3-D hit: perspective-correct by construction
  if (m.texture && m.corner_uvs) {
    const Vec2f t0 = m.corner_uvs[3 * tri], t1 = m.corner_uvs[3 * tri + 1], t2 = m.corner_uvs[3 * tri + 2];
    return sample_texture(m, w0 * t0.x + w1 * t1.x + w2 * t2.x, w0 * t0.y + w1 * t1.y + w2 * t2.y);
  }
  if (m.vertex_colors) {
    const std::int32_t* f = m.triangles + 3 * tri;
    const Rgb8 c0 = m.vertex_colors[f[0]], c1 = m.vertex_colors[f[1]], c2 = m.vertex_colors[f[2]];
    return {to_u8(w0 * c0.r + w1 * c1.r + w2 * c2.r), to_u8(w0 * c0.g + w1 * c1.g + w2 * c2.g),
            to_u8(w0 * c0.b + w1 * c1.b + w2 * c2.b)};
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

/// Writes the triangles of [first, last) (at most kCandidateBatch) that may cover a sample of `roi`
/// (span_may_cover) to `list`, returns their count. At stride >= 2 most of a model's triangles cover no
/// sample: this filter is branch-free (no misprediction per rejected triangle) and, with SSE2, tests two
/// triangles' packed spans per instruction.
PERCH2_HD_FORCE_INLINE int grid_candidates(const std::int32_t* __restrict__ triangles,
                                           const GridSpan* __restrict__ span, int first, int last,
                                           const GridRoi& roi, int* __restrict__ list) {
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
    list[n] = tri, n += (empty & 0xF) == 0;
    list[n] = tri + 1, n += (empty & 0xF00) == 0;
  }
#endif
  for (; tri < last; ++tri) {
    const std::int32_t* f = triangles + 3 * tri;
    list[n] = tri, n += span_may_cover(span[f[0]], span[f[1]], span[f[2]], roi);
  }
  return n;
}

/// Rasterise triangles [begin, end) of a posed model into an ROI z-buffer: calls plot(roi_index,
/// packed_word) for every covered sample. The backend's plot does the z-test (plain min in the reference, a
/// 64-bit atomic min in the Thrust backend). Inputs are copied to locals so that plot's stores (an atomic is
/// a compiler barrier) do not force reloads of the mesh, camera and ROI.
template <class Plot>
PERCH2_HD void rasterize_triangle_run(const MeshView& m, PosedVertices v, int begin, int end,
                                      const Intrinsics& K, int stride, float near_m, const GridRoi& roi,
                                      bool cull_back_faces, Plot& plot) {
  const std::int32_t* const triangles = m.triangles;
  const Intrinsics K_local = K;
  const GridRays rays(K, stride);
  const GridRoi roi_local = roi;
  int list[kCandidateBatch];
  for (int first = begin; first < end; first += kCandidateBatch) {
    const int n =
        grid_candidates(triangles, v.span, first, min_int(end, first + kCandidateBatch), roi_local, list);
    for (int k = 0; k < n; ++k) {
      const int tri = list[k];
      const std::int32_t* f = triangles + 3 * tri;
      TriangleRaster t;
      if (!setup_triangle(v, f, v.span[f[0]], v.span[f[1]], v.span[f[2]], K_local, stride, near_m, roi_local,
                          cull_back_faces, t))
        continue;
      for (int j = t.cover.j0; j < t.cover.j0 + t.cover.height; ++j)
        for (int i = t.cover.i0; i < t.cover.i0 + t.cover.width; ++i) {
          float depth_m;
          const bool hit = sample_triangle(t, rays(i, j), near_m, depth_m);
          // A miss plots the empty word, which never wins the z-test (a select, not a branch).
          plot((j - roi_local.j0) * roi_local.width + (i - roi_local.i0),
               hit ? pack_depth_triangle(depth_m, std::uint32_t(tri)) : kEmptyPixel);
        }
    }
  }
}

/// The camera centre in the object frame: -R^T t.
PERCH2_HD inline Vec3f camera_in_object(const Rigid3f& T_cam_obj) {
  const float* R = T_cam_obj.R.m;
  const Vec3f t = T_cam_obj.t;
  return {-(R[0] * t.x + R[3] * t.y + R[6] * t.z), -(R[1] * t.x + R[4] * t.y + R[7] * t.z),
          -(R[2] * t.x + R[5] * t.y + R[8] * t.z)};
}

/// rasterize_triangle_run over [begin, end), skipping the model's clusters that face away from the camera
/// as a whole when back faces are culled.
template <class Plot>
PERCH2_HD void rasterize_triangles(const MeshView& m, PosedVertices v, int begin, int end,
                                   const Rigid3f& T_cam_obj, const Intrinsics& K, int stride, float near_m,
                                   const GridRoi& roi, bool cull_back_faces, Plot&& plot) {
  if (!cull_back_faces || !m.clusters) {
    rasterize_triangle_run(m, v, begin, end, K, stride, near_m, roi, cull_back_faces, plot);
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
                           K, stride, near_m, roi, cull_back_faces, plot);
  }
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

/// Resolve pass for one z-buffer word of grid sample (i, j): decode the winning triangle, drop the sample if
/// an observed occluder hides it, else shade it. Returns false for empty or occluded samples.
PERCH2_HD inline bool resolve_sample(const MeshView& m, const PosedVertices& verts_cam, DepthTriangle word,
                                     const Intrinsics& K, const GridRays& rays, int i, int j,
                                     const OccluderView& occ, std::int32_t hypothesis_label,
                                     RenderedSample& out) {
  if (word == kEmptyPixel) return false;
  const float depth_m = unpack_depth(word);
  const int tri = int(unpack_triangle(word));
  const int u = rays.stride * i, v = rays.stride * j;
  out.pixel = v * K.width + u;
  if (occ.depth_m && is_occluded(depth_m, occ.depth_m[out.pixel], occ.labels != nullptr,
                                 occ.labels ? occ.labels[out.pixel] : 0, hypothesis_label, occ.margin_m))
    return false;
  out.p_cam = depth_m * rays(i, j);
  const std::int32_t* f = m.triangles + 3 * tri;
  out.rgb = pack_rgb(shade(m, tri, verts_cam[f[0]], verts_cam[f[1]], verts_cam[f[2]], out.p_cam));
  return true;
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
};

/// Renders one hypothesis start to end in one thread: poses the model, rasterises it into the ROI z-buffer
/// and resolves the visible samples, in raster order of the stride grid, into out (room for roi.size()).
/// Returns their count. The reference backend and the Thrust backend on CPU systems render this way (each
/// hypothesis' working set stays in cache); on GPUs the Thrust backend runs the same steps as passes.
PERCH2_HD inline int render_hypothesis(const MeshView& m, const Rigid3f& T_cam_obj, std::int32_t label,
                                       const GridRoi& roi, const RenderParams& p, const HypothesisScratch& s,
                                       RenderedSample* out) {
  if (roi.size() == 0) return 0;
  for (int k = 0; k < roi.size(); ++k) s.zbuf[k] = kEmptyPixel;
  pose_vertices(m, T_cam_obj, p.K, p.stride, p.near_m, 0, m.num_vertices, s.p_cam, s.span);
  const PosedVertices posed{s.p_cam, s.span};
  DepthTriangle* const zbuf = s.zbuf;
  rasterize_triangles(m, posed, 0, m.num_triangles, T_cam_obj, p.K, p.stride, p.near_m, roi,
                      p.cull_back_faces,
                      [zbuf](int idx, DepthTriangle w) { zbuf[idx] = zbuf[idx] < w ? zbuf[idx] : w; });
  const GridRays rays(p.K, p.stride);
  int n = 0;
  for (int j = 0; j < roi.height; ++j)
    for (int i = 0; i < roi.width; ++i)
      n += resolve_sample(m, posed, zbuf[j * roi.width + i], p.K, rays, roi.i0 + i, roi.j0 + j, p.occ, label,
                          out[n]);
  return n;
}

}  // namespace perch2
