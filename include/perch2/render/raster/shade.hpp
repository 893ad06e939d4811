// Colour of a triangle at a hit: barycentrics, texture coordinates, bilinear texture lookup (in two steps,
// TexelQuad then mix_texels), interpolated vertex colours or the model's base colour (shade).
#pragma once

#include <cmath>
#include <cstdint>

#include "perch2/core/device.hpp"
#include "perch2/render/raster/common.hpp"
#include "perch2/render/raster/mesh_view.hpp"

namespace perch2 {

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

}  // namespace perch2
