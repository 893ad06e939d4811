// The local search after the second pass (LocalSearchSettings): GICP cannot see what the geometry does not
// show, so a printed can turned about its axis or a box turned to show its back fits the depth equally
// well. The best local.candidates_per_instance poses of each instance are turned about their model's own
// axes, coarse to fine (search_turns, perch2/search/local_search.hpp): among the turns whose depth-only
// cost stays within turns.geometry_tolerance, the correlation of rendered and observed colours decides.
// Then one more tight GICP pass (polish) restores any tilt the turns brought, and the final cost at the
// moved poses picks one winner per instance.
#pragma once

#include <Eigen/Geometry>
#include <utility>
#include <vector>

#include "perch2/cost/appearance.hpp"
#include "perch2/search/local_search.hpp"
#include "perch2/search/sixdof/context.hpp"
#include "perch2/search/sixdof/pass.hpp"
#include "perch2/search/sixdof/second_pass.hpp"
#include "perch2/search/sixdof/select.hpp"

namespace perch2 {
namespace sixdof_detail {

/// The local search (LocalSearchSettings) around each of `hyps`, which it moves.
template <class Backend>
void local_search(const Context<Backend>& ctx, std::vector<Hypothesis>& hyps,
                  const std::vector<std::size_t>& points_estimate, SixDofResult& result) {
  auto turn = [](Hypothesis h, int axis, float angle_rad) {  // about the model's own axis
    h.T_cam_obj.linear() =
        h.T_cam_obj.linear() * Eigen::AngleAxisf(angle_rad, Eigen::Vector3f::Unit(axis)).toRotationMatrix();
    return h;
  };
  CostSettings depth_only = ctx.shared.settings.cost;
  depth_only.use_color = false;
  depth_only.normalization = Normalization::Fractions;
  auto measure = [&](const std::vector<Hypothesis>& h, int stride, bool geometry) {
    std::vector<TurnSample> out;
    out.reserve(h.size());
    for_rendered_chunks(ctx, h, stride, points_estimate, result,
                        [&](const std::vector<Hypothesis>& chunk, const CloudBatch& rendered) {
                          const auto t = Clock::now();
                          std::vector<AppearanceSamples> a =
                              appearance_samples(rendered, ctx.frame, depth_only.delta_m);
                          std::vector<CostBreakdown> c(chunk.size());
                          if (geometry)
                            c = ctx.cost.evaluate(rendered, ctx.request(chunk), depth_only).hypotheses;
                          for (std::size_t i = 0; i < c.size(); ++i)
                            out.push_back({c[i].total, std::move(a[i])});
                          result.timings.cost += seconds_since(t);
                        });
    return out;
  };
  auto shift = [](Hypothesis h, int axis, float m) {  // across the line of sight (camera x or y)
    h.T_cam_obj.translation()[axis] += m;
    return h;
  };
  search_turns(hyps, 3, 2, ctx.frame.camera.width, ctx.shared.settings.local.turns, turn, shift, measure,
               &result.local_candidates);
}

/// The local search (LocalSearchSettings) around `finalists` (the best few hypotheses of each of the K
/// jobs, in job order, with their final costs), then the second pass' GICP (polish); leaves one winner
/// per job, in job order, with its final cost.
template <class Backend>
void local_stage(const Context<Backend>& ctx, std::vector<Hypothesis>& finalists,
                 std::vector<CostBreakdown>& final_costs, std::size_t K,
                 const std::vector<std::size_t>& points_estimate, SixDofResult& result) {
  const SixDofSettings& s = ctx.shared.settings;
  const auto t = Clock::now();
  local_search(ctx, finalists, points_estimate, result);
  const Pass second = second_pass_settings(s);
  if (s.local.polish && second.refine) {  // GICP restores what the turns may have tilted (it cannot undo a
                                          // turn it cannot see)
    const CloudBatch rendered = render(ctx, finalists, s.second_pass_stride, result);
    refine(ctx, finalists, rendered, second.gicp, result);
  }
  // The winner per job (acceptable first) by the final cost, re-evaluated at the moved poses.
  const std::vector<CostBreakdown> moved_costs =
      score(ctx, finalists, s.score_stride, s.cost, points_estimate, result);
  const std::vector<std::size_t> winners = best_per_instance(s, finalists, moved_costs, K, 1, s.score_stride);
  std::vector<Hypothesis> chosen;
  final_costs.clear();
  for (const std::size_t h : winners) chosen.push_back(finalists[h]), final_costs.push_back(moved_costs[h]);
  finalists = std::move(chosen);
  result.timings.local += seconds_since(t);
}

}  // namespace sixdof_detail
}  // namespace perch2
