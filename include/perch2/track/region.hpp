// Which readings of a frame belong to which tracked object, from the objects rendered at their current
// poses: each object's silhouette on the render's stride grid (nearest object wins a cell), grown by a
// margin (the pose's error in the image; a cell goes to the nearest silhouette), and of the readings in an
// object's region those within a depth gate of its rendered depth range. Only the cells around the tracked
// objects are visited: no full-frame work per object.
//
// The same assignment decides occlusion (as the 6-DoF search's labelled occluders): a reading nearer than
// a rendered point hides it unless it is that object's own. A hand in front of an object, or another object
// whose readings are its own, hides it; its own readings never do.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <deque>
#include <limits>
#include <vector>

#include "perch2/core/camera.hpp"
#include "perch2/core/cloud.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/observed.hpp"

namespace perch2 {
namespace track_detail {

/// A camera whose image is the frame's grown by `pad` pixels on every side: renders through it keep the
/// parts of a silhouette outside the frame (how much of an object is in view). pad is a multiple of the
/// render stride, so the padded stride grid samples the frame's stride grid.
struct PaddedCamera {
  Intrinsics camera;
  int pad = 0;
  int frame_width = 0, frame_height = 0;

  PaddedCamera(const Intrinsics& frame, int stride, int min_pad_px = 128)
      : camera(frame), pad(stride * ((min_pad_px + stride - 1) / stride)) {
    frame_width = frame.width, frame_height = frame.height;
    camera.cx += float(pad), camera.cy += float(pad);
    camera.width += 2 * pad, camera.height += 2 * pad;
  }
  /// The frame pixel (u, v) of a padded pixel index (may lie outside the frame).
  void frame_pixel(std::int32_t padded_pixel, int& u, int& v) const {
    u = padded_pixel % camera.width - pad, v = padded_pixel / camera.width - pad;
  }
  bool in_frame(int u, int v) const { return u >= 0 && v >= 0 && u < frame_width && v < frame_height; }
};

/// Per cell of the frame's render grid (cell (i, j): pixels [s i, s i + s) x [s j, s j + s)), the object
/// whose render is nearest there, grown by a margin; per object its rendered depth range.
class Regions {
 public:
  /// `rendered`: cloud c = object c rendered through `pc` at `stride`. An object with `yields[c]` set (a
  /// lost one) gets no cell another object's render covers, whatever their depths: a lost pose must not
  /// take the readings of an object that is tracked (empty: none yields).
  Regions(const CloudBatch& rendered, const PaddedCamera& pc, int stride,
          const std::vector<bool>& yields = {})
      : cell_(stride) {
    cols_ = (pc.frame_width + stride - 1) / stride, rows_ = (pc.frame_height + stride - 1) / stride;
    const std::size_t n = rendered.num_clouds();
    owner_.assign(std::size_t(cols_) * std::size_t(rows_), -1);
    depth_.assign(owner_.size(), std::numeric_limits<float>::infinity());
    z_min_.assign(n, std::numeric_limits<float>::infinity());
    z_max_.assign(n, -std::numeric_limits<float>::infinity());
    rendered_points_.assign(n, 0);
    for (std::size_t c = 0; c < n; ++c)
      for (auto i = std::size_t(rendered.offsets[c]); i < std::size_t(rendered.offsets[c + 1]); ++i) {
        const float z = rendered.z[i];
        z_min_[c] = std::min(z_min_[c], z), z_max_[c] = std::max(z_max_[c], z);
        ++rendered_points_[c];
        int u, v;
        pc.frame_pixel(rendered.pixel[i], u, v);
        if (!pc.in_frame(u, v)) continue;
        const std::size_t k = cell(u, v);
        const bool yielding = !yields.empty() && yields[c];
        const bool held = owner_[k] >= 0 && !yields.empty() && yields[std::size_t(owner_[k])];
        if (owner_[k] < 0 || (held && !yielding) || (held == yielding && z < depth_[k]))
          depth_[k] = z, owner_[k] = std::int32_t(c);
      }
    silhouette_ = owner_;
  }

  /// Grows every silhouette by `margin_px` (rounded up to whole cells; a cell goes to the nearest
  /// silhouette, 8-connected steps) and sets the depth gate of owner_of(). Starts from the silhouettes
  /// each time.
  void grow(int margin_px, float depth_gate_m) {
    gate_ = depth_gate_m;
    owner_ = silhouette_;
    near_depth_ = depth_;
    const int steps = (margin_px + cell_ - 1) / cell_;
    std::vector<int> dist(owner_.size(), -1);
    std::deque<std::size_t> queue;
    for (std::size_t k = 0; k < owner_.size(); ++k)
      if (owner_[k] >= 0) dist[k] = 0, queue.push_back(k);
    box_ = {cols_, rows_, -1, -1};
    while (!queue.empty()) {
      const std::size_t k = queue.front();
      queue.pop_front();
      const int i = int(k % std::size_t(cols_)), j = int(k / std::size_t(cols_));
      box_[0] = std::min(box_[0], i), box_[1] = std::min(box_[1], j);
      box_[2] = std::max(box_[2], i), box_[3] = std::max(box_[3], j);
      if (dist[k] == steps) continue;
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const int a = i + di, b = j + dj;
          if (a < 0 || b < 0 || a >= cols_ || b >= rows_) continue;
          const std::size_t m = std::size_t(b) * std::size_t(cols_) + std::size_t(a);
          if (dist[m] >= 0) continue;
          dist[m] = dist[k] + 1, owner_[m] = owner_[k], near_depth_[m] = near_depth_[k];
          queue.push_back(m);
        }
    }
  }

