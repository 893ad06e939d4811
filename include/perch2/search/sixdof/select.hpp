// Selection: which hypotheses go on and which pose is an instance's answer. Many proposals converge to
// one pose, so poses are compared under the model's symmetries (same_pose, distinct_poses); after the
// first pass only the best few distinct poses of each instance are kept for the second (keep_best); after
// the second the best acceptable ones (showing min_rendered_points) are searched around and the lowest
// final cost wins (best_per_instance, one_per_job). Also the BOP score of a pose (pose_score) and, for
// estimate_scene(), whether a candidate may be placed (acceptable, better_explanation).
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <tuple>
#include <utility>
#include <vector>

#include "perch2/search/sixdof/context.hpp"
#include "perch2/search/table_plane.hpp"

namespace perch2 {
namespace sixdof_detail {

/// Whether two poses of one model are the same (distinct_translation_m, distinct_rotation_rad, under the
/// model's symmetries).
template <class Backend>
bool same_pose(const Shared<Backend>& sh, const Hypothesis& a, const Hypothesis& b) {
  const SixDofSettings& s = sh.settings;
  return (a.T_cam_obj.translation() - b.T_cam_obj.translation()).norm() < s.distinct_translation_m &&
         symmetric_rotation_distance(a.T_cam_obj.linear(), b.T_cam_obj.linear(),
                                     sh.models[std::size_t(a.model)].symmetries) < s.distinct_rotation_rad;
}

/// The hypotheses, in order, without those that repeat an earlier one's pose of the same instance
/// (same_pose). Poses are bucketed by translation (cells of distinct_translation_m), so each is compared
/// with the kept poses of its 27 neighbouring cells only.
template <class Backend>
std::vector<Hypothesis> distinct_poses(const Shared<Backend>& sh, const std::vector<Hypothesis>& hyps) {
  const float cell = sh.settings.distinct_translation_m;
  if (!(cell > 0) || !(sh.settings.distinct_rotation_rad > 0)) return hyps;
  std::map<std::array<std::int64_t, 4>, std::vector<std::size_t>> kept_in;  // (label, cell) -> kept
  std::vector<Hypothesis> out;
  for (const Hypothesis& h : hyps) {
    const Eigen::Vector3f c = h.T_cam_obj.translation() / cell;
    const std::array<std::int64_t, 4> key{h.label, std::int64_t(std::floor(c.x())),
                                          std::int64_t(std::floor(c.y())), std::int64_t(std::floor(c.z()))};
    bool duplicate = false;
    for (int dx = -1; dx <= 1 && !duplicate; ++dx)
      for (int dy = -1; dy <= 1 && !duplicate; ++dy)
        for (int dz = -1; dz <= 1 && !duplicate; ++dz) {
          const auto it = kept_in.find({key[0], key[1] + dx, key[2] + dy, key[3] + dz});
          if (it == kept_in.end()) continue;
          duplicate = std::any_of(it->second.begin(), it->second.end(),
                                  [&](std::size_t o) { return same_pose(sh, out[o], h); });
        }
    if (duplicate) continue;
    kept_in[key].push_back(out.size());
    out.push_back(h);
  }
  return out;
}

/// min_rendered_points (counted at score_stride) scaled to a render at `stride`, at least 3.
inline int min_points_at(const SixDofSettings& s, int stride) {
  const float ratio = float(s.score_stride) / float(stride);
  return std::max(3, int(std::lround(float(s.min_rendered_points) * ratio * ratio)));
}

/// Keep: the best keep_per_instance distinct hypotheses of each instance by cost (all if 0), in instance
/// then cost order. A hypothesis showing fewer than min_rendered_points (scaled to the first pass' stride)
/// ranks after every one that shows enough.
template <class Backend>
std::vector<Hypothesis> keep_best(const Shared<Backend>& sh, const std::vector<Hypothesis>& hyps,
                                  const std::vector<CostBreakdown>& costs, const std::vector<int>& stride,
                                  std::size_t K) {
  const SixDofSettings& s = sh.settings;
  std::vector<int> min_points(K);
  for (std::size_t k = 0; k < K; ++k) min_points[k] = min_points_at(s, stride[k]);
  std::vector<std::size_t> order(hyps.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  auto rank = [&](std::size_t i) {  // (shows too few points, cost): showing enough ranks first
    return std::make_pair(costs[i].rendered_points < min_points[std::size_t(hyps[i].label - 1)],
                          costs[i].total);
  };
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return hyps[a].label != hyps[b].label ? hyps[a].label < hyps[b].label : rank(a) < rank(b);
  });
  std::vector<Hypothesis> kept;
  std::vector<std::size_t> count(K, 0);
  for (const std::size_t i : order) {
    const auto k = std::size_t(hyps[i].label - 1);
    // A mostly hidden instance (first pass on a finer grid) keeps every distinct pose: its ranking rests
    // on few points, and its second pass is cheap for the same reason.
    const bool all = s.keep_per_instance == 0 || stride[k] < s.render.stride;
    if (!all && count[k] >= std::size_t(s.keep_per_instance)) continue;
    const bool duplicate = s.keep_per_instance > 0 &&
                           std::any_of(kept.end() - std::ptrdiff_t(count[k]), kept.end(),
                                       [&](const Hypothesis& o) { return same_pose(sh, hyps[i], o); });
    if (duplicate) continue;
    kept.push_back(hyps[i]);
    ++count[k];
  }
  return kept;
}

/// The indices of the best (at most n) hypotheses of each instance, instance by instance, best first:
/// those showing min_rendered_points (scaled from score_stride to `stride`) before the rest, then by
/// total cost.
inline std::vector<std::size_t> best_per_instance(const SixDofSettings& s,
                                                  const std::vector<Hypothesis>& hyps,
                                                  const std::vector<CostBreakdown>& costs, std::size_t K,
                                                  std::size_t n, int stride) {
  const float ratio = float(s.score_stride) / float(stride);
  const int min_points = std::max(1, int(std::lround(float(s.min_rendered_points) * ratio * ratio)));
  std::vector<std::size_t> order(hyps.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  auto rank = [&](std::size_t i) {
    return std::make_tuple(hyps[i].label, costs[i].rendered_points < min_points, costs[i].total);
  };
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return rank(a) < rank(b); });
  std::vector<std::size_t> out, count(K, 0);
  for (const std::size_t i : order)
    if (count[std::size_t(hyps[i].label - 1)]++ < n) out.push_back(i);
  return out;
}

