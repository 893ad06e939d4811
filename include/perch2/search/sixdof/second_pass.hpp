// The second pass: only the hypotheses keep_best kept (the best few distinct poses of each instance) are
// re-rendered at second_pass_stride (4) and refined by GICP with a tighter cap (second_pass_cap_m), so a
// badly trimmed mask's remaining stray points cannot pull the converged pose; then re-rendered at
// score_stride and scored with the final cost (SixDofSettings::cost, J_o over the instance's whole
// segment). The same GICP settings polish the local search's poses and refine scene candidates again.
#pragma once

#include <vector>

#include "perch2/search/sixdof/context.hpp"
#include "perch2/search/sixdof/pass.hpp"

namespace perch2 {
namespace sixdof_detail {

/// The second pass' settings (SixDofSettings::second_pass_*).
inline Pass second_pass_settings(const SixDofSettings& s) {
  Pass second;
  second.stride = s.second_pass_stride;
  second.gicp = s.gicp;
  second.gicp.max_correspondence_distance_m = s.second_pass_cap_m;
  second.gicp.max_iterations = s.second_pass_iterations;
  second.gicp.icp_warmup_iterations = 0;
  second.refine = s.second_pass_cap_m > 0;
  second.score_stride = s.score_stride;
  second.cost = &s.cost;
  return second;
}

/// Runs the second pass over `kept`, which it moves to the refined poses; returns their final costs, in
/// order.
template <class Backend>
std::vector<CostBreakdown> second_pass(const Context<Backend>& ctx, std::vector<Hypothesis>& kept,
                                       const std::vector<std::size_t>& points_estimate,
                                       SixDofResult& result) {
  result.second_pass_hypotheses += kept.size();
  const Pass second = second_pass_settings(ctx.shared.settings);
  return run_chunks(ctx, second, kept, points_estimate, result);
}

}  // namespace sixdof_detail
}  // namespace perch2
