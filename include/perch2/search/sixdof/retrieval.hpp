// detect()'s retrieval: on each segment only the models that fit it best earn the full search, so the
// search grows with the segments, not with the catalogue. Every job the size and colour screening let
// through first gets a coarse render-and-compare (coarse_scores): a few rotations (DetectSettings::
// retrieval_*) at the middle of its depths, the best few of them after the screen (stride 16, ICP), through
// the first pass (render, ICP warm-up + GICP, cheap RGB-D cost), scored as the explanation will choose
// (acceptable first, then the readings explained);
// keep_best_jobs keeps the best few (model, piece) jobs of each segment. Colours alone (screen_colours'
// coverage, keep_best_models) rank poorly: a broad palette covers most segments.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <set>
#include <utility>
#include <vector>

#include "perch2/search/sixdof/context.hpp"
#include "perch2/search/sixdof/first_pass.hpp"
#include "perch2/search/sixdof/proposals.hpp"
#include "perch2/search/sixdof/scene_jobs.hpp"

namespace perch2 {
namespace sixdof_detail {

/// What the retrieval does: detect()'s DetectSettings (estimate_scene()'s with
/// SceneSettings::retrieval_jobs_per_object).
struct RetrievalPlan {
  /// The coarse search's proposals (DetectSettings::retrieval_*); 0 viewpoints = colours rank instead.
  ProposalSettings coarse = [] {
    ProposalSettings p;
    p.viewpoints = 0;
    return p;
  }();
  int jobs_per_object = 0;         ///< DetectSettings::retrieval_jobs_per_object; 0 = every job
  int screen_keep = 0;             ///< DetectSettings::retrieval_screen_keep; 0 = no screen
  bool acceptable_only = false;    ///< DetectSettings::retrieval_acceptable_only
  bool seed_depth = false;         ///< DetectSettings::seed_depth
  bool align_inplane = false;      ///< DetectSettings::retrieval_align_inplane
  float align_min_elongation = 2;  ///< DetectSettings::retrieval_align_min_elongation
};

/// The long axis of a job's pixels (its piece's, else its segment label's inside its box), as
/// principal_angle() gives it, if they are at least `min_elongation` times as long as wide (the square root
/// of their second moments' eigenvalue ratio); NaN otherwise (no long axis to align to).
inline float job_image_axis(const Job& job, const LabelImage& labels, float min_elongation) {
  double n = 0, su = 0, sv = 0, suu = 0, suv = 0, svv = 0;
  auto add = [&](double u, double v) { n += 1, su += u, sv += v, suu += u * u, suv += u * v, svv += v * v; };
  if (!job.piece_pixels.empty()) {
    for (const std::int32_t i : job.piece_pixels) add(double(i % labels.width), double(i / labels.width));
  } else {
    const Eigen::Vector4i& b = job.box_xywh;
    for (int v = std::max(b[1], 0); v <= std::min(b[1] + b[3], labels.height - 1); ++v)
      for (int u = std::max(b[0], 0); u <= std::min(b[0] + b[2], labels.width - 1); ++u)
        if (labels(u, v) == job.label) add(u, v);
  }
  if (n < 2) return NAN;
  const double mu = su / n, mv = sv / n;
  const double a = suu / n - mu * mu, b = suv / n - mu * mv, c = svv / n - mv * mv;
  const double mid = 0.5 * (a + c), half = std::sqrt(0.25 * (a - c) * (a - c) + b * b);
  const double lo = std::max(mid - half, 0.0), hi = mid + half;
  if (!(hi >= double(min_elongation) * double(min_elongation) * lo)) return NAN;
  return principal_angle(a, b, c);
}

/// Per segment label, per model: its best Job::retrieval_score over its jobs there, and the number of
/// pieces it cut the segment into (its jobs there that are not Job::half).
struct SegmentModel {
  float score = -std::numeric_limits<float>::infinity();
  int pieces = 0;
};
using SegmentModels = std::map<std::int32_t, std::map<int, SegmentModel>>;

inline SegmentModels segment_models(const std::vector<Job>& jobs) {
  SegmentModels seen;
  for (const Job& j : jobs) {
    SegmentModel& m = seen[j.label][j.model];
    m.score = std::max(m.score, j.retrieval_score);
    m.pieces += !j.half;  // the halves are alternatives to the whole, not more objects
  }
  return seen;
}

/// How many of a segment's models (or jobs) keep their jobs: `n` per object it may hold (the fewest pieces
/// any model cut it into), at most `of`.
inline std::size_t kept_of(const std::map<int, SegmentModel>& models, int n, std::size_t of) {
  int objects = std::numeric_limits<int>::max();
  for (const auto& [model, m] : models) objects = std::min(objects, std::max(m.pieces, 1));  // halves only: 1
  return std::min(of, std::size_t(n) * std::size_t(objects));
}

/// On each segment only the kept_of() models with the best Job::retrieval_score keep their jobs, ties kept
/// (with colour coverage as the score, a model and its same-print copy at another size cover the same
/// readings; the search tells them apart).
inline void keep_best_models(std::vector<Job>& jobs, int n) {
  std::set<std::pair<std::int32_t, int>> kept;  // (segment label, model)
  for (const auto& [label, models] : segment_models(jobs)) {
    std::vector<float> scores;
    for (const auto& [model, m] : models) scores.push_back(m.score);
    std::sort(scores.rbegin(), scores.rend());
    const float least = scores[kept_of(models, n, scores.size()) - 1];
    for (const auto& [model, m] : models)
      if (m.score >= least) kept.insert({label, model});
  }
  jobs.erase(std::remove_if(jobs.begin(), jobs.end(),
                            [&](const Job& j) {
                              return !kept.count({j.label, j.model});
                            }),
             jobs.end());
}

/// On each segment only the kept_of() best-scored jobs (model, piece) are kept, ties kept: a coarse
/// search scores each piece, and a model's other pieces of a large segment need not be searched.
inline void keep_best_jobs(std::vector<Job>& jobs, int n) {
  std::map<std::int32_t, std::vector<float>> scores;  // segment label -> its jobs' scores
  for (const Job& j : jobs) scores[j.label].push_back(j.retrieval_score);
  std::map<std::int32_t, float> least;  // segment label -> the lowest score kept
  for (const auto& [label, models] : segment_models(jobs)) {
    std::vector<float>& s = scores[label];
    std::sort(s.rbegin(), s.rend());
    least[label] = s[kept_of(models, n, s.size()) - 1];
  }
  jobs.erase(std::remove_if(jobs.begin(), jobs.end(),
                            [&](const Job& j) { return j.retrieval_score < least[j.label]; }),
             jobs.end());
}

/// Every job's Job::retrieval_score from a coarse search: the plan's rotations (align_inplane: started from
/// the long axis of the job's pixels) at the middle of the job's depths, screened (screen_keep), through
/// the first pass, against the jobs' own targets. The best of its hypotheses that show
/// enough points (keep_best's rule) as the explanation would pick it: the readings it explains, scaled by
/// 1e-3 unless acceptable (detect_colour_mismatch); -infinity if none shows enough points.
template <class Backend>
void coarse_scores(const Shared<Backend>& sh, const RgbdFrame& frame, const FrameSegments& segments,
                   const LabelImage& labels, std::size_t S, const RetrievalPlan& plan,
                   float detect_colour_mismatch, std::vector<Job>& jobs) {
  const SixDofSettings& s = sh.settings;
  SixDofResult scratch;  // the coarse search's counts and times are not the search's (timings.retrieve)
  const JobTargets<Backend> targets(sh, frame, segments, labels, S, jobs);
  const Context<Backend> ctx = targets.context(sh, frame);
  std::vector<Job> middle(jobs.size());  // what propose() reads, at the middle depth (no piece pixels)
  for (std::size_t k = 0; k < jobs.size(); ++k) {
    middle[k].model = jobs[k].model, middle[k].box_xywh = jobs[k].box_xywh;
    middle[k].depths = {jobs[k].depths[jobs[k].depths.size() / 2]};
    if (plan.align_inplane)
      middle[k].image_axis_rad = job_image_axis(jobs[k], labels, plan.align_min_elongation);
  }
  std::vector<std::size_t> points_estimate;
  std::vector<Hypothesis> hyps = propose(ctx, middle, plan.coarse, points_estimate, scratch);
  const std::vector<int> stride = first_pass_strides(s, jobs, targets.group_points);
  if (plan.screen_keep > 0 && s.screen.stride > 0) {  // exactly the best screen_keep of a screened job
    ScreenSettings sc = s.screen;
    sc.min_keep = plan.screen_keep, sc.keep_fraction = 0.f;
    screen(ctx, sc, jobs, targets.group_points, stride, hyps, points_estimate, scratch);
  }
  const std::vector<CostBreakdown> costs = first_pass(ctx, stride, hyps, points_estimate, scratch);
  for (Job& j : jobs)
    j.retrieval_score = -std::numeric_limits<float>::infinity(), j.retrieval_acceptable = false;
  for (std::size_t h = 0; h < hyps.size(); ++h) {
    const auto k = std::size_t(hyps[h].label - 1);
    if (costs[h].rendered_points < min_points_at(s, stride[k])) continue;
    // As the explanation will choose: acceptable first, then by the readings explained.
    const float explains = float(std::max(explained(costs[h]), 0));
    const float score = acceptable(s, costs[h], detect_colour_mismatch) ? explains : 1e-3f * explains;
    if (score > jobs[k].retrieval_score)
      jobs[k].retrieval_score = score, jobs[k].retrieval_depth_m = hyps[h].T_cam_obj.translation().z(),
      jobs[k].retrieval_acceptable = acceptable(s, costs[h], detect_colour_mismatch);
  }
}

/// detect()'s retrieval: coarse_scores, then (acceptable_only) no job whose coarse best is not acceptable,
/// then keep_best_jobs (jobs_per_object per object a segment may hold); nothing when every segment keeps
/// all its jobs. seed_depth: the kept jobs propose at their coarse best's depth.
template <class Backend>
void retrieve(const Shared<Backend>& sh, const RgbdFrame& frame, const FrameSegments& segments,
              const LabelImage& labels, std::size_t S, const RetrievalPlan& plan,
              float detect_colour_mismatch, std::vector<Job>& jobs, SixDofResult& result) {
  const int n = plan.jobs_per_object;
  const SegmentModels seen = segment_models(jobs);
  if (std::all_of(seen.begin(), seen.end(), [&](const auto& s) {
        std::size_t pieces = 0;
        for (const auto& [model, m] : s.second) pieces += std::size_t(m.pieces);
        return kept_of(s.second, n, pieces) == pieces;
      }))
    return;
  const auto t = Clock::now();
  coarse_scores(sh, frame, segments, labels, S, plan, detect_colour_mismatch, jobs);
  if (plan.acceptable_only)
    jobs.erase(std::remove_if(jobs.begin(), jobs.end(), [](const Job& j) { return !j.retrieval_acceptable; }),
               jobs.end());
  keep_best_jobs(jobs, n);
  if (plan.seed_depth)  // the full search proposes at the depth GICP found
    for (Job& j : jobs)
      if (std::isfinite(j.retrieval_score)) j.depths = {j.retrieval_depth_m};
  result.timings.retrieve += seconds_since(t);
}

}  // namespace sixdof_detail
}  // namespace perch2
