// estimate_scene()'s explanation (no detector): every job's best pose is a candidate; each round scores
// all candidates against the readings still unexplained (placed objects' readings hide what is behind them
// and explain nothing more) and places, among the acceptable ones (select.hpp: acceptable), the one that
// explains most readings. Its readings within explain_distance_m of its full-resolution render become its
// own, and the candidates it took readings from are refined again (refine_after_placing; undone where the
// earlier pose explained the scene better). Until every requested instance is placed or none is
// acceptable, then up to SceneSettings::spare_placements more per object (estimate_scene keeps each
// object's best scored). Then the readings still unexplained are segmented again for the instances still
// missing (residual_segments, residual_pass), and each placed object gets its final cost, surface fit and
// score on its own readings (fit_placed).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "perch2/core/observed.hpp"
#include "perch2/search/segmentation.hpp"
#include "perch2/search/sixdof/context.hpp"
#include "perch2/search/sixdof/first_pass.hpp"
#include "perch2/search/sixdof/pass.hpp"
#include "perch2/search/sixdof/retrieval.hpp"
#include "perch2/search/sixdof/scene_jobs.hpp"
#include "perch2/search/sixdof/second_pass.hpp"
#include "perch2/search/sixdof/select.hpp"
#include "perch2/search/sixdof/surface_fit.hpp"
#include "perch2/search/sixdof/turn_search.hpp"