/// After the second pass: the best local.candidates_per_instance (at least 1) hypotheses of each of the K
/// jobs (best_per_instance), job by job, best first, with their final costs.
inline void select_finalists(const SixDofSettings& s, const std::vector<Hypothesis>& kept,
                             const std::vector<CostBreakdown>& costs, std::size_t K,
                             std::vector<Hypothesis>& finalists, std::vector<CostBreakdown>& final_costs,
                             SixDofResult& result) {
  const auto t = Clock::now();
  const std::size_t n_local = s.local.candidates_per_instance > 0 ? s.local.candidates_per_instance : 1;
  std::vector<std::size_t> top = best_per_instance(s, kept, costs, K, n_local, s.score_stride);
  result.timings.select += seconds_since(t);
  for (const std::size_t h : top) finalists.push_back(kept[h]);
  for (const std::size_t h : top) final_costs.push_back(costs[h]);
}

/// One finalist per job, in job order: each job's first (best) of `finalists`, with its local starts.
inline std::vector<Finalist> one_per_job(const std::vector<Job>& jobs,
                                         const std::vector<Hypothesis>& finalists,
                                         const std::vector<CostBreakdown>& final_costs,
                                         std::vector<std::vector<Hypothesis>>& local_starts,
                                         SixDofResult& result) {
  const std::size_t K = jobs.size();
  const auto t = Clock::now();
  std::vector<Finalist> out(K);
  for (std::size_t k = 0; k < K; ++k) {
    out[k].hypothesis = {jobs[k].model, Pose::Identity(), std::int32_t(k + 1)};
    out[k].cost.rendered_points = -1;  // no finalist (cannot happen: every job has proposals)
  }
  std::vector<bool> seen(K, false);
  for (std::size_t h = 0; h < finalists.size(); ++h) {  // in order: a job's best comes first
    const auto k = std::size_t(finalists[h].label - 1);
    if (seen[k]) continue;
    seen[k] = true;
    out[k] = {finalists[h], final_costs[h], std::move(local_starts[k])};
  }
  result.timings.select += seconds_since(t);
  return out;
}

