// Segments of an RGB-D frame without a detector (6-DoF `--masks none`): the support plane (table, bin floor,
// shelf) by RANSAC where there is one, and the readings off it split into connected components on the image
// grid wherever neighbouring depths jump by more than a range-scaled threshold.
//
//   perch2::FrameSegments s = perch2::segment_frame(frame, settings, min_area_m2);
//   for (std::size_t k = 0; k < s.segments.size(); ++k) use(s.labels /* == k + 1 */, s.segments[k]);
//
// A segment is what depth alone separates: touching objects may share one, an object split by an occluder
// gives two. SixDofEstimator::estimate_scene copes with both (perch2/search/sixdof.hpp).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/search/table_plane.hpp"

namespace perch2 {

struct SegmentationSettings {
  /// Look for a support plane (RANSAC, `plane`) and drop its readings and those below it. No plane found is
  /// allowed (the frame is then segmented as it is).
  bool remove_plane = true;
  /// RANSAC's settings; a support plane may hold only a tenth of the readings (a crowded table).
  TablePlaneSettings plane = [] {
    TablePlaneSettings p;
    p.min_inlier_fraction = 0.1f;
    return p;
  }();
  /// Candidate planes, found one after the other (perch2::estimate_planes). The support is the largest,
  /// unless a plane parallel to it (within 20 deg) lies wholly more than max_height_m above it: a floor seen
  /// around a table can hold more readings than the table top.
  int max_planes = 3;
  /// A reading within this of the plane, or below it, is support, not object, metres. Also the height of an
  /// object's bottom that is lost with the plane.
  float plane_distance_m = 0.008f;
  /// Readings higher above the plane than this are dropped (walls, people behind the table), metres;
  /// 0 = keep all. Only with a plane.
  float max_height_m = 0.6f;
  /// Readings nearer or farther than these are dropped, metres.
  float min_depth_m = 0.1f, max_depth_m = 4.f;
  /// Two 4-neighbours belong together if their depths differ by at most jump_m + jump_per_m * depth:
  /// the 5 mm covers the sensor's quantisation, the 1 % per metre a surface slanted ~80 deg at 1-2 m.
  float jump_m = 0.005f, jump_per_m = 0.01f;
  /// Segments whose surface area (sum over its pixels of depth^2 / (fx fy), m^2, range-invariant) is below
  /// this fraction of the smallest model's smallest bounding-box face are dropped (specks, edges, noise).
  float min_area_fraction = 0.1f;
  int min_pixels = 30;  ///< and segments with fewer pixels than this
};

/// One connected component of object readings.
struct FrameSegment {
  int label = 0;                                           ///< its value in FrameSegments::labels (1-based)
  int pixels = 0;                                          ///< full-resolution pixels with a reading
  float area_m2 = 0;                                       ///< surface area seen, m^2 (see min_area_fraction)
  Eigen::Vector4i box_xywh{0, 0, 0, 0};                    ///< pixel box (w = x_max - x_min, as mask boxes)
  float depth_min_m = 0, depth_max_m = 0;                  ///< depth range, metres
  Eigen::Vector3f centroid_cam = Eigen::Vector3f::Zero();  ///< camera frame, metres
  /// Twice the 95th percentile of the readings' distances from the centroid, metres: the segment's size to
  /// compare with a model's diameter.
  float extent_m = 0;
};

struct FrameSegments {
  LabelImage labels;  ///< full resolution: 0 = support, background or dropped; k + 1 = segments[k]
  std::vector<FrameSegment> segments;  ///< largest area first
  std::optional<TablePlane> plane;     ///< the support plane, if one was found
  int support_pixels = 0;              ///< readings on (or below) the plane
  int dropped_segments = 0;            ///< components below the size rule
};

namespace segmentation_detail {

inline int find(std::vector<int>& parent, int i) {
  while (parent[std::size_t(i)] != i) {
    parent[std::size_t(i)] = parent[std::size_t(parent[std::size_t(i)])];  // path halving
    i = parent[std::size_t(i)];
  }
  return i;
}

inline void unite(std::vector<int>& parent, int a, int b) {
  a = find(parent, a), b = find(parent, b);
  if (a != b) parent[std::size_t(std::max(a, b))] = std::min(a, b);
}

/// The camera-frame point of pixel (u, v) at planar depth d.
inline Eigen::Vector3f point_at(const Intrinsics& cam, int u, int v, float d) {
  const Vec3f p = d * cam.ray(float(u), float(v));
  return {p.x, p.y, p.z};
}

inline void check(const SegmentationSettings& s) {
  if (!(s.plane_distance_m >= 0) || !(s.max_height_m >= 0))
    throw InvalidInput("SegmentationSettings::plane_distance_m/max_height_m", "must be >= 0");
  if (!(s.min_depth_m >= 0) || !(s.max_depth_m > s.min_depth_m))
    throw InvalidInput("SegmentationSettings::min_depth_m/max_depth_m", "need 0 <= min < max");
  if (!(s.jump_m >= 0) || !(s.jump_per_m >= 0) || !std::isfinite(s.jump_m) || !std::isfinite(s.jump_per_m))
    throw InvalidInput("SegmentationSettings::jump_m/jump_per_m", "must be finite and >= 0");
  if (s.max_planes < 1) throw InvalidInput("SegmentationSettings::max_planes", "must be >= 1");
  if (!(s.min_area_fraction >= 0) || s.min_pixels < 1)
    throw InvalidInput("SegmentationSettings::min_area_fraction/min_pixels", "need >= 0 and >= 1");
}

/// The support among the candidate planes (SegmentationSettings::max_planes): the largest, unless a
/// plane parallel to it lies wholly above it by more than max_height_m (a table seen over a floor:
/// everything on the table would be dropped as too high); none if no plane holds enough readings.
inline std::optional<TablePlane> support_plane(const RgbdFrame& frame, const SegmentationSettings& s) {
  const std::vector<TablePlane> planes = estimate_planes(frame, s.plane, s.max_planes);
  if (planes.empty()) return std::nullopt;
  const std::vector<Eigen::Vector3f> pts = table_detail::sampled_points(frame, s.plane.stride);
  auto height = [&](const TablePlane& p, const Eigen::Vector3f& x) {
    return p.normal_cam.dot(x) + p.offset_m;
  };
  auto above = [&](const TablePlane& q, const TablePlane& base) {  // q parallel to base, all of it too high
    if (s.max_height_m <= 0 || q.normal_cam.dot(base.normal_cam) < std::cos(0.35f)) return false;  // 20 deg
    int n = 0, high = 0;
    for (const auto& x : pts)
      if (std::abs(height(q, x)) <= s.plane.inlier_distance_m) ++n, high += height(base, x) > s.max_height_m;
    return n > 0 && high >= 0.95 * n;
  };
  std::size_t support = 0;
  for (std::size_t q = 1; q < planes.size(); ++q)
    if (above(planes[q], planes[support])) support = q;
  return planes[support];
}

/// segment_readings() on a checked frame and settings: `object` marks the readings to segment (depth in
/// range).
inline FrameSegments components(const RgbdFrame& frame, const std::vector<std::uint8_t>& object,
                                const SegmentationSettings& s, float min_model_face_m2) {
  const Intrinsics& cam = frame.camera;
  const int w = cam.width, h = cam.height;
  FrameSegments out;
  // Connected components (union-find over 4-neighbours that do not jump).
  std::vector<int> parent(object.size());
  std::iota(parent.begin(), parent.end(), 0);
  auto joined = [&](std::size_t a, std::size_t b) {
    const float za = frame.depth_m.data[a], zb = frame.depth_m.data[b];
    return std::abs(za - zb) <= s.jump_m + s.jump_per_m * std::min(za, zb);
  };
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const std::size_t i = std::size_t(v) * std::size_t(w) + std::size_t(u);
      if (!object[i]) continue;
      if (u + 1 < w && object[i + 1] && joined(i, i + 1)) unite(parent, int(i), int(i + 1));
      if (v + 1 < h && object[i + std::size_t(w)] && joined(i, i + std::size_t(w)))
        unite(parent, int(i), int(i + std::size_t(w)));
    }
  // Per component: pixels, area, box, depth range, centroid.
  struct Acc {
    int pixels = 0;
    double area = 0;
    int x0 = 1 << 30, y0 = 1 << 30, x1 = -1, y1 = -1;
    float zmin = INFINITY, zmax = 0;
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  };
  std::vector<int> component(object.size(), -1);
  std::vector<Acc> acc;
  std::vector<int> index_of_root(object.size(), -1);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const std::size_t i = std::size_t(v) * std::size_t(w) + std::size_t(u);
      if (!object[i]) continue;
      const int r = find(parent, int(i));
      int& c = index_of_root[std::size_t(r)];
      if (c < 0) c = int(acc.size()), acc.emplace_back();
      component[i] = c;
      Acc& a = acc[std::size_t(c)];
      const float d = frame.depth_m.data[i];
      ++a.pixels;
      a.area += double(d) * double(d) / (double(cam.fx) * double(cam.fy));
      a.x0 = std::min(a.x0, u), a.x1 = std::max(a.x1, u), a.y0 = std::min(a.y0, v), a.y1 = std::max(a.y1, v);
      a.zmin = std::min(a.zmin, d), a.zmax = std::max(a.zmax, d);
      a.sum += point_at(cam, u, v, d).cast<double>();
    }
  // The size rule, then largest first.
  const double min_area = double(s.min_area_fraction) * double(std::max(min_model_face_m2, 0.f));
  std::vector<int> kept;
  for (std::size_t c = 0; c < acc.size(); ++c) {
    if (acc[c].pixels >= s.min_pixels && acc[c].area >= min_area)
      kept.push_back(int(c));
    else
      ++out.dropped_segments;
  }
  std::stable_sort(kept.begin(), kept.end(),
                   [&](int a, int b) { return acc[std::size_t(a)].area > acc[std::size_t(b)].area; });
  std::vector<int> label_of(acc.size(), 0);
  for (std::size_t k = 0; k < kept.size(); ++k) {
    const Acc& a = acc[std::size_t(kept[k])];
    FrameSegment seg;
    seg.label = int(k + 1);
    seg.pixels = a.pixels;
    seg.area_m2 = float(a.area);
    seg.box_xywh = {a.x0, a.y0, a.x1 - a.x0, a.y1 - a.y0};
    seg.depth_min_m = a.zmin, seg.depth_max_m = a.zmax;
    seg.centroid_cam = (a.sum / double(a.pixels)).cast<float>();
    out.segments.push_back(seg);
    label_of[std::size_t(kept[k])] = int(k + 1);
  }
  out.labels = LabelImage(w, h, 0);
  std::vector<std::vector<float>> distances(out.segments.size());
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const std::size_t i = std::size_t(v) * std::size_t(w) + std::size_t(u);
      if (component[i] < 0) continue;
      const int l = label_of[std::size_t(component[i])];
      if (l == 0) continue;
      out.labels.data[i] = l;
      const Eigen::Vector3f p = point_at(cam, u, v, frame.depth_m.data[i]);
      distances[std::size_t(l - 1)].push_back((p - out.segments[std::size_t(l - 1)].centroid_cam).norm());
    }
  for (std::size_t k = 0; k < out.segments.size(); ++k) {
    auto& d = distances[k];
    const std::size_t q = std::min(d.size() - 1, std::size_t(0.95 * double(d.size())));
    std::nth_element(d.begin(), d.begin() + std::ptrdiff_t(q), d.end());
    out.segments[k].extent_m = 2.f * d[q];
  }
  return out;
}

}  // namespace segmentation_detail

