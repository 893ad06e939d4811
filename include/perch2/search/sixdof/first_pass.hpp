// The first pass: every proposal rendered at render.stride (8), brought into its basin by an ICP warm-up
// then GICP against its own segment's coarser targets (first_pass_target_stride), re-rendered and ranked
// by the cheap first_pass_cost. It only has to rank: the second pass finishes the pose. Each job runs at
// the coarsest stride that still shows it with first_pass_min_points, so a mostly hidden object is refined
// on a finer grid; hypotheses are grouped by job, so each stride is a contiguous run.
#pragma once

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

/// Runs the first pass over `hyps` (grouped by job; job k at first_stride[k]) against ctx's first-pass
/// targets; moves them to their refined poses (without the warm-up's duplicates, dedupe_after_warmup) and
/// returns their first_pass_cost, in order.
template <class Backend>
std::vector<CostBreakdown> first_pass(const Context<Backend>& ctx, const std::vector<int>& first_stride,
                                      std::vector<Hypothesis>& hyps,
                                      const std::vector<std::size_t>& points_estimate, SixDofResult& result) {
  const SixDofSettings& s = ctx.shared.settings;
  Context<Backend> first_ctx = ctx;  // against the first pass' coarser targets
  first_ctx.registration = ctx.first_pass_registration;
  std::vector<CostBreakdown> first_costs;
  std::vector<Hypothesis> refined;  // after the first pass (without the warm-up's duplicates), in order
  for (std::size_t begin = 0; begin < hyps.size();) {
    const int stride = first_stride[std::size_t(hyps[begin].label - 1)];
    std::size_t end = begin;
    while (end < hyps.size() && first_stride[std::size_t(hyps[end].label - 1)] == stride) ++end;
    Pass first;
    first.stride = first.score_stride = stride;
    first.gicp = s.gicp;
    first.cost = &s.first_pass_cost;
    first.dedupe_after_warmup = s.dedupe_after_warmup;
    first.first = true;
    std::vector<Hypothesis> run(hyps.begin() + std::ptrdiff_t(begin), hyps.begin() + std::ptrdiff_t(end));
    const auto c = run_chunks(first_ctx, first, run, points_estimate, result);
    refined.insert(refined.end(), run.begin(), run.end());
    first_costs.insert(first_costs.end(), c.begin(), c.end());
    begin = end;
  }
  hyps = std::move(refined);
  return first_costs;
}

}  // namespace sixdof_detail
}  // namespace perch2
