// The last step: the selected pose of each instance fitted onto its observed points at full resolution
// (fit_stride): robust point-to-surface, observed -> model (perch2/registration/surface_fit.hpp). The rest
// of the search works on stride 2-8 grids and rendered clouds, whose sampling and silhouettes leave the pose
// a few millimetres off; every reading of the object constrains this fit. The fitted pose is re-scored with
// the final cost and kept unless that cost rose by more than fit_cost_slack (nothing pulls the model onto
// the readings: with one face in view it may slide along it). Then each pose's score (pose_score).
#pragma once

#include <cmath>
#include <cstdint>
#include <vector>

#include "perch2/core/observed.hpp"
#include "perch2/registration/surface_fit.hpp"
#include "perch2/search/sixdof/context.hpp"
#include "perch2/search/sixdof/pass.hpp"

namespace perch2 {
namespace sixdof_detail {

/// The final fit (SixDofSettings::fit) of every found pose onto its instance's observed points on the
/// fit_stride grid (the pixels labelled with it after trimming), then the cost at the fitted pose.
template <class Backend>
void fit_poses(const Context<Backend>& ctx, const LabelImage& labels,
               const std::vector<std::size_t>& points_estimate, std::vector<SixDofPose>& best,
               SixDofResult& result) {
  const SixDofSettings& s = ctx.shared.settings;
  const RgbdFrame& frame = ctx.frame;
  CloudBatch support;
  std::vector<int> model;
  std::vector<Pose> start;
  std::vector<std::size_t> which;
  for (std::size_t k = 0; k < best.size(); ++k) {
    if (!best[k].found) continue;
    for (int v = 0; v < frame.camera.height; v += s.fit_stride)
      for (int u = 0; u < frame.camera.width; u += s.fit_stride)
        if (const float d = frame.depth_m(u, v);
            labels(u, v) == std::int32_t(k + 1) && observed_detail::keep(d, s.observed))
          observed_detail::append_pixel(frame, u, v, d, std::int32_t(which.size()), support);
    support.offsets.push_back(std::int64_t(support.size()));
    model.push_back(best[k].model), start.push_back(best[k].T_cam_obj), which.push_back(k);
  }
  if (which.empty()) return;
  const SurfaceFitResult r = ctx.shared.surface_fit.fit(support, model, start, s.fit);
  std::vector<Hypothesis> fitted;
  for (std::size_t i = 0; i < which.size(); ++i)
    fitted.push_back({model[i], r.T_cam_obj[i], std::int32_t(which[i] + 1)});
  const std::vector<CostBreakdown> c = score(ctx, fitted, s.score_stride, s.cost, points_estimate, result);
  for (std::size_t i = 0; i < which.size(); ++i) {
    SixDofPose& p = best[which[i]];
    const float slack = s.fit_cost_slack * float(p.cost.rendered_points + p.cost.observed_in_volume);
    if (c[i].rendered_points < s.min_rendered_points || c[i].total > p.cost.total + slack) continue;
    p.T_cam_obj = r.T_cam_obj[i], p.cost = c[i];
    ++result.fits_kept;
  }
}

/// Per found pose, of the pixels of its visible surface (rendered at score_stride; readings of other labels
/// in front hide it) that hold a reading, the fraction whose reading is within explain_distance_m of the
/// render: near 1 where the readings show the model's shape, low where it covers other depths (a model
/// placed across two objects or in front of the background); 0 if none holds one. Pixels without a
/// reading (dropout at edges, dark or glossy patches) count neither way: counted against, they ranked a
/// partly hidden object below a pose on another object's readings (generated seed 301). The cost's tests
/// are 3-D neighbour tests, tolerant by design; this one is per pixel.
template <class Backend>
void depth_agreement(const Context<Backend>& ctx, std::vector<SixDofPose>& poses, SixDofResult& result) {
  const SixDofSettings& s = ctx.shared.settings;
  std::vector<Hypothesis> found;
  std::vector<std::size_t> which;
  for (std::size_t k = 0; k < poses.size(); ++k)
    if (poses[k].found)
      found.push_back({poses[k].model, poses[k].T_cam_obj, std::int32_t(k + 1)}), which.push_back(k);
  if (found.empty()) return;
  const CloudBatch r = render(ctx, found, s.score_stride, result);
  const float tol = s.scene.explain_distance_m;
  for (std::size_t i = 0; i < which.size(); ++i) {
    std::size_t visible = 0, agree = 0;
    for (auto j = std::size_t(r.offsets[i]); j < std::size_t(r.offsets[i + 1]); ++j) {
      if (r.pixel[j] < 0) continue;
      const float d = ctx.frame.depth_m.data[std::size_t(r.pixel[j])];
      if (!(d > 0)) continue;  // no reading: a dark or glossy patch, an edge; neither for nor against
      ++visible;
      agree += std::abs(d - r.z[j]) <= tol;
    }
    poses[which[i]].depth_agreement = visible > 0 ? float(agree) / float(visible) : 0.f;
  }
}

/// The last steps of both entry points: fit (fit_poses, timed in SixDofTimings::fit; if fit.iterations >
/// 0), then score every pose (pose_score) and measure its depth agreement (depth_agreement).
template <class Backend>
void fit_and_score(const Context<Backend>& ctx, const LabelImage& labels,
                   const std::vector<std::size_t>& points_estimate, std::vector<SixDofPose>& poses,
                   SixDofResult& result) {
  if (ctx.shared.settings.fit.iterations > 0) {
    const auto t = Clock::now();
    fit_poses(ctx, labels, points_estimate, poses, result);
    result.timings.fit += seconds_since(t);
  }
  for (auto& p : poses) p.score = pose_score(p.cost);
  depth_agreement(ctx, poses, result);
}

}  // namespace sixdof_detail
}  // namespace perch2
