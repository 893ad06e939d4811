// The observed side of render-and-compare: an RGB-D frame's points as a target CloudBatch for the kNN and
// registration stages, either as one cloud (3-DoF: the whole scene) or one segment per object label (6-DoF:
// a hypothesis of object l only searches the points labelled l).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "perch2/core/cloud.hpp"
#include "perch2/core/image.hpp"

namespace perch2 {

namespace observed_detail {

inline void check_stride(int stride, const std::string& who) {
  if (stride < 1) throw InvalidInput(who, "stride must be >= 1, got " + std::to_string(stride));
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

/// The frame's points as one cloud: every pixel (u, v) with u, v multiples of `stride` and a depth reading
/// (> 0), in raster order, camera frame, metres; rgb from the colour image (0 if the frame has none).
/// Throws InvalidInput on a malformed frame (sizes, NaN or negative depth) or stride < 1.
inline CloudBatch observed_cloud(const RgbdFrame& frame, int stride = 1) {
  frame.validate("observed frame");
  observed_detail::check_stride(stride, "observed_cloud");
  CloudBatch out;
  for (int v = 0; v < frame.camera.height; v += stride)
    for (int u = 0; u < frame.camera.width; u += stride)
      if (const float d = frame.depth_m(u, v); d > 0.f) observed_detail::append_pixel(frame, u, v, d, 0, out);
  out.offsets = {0, std::int64_t(out.size())};
  return out;
}

/// One cloud per entry of `segment_labels`: cloud s holds the frame's points (as in observed_cloud) whose
/// label is segment_labels[s]. A label with no points gives an empty cloud. A hypothesis of the object
/// labelled l then searches segment s with segment_labels[s] == l (the query_segment of kNN/registration).
/// Throws InvalidInput on a malformed frame, a label image of the wrong size, a repeated label or stride < 1.
inline CloudBatch observed_segments(const RgbdFrame& frame, const LabelImage& labels,
                                    const std::vector<std::int32_t>& segment_labels, int stride = 1) {
  frame.validate("observed frame");
  check_size(labels, frame.camera.width, frame.camera.height, "observed label image");
  observed_detail::check_stride(stride, "observed_segments");
  for (std::size_t s = 0; s < segment_labels.size(); ++s)
    for (std::size_t t = 0; t < s; ++t)
      if (segment_labels[s] == segment_labels[t])
        throw InvalidInput("observed_segments", "label " + std::to_string(segment_labels[s]) +
                                                    " is listed twice in segment_labels");
  CloudBatch out;
  for (std::size_t s = 0; s < segment_labels.size(); ++s) {
    for (int v = 0; v < frame.camera.height; v += stride)
      for (int u = 0; u < frame.camera.width; u += stride)
        if (const float d = frame.depth_m(u, v); d > 0.f && labels(u, v) == segment_labels[s])
          observed_detail::append_pixel(frame, u, v, d, std::int32_t(s), out);
    out.offsets.push_back(std::int64_t(out.size()));
  }
  return out;
}

}  // namespace perch2