/// The segments of the readings `mask` marks (full resolution, row-major; nonzero = an object reading, kept
/// if its depth is within [min_depth_m, max_depth_m]):
/// connected components where neighbouring depths do not jump, the size rule of segment_frame(), largest
/// first; `plane` and `support_pixels` are left unset. segment_frame()'s second half, also used on what is
/// left of segments once some of their readings are explained (SixDofEstimator::estimate_scene). Throws
/// InvalidInput for a malformed frame, a mask of the wrong size or bad settings.
inline FrameSegments segment_readings(const RgbdFrame& frame, const std::vector<std::uint8_t>& mask,
                                      const SegmentationSettings& s, float min_model_face_m2) {
  using namespace segmentation_detail;
  frame.validate("segmented frame");
  check(s);
  const int w = frame.camera.width, h = frame.camera.height;
  if (mask.size() != std::size_t(w) * std::size_t(h))
    throw InvalidInput("segment_readings: object mask",
                       "has " + std::to_string(mask.size()) + " pixels, the frame " + std::to_string(w * h));
  std::vector<std::uint8_t> object(mask.size(), 0);  // marked readings with a depth in range
  for (std::size_t i = 0; i < mask.size(); ++i) {
    const float d = frame.depth_m.data[i];
    object[i] = mask[i] && d >= s.min_depth_m && d <= s.max_depth_m;
  }
  return components(frame, object, s, min_model_face_m2);
}

