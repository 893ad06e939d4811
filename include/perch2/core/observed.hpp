// The observed side of render-and-compare: an RGB-D frame's points as a target CloudBatch for the kNN and
// registration stages, either as one cloud (3-DoF: the whole scene) or one segment per object label (6-DoF:
// a hypothesis of object l only searches the points labelled l).
#pragma once

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "perch2/core/cloud.hpp"
#include "perch2/core/image.hpp"

namespace perch2 {

/// Which pixels of a frame become observed points.
struct ObservedCloudSettings {
  int stride = 1;           ///< every stride-th pixel in u and v (u, v multiples of stride), >= 1
  float min_depth_m = 0.f;  ///< readings nearer than this are dropped, metres
  /// Readings farther than this are dropped (e.g. the room behind the table), metres.
  float max_depth_m = std::numeric_limits<float>::infinity();
};

namespace observed_detail {

inline void check(const ObservedCloudSettings& s, const std::string& who) {
  if (s.stride < 1) throw InvalidInput(who, "stride must be >= 1, got " + std::to_string(s.stride));
  if (!(s.min_depth_m >= 0.f) || !(s.max_depth_m > s.min_depth_m))
    throw InvalidInput(who, "depth range must satisfy 0 <= min_depth_m < max_depth_m, got [" +
                                std::to_string(s.min_depth_m) + ", " + std::to_string(s.max_depth_m) + "]");
}

/// A reading (> 0, 0 = none) inside the requested depth range.
inline bool keep(float d, const ObservedCloudSettings& s) {
  return d > 0.f && d >= s.min_depth_m && d <= s.max_depth_m;
}

/// Appends the pixel (u, v) of the frame with depth d to the batch, as cloud `c`. The point is d times the
/// renderer's ray through the pixel, so a rendered depth image turns back into the renderer's points exactly.
inline void append_pixel(const RgbdFrame& f, int u, int v, float d, std::int32_t c, CloudBatch& out) {
  const Vec3f p = d * f.camera.ray(float(u), float(v));
  const std::int32_t pixel = v * f.camera.width + u;
  out.x.push_back(p.x), out.y.push_back(p.y), out.z.push_back(p.z);
  out.rgb.push_back(f.rgb.empty() ? 0u : pack_rgb(f.rgb.data[std::size_t(pixel)]));
  out.pixel.push_back(pixel);
  out.cloud.push_back(c);
}

}  // namespace observed_detail

/// The frame's points as one cloud: every pixel on the stride grid with a reading in the depth range, in
/// raster order, camera frame, metres; rgb from the colour image (0 if the frame has none).
/// Throws InvalidInput on a malformed frame (sizes, NaN or negative depth) or bad settings.
inline CloudBatch observed_cloud(const RgbdFrame& frame, const ObservedCloudSettings& s = {}) {
  frame.validate("observed frame");
  observed_detail::check(s, "observed_cloud");
  CloudBatch out;
  for (int v = 0; v < frame.camera.height; v += s.stride)
    for (int u = 0; u < frame.camera.width; u += s.stride)
      if (const float d = frame.depth_m(u, v); observed_detail::keep(d, s))
        observed_detail::append_pixel(frame, u, v, d, 0, out);
  out.offsets = {0, std::int64_t(out.size())};
  return out;
}

/// One cloud per entry of `segment_labels`: cloud s holds the frame's points (as in observed_cloud) whose
/// label is segment_labels[s]. A label with no points gives an empty cloud. A hypothesis of the object
/// labelled l then searches segment s with segment_labels[s] == l (the query_segment of kNN/registration).
/// Throws InvalidInput on a malformed frame, a label image of the wrong size, a repeated label or bad
/// settings.
inline CloudBatch observed_segments(const RgbdFrame& frame, const LabelImage& labels,
                                    const std::vector<std::int32_t>& segment_labels,
                                    const ObservedCloudSettings& s = {}) {
  frame.validate("observed frame");
  check_size(labels, frame.camera.width, frame.camera.height, "observed label image");
  observed_detail::check(s, "observed_segments");
  for (std::size_t a = 0; a < segment_labels.size(); ++a)
    for (std::size_t b = 0; b < a; ++b)
      if (segment_labels[a] == segment_labels[b])
        throw InvalidInput("observed_segments", "label " + std::to_string(segment_labels[a]) +
                                                    " is listed twice in segment_labels");
  CloudBatch out;
  for (std::size_t seg = 0; seg < segment_labels.size(); ++seg) {
    for (int v = 0; v < frame.camera.height; v += s.stride)
      for (int u = 0; u < frame.camera.width; u += s.stride)
        if (const float d = frame.depth_m(u, v);
            observed_detail::keep(d, s) && labels(u, v) == segment_labels[seg])
          observed_detail::append_pixel(frame, u, v, d, std::int32_t(seg), out);
    out.offsets.push_back(std::int64_t(out.size()));
  }
  return out;
}

/// Each cloud of `observed` (points of a frame `width` pixels wide) thinned to the pixels on the coarser
/// stride grid (u, v multiples of stride), in order; a cloud that would keep fewer than min_points (or
/// has points without a pixel) keeps all its points. Throws InvalidInput if stride < 1.
inline CloudBatch on_stride_grid(const CloudBatch& observed, int width, int stride, std::size_t min_points) {
  if (stride < 1) throw InvalidInput("on_stride_grid", "stride must be >= 1, got " + std::to_string(stride));
  auto on_grid = [&](std::int32_t px) {
    return px >= 0 && (px % width) % stride == 0 && (px / width) % stride == 0;
  };
  CloudBatch out;
  for (std::size_t c = 0; c < observed.num_clouds(); ++c) {
    const auto begin = std::size_t(observed.offsets[c]), end = std::size_t(observed.offsets[c + 1]);
    std::size_t kept = 0;
    bool all_pixels = true;
    for (std::size_t i = begin; i < end; ++i)
      kept += on_grid(observed.pixel[i]), all_pixels &= observed.pixel[i] >= 0;
    const bool keep_all = kept < min_points || !all_pixels;
    for (std::size_t i = begin; i < end; ++i) {
      if (!keep_all && !on_grid(observed.pixel[i])) continue;
      out.x.push_back(observed.x[i]), out.y.push_back(observed.y[i]), out.z.push_back(observed.z[i]);
      out.rgb.push_back(observed.rgb[i]), out.pixel.push_back(observed.pixel[i]);
      out.cloud.push_back(std::int32_t(c));
    }
    out.offsets.push_back(std::int64_t(out.size()));
  }
  return out;
}

}  // namespace perch2
