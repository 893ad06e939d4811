// The screen, then the first pass. The screen (ScreenSettings): every proposal of an instance large enough
// rendered at a coarser stride, pulled by ICP and ranked by first_pass_cost; only the best fraction go on.
// The first pass: every proposal left rendered at render.stride (8), brought into its basin by an ICP warm-up
// then GICP against its own segment's coarser targets (first_pass_target_stride), re-rendered and ranked
// by the cheap first_pass_cost. It only has to rank: the second pass finishes the pose. Each job runs at
// the coarsest stride that still shows it with first_pass_min_points, so a mostly hidden object is refined
// on a finer grid; hypotheses are grouped by job, so each stride is a contiguous run.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <optional>
#include <utility>
#include <vector>

#include "perch2/search/sixdof/context.hpp"
#include "perch2/search/sixdof/pass.hpp"

namespace perch2 {
namespace sixdof_detail {

/// The first pass' stride for an instance with `segment_points` observed points (see
/// SixDofSettings::first_pass_min_points).
inline int first_pass_stride(const SixDofSettings& s, std::size_t segment_points) {
  int stride = s.render.stride;
  auto expected = [&](int st) {
    return double(segment_points) * double(s.observed.stride * s.observed.stride) / double(st * st);
  };
  while (stride / 2 >= s.second_pass_stride && expected(stride) < double(s.first_pass_min_points))
    stride /= 2;
  return stride;
}

/// The first pass' stride of every job (first_pass_stride of its segment's observed points).
inline std::vector<int> first_pass_strides(const SixDofSettings& s, const std::vector<Job>& jobs,
                                           const std::vector<std::size_t>& segment_points) {
  std::vector<int> first_stride(jobs.size());
  for (std::size_t k = 0; k < jobs.size(); ++k)
    first_stride[k] = first_pass_stride(s, segment_points[std::size_t(jobs[k].segment)]);
  return first_stride;
}

/// The first pass' GICP targets built from `targets` (SixDofSettings::first_pass_target_stride); none
/// when that grid is not coarser than the observed one (the first pass then uses `targets` itself).
template <class Backend>
std::optional<typename Backend::Registration> first_pass_targets(const Shared<Backend>& sh,
                                                                 const RgbdFrame& frame,
                                                                 const CloudBatch& targets) {
  const SixDofSettings& s = sh.settings;
  if (s.first_pass_target_stride <= s.observed.stride) return std::nullopt;
  return std::optional<typename Backend::Registration>(
      std::in_place, on_stride_grid(targets, frame.camera.width, s.first_pass_target_stride,
                                    SixDofSettings::kFirstPassMinTargets));
}

template <class Registration>
const Registration* or_same(const std::optional<Registration>& coarse, const Registration& all) {
  return coarse ? &*coarse : &all;
}

/// Runs `pass` (its stride and score_stride set per run) over each contiguous run of `hyps` whose jobs
/// share a stride (job k at stride_of[k]; hypotheses are grouped by job) against ctx's first-pass targets;
/// moves them as run_chunks does and returns their costs, in order.
template <class Backend>
std::vector<CostBreakdown> run_by_stride(const Context<Backend>& ctx, Pass pass,
                                         const std::vector<int>& stride_of, std::vector<Hypothesis>& hyps,
                                         const std::vector<std::size_t>& points_estimate,
                                         SixDofResult& result) {
  Context<Backend> first_ctx = ctx;  // against the first pass' coarser targets
  first_ctx.registration = ctx.first_pass_registration;
  auto stride = [&](const Hypothesis& h) { return stride_of[std::size_t(h.label - 1)]; };
  std::vector<CostBreakdown> costs;
  std::vector<Hypothesis> moved;  // after the pass (without the warm-up's duplicates), in order
  for (std::size_t begin = 0; begin < hyps.size();) {
    std::size_t end = begin;
    while (end < hyps.size() && stride(hyps[end]) == stride(hyps[begin])) ++end;
    pass.stride = pass.score_stride = stride(hyps[begin]);
    std::vector<Hypothesis> run(hyps.begin() + std::ptrdiff_t(begin), hyps.begin() + std::ptrdiff_t(end));
    const std::vector<CostBreakdown> c = run_chunks(first_ctx, pass, run, points_estimate, result);
    costs.insert(costs.end(), c.begin(), c.end());
    moved.insert(moved.end(), run.begin(), run.end());
    begin = end;
  }
  hyps = std::move(moved);
  return costs;
}

/// The screen's stride for a job whose first pass runs at `first_stride`: screen.stride for one at
/// render.stride, the same ratio finer for a mostly hidden instance refined on a finer grid
/// (screen.hidden; 0 = not screened).
inline int screen_stride(const SixDofSettings& s, const ScreenSettings& sc, int first_stride) {
  if (sc.stride == 0) return 0;
  if (first_stride >= s.render.stride) return sc.stride;
  return sc.hidden ? std::max(first_stride + 1, first_stride * sc.stride / s.render.stride) : 0;
}

/// Whether the screen runs for a job whose first pass runs at `first_stride` on a segment of
/// `segment_points` observed points: it has a screen_stride() and is expected to show at least
/// screen.min_points there.
inline bool screened(const SixDofSettings& s, const ScreenSettings& sc, int first_stride,
                     std::size_t segment_points) {
  const int stride = screen_stride(s, sc, first_stride);
  if (stride == 0) return false;
  const double expected =
      double(segment_points) * double(s.observed.stride * s.observed.stride) / double(stride * stride);
  return expected >= double(sc.min_points);
}

/// The screen (`sc`: SixDofSettings::screen, or the retrieval's): the proposals of every screened job
/// (screened(), and more than min_keep of them) rendered at screen.stride, moved by the ICP passes against
/// the first pass' targets and scored with first_pass_cost; each such job keeps its best keep_fraction (at
/// least min_keep; those showing too few points rank last) at the poses the screen reached. `hyps` stays
/// grouped by job, in order.
template <class Backend>
void screen(const Context<Backend>& ctx, const ScreenSettings& sc, const std::vector<Job>& jobs,
            const std::vector<std::size_t>& segment_points, const std::vector<int>& first_stride,
            std::vector<Hypothesis>& hyps, const std::vector<std::size_t>& points_estimate,
            SixDofResult& result) {
  const SixDofSettings& s = ctx.shared.settings;
  std::vector<std::size_t> proposals(jobs.size(), 0);
  for (const Hypothesis& h : hyps) ++proposals[std::size_t(h.label - 1)];
  std::vector<char> on(jobs.size());  // a job with no more than min_keep proposals would keep them all
  for (std::size_t k = 0; k < jobs.size(); ++k)
    on[k] = proposals[k] > std::size_t(sc.min_keep) &&
            screened(s, sc, first_stride[k], segment_points[std::size_t(jobs[k].segment)]);
  std::vector<Hypothesis> coarse;
  for (const Hypothesis& h : hyps)
    if (on[std::size_t(h.label - 1)]) coarse.push_back(h);
  if (coarse.empty()) return;
  const auto t = Clock::now();
  CostSettings cost = s.first_pass_cost;
  cost.use_color = sc.use_color;
  Pass pass;
  pass.gicp = s.gicp;
  pass.gicp.icp_warmup_iterations = sc.icp_iterations;
  pass.warmup_only = true;
  pass.cost = &cost;
  std::vector<int> stride_of(jobs.size());
  for (std::size_t k = 0; k < jobs.size(); ++k) stride_of[k] = screen_stride(s, sc, first_stride[k]);
  const std::vector<CostBreakdown> costs =
      run_by_stride(ctx, pass, stride_of, coarse, points_estimate, result);

  std::vector<std::vector<std::size_t>> of_job(jobs.size());
  for (std::size_t i = 0; i < coarse.size(); ++i) of_job[std::size_t(coarse[i].label - 1)].push_back(i);
  std::vector<char> keep(coarse.size(), 0);
  for (std::vector<std::size_t>& idx : of_job) {
    if (idx.empty()) continue;
    const int min_points = min_points_at(s, stride_of[std::size_t(coarse[idx[0]].label - 1)]);
    auto rank = [&](std::size_t i) {
      return std::make_pair(costs[i].rendered_points < min_points, costs[i].total);
    };
    std::stable_sort(idx.begin(), idx.end(), [&](std::size_t a, std::size_t b) { return rank(a) < rank(b); });
    const std::size_t n = std::max(std::size_t(sc.min_keep),
                                   std::size_t(std::ceil(double(sc.keep_fraction) * double(idx.size()))));
    for (std::size_t r = 0; r < std::min(n, idx.size()); ++r) keep[idx[r]] = 1;
  }
  std::vector<Hypothesis> out;
  std::size_t c = 0;
  for (const Hypothesis& h : hyps) {
    if (!on[std::size_t(h.label - 1)]) {
      out.push_back(h);
      continue;
    }
    if (keep[c]) out.push_back(coarse[c]);
    ++c;
  }
  result.proposals_screened_out += hyps.size() - out.size();
  hyps = std::move(out);
  result.timings.screen += seconds_since(t);
}

/// Runs the first pass over `hyps` (grouped by job; job k at first_stride[k]) against ctx's first-pass
/// targets; moves them to their refined poses (without the warm-up's duplicates, dedupe_after_warmup) and
/// returns their first_pass_cost, in order.
template <class Backend>
std::vector<CostBreakdown> first_pass(const Context<Backend>& ctx, const std::vector<int>& first_stride,
                                      std::vector<Hypothesis>& hyps,
                                      const std::vector<std::size_t>& points_estimate, SixDofResult& result) {
  const SixDofSettings& s = ctx.shared.settings;
  Pass first;
  first.gicp = s.gicp;
  first.cost = &s.first_pass_cost;
  first.dedupe_after_warmup = s.dedupe_after_warmup;
  first.first = true;
  return run_by_stride(ctx, first, first_stride, hyps, points_estimate, result);
}

}  // namespace sixdof_detail
}  // namespace perch2
