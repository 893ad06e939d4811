// The polish of the Parallel search (TabletopSettings::polish_rounds; perch2/search/tabletop.hpp): every
// selected pose rendered again at polish_stride and aligned by (x, y, yaw) ICP with all its points, pairs
// within polish_max_distance_m, a few rounds. The search's refinement starts from the grid with a few points
// of a coarse render and a wide pair distance: it finds the place but stops a few millimetres or degrees
// short, and the tolerant cost cannot tell.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "perch2/registration/registration.hpp"
#include "perch2/search/tabletop/context.hpp"
#include "perch2/search/tabletop/refine.hpp"
#include "perch2/search/tabletop/score.hpp"
#include "perch2/search/tabletop/select.hpp"

namespace perch2::tabletop_detail {

/// The polish (TabletopSettings::polish_rounds) of every pose in result.poses: rounds of rendering at
/// polish_stride (occluders marked as in the search) and (x, y, yaw) ICP of all its points against the
/// object readings, pairs within polish_max_distance_m. A polished pose is scored again at score_stride
/// as selection scored it and kept if it is still acceptable.
template <class Backend>
void polish(const Context<Backend>& ctx, const Frame<Backend>& f, TabletopResult& result) {
  const TabletopSettings& s = ctx.settings;
  if (s.polish_rounds <= 0 || result.poses.empty()) return;
  const Occluders* occ = s.occluder_marking ? &f.occluders : nullptr;
  std::vector<Candidate> cands;
  for (const auto& p : result.poses) cands.push_back({p.model, p.x_m, p.y_m, p.yaw_rad});
  IcpSettings icp = icp_settings(ctx, f);
  icp.max_correspondence_distance_m = s.polish_max_distance_m;
  icp.max_iterations = s.polish_iterations;
  for (int round = 0; round < s.polish_rounds; ++round) {
    const CloudBatch rendered = render(ctx, f, cands, s.polish_stride, occ, result.timings);
    const auto t = Clock::now();
    const RegistrationResult r =
        f.registration->icp(rendered, std::vector<std::int32_t>(cands.size(), 0), icp);
    for (std::size_t h = 0; h < cands.size(); ++h)
      if (rendered.cloud_size(h) >= std::size_t(s.min_rendered_points))
        cands[h] = corrected(ctx, f, cands[h], r.T_corr[h]);
    result.timings.refine += seconds_since(t);
  }
  const Scored sc = score_for_selection(ctx, f, cands, occ, true, result.timings);
  for (std::size_t k = 0; k < cands.size(); ++k)
    if (acceptable(ctx, sc.costs[k]))
      result.poses[k] = make_pose(ctx, f, cands[k], result.poses[k].instance, sc.scores[k], sc.costs[k]);
}

}  // namespace perch2::tabletop_detail
