// One pass over hypotheses, the step every stage of the 6-DoF search repeats: render (each hypothesis as
// its own segment's: that segment's pixels never hide it), refine with GICP against its own segment,
// re-render at the refined pose and score with the RGB-D cost. Hypotheses go through in chunks sized to
// SixDofSettings::memory_budget_bytes (per-instance rendered-point estimates x bytes_per_point), so many
// more proposals run in the same memory, just slower. The first and second passes are Pass settings run
// by run_chunks(); score() and for_rendered_chunks() render and evaluate without refining.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <cstdint>
#include <vector>

#include "perch2/search/sixdof/context.hpp"
#include "perch2/search/sixdof/select.hpp"

namespace perch2 {
namespace sixdof_detail {

/// Renders the hypotheses (of jobs) as their segments' own: pixels of a hypothesis' segment never hide it.
template <class Backend>
CloudBatch render(const Context<Backend>& ctx, const std::vector<Hypothesis>& h, int stride,
                  SixDofResult& result) {
  const auto t = Clock::now();
  RenderSettings rs = ctx.shared.settings.render;
  rs.stride = stride;
  std::vector<Hypothesis> as_segments = h;
  for (auto& x : as_segments) x.label = ctx.label_of(x);
  CloudBatch out = ctx.shared.renderer_at(stride).render(as_segments, ctx.frame.camera, rs, &ctx.occ);
  result.timings.render += seconds_since(t);
  return out;
}

/// One GICP pass of every hypothesis against its own segment (only gs's ICP warm-up if warmup_only);
/// moves the hypotheses.
template <class Backend>
void refine(const Context<Backend>& ctx, std::vector<Hypothesis>& chunk, const CloudBatch& rendered,
            const GicpSettings& gs, SixDofResult& result, bool warmup_only = false) {
  const auto t = Clock::now();
  std::vector<std::int32_t> segment(chunk.size());
  for (std::size_t h = 0; h < chunk.size(); ++h) segment[h] = ctx.target_of(chunk[h]);
  const RegistrationResult r = warmup_only ? ctx.registration->icp(rendered, segment, icp_warmup_settings(gs))
                                           : ctx.registration->gicp(rendered, segment, gs);
  for (std::size_t h = 0; h < chunk.size(); ++h) {
    Pose T = r.T_corr[h] * chunk[h].T_cam_obj;
    T.linear() = Eigen::Quaternionf(T.linear()).normalized().toRotationMatrix();  // keep it rigid
    chunk[h].T_cam_obj = T;
  }
  result.timings.refine += seconds_since(t);
}

/// One pass over hypotheses: render at `stride`, refine with `gicp` (if `refine`), re-render at
/// score_stride and score.
struct Pass {
  int stride = 4;
  GicpSettings gicp;
  bool refine = true;
  int score_stride = 4;
  const CostSettings* cost = nullptr;
  bool dedupe_after_warmup = false;  ///< GICP only the distinct poses the ICP warm-up reached
  bool warmup_only = false;          ///< refine with gicp's ICP warm-up only (the screen)
  bool first = false;                ///< the first pass (counted in first_pass_distinct)
};

/// The end of the chunk starting at `begin`: as many hypotheses as fit the memory budget (at least one),
/// each estimated at points_estimate[its instance] x scale points.
inline std::size_t chunk_end(const SixDofSettings& s, const std::vector<Hypothesis>& hyps, std::size_t begin,
                             double scale, const std::vector<std::size_t>& points_estimate) {
  std::size_t end = begin, bytes = 0;
  while (end < hyps.size()) {
    const std::size_t b = std::size_t(double(points_estimate[std::size_t(hyps[end].label - 1)]) * scale *
                                      double(s.bytes_per_point)) +
                          1;
    if (end > begin && bytes + b > s.memory_budget_bytes) break;
    bytes += b, ++end;
  }
  return end;
}

/// Renders, refines, re-renders and scores one chunk (appending its costs). Returns its largest rendered
/// point count.
template <class Backend>
std::size_t run_chunk(const Context<Backend>& ctx, const Pass& pass, std::vector<Hypothesis>& chunk,
                      std::vector<CostBreakdown>& costs, SixDofResult& result) {
  std::size_t points = 0;
  if (pass.refine && pass.dedupe_after_warmup && pass.gicp.icp_warmup_iterations > 0) {
    // ICP warm-up, then GICP only for the distinct poses it reached (re-rendered there).
    const CloudBatch rendered = render(ctx, chunk, pass.stride, result);
    points = rendered.size();
    refine(ctx, chunk, rendered, pass.gicp, result, /*warmup_only=*/true);
    chunk = distinct_poses(ctx.shared, chunk);
    result.first_pass_distinct += chunk.size();
    GicpSettings rest = pass.gicp;
    rest.icp_warmup_iterations = 0;
    const CloudBatch moved = render(ctx, chunk, pass.stride, result);
    points = std::max(points, moved.size());
    refine(ctx, chunk, moved, rest, result);
  } else if (pass.refine) {
    if (pass.first) result.first_pass_distinct += chunk.size();
    const CloudBatch rendered = render(ctx, chunk, pass.stride, result);
    points = rendered.size();
    refine(ctx, chunk, rendered, pass.gicp, result, pass.warmup_only);
  }
  const CloudBatch rendered = render(ctx, chunk, pass.score_stride, result);
  points = std::max(points, rendered.size());
  const auto t = Clock::now();
  const std::vector<CostBreakdown> c = ctx.cost.evaluate(rendered, ctx.request(chunk), *pass.cost).hypotheses;
  costs.insert(costs.end(), c.begin(), c.end());
  result.timings.cost += seconds_since(t);
  return points;
}

/// Runs `pass` over `hyps` in chunks under the memory budget; moves the hypotheses to their refined
/// poses and returns their costs, in order.
template <class Backend>
std::vector<CostBreakdown> run_chunks(const Context<Backend>& ctx, const Pass& pass,
                                      std::vector<Hypothesis>& hyps,
                                      const std::vector<std::size_t>& points_estimate, SixDofResult& result) {
  const SixDofSettings& s = ctx.shared.settings;
  // points_estimate is for the finest stride in use; a coarser render has fewer points.
  const int finest = std::min({s.render.stride, s.second_pass_stride, s.score_stride});
  const int coarsest_here = std::min(pass.stride, pass.score_stride);
  const double scale = double(finest * finest) / double(coarsest_here * coarsest_here);
  std::vector<CostBreakdown> costs;
  costs.reserve(hyps.size());
  std::vector<Hypothesis> out;  // the chunks' hypotheses after the pass (without warm-up duplicates)
  out.reserve(hyps.size());
  std::size_t begin = 0;
  while (begin < hyps.size()) {
    const std::size_t end = chunk_end(s, hyps, begin, scale, points_estimate);
    std::vector<Hypothesis> chunk(hyps.begin() + std::ptrdiff_t(begin), hyps.begin() + std::ptrdiff_t(end));
    const std::size_t points = run_chunk(ctx, pass, chunk, costs, result);
    out.insert(out.end(), chunk.begin(), chunk.end());
    result.peak_chunk_bytes = std::max(result.peak_chunk_bytes, points * s.bytes_per_point);
    result.chunk_hypotheses = std::max(result.chunk_hypotheses, end - begin);
    ++result.chunks;
    begin = end;
  }
  hyps = std::move(out);
  return costs;
}

/// Renders `hyps` at `stride` in chunks under the memory budget (counted in peak_chunk_bytes, not in
/// chunks) and calls use(chunk, rendered) for each, in order.
template <class Backend, class Use>
void for_rendered_chunks(const Context<Backend>& ctx, const std::vector<Hypothesis>& hyps, int stride,
                         const std::vector<std::size_t>& points_estimate, SixDofResult& result, Use&& use) {
  const SixDofSettings& s = ctx.shared.settings;
  const int finest = std::min({s.render.stride, s.second_pass_stride, s.score_stride});
  const double scale = double(finest * finest) / double(stride * stride);
  for (std::size_t begin = 0; begin < hyps.size();) {
    const std::size_t end = chunk_end(s, hyps, begin, scale, points_estimate);
    const std::vector<Hypothesis> chunk(hyps.begin() + std::ptrdiff_t(begin),
                                        hyps.begin() + std::ptrdiff_t(end));
    const CloudBatch rendered = render(ctx, chunk, stride, result);
    result.peak_chunk_bytes = std::max(result.peak_chunk_bytes, rendered.size() * s.bytes_per_point);
    use(chunk, rendered);
    begin = end;
  }
}

/// Renders `hyps` at `stride` and scores them with `cs`, in chunks under the memory budget (counted in
/// peak_chunk_bytes, not in chunks).
template <class Backend>
std::vector<CostBreakdown> score(const Context<Backend>& ctx, const std::vector<Hypothesis>& hyps, int stride,
                                 const CostSettings& cs, const std::vector<std::size_t>& points_estimate,
                                 SixDofResult& result) {
  std::vector<CostBreakdown> costs;
  costs.reserve(hyps.size());
  for_rendered_chunks(ctx, hyps, stride, points_estimate, result,
                      [&](const std::vector<Hypothesis>& chunk, const CloudBatch& rendered) {
                        const auto t = Clock::now();
                        const std::vector<CostBreakdown> c =
                            ctx.cost.evaluate(rendered, ctx.request(chunk), cs).hypotheses;
                        costs.insert(costs.end(), c.begin(), c.end());
                        result.timings.cost += seconds_since(t);
                      });
  return costs;
}

}  // namespace sixdof_detail
}  // namespace perch2
