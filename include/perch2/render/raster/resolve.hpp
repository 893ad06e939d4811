// From a z-buffer word to a rendered sample: the C-PERCH occluder test, the resolve pass (point and pixel)
// and shading of the resolved samples (with texel prefetching for textured models).
#pragma once

#include <cstdint>

#include "perch2/core/camera.hpp"
#include "perch2/core/device.hpp"
#include "perch2/render/raster/common.hpp"
#include "perch2/render/raster/grid.hpp"
#include "perch2/render/raster/mesh_view.hpp"
#include "perch2/render/raster/pose_vertices.hpp"
#include "perch2/render/raster/shade.hpp"

namespace perch2 {

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

}  // namespace perch2
