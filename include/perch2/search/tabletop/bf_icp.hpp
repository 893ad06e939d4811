// The brute-force ICP baseline's pieces (SearchMode::BruteForceIcp, PERCH's BF-ICP;
// perch2/search/tabletop.hpp): every grid hypothesis' visible surface is refined by ICP (refine_and_score,
// all its points) and ranked by the truncated mean squared correspondence distance (icp_fitness) instead of
// the rendering cost; the chosen poses' explanation cost is reported beside it (report_costs).
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "perch2/registration/registration.hpp"
#include "perch2/search/tabletop/context.hpp"
#include "perch2/search/tabletop/score.hpp"

namespace perch2::tabletop_detail {

/// BF-ICP's score of refined candidates: the truncated mean squared distance of their `points` rendered
/// points to the object readings (ICP's final error over its inliers; points without a correspondence count
/// as the cap, icp.max_correspondence_distance_m), metres squared. costs hold the point and inlier counts
/// only.
inline Scored icp_fitness(const TabletopSettings& s, std::size_t num_cands,
                          const std::vector<std::int64_t>& points, const RegistrationResult& icp) {
  Scored out;
  out.scores.assign(num_cands, 0.f);
  out.costs.resize(num_cands);
  const float cap2 = s.icp.max_correspondence_distance_m * s.icp.max_correspondence_distance_m;
  for (std::size_t h = 0; h < num_cands; ++h) {
    const float n = float(points[h]), in = float(icp.inliers[h]);
    const float e = std::isfinite(icp.final_error[h]) ? icp.final_error[h] : 0.f;
    out.scores[h] = n > 0 ? (in * e * e + (n - in) * cap2) / n : INFINITY;
    out.costs[h].rendered_points = std::int32_t(points[h]);
    out.costs[h].rendered_inliers = icp.inliers[h];
  }
  return out;
}

/// The explanation cost of the chosen candidates (indices into `scored`, in the order of result.poses) into
/// result.poses' cost: BF-ICP selects by fitness, and reports the cost too.
template <class Backend>
void report_costs(const Context<Backend>& ctx, const Frame<Backend>& f, const Scored& scored,
                  const std::vector<std::size_t>& chosen_index, TabletopResult& result) {
  const TabletopSettings& s = ctx.settings;
  std::vector<Candidate> chosen;
  for (const std::size_t h : chosen_index) chosen.push_back(scored.cands[h]);
  if (!chosen.empty()) {
    const Occluders* occ = s.occluder_marking ? &f.occluders : nullptr;
    const std::vector<CostBreakdown> b =
        score(ctx, f, chosen, render(ctx, f, chosen, s.score_stride, occ, result.timings), result.timings);
    for (std::size_t k = 0; k < chosen.size(); ++k) result.poses[k].cost = b[k];
  }
}

}  // namespace perch2::tabletop_detail
