// Scoring in the tabletop search (perch2/search/tabletop.hpp): hypotheses rendered and scored by the
// explanation cost (perch2/cost/cost.hpp), J_o's volume being each model's footprint prism from min_height_m
// to its top; the share of a hypothesis that is not seen (hidden_shares); the score selection ranks by
// (score_for_selection: cost total + hidden_point_weight * hidden share); and the coarse pass of
// coarse-to-fine scoring (best_coarse): everything at coarse_score_stride, then only the best few yaws at
// each model's best places at score_stride.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <cstddef>
#include <numeric>
#include <utility>
#include <vector>

#include "perch2/core/camera.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/render/render.hpp"
#include "perch2/search/tabletop/context.hpp"

namespace perch2::tabletop_detail {

/// Per candidate, the share of its samples at score_stride that are not seen: hidden by nearer observed
/// depth or a missing reading (Frame::occluders) or outside the image. Rendered once more without occluders
/// into the image grown by its own size on every side (on the same sample grid; only the counts are used).
/// Empty without occluder marking or weight.
template <class Backend>
std::vector<float> hidden_shares(const Context<Backend>& ctx, const Frame<Backend>& f,
                                 const std::vector<Candidate>& cands, const std::vector<CostBreakdown>& costs,
                                 bool marked, TabletopTimings& timings) {
  if (!marked || !(ctx.settings.hidden_point_weight > 0.f) || cands.empty()) return {};
  const auto t = Clock::now();
  const int stride = ctx.settings.score_stride;
  Intrinsics grown = f.rgbd.camera;
  const int mx = (grown.width + stride - 1) / stride * stride,
            my = (grown.height + stride - 1) / stride * stride;
  grown.width += 2 * mx, grown.height += 2 * my, grown.cx += float(mx), grown.cy += float(my);
  RenderSettings rs = ctx.settings.render;
  rs.stride = stride;
  const CloudBatch all = ctx.renderer.render(to_hypotheses(ctx, f, cands), grown, rs, nullptr);
  timings.render += seconds_since(t);
  std::vector<float> out(cands.size(), 0.f);
  for (std::size_t h = 0; h < cands.size(); ++h) {
    const auto n = float(all.cloud_size(h));
    if (n > 0.f) out[h] = std::max(0.f, 1.f - float(costs[h].rendered_points) / n);
  }
  return out;
}

/// The cost's request for candidates: their poses and, per model, the footprint prism of J_o's volume
/// from min_height_m (or the model's top, if lower) up.
template <class Backend>
CostRequest cost_request(const Context<Backend>& ctx, const Frame<Backend>& f,
                         const std::vector<Candidate>& cands) {
  CostRequest req;
  req.footprints = ctx.footprints;
  for (auto& fp : req.footprints) fp.z_min_m = std::min(ctx.settings.min_height_m, fp.z_max_m);
  for (const auto& c : cands) req.add(0, c.model, f.T_cam_world * placement(c.x, c.y, c.yaw));
  return req;
}

/// The explanation cost (`cs`) of candidates rendered as `rendered`; timed into timings.cost.
template <class Backend>
std::vector<CostBreakdown> score(const Context<Backend>& ctx, const Frame<Backend>& f,
                                 const std::vector<Candidate>& cands, const CloudBatch& rendered,
                                 const CostSettings& cs, TabletopTimings& timings) {
  const auto t = Clock::now();
  std::vector<CostBreakdown> out = f.cost->evaluate(rendered, cost_request(ctx, f, cands), cs).hypotheses;
  timings.cost += seconds_since(t);
  return out;
}

/// As above, with settings.cost.
template <class Backend>
std::vector<CostBreakdown> score(const Context<Backend>& ctx, const Frame<Backend>& f,
                                 const std::vector<Candidate>& cands, const CloudBatch& rendered,
                                 TabletopTimings& timings) {
  return score(ctx, f, cands, rendered, ctx.settings.cost, timings);
}

/// Scored candidates: cost and, when occluders are marked, hidden share; score = what selection ranks by.
struct Scored {
  std::vector<Candidate> cands;
  std::vector<float> scores, hidden;  ///< hidden: empty unless occluders are marked (hidden_shares)
  std::vector<CostBreakdown> costs;
};

/// Renders and scores candidates at score_stride as Parallel selection ranks them: cost total plus
/// hidden_point_weight times the hidden share (with occluders and hidden_term).
template <class Backend>
Scored score_for_selection(const Context<Backend>& ctx, const Frame<Backend>& f, std::vector<Candidate> cands,
                           const Occluders* occ, bool hidden_term, TabletopTimings& timings) {
  Scored out;
  if (!cands.empty())
    out.costs = score(ctx, f, cands, render(ctx, f, cands, ctx.settings.score_stride, occ, timings), timings);
  out.hidden = hidden_shares(ctx, f, cands, out.costs, hidden_term && occ != nullptr, timings);
  for (std::size_t h = 0; h < cands.size(); ++h)
    out.scores.push_back(out.costs[h].total +
                         (out.hidden.empty() ? 0.f : ctx.settings.hidden_point_weight * out.hidden[h]));
  out.cands = std::move(cands);
  return out;
}

template <class Backend>
void keep_scored(const Context<Backend>& ctx, const Frame<Backend>& f, const std::vector<Candidate>& cands,
                 const std::vector<float>& scores, const std::vector<CostBreakdown>& costs,
                 TabletopResult& result) {
  if (!ctx.settings.keep_scored) return;
  for (std::size_t h = 0; h < cands.size(); ++h)
    result.scored.push_back(make_pose(ctx, f, cands[h], -1, scores[h], costs[h]));
}

/// The coarse pass of coarse-to-fine scoring: scores every candidate at coarse_score_stride and keeps,
/// per requested model, the acceptable ones at its best places: in order of coarse cost, a candidate
/// within rescore_place_radius_m of a kept place joins it (at most rescore_yaws per place), any other
/// opens a new place while the model has fewer than (requested instances + rescore_extra_places).
/// Returns them in their original order.
template <class Backend>
std::vector<Candidate> best_coarse(const Context<Backend>& ctx, const Frame<Backend>& f,
                                   const std::vector<Candidate>& cands,
                                   const std::vector<ObjectCount>& objects, const Occluders* occ,
                                   TabletopResult& result) {
  const TabletopSettings& s = ctx.settings;
  const std::vector<CostBreakdown> coarse =
      score(ctx, f, cands, render(ctx, f, cands, s.coarse_score_stride, occ, result.timings), result.timings);
  result.hypotheses_coarse += cands.size();
  std::vector<std::size_t> order(cands.size());
  std::iota(order.begin(), order.end(), std::size_t(0));
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return coarse[a].total < coarse[b].total; });
  int instances = 0;
  for (const auto& o : objects) instances += o.count;
  const std::size_t max_places = std::size_t(instances + s.rescore_extra_places);
  struct Place {
    Eigen::Vector2f xy;
    int kept;
  };
  std::vector<std::vector<Place>> places(ctx.models.size());
  const float r2 = s.rescore_place_radius_m * s.rescore_place_radius_m;
  // The acceptance test at the coarse stride: rendered counts scale with the sample density; the
  // observed points in the volume do not depend on it.
  const float density =
      float(s.score_stride * s.score_stride) / float(s.coarse_score_stride * s.coarse_score_stride);
  const float min_points = std::max(1.f, float(s.min_rendered_points) * density);
  std::vector<char> keep(cands.size(), 0);
  for (const std::size_t h : order) {
    const CostBreakdown& b = coarse[h];
    if (float(b.rendered_points) < min_points || b.observed_in_volume < s.min_observed_in_volume ||
        float(b.rendered_inliers) < s.min_inlier_fraction * float(b.rendered_points))
      continue;
    const Eigen::Vector2f xy(cands[h].x, cands[h].y);
    auto& mine = places[std::size_t(cands[h].model)];
    const auto near = std::find_if(mine.begin(), mine.end(),
                                   [&](const Place& p) { return (p.xy - xy).squaredNorm() <= r2; });
    if (near != mine.end()) {
      if (near->kept < s.rescore_yaws) keep[h] = 1, ++near->kept;
    } else if (mine.size() < max_places) {
      mine.push_back({xy, 1}), keep[h] = 1;
    }
  }
  std::vector<Candidate> out;
  for (std::size_t h = 0; h < cands.size(); ++h)
    if (keep[h]) out.push_back(cands[h]);
  return out;
}

}  // namespace perch2::tabletop_detail
