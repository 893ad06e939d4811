// Refinement in the tabletop search (perch2/search/tabletop.hpp): hypotheses rendered at render.stride
// (occluders marked) and aligned to the object readings by (x, y, yaw) ICP (Dof::TableXYYaw, at most
// icp_max_points points each), every ICP correction then put back onto the table exactly (corrected: the
// rounding that would tilt a model off the table is dropped), and those whose ICP matched too few points
// dropped (well_supported). refine_and_score is the Parallel search's pass over a batch: refine, keep the
// well supported, de-duplicate, score coarse to fine (score.hpp; BF-ICP: by fitness, bf_icp.hpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "perch2/core/pose.hpp"
#include "perch2/registration/registration.hpp"
#include "perch2/search/tabletop/bf_icp.hpp"
#include "perch2/search/tabletop/context.hpp"
#include "perch2/search/tabletop/grid.hpp"
#include "perch2/search/tabletop/score.hpp"

namespace perch2::tabletop_detail {

/// At most `max_points` points of every cloud, evenly spread over its points (every ceil(n / max_points)-th).
inline CloudBatch thin_clouds(const CloudBatch& in, int max_points) {
  if (max_points <= 0) return in;
  CloudBatch out;
  out.offsets = {0};
  for (std::size_t c = 0; c < in.num_clouds(); ++c) {
    const auto begin = std::size_t(in.offsets[c]), end = std::size_t(in.offsets[c + 1]);
    const std::size_t step =
        std::max<std::size_t>(1, (end - begin + std::size_t(max_points) - 1) / std::size_t(max_points));
    for (std::size_t i = begin; i < end; i += step) {
      out.x.push_back(in.x[i]), out.y.push_back(in.y[i]), out.z.push_back(in.z[i]);
      out.rgb.push_back(in.rgb[i]), out.pixel.push_back(in.pixel[i]), out.cloud.push_back(in.cloud[i]);
    }
    out.offsets.push_back(std::int64_t(out.size()));
  }
  return out;
}

template <class Backend>
IcpSettings icp_settings(const Context<Backend>& ctx, const Frame<Backend>& f) {
  IcpSettings s = ctx.settings.icp;
  s.dof = Dof::TableXYYaw;
  s.up_cam = f.T_cam_world.linear().col(2);
  s.origin_cam = f.T_cam_world.translation();
  return s;
}

/// A candidate moved by an ICP correction (camera frame), back to exact (x, y, yaw): the rounding that
/// would tilt the model off the table is dropped.
template <class Backend>
Candidate corrected(const Context<Backend>& ctx, const Frame<Backend>& f, Candidate c,
                    const Pose& T_corr_cam) {
  const Pose T = f.T_cam_world.inverse() * T_corr_cam * f.T_cam_world * T_world_obj(ctx, c);
  const Pose T_world_place = T * ctx.models[c.model].T_place_obj->inverse();
  c.x = T_world_place.translation().x(), c.y = T_world_place.translation().y();
  c.yaw = std::atan2(T_world_place.linear()(1, 0), T_world_place.linear()(0, 0));
  return c;
}

/// Renders at the refinement stride, runs (x, y, yaw) ICP against `target` (readings of the frame above the
/// table: f.registration, or the second look's) and moves every candidate to its result. Returns the ICP
/// result (BF-ICP selects on it), the rendered point counts and the points ICP aligned.
template <class Backend>
RegistrationResult refine(const Context<Backend>& ctx, const Frame<Backend>& f,
                          const typename Backend::Registration& target, std::vector<Candidate>& cands,
                          const Occluders* occ, std::vector<std::int64_t>& points,
                          std::vector<std::int64_t>& icp_points, TabletopTimings& timings) {
  const CloudBatch rendered = render(ctx, f, cands, ctx.settings.render.stride, occ, timings);
  points.resize(cands.size());
  for (std::size_t h = 0; h < cands.size(); ++h) points[h] = std::int64_t(rendered.cloud_size(h));
  const auto t = Clock::now();
  const std::vector<std::int32_t> seg(cands.size(), 0);
  const int max_points = ctx.settings.mode == SearchMode::BruteForceIcp ? 0 : ctx.settings.icp_max_points;
  const CloudBatch sources = thin_clouds(rendered, max_points);
  RegistrationResult r = target.icp(sources, seg, icp_settings(ctx, f));
  icp_points.resize(cands.size());
  for (std::size_t h = 0; h < cands.size(); ++h) icp_points[h] = std::int64_t(sources.cloud_size(h));
  for (std::size_t h = 0; h < cands.size(); ++h) cands[h] = corrected(ctx, f, cands[h], r.T_corr[h]);
  timings.refine += seconds_since(t);
  return r;
}

/// The refined candidates whose ICP matched at least min_icp_inlier_fraction of the points it aligned.
template <class Backend>
std::vector<Candidate> well_supported(const Context<Backend>& ctx, const std::vector<Candidate>& cands,
                                      const RegistrationResult& icp,
                                      const std::vector<std::int64_t>& icp_points) {
  std::vector<Candidate> out;
  for (std::size_t h = 0; h < cands.size(); ++h)
    if (float(icp.inliers[h]) >= ctx.settings.min_icp_inlier_fraction * float(icp_points[h]) &&
        icp_points[h] > 0)
      out.push_back(cands[h]);
  return out;
}

/// Refines a batch of candidates against `target` and scores what stays: well supported, de-duplicated,
/// coarse to fine (best_coarse, then score_for_selection); BF-ICP: all of them, by ICP fitness. Counts
/// them into result (refined, scored) and keeps every scored one there with keep_scored.
template <class Backend>
Scored refine_and_score(const Context<Backend>& ctx, const Frame<Backend>& f,
                        const typename Backend::Registration& target, std::vector<Candidate> cands,
                        const std::vector<ObjectCount>& objects, TabletopResult& result) {
  const TabletopSettings& s = ctx.settings;
  const bool bf = s.mode == SearchMode::BruteForceIcp;
  const Occluders* occ = s.occluder_marking ? &f.occluders : nullptr;
  Scored out;
  if (cands.empty()) return out;
  std::vector<std::int64_t> points, icp_points;
  RegistrationResult icp;
  if (s.refine || bf) icp = refine(ctx, f, target, cands, occ, points, icp_points, result.timings);
  result.hypotheses_refined += cands.size();
  if (s.refine && !bf) cands = well_supported(ctx, cands, icp, icp_points);
  if (bf) {  // truncated mean squared distance: points without a correspondence count as the cap
    out = icp_fitness(s, cands.size(), points, icp);
  } else {
    cands = dedupe(cands, s.dedupe_xy_m, s.dedupe_yaw_rad, ctx.yaw_symmetric);
    if (s.coarse_score_stride > s.score_stride && !cands.empty())
      cands = best_coarse(ctx, f, cands, objects, occ, result);
    out = score_for_selection(ctx, f, cands, occ, true, result.timings);
  }
  result.hypotheses_scored += cands.size();
  keep_scored(ctx, f, cands, out.scores, out.costs, result);
  out.cands = std::move(cands);
  return out;
}

}  // namespace perch2::tabletop_detail