  /// The object a reading of depth d at frame pixel (u, v) belongs to, or -1: the owner of its cell if d
  /// lies within the depth gate of the owner's rendered depth there (in the margin: at the nearest cell of
  /// its silhouette). The table next to an object is farther than the gate from its top, and the readings
  /// of its surface that a slid pose left uncovered are not.
  std::int32_t owner_of(int u, int v, float d) const {
    if (d <= 0.f) return -1;
    const std::size_t k = cell(u, v);
    const std::int32_t o = owner_[k];
    return o >= 0 && std::abs(d - near_depth_[k]) <= gate_ ? o : -1;
  }

  /// Each object's readings (one cloud per object, observed stride grid, raster order), as the
  /// registration targets and the cost's observed segments.
  CloudBatch segments(const RgbdFrame& frame, int observed_stride) const {
    const std::size_t n = z_min_.size();
    std::vector<std::vector<std::int32_t>> pixels(n);
    if (box_[2] >= 0) {
      const int s = observed_stride;
      const int v0 = (box_[1] * cell_ + s - 1) / s * s, u0 = (box_[0] * cell_ + s - 1) / s * s;
      const int v1 = std::min(frame.camera.height, (box_[3] + 1) * cell_);
      const int u1 = std::min(frame.camera.width, (box_[2] + 1) * cell_);
      for (int v = v0; v < v1; v += s)
        for (int u = u0; u < u1; u += s)
          if (const std::int32_t o = owner_of(u, v, frame.depth_m(u, v)); o >= 0)
            pixels[std::size_t(o)].push_back(v * frame.camera.width + u);
    }
    CloudBatch out;
    for (std::size_t c = 0; c < n; ++c) {
      for (const std::int32_t p : pixels[c]) {
        const int u = p % frame.camera.width, v = p / frame.camera.width;
        observed_detail::append_pixel(frame, u, v, frame.depth_m(u, v), std::int32_t(c), out);
      }
      out.offsets.push_back(std::int64_t(out.size()));
    }
    return out;
  }

  /// The rendered points in the frame where the frame has a reading that does not hide them (nearer by more
  /// than margin_m and not the object's own), as frame pixels; per object the count of all its rendered
  /// points (visible_fraction's denominator: also those outside the frame) in all_points.
  CloudBatch visible(const CloudBatch& rendered, const PaddedCamera& pc, const RgbdFrame& frame,
                     float margin_m) const {
    CloudBatch out;
    for (std::size_t c = 0; c < rendered.num_clouds(); ++c) {
      for (auto i = std::size_t(rendered.offsets[c]); i < std::size_t(rendered.offsets[c + 1]); ++i) {
        int u, v;
        pc.frame_pixel(rendered.pixel[i], u, v);
        if (!pc.in_frame(u, v)) continue;
        const float d = frame.depth_m(u, v), z = rendered.z[i];
        // No reading (dropout at depth edges, dark or glossy patches): neither for nor against the pose.
        if (!(d > 0.f)) continue;
        if (d < z - margin_m && owner_of(u, v, d) != std::int32_t(c)) continue;
        out.x.push_back(rendered.x[i]), out.y.push_back(rendered.y[i]), out.z.push_back(z);
        out.rgb.push_back(rendered.rgb[i]), out.pixel.push_back(v * frame.camera.width + u);
        out.cloud.push_back(std::int32_t(c));
      }
      out.offsets.push_back(std::int64_t(out.size()));
    }
    return out;
  }

  int rendered_points(std::size_t c) const { return rendered_points_[c]; }

 private:
  std::size_t cell(int u, int v) const {
    return std::size_t(v / cell_) * std::size_t(cols_) + std::size_t(u / cell_);
  }

  int cell_ = 4, cols_ = 0, rows_ = 0;
  float gate_ = 0.f;
  std::vector<std::int32_t> silhouette_, owner_;  ///< per cell: nearest render's object (grown), -1 none
  std::vector<float> depth_;                      ///< per cell: the nearest rendered depth, metres
  std::vector<float> near_depth_;     ///< per cell: the rendered depth of the nearest silhouette cell, metres
  std::vector<float> z_min_, z_max_;  ///< per object: rendered depth range, metres
  std::vector<int> rendered_points_;  ///< per object, also outside the frame
  std::array<int, 4> box_{0, 0, -1, -1};  ///< grown cells' bounds: i_min, j_min, i_max, j_max
};

}  // namespace track_detail
}  // namespace perch2
