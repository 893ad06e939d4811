// Triangle set-up and sampling in float (TriangleRaster: canonical edge planes, watertight; the plane and
// its depth along a ray), and the exact coverage test in double (covers_exactly). The conditioning of these
// quantities is described at the top of render/raster.hpp.
#pragma once

#include <cstdint>

#include "perch2/core/camera.hpp"
#include "perch2/core/device.hpp"
#include "perch2/render/raster/common.hpp"
#include "perch2/render/raster/grid.hpp"
#include "perch2/render/raster/mesh_view.hpp"
#include "perch2/render/raster/pose_vertices.hpp"

namespace perch2 {

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

}  // namespace perch2
