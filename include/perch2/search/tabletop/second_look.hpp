// The second look of the Parallel search (TabletopSettings::second_look; perch2/search/tabletop.hpp): when
// selection leaves requested instances missing, the object readings no selected footprint explains get a grid
// of their own at half the step, refined against them alone, and selection runs again over both passes'
// candidates. A mostly hidden object shows a sliver of readings between the first grid's positions, and ICP
// from there slides onto the larger neighbour beside it.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <cstddef>
#include <utility>
#include <vector>

#include "perch2/search/tabletop/context.hpp"
#include "perch2/search/tabletop/grid.hpp"
#include "perch2/search/tabletop/refine.hpp"
#include "perch2/search/tabletop/score.hpp"
#include "perch2/search/tabletop/select.hpp"

namespace perch2::tabletop_detail {

/// The second look (TabletopSettings::second_look): the object readings outside every selected pose's
/// footprint (grown by second_look_margin_m) are what the selection left unexplained; a grid at half the
/// step over them, supported by them alone, is refined against them alone (so a neighbour's readings
/// cannot pull a start onto the neighbour), scored as the first pass scored, and selection runs again over
/// both passes' candidates. Replaces result.poses / missing and `chosen` (indices into `scored`, which
/// gains the new candidates).
template <class Backend>
void second_look(const Context<Backend>& ctx, const Frame<Backend>& f,
                 const std::vector<ObjectCount>& objects, Scored& scored, std::vector<std::size_t>& chosen,
                 TabletopResult& result) {
  const TabletopSettings& s = ctx.settings;
  std::vector<std::vector<Eigen::Vector2f>> taken;
  for (const std::size_t h : chosen)
    taken.push_back(posed_polygon(ctx.footprints[std::size_t(scored.cands[h].model)], scored.cands[h]));
  std::vector<char> residual(f.object_xy.size(), 0);
  std::vector<Eigen::Vector2f> residual_xy;
  for (std::size_t i = 0; i < f.object_xy.size(); ++i) {
    residual[i] = std::none_of(taken.begin(), taken.end(), [&](const auto& poly) {
      return distance_outside_m(poly, f.object_xy[i]) <= s.second_look_margin_m;
    });
    if (residual[i]) residual_xy.push_back(f.object_xy[i]);
  }
  if (int(residual_xy.size()) < s.min_support_points) return;
  std::vector<Candidate> cands;
  for (const ObjectCount& m : result.missing) {
    const std::vector<Candidate> c =
        grid(ctx, f, m.model, residual_xy, 0.5f * s.xy_step_m, result.hypotheses_grid);
    cands.insert(cands.end(), c.begin(), c.end());
  }
  if (cands.empty()) return;
  result.hypotheses_kept += cands.size();
  const typename Backend::Registration target(
      filter_points(f.objects, [&](std::size_t i) { return residual[i] != 0; }));
  Scored more = refine_and_score(ctx, f, target, std::move(cands), result.missing, result);
  if (more.cands.empty()) return;
  const auto t = Clock::now();
  scored.cands.insert(scored.cands.end(), more.cands.begin(), more.cands.end());
  scored.scores.insert(scored.scores.end(), more.scores.begin(), more.scores.end());
  scored.costs.insert(scored.costs.end(), more.costs.begin(), more.costs.end());
  scored.hidden.insert(scored.hidden.end(), more.hidden.begin(), more.hidden.end());
  result.poses.clear(), result.missing.clear();
  chosen = select_parallel(ctx, f, scored.cands, scored.scores, scored.costs, scored.hidden, objects, result);
  result.timings.select += seconds_since(t);
}

}  // namespace perch2::tabletop_detail