/// 1 - (rendered outliers + unexplained observed points) / (rendered + observed points), in [0, 1].
inline float pose_score(const CostBreakdown& b) {
  const float n = float(b.rendered_points + b.observed_in_volume);
  return n > 0 ? std::clamp(1.f - float(b.rendered_outliers() + b.observed_unexplained()) / n, 0.f, 1.f)
               : 0.f;
}

/// The observed readings a hypothesis explains (in its volume, not unexplained).
inline std::int32_t explained(const CostBreakdown& c) {
  return c.observed_in_volume - c.observed_unexplained();
}

/// detect()'s score, in [0, 1]: pose_score weighed by how much of its visible surface the readings show
/// (`depth_agreement`: a model put on another object's readings explains them, but not pixel by pixel), by
/// the share of the readings near its surface whose colours it shows, and by its evidence, n / (n +
/// half_evidence) for the n readings it explains (a small fragment of clutter fits many models).
inline float detection_score(const CostBreakdown& c, float depth_agreement, float half_evidence) {
  const float reached = float(c.observed_in_volume - c.observed_depth_outliers);
  const float colour = reached > 0 ? 1.f - float(c.observed_color_outliers) / reached : 0.f;
  const float n = float(std::max(explained(c), 0));
  const float evidence = n > 0 ? n / (n + half_evidence) : 0.f;
  return std::clamp(pose_score(c) * depth_agreement * colour * evidence, 0.f, 1.f);
}

/// Signed height of the lowest vertex of `mesh` at T_cam_obj above `plane`, metres (< 0: below it).
inline float height_above(const TablePlane& plane, const Mesh& mesh, const Pose& T_cam_obj) {
  float lowest = std::numeric_limits<float>::infinity();
  for (const Eigen::Vector3f& v : mesh.vertices)
    lowest = std::min(lowest, plane.normal_cam.dot(T_cam_obj * v) + plane.offset_m);
  return lowest;
}

/// Whether a scene candidate, scored against what is still unexplained, may be placed (SceneSettings).
/// detect_colour_mismatch (detect(): DetectSettings::max_colour_mismatch; 1 = no test): the
/// largest fraction of its rendered points near readings whose colour matches none of them (the readings
/// near its surface that match none of its colours: SceneSettings::max_colour_mismatch, always).
inline bool acceptable(const SixDofSettings& s, const CostBreakdown& c, float detect_colour_mismatch = 1.f) {
  const SceneSettings& ss = s.scene;
  if (c.rendered_points < s.min_rendered_points) return false;
  const float inliers = float(c.rendered_points - c.rendered_outliers());
  const float reached = float(c.observed_in_volume - c.observed_depth_outliers);  // near its surface
  const float near = float(c.rendered_points - c.rendered_depth_outliers);
  return inliers >= ss.min_inlier_fraction * float(c.rendered_points) &&
         explained(c) >= ss.min_explained_points &&
         float(c.observed_color_outliers) <= ss.max_colour_mismatch * reached &&
         (detect_colour_mismatch >= 1.f || float(c.rendered_color_outliers) <= detect_colour_mismatch * near);
}

/// Whether a candidate with cost `a` explains the scene better than with `b`: acceptable before not, then
/// more readings explained.
inline bool better_explanation(const SixDofSettings& s, const CostBreakdown& a, const CostBreakdown& b,
                               float detect_colour_mismatch = 1.f) {
  const bool ok_a = acceptable(s, a, detect_colour_mismatch);
  if (ok_a != acceptable(s, b, detect_colour_mismatch)) return ok_a;
  return explained(a) > explained(b);
}

}  // namespace sixdof_detail
}  // namespace perch2