namespace perch2 {
namespace sixdof_detail {

/// estimate_scene()'s state across its passes.
struct SceneState {
  /// Full resolution: 1..segments = the pass' segments (readings not yet explained), segments + 1 + j =
  /// placed object j's readings, 0 = support, background or dropped.
  LabelImage labels;
  std::size_t segments = 0;
  std::vector<int> remaining;        ///< per object given: instances still to place
  std::vector<int> spare;            ///< per object given: placements beyond its count still allowed
  std::vector<int> model_of_object;  ///< per object given: its model
  std::vector<int> object_of_model;  ///< per model: its object's index, -1 if not requested
  std::vector<Hypothesis> placed;    ///< in placement order
  std::vector<int> placed_object;
  std::vector<std::size_t> placed_estimate;  ///< per placed object: its job's rendered-points estimate
  float detect_colour_mismatch = 1.f;        ///< acceptable()'s (detect(): DetectSettings); 1 = no test
  RetrievalPlan retrieval;                   ///< detect()'s (retrieval.hpp); by default none
};

/// The state before the first pass: every object's count still to place, the maps between objects and
/// models (over `models` models).
inline SceneState scene_state(std::size_t models, const std::vector<SixDofObject>& objects) {
  SceneState scene;
  scene.object_of_model.assign(models, -1);
  for (std::size_t i = 0; i < objects.size(); ++i) {
    scene.remaining.push_back(objects[i].count), scene.model_of_object.push_back(objects[i].model);
    scene.spare.push_back(0);
    if (objects[i].count > 0) scene.object_of_model[std::size_t(objects[i].model)] = int(i);
  }
  return scene;
}

/// The smallest bounding-box face (m^2) of the models requested (count > 0), the segmentation's size
/// rule; infinite if none is requested.
template <class Backend>
float smallest_face_m2(const Shared<Backend>& sh, const std::vector<SixDofObject>& objects) {
  float smallest_face = INFINITY;
  for (const auto& o : objects)
    if (o.count > 0) smallest_face = std::min(smallest_face, sh.face_m2[std::size_t(o.model)].first);
  return smallest_face;
}

/// Labels the readings that `placed` explains (unexplained object readings, labels 1..S, within
/// explain_distance_m of its render at full resolution, the same pixel) with `label`.
template <class Backend>
void explain(const Context<Backend>& now, const Hypothesis& placed, std::int32_t label, std::size_t S,
             LabelImage& labels, SixDofResult& result) {
  const CloudBatch r = render(now, {placed}, 1, result);
  const float tol = now.shared.settings.scene.explain_distance_m;
  for (std::size_t i = 0; i < r.size(); ++i) {
    const std::int32_t p = r.pixel[i];
    if (p < 0) continue;
    const std::int32_t l = labels.data[std::size_t(p)];
    const float d = now.frame.depth_m.data[std::size_t(p)];
    if (l >= 1 && l <= std::int32_t(S) && d > 0 && std::abs(d - r.z[i]) <= tol)
      labels.data[std::size_t(p)] = label;
  }
}

/// Both GICP passes of candidates[touched] again, against `unexplained` (ctx's cost clouds, its
/// registration unset): the readings a placed neighbour took no longer pull them. The time counts in
/// observed (the GICP targets), render and refine, not in explain.
template <class Backend>
void refine_again(const Context<Backend>& ctx, const CloudBatch& unexplained,
                  std::vector<Hypothesis>& candidates, const std::vector<std::size_t>& touched,
                  SixDofResult& result) {
  const SixDofSettings& s = ctx.shared.settings;
  const auto t = Clock::now();
  const typename Backend::Registration registration(unexplained);
  result.timings.observed += seconds_since(t);  // as the search's GICP targets
  Context<Backend> with_targets = ctx;
  // Both passes against every unexplained reading: the candidates are already near their poses.
  with_targets.registration = with_targets.first_pass_registration = &registration;
  std::vector<Hypothesis> moved;
  for (const std::size_t i : touched) moved.push_back(candidates[i]);
  refine(with_targets, moved, render(with_targets, moved, s.render.stride, result), s.gicp, result);
  const Pass second = second_pass_settings(s);
  if (second.refine)
    refine(with_targets, moved, render(with_targets, moved, s.second_pass_stride, result), second.gicp,
           result);
  for (std::size_t j = 0; j < touched.size(); ++j) candidates[touched[j]] = moved[j];
  result.timings.explain -= seconds_since(t);
}

/// The local search (local_stage) of the candidate about to be placed, from its job's best hypotheses
/// (`starts`, the first replaced by its current pose), in the search's context `ctx`; the winner
/// replaces `placed` if it is still acceptable against what is unexplained now (context `now`).
template <class Backend>
void search_placed(const Context<Backend>& ctx, const Context<Backend>& now, std::vector<Hypothesis> starts,
                   Hypothesis& placed, const std::vector<std::size_t>& points_estimate,
                   float detect_colour_mismatch, SixDofResult& result) {
  const SixDofSettings& s = ctx.shared.settings;
  if (starts.empty()) return;
  const auto t = Clock::now();
  starts.front() = placed;
  std::vector<CostBreakdown> costs(starts.size());
  local_stage(ctx, starts, costs, std::size_t(placed.label), points_estimate, result);
  const std::vector<CostBreakdown> c = score(now, starts, s.score_stride, s.cost, points_estimate, result);
  if (acceptable(s, c.front(), detect_colour_mismatch)) placed = starts.front();
  result.timings.explain -= seconds_since(t);  // counted in local
}

/// One pass of estimate_scene() over `segments` (whose labels are scene.labels' 1..scene.segments):
/// the jobs, their search and the scene explained object by object; places into `scene`. Returns the
/// segments' readings on the observed grid.
template <class Backend>
std::vector<std::size_t> explain_segments(const Shared<Backend>& sh, const RgbdFrame& frame,
                                          const FrameSegments& segments, SceneState& scene,
                                          SixDofSceneResult& out) {
  const SixDofSettings& s = sh.settings;
  const SceneSettings& ss = s.scene;
  SixDofResult& result = out.search;
  const std::size_t S = scene.segments;

  // ---- jobs: every model still missing on every segment of a compatible size (pieces of a large one)
  auto t = Clock::now();
  std::vector<std::int32_t> segment_labels(S);
  for (std::size_t k = 0; k < S; ++k) segment_labels[k] = std::int32_t(k + 1);
  std::vector<std::size_t> segment_points;
  {
    const CloudBatch grid = observed_segments(frame, scene.labels, segment_labels, s.observed);
    for (std::size_t k = 0; k < S; ++k) segment_points.push_back(grid.cloud_size(k));
  }
  std::vector<Job> jobs;
  PieceCache pieces;
  for (std::size_t i = 0; i < scene.remaining.size(); ++i) {
    if (scene.remaining[i] <= 0 && scene.spare[i] <= 0) continue;
    for (std::size_t k = 0; k < S; ++k)
      if (segment_points[k] >= std::size_t(ss.min_segment_points))
        add_scene_jobs(sh, frame, segments, int(k), scene.model_of_object[i], pieces, jobs);
  }
  if (ss.half_jobs && scene.retrieval.jobs_per_object > 0 && scene.retrieval.coarse.viewpoints > 0) {
    const std::size_t before = jobs.size();
    add_half_jobs(sh, frame, segments, pieces, jobs);  // ranked with the rest by the retrieval
    out.halves += jobs.size() - before;
  }
  if (ss.min_colour_fraction > 0 && s.cost.use_color) {
    const std::size_t before = jobs.size();
    screen_colours(sh, frame, scene.labels, jobs);
    out.screened_out += before - jobs.size();
    const std::size_t screened = jobs.size();
    if (scene.retrieval.jobs_per_object > 0 && scene.retrieval.coarse.viewpoints == 0)
      keep_best_models(jobs, scene.retrieval.jobs_per_object);
    out.retrieved_out += screened - jobs.size();
  }
  result.timings.proposals += seconds_since(t);
  if (scene.retrieval.coarse.viewpoints > 0 && scene.retrieval.jobs_per_object > 0 && !jobs.empty()) {
    const std::size_t screened = jobs.size();
    retrieve(sh, frame, segments, scene.labels, S, scene.retrieval, scene.detect_colour_mismatch, jobs,
             result);
    out.retrieved_out += screened - jobs.size();
  }
  out.jobs += jobs.size();
  if (jobs.empty()) return segment_points;
  t = Clock::now();
  // Each job's GICP targets and J_o's points: its segment and those that may be other parts of the same
  // object (an occluder in front splits it), as one observed cloud per distinct group.
  const JobTargets<Backend> job_targets(sh, frame, segments, scene.labels, S, jobs);
  const std::vector<std::vector<std::int32_t>>& groups = job_targets.groups;
  const std::vector<std::size_t>& group_points = job_targets.group_points;
  const std::vector<std::int32_t>& job_cloud = job_targets.job_cloud;
  const std::vector<std::int32_t>& job_label = job_targets.job_label;
  result.segment_points.insert(result.segment_points.end(), group_points.begin(), group_points.end());
  result.timings.observed += seconds_since(t);
  const Context<Backend> ctx = job_targets.context(sh, frame);
  std::vector<std::size_t> points_estimate;
  const std::vector<Finalist> found =
      search(ctx, jobs, group_points, points_estimate, result, ss.local_search_placed_only,
             ctx.shared.settings.screen.in_scene);

  // ---- explain the scene object by object
  t = Clock::now();
  std::vector<Hypothesis> candidates;
  for (const Finalist& f : found)
    if (f.cost.rendered_points >= s.min_rendered_points) candidates.push_back(f.hypothesis);
  out.candidates += candidates.size();
  std::vector<std::size_t> group_size = group_points;  // unexplained readings per group, last round
  const std::size_t placed_before = scene.placed.size();
  auto left = [](const std::vector<int>& n) {
    return std::any_of(n.begin(), n.end(), [](int r) { return r > 0; });
  };
  while (!candidates.empty() && (left(scene.remaining) || left(scene.spare))) {
    const Occluders occ_now{frame.depth_m, scene.labels};
    const CloudBatch unexplained = group_clouds(s.observed, frame, scene.labels, groups, S);
    const typename Backend::Cost cost_now(unexplained);
    const Context<Backend> now{sh,       frame,     occ_now,   nullptr,  nullptr,
                               cost_now, job_cloud, job_label, job_cloud};
    // The candidates whose groups lost readings to the last placement, refined again (their poses
    // before kept in `previous`); a refinement that explains the scene worse is undone.
    std::vector<std::size_t> touched;
    std::vector<Hypothesis> previous;
    if (ss.refine_after_placing && scene.placed.size() > placed_before) {
      for (std::size_t i = 0; i < candidates.size(); ++i) {
        const auto g = std::size_t(job_cloud[std::size_t(candidates[i].label - 1)]);
        if (unexplained.cloud_size(g) != group_size[g] &&
            unexplained.cloud_size(g) >= std::size_t(ss.min_segment_points))
          touched.push_back(i);
      }
      for (const std::size_t i : touched) previous.push_back(candidates[i]);
      if (!touched.empty()) refine_again(now, unexplained, candidates, touched, result);
      out.refined += touched.size();
    }
    for (std::size_t g = 0; g < groups.size(); ++g) group_size[g] = unexplained.cloud_size(g);
    std::vector<CostBreakdown> c = score(now, candidates, s.score_stride, s.cost, points_estimate, result);
    if (!previous.empty()) {
      const std::vector<CostBreakdown> was =
          score(now, previous, s.score_stride, s.cost, points_estimate, result);
      for (std::size_t j = 0; j < previous.size(); ++j)
        if (better_explanation(s, was[j], c[touched[j]], scene.detect_colour_mismatch))
          candidates[touched[j]] = previous[j], c[touched[j]] = was[j], ++out.reverted;
    }
    ++out.rounds;
    // The requested instances first; spare placements only when none of them can be placed.
    std::size_t pick = candidates.size();
    for (const std::vector<int>* allowed : {&scene.remaining, &scene.spare}) {
      for (std::size_t i = 0; i < candidates.size(); ++i) {
        const int obj = scene.object_of_model[std::size_t(candidates[i].model)];
        if (obj < 0 || (*allowed)[std::size_t(obj)] <= 0 ||
            !acceptable(s, c[i], scene.detect_colour_mismatch))
          continue;
        if (pick == candidates.size() || explained(c[i]) > explained(c[pick])) pick = i;
      }
      if (pick < candidates.size()) break;
    }
    if (pick == candidates.size()) break;  // nothing acceptable is left: the rest is missing
    if (ss.local_search_placed_only && s.local.candidates_per_instance > 0)
      search_placed(ctx, now, found[std::size_t(candidates[pick].label - 1)].local_starts, candidates[pick],
                    points_estimate, scene.detect_colour_mismatch, result);
    const std::int32_t label = std::int32_t(S + 1 + scene.placed.size());
    explain(now, candidates[pick], label, S, scene.labels, result);
    const auto obj = std::size_t(scene.object_of_model[std::size_t(candidates[pick].model)]);
    --(scene.remaining[obj] > 0 ? scene.remaining : scene.spare)[obj];
    scene.placed.push_back(candidates[pick]), scene.placed_object.push_back(int(obj));
    scene.placed_estimate.push_back(points_estimate[std::size_t(candidates[pick].label - 1)]);
    candidates.erase(candidates.begin() + std::ptrdiff_t(pick));
  }
  result.timings.explain += seconds_since(t);
  return segment_points;
}

/// The readings of scene's segments that no placed object explains, segmented again
/// (segment_readings): a neighbour placed in the same segment leaves the part it did not explain, which
/// can be the whole visible part of a hidden object. Relabels scene.labels to the new segments (placed
/// objects' readings kept after them).
inline FrameSegments residual_segments(const SixDofSettings& s, const RgbdFrame& frame, SceneState& scene,
                                       float smallest_face) {
  const auto S = std::int32_t(scene.segments);
  std::vector<std::uint8_t> left(scene.labels.data.size(), 0);
  for (std::size_t i = 0; i < left.size(); ++i)
    left[i] = scene.labels.data[i] >= 1 && scene.labels.data[i] <= S;
  FrameSegments residual = segment_readings(frame, left, s.scene.segmentation, smallest_face);
  const auto R = std::int32_t(residual.segments.size());
  for (std::size_t i = 0; i < left.size(); ++i)
    if (scene.labels.data[i] > S) residual.labels.data[i] = R + scene.labels.data[i] - S;
  scene.labels = residual.labels;
  scene.segments = std::size_t(R);
  return residual;
}

/// Each placed object's final cost and surface fit on its own readings (as estimate()'s), into out.poses.
template <class Backend>
void fit_placed(const Shared<Backend>& sh, const RgbdFrame& frame, SceneState& scene,
                SixDofSceneResult& out) {
  const SixDofSettings& s = sh.settings;
  SixDofResult& result = out.search;
  const std::size_t P = scene.placed.size();
  if (P == 0) return;
  const auto t = Clock::now();
  const auto S = std::int32_t(scene.segments);
  LabelImage own(scene.labels.width, scene.labels.height, 0);  // placed object j's readings: j + 1
  for (std::size_t i = 0; i < own.data.size(); ++i)
    if (scene.labels.data[i] > S) own.data[i] = scene.labels.data[i] - S;
  std::vector<std::int32_t> own_labels(P), own_segment(P);  // job j: cloud j, label j + 1
  std::vector<Hypothesis> placed = scene.placed;
  for (std::size_t j = 0; j < P; ++j) {
    own_labels[j] = std::int32_t(j + 1), own_segment[j] = std::int32_t(j);
    placed[j].label = std::int32_t(j + 1);  // job j of the final context
  }
  const CloudBatch own_cloud = observed_segments(frame, own, own_labels, s.observed);
  const typename Backend::Cost own_cost(own_cloud);
  const Occluders own_occ{frame.depth_m, own};
  const Context<Backend> fin{sh,       frame,       own_occ,    nullptr,    nullptr,
                             own_cost, own_segment, own_labels, own_segment};
  const std::vector<CostBreakdown> c =
      score(fin, placed, s.score_stride, s.cost, scene.placed_estimate, result);
  std::vector<SixDofPose> poses(P);
  for (std::size_t j = 0; j < P; ++j) {
    poses[j].instance = scene.placed_object[j], poses[j].model = placed[j].model;
    poses[j].T_cam_obj = placed[j].T_cam_obj, poses[j].cost = c[j], poses[j].found = true;
  }
  result.timings.select += seconds_since(t);
  fit_and_score(fin, own, scene.placed_estimate, poses, result);
  out.poses = std::move(poses);
}

/// Sets the total time; returns `out`.
inline SixDofSceneResult& finish(SixDofSceneResult& out, Clock::time_point t_start) {
  out.search.timings.total = seconds_since(t_start);
  return out;
}

}  // namespace sixdof_detail
}  // namespace perch2
