// The Tree search (SearchMode::Tree: Monotone Scene Generation, the variants Perch2B and Perch;
// perch2/search/tabletop.hpp): objects are placed one per level; each level refines and scores every
// remaining model's hypotheses in the scene rendered so far (placed objects hide them), drops placements that
// would hide placed objects, and places the model whose best placement explains the largest fraction of its
// points. Greedy: each level keeps the single best placement (a beam of width 1, not PERCH's full tree).
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "perch2/core/image.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/render/render.hpp"
#include "perch2/search/tabletop/context.hpp"
#include "perch2/search/tabletop/grid.hpp"
#include "perch2/search/tabletop/refine.hpp"
#include "perch2/search/tabletop/score.hpp"
#include "perch2/search/tabletop/select.hpp"

namespace perch2::tabletop_detail {

/// Monotone Scene Generation, greedily: each level refines and scores every remaining model's candidates
/// in the scene rendered so far (placed objects hide them), drops placements that would hide placed
/// objects, and places the model whose best placement explains the largest fraction of its points.
template <class Backend>
void search_tree(const Context<Backend>& ctx, const Frame<Backend>& f,
                 const std::vector<ObjectCount>& objects, const std::vector<Candidate>& grid,
                 TabletopResult& result) {
  const TabletopSettings& s = ctx.settings;
  const Intrinsics& cam = f.rgbd.camera;
  DepthImage placed_depth(cam.width, cam.height, 0.f);  // nearest placed surface, 0 = none
  std::vector<Candidate> placed;
  std::vector<int> remaining(ctx.models.size(), 0);
  for (const auto& o : objects) remaining[std::size_t(o.model)] = o.count;
  std::vector<std::vector<TabletopPose>> found(ctx.models.size());
  const float margin = s.render.occlusion_margin_m;
  auto hides = [margin](float occluder, float z) { return occluder > 0.f && occluder < z - margin; };
  for (;;) {
    std::vector<Candidate> cands;
    for (const auto& c : grid)
      if (remaining[std::size_t(c.model)] > 0) cands.push_back(c);
    if (cands.empty()) break;
    // Occluders: the placed objects (and the observed depth if marking is on).
    Occluders occ{placed_depth, {}};
    if (s.occluder_marking)
      for (std::size_t i = 0; i < occ.depth_m.data.size(); ++i) {
        const float d = f.occluders.depth_m.data[i], p = occ.depth_m.data[i];
        occ.depth_m.data[i] = p > 0.f && (d <= 0.f || p < d) ? p : d;
      }
    std::vector<std::int64_t> points, icp_points;
    if (s.refine) {
      const RegistrationResult icp =
          refine(ctx, f, *f.registration, cands, &occ, points, icp_points, result.timings);
      result.hypotheses_refined += cands.size();
      cands = well_supported(ctx, cands, icp, icp_points);
      if (cands.empty()) break;
    } else {
      result.hypotheses_refined += cands.size();
    }
    cands = dedupe(cands, s.dedupe_xy_m, s.dedupe_yaw_rad, ctx.yaw_symmetric);
    const CloudBatch all = render(ctx, f, cands, s.score_stride, nullptr, result.timings);
    std::vector<std::int32_t> hiding(cands.size(), 0);
    for (std::size_t h = 0; h < cands.size(); ++h)
      for (auto i = std::size_t(all.offsets[h]); i < std::size_t(all.offsets[h + 1]); ++i)
        hiding[h] += hides(all.z[i], placed_depth.data[std::size_t(all.pixel[i])]);
    const CloudBatch visible = filter_points(
        all, [&](std::size_t i) { return !hides(occ.depth_m.data[std::size_t(all.pixel[i])], all.z[i]); });
    const std::vector<CostBreakdown> costs = score(ctx, f, cands, visible, result.timings);
    result.hypotheses_scored += cands.size();
    std::vector<float> totals(costs.size());
    for (std::size_t h = 0; h < costs.size(); ++h) totals[h] = costs[h].total;
    keep_scored(ctx, f, cands, totals, costs, result);

    const auto t = Clock::now();
    std::ptrdiff_t best = -1;
    float best_fraction = INFINITY;
    std::vector<float> best_total(ctx.models.size(), INFINITY);
    std::vector<std::ptrdiff_t> best_of(ctx.models.size(), -1);
    for (std::size_t h = 0; h < cands.size(); ++h) {
      const auto m = std::size_t(cands[h].model);
      const CostBreakdown& b = costs[h];
      if (!acceptable(ctx, b) || float(hiding[h]) > s.tree_max_occluding_fraction * float(all.cloud_size(h)))
        continue;
      if (std::any_of(placed.begin(), placed.end(),
                      [&](const Candidate& c) { return overlaps(ctx, c, cands[h]); }))
        continue;
      if (b.total < best_total[m]) best_total[m] = b.total, best_of[m] = std::ptrdiff_t(h);
    }
    for (std::size_t m = 0; m < ctx.models.size(); ++m) {
      if (best_of[m] < 0) continue;
      const CostBreakdown& b = costs[std::size_t(best_of[m])];
      const float fraction = float(b.rendered_outliers() + b.observed_unexplained()) /
                             float(std::max(1, b.rendered_points + b.observed_in_volume));
      if (fraction < best_fraction) best_fraction = fraction, best = best_of[m];
    }
    result.timings.select += seconds_since(t);
    if (best < 0) break;  // no model can be placed any more
    const Candidate& c = cands[std::size_t(best)];
    found[std::size_t(c.model)].push_back(make_pose(ctx, f, c, int(found[std::size_t(c.model)].size()),
                                                    costs[std::size_t(best)].total,
                                                    costs[std::size_t(best)]));
    placed.push_back(c);
    --remaining[std::size_t(c.model)];
    const CloudBatch full = render(ctx, f, {c}, 1, nullptr, result.timings);  // full-resolution depth of it
    for (std::size_t i = 0; i < full.size(); ++i) {
      float& d = placed_depth.data[std::size_t(full.pixel[i])];
      d = d > 0.f ? std::min(d, full.z[i]) : full.z[i];
    }
  }
  for (const auto& o : objects) {
    auto& poses = found[std::size_t(o.model)];
    result.poses.insert(result.poses.end(), poses.begin(), poses.end());
    if (remaining[std::size_t(o.model)] > 0)
      result.missing.push_back({o.model, remaining[std::size_t(o.model)]});
  }
}

}  // namespace perch2::tabletop_detail
