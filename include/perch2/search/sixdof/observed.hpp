// estimate()'s observed points: instance k's mask pixels carry label k + 1 (later instances win overlaps),
// and each instance is trimmed for depth consistency: mask pixels whose depth lies outside its robust
// range [q_lo - trim_margin_m, min(q_hi + trim_margin_m, q_lo + diameter)] (a mask bleeding onto the table
// behind, or a neighbour in front) lose the label and count as background. The labelled points on the
// observed stride grid are the per-instance segments: GICP's targets and J_o's points.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/observed.hpp"
#include "perch2/search/sixdof/context.hpp"

namespace perch2 {
namespace sixdof_detail {

/// Depth-consistency trimming of instance `label`'s pixels (see above); returns the pixels dropped. Throws
/// InvalidInput for an empty mask or one without valid depth.
template <class Backend>
std::size_t trim(const Shared<Backend>& sh, const DepthImage& depth, LabelImage& labels, std::int32_t label,
                 const SixDofInstance& in) {
  const SixDofSettings& s = sh.settings;
  const std::string who = "instances[" + std::to_string(label - 1) + "] mask";
  std::vector<float> z;
  bool any = false;
  for (std::size_t i = 0; i < labels.data.size(); ++i)
    if (in.mask.data[i]) {
      any = true;
      if (labels.data[i] == label && depth.data[i] > 0) z.push_back(depth.data[i]);
    }
  if (!any) throw InvalidInput(who, "is empty (no pixel inside)");
  if (z.empty()) throw InvalidInput(who, "has no valid depth reading inside it (or other masks cover it)");
  if (s.trim_margin_m < 0) return 0;
  std::sort(z.begin(), z.end());
  auto quantile = [&](float q) { return z[std::size_t(std::lround(q * float(z.size() - 1)))]; };
  const float lo = quantile(s.trim_quantile_low) - s.trim_margin_m;
  const float hi = std::min(quantile(s.trim_quantile_high) + s.trim_margin_m,
                            quantile(s.trim_quantile_low) + sh.diameter[std::size_t(in.model)]);
  std::size_t dropped = 0;
  for (std::size_t i = 0; i < labels.data.size(); ++i)
    if (labels.data[i] == label && depth.data[i] > 0 && (depth.data[i] < lo || depth.data[i] > hi))
      labels.data[i] = 0, ++dropped;
  return dropped;
}

/// The instances' labels (k + 1, after trimming) and their observed segments (cloud k = instance k).
struct ObservedInstances {
  LabelImage labels;
  CloudBatch observed;
};

/// Labels, trims and collects every instance's observed points; fills result.trimmed_pixels and
/// segment_points. Throws InvalidInput for an instance without any observed point.
template <class Backend>
ObservedInstances observe_instances(const Shared<Backend>& sh, const RgbdFrame& frame,
                                    const std::vector<SixDofInstance>& instances, SixDofResult& result) {
  const SixDofSettings& s = sh.settings;
  const std::size_t K = instances.size();
  LabelImage labels(frame.camera.width, frame.camera.height, 0);
  for (std::size_t k = 0; k < K; ++k)
    for (std::size_t i = 0; i < labels.data.size(); ++i)
      if (instances[k].mask.data[i]) labels.data[i] = std::int32_t(k + 1);
  std::vector<std::int32_t> segment_labels;
  for (std::size_t k = 0; k < K; ++k) {
    result.trimmed_pixels.push_back(trim(sh, frame.depth_m, labels, std::int32_t(k + 1), instances[k]));
    segment_labels.push_back(std::int32_t(k + 1));
  }
  CloudBatch observed = observed_segments(frame, labels, segment_labels, s.observed);
  for (std::size_t k = 0; k < K; ++k) {
    result.segment_points.push_back(observed.cloud_size(k));
    if (observed.cloud_size(k) == 0)
      throw InvalidInput("instances[" + std::to_string(k) + "]",
                         "has no observed point on the stride-" + std::to_string(s.observed.stride) +
                             " grid (mask too small or without depth there)");
  }
  return {std::move(labels), std::move(observed)};
}

}  // namespace sixdof_detail
}  // namespace perch2
