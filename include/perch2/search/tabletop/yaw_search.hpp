// The yaw search after selection (YawSearchSettings; perch2/search/tabletop.hpp): ICP cannot turn a printed
// can or bottle (its depth is the same at every turn), and the grid's yaws and the tolerant colour test leave
// its label up to tens of degrees off. Every selected pose of a model whose colours a turn changes is turned
// about the table normal (and shifted by a millimetre or two) by the turn search of
// perch2/search/local_search.hpp: the look-alike turns by geometry, the print deciding among them.
#pragma once

#include <cmath>
#include <cstddef>
#include <utility>
#include <vector>

#include "perch2/cost/appearance.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/search/local_search.hpp"
#include "perch2/search/tabletop/context.hpp"
#include "perch2/search/tabletop/score.hpp"

namespace perch2::tabletop_detail {

/// The yaw search (YawSearchSettings) of every pose in result.poses whose model has a yaw the colour
/// test can see (yaw_visible_in_colour).
/// A pose it turned is scored again at score_stride as selection scored it (Parallel mode's score, with
/// the hidden term when occluders are marked).
template <class Backend>
void search_yaws(const Context<Backend>& ctx, const Frame<Backend>& f, TabletopResult& result) {
  const YawSearchSettings& ys = ctx.settings.yaw_search;
  if (!yaw_search_runs(ctx.settings)) return;
  const auto t = Clock::now();
  std::vector<Candidate> cands;
  std::vector<std::size_t> pose_of;  // index into result.poses
  for (std::size_t k = 0; k < result.poses.size(); ++k) {
    const TabletopPose& p = result.poses[k];
    if (ctx.yaw_searched[std::size_t(p.model)])
      cands.push_back({p.model, p.x_m, p.y_m, p.yaw_rad}), pose_of.push_back(k);
  }
  const Occluders* occ = ctx.settings.occluder_marking ? &f.occluders : nullptr;
  const std::vector<Candidate> start = cands;
  auto turn = [&](Candidate c, int, float angle_rad) {  // about the table normal
    c.yaw = std::remainder(c.yaw + angle_rad, kTwoPi);
    return c;
  };
  CostSettings depth_only = ctx.settings.cost;
  depth_only.use_color = false;
  depth_only.normalization = Normalization::Fractions;
  auto measure = [&](const std::vector<Candidate>& c, int stride, bool geometry) {
    const CloudBatch rendered = render(ctx, f, c, stride, occ, result.timings);
    const std::vector<CostBreakdown> g = geometry ? score(ctx, f, c, rendered, depth_only, result.timings)
                                                  : std::vector<CostBreakdown>(c.size());
    const auto t_app = Clock::now();
    std::vector<AppearanceSamples> a = appearance_samples(rendered, f.rgbd, depth_only.delta_m);
    result.timings.cost += seconds_since(t_app);
    std::vector<TurnSample> out;
    for (std::size_t i = 0; i < c.size(); ++i) out.push_back({g[i].total, std::move(a[i])});
    return out;
  };
  auto shift = [](Candidate c, int axis, float m) {  // along the table's x or y
    (axis == 0 ? c.x : c.y) += m;
    return c;
  };
  if (!cands.empty())
    search_turns(cands, 1, 2, f.rgbd.camera.width, ys.turns, turn, shift, measure, &result.yaw_candidates);
  std::vector<Candidate> moved;
  std::vector<std::size_t> moved_pose;
  for (std::size_t i = 0; i < cands.size(); ++i)
    if (cands[i].yaw != start[i].yaw || cands[i].x != start[i].x || cands[i].y != start[i].y)
      moved.push_back(cands[i]), moved_pose.push_back(pose_of[i]);
  if (!moved.empty()) {
    const Scored sc =
        score_for_selection(ctx, f, moved, occ, ctx.settings.mode == SearchMode::Parallel, result.timings);
    for (std::size_t j = 0; j < moved.size(); ++j) {
      TabletopPose& p = result.poses[moved_pose[j]];
      p = make_pose(ctx, f, moved[j], p.instance, sc.scores[j], sc.costs[j]);
    }
  }
  result.timings.yaw += seconds_since(t);
}

}  // namespace perch2::tabletop_detail