/// The frame's segments (see the file comment). `min_model_face_m2`: the smallest bounding-box face of the
/// smallest model, m^2 (the size rule). Throws InvalidInput for a malformed frame or bad settings.
inline FrameSegments segment_frame(const RgbdFrame& frame, const SegmentationSettings& s,
                                   float min_model_face_m2) {
  using namespace segmentation_detail;
  frame.validate("segmented frame");
  check(s);
  const Intrinsics& cam = frame.camera;
  const int w = cam.width, h = cam.height;
  std::optional<TablePlane> plane;
  if (s.remove_plane) plane = support_plane(frame, s);
  // Object readings: valid, in range, off (and above) the plane.
  int support_pixels = 0;
  std::vector<std::uint8_t> object(std::size_t(w) * std::size_t(h), 0);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const float d = frame.depth_m(u, v);
      if (!(d >= s.min_depth_m && d <= s.max_depth_m)) continue;
      if (plane) {
        const Eigen::Vector3f p = point_at(cam, u, v, d);
        const float height = plane->normal_cam.dot(p) + plane->offset_m;
        if (height <= s.plane_distance_m) {
          ++support_pixels;
          continue;
        }
        if (s.max_height_m > 0 && height > s.max_height_m) continue;
      }
      object[std::size_t(v) * std::size_t(w) + std::size_t(u)] = 1;
    }
  FrameSegments out = components(frame, object, s, min_model_face_m2);
  out.plane = plane, out.support_pixels = support_pixels;
  return out;
}

}  // namespace perch2
