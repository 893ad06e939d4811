// 6-DoF PERCH 2.0 (Section V, Fig. 4): the full pose of each detected instance (model, mask, box) in one
// RGB-D frame, by rendering mask-driven pose proposals, refining every one with GICP against its own
// instance's observed points, re-rendering and scoring them with the RGB-D explanation cost.
//
//   perch2::SixDofEstimator<perch2::cpu::Backend> estimator({{mesh, symmetries}, ...});
//   perch2::SixDofResult r = estimator.estimate(frame, {{model, mask, box_xywh}, ...});
//   for (const auto& p : r.poses) use(p.instance, p.model, p.T_cam_obj, p.score);
//
// Pipeline per frame (timed per stage in SixDofResult::timings):
//   observed   instance k's pixels carry label k + 1 (later instances win overlaps). Each segment is
//              trimmed for depth consistency: mask pixels whose depth lies outside the segment's robust
//              range [q_lo - trim_margin_m, min(q_hi + trim_margin_m, q_lo + diameter)] (a mask bleeding
//              onto the table behind or a neighbour in front) lose the label and count as background.
//              The labelled points on the observed stride grid are the per-instance segments (GICP
//              targets, J_o's points).
//   proposals  rotations (viewpoints x in-plane, symmetry de-duplicated) x depths on the box centre's ray
//              (perch2/search/proposals.hpp)
//   screen     (estimate(); estimate_scene() with screen.in_scene) each instance's proposals rendered at
//              screen.stride (16), pulled by ICP, ranked by the cheap cost: its best third go on from there
//   first pass, every proposal left, in chunks (sized to memory_budget_bytes: 10x the proposals run in the
//   same memory, just slower):
//     render   at render.stride (8), occluders = observed depth with labels: only other instances' or
//              background pixels hide a hypothesis (its own label never does)
//     refine   GICP (ICP warm-up first: starts are up to half a proposal spacing off) against the
//              hypothesis' own segment
//              (dedupe_after_warmup, off by default: GICP only the distinct poses the warm-up reached)
//     cost     re-rendered at render.stride and scored with the RGB-D cost: a cheap ranking
//   keep       the best keep_per_instance distinct poses per instance (many proposals converge to one pose)
//   second pass, the kept hypotheses only:
//     refine   re-rendered at second_pass_stride (4), GICP with a tighter cap, so a badly trimmed mask's
//              remaining stray points cannot pull the converged pose
//     cost     re-rendered at score_stride; RGB-D cost (perch2/cost/cost.hpp) with J_o over the whole
//              segment of the instance (volume -1)
//   local search, the best local.candidates_per_instance acceptable hypotheses of each instance (3):
//              coarse-to-fine hill climbing over turns about the model's own axes, scored with the
//              nearest-neighbour colour test (LocalSearchSettings): recovers the turn of a printed can
//              or bottle about its axis, which GICP cannot see
//              then one more tight GICP pass (polish) and a re-render
//   select     the lowest final cost per instance at the searched poses (acceptable first)
//   fit        the selected pose of each instance fitted onto its observed points at full resolution
//              (fit_stride): robust point-to-surface, observed -> model
//              (perch2/registration/surface_fit.hpp), re-scored there and kept unless the final cost rose
//              (fit_cost_slack)
//   score      1 - (rendered outliers + unexplained observed points) / (rendered + observed points), in
//              [0, 1]: the fraction of both clouds that the pose explains (BOP's score column)
#pragma once

// Each stage is one header of perch2/search/sixdof/, named after it: settings.hpp and result.hpp (the
// public types), context.hpp (what the passes share), validate.hpp, observed.hpp, proposals.hpp,
// first_pass.hpp, select.hpp (keep, select, score), second_pass.hpp, turn_search.hpp (the local search),
// surface_fit.hpp, and under them pass.hpp (one render-refine-score pass in chunks); estimate_scene()'s
// jobs and explanation in scene_jobs.hpp and scene.hpp, detect()'s retrieval in retrieval.hpp. search() below
// strings the passes together for both entry points.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <optional>
#include <vector>

#include "perch2/core/parallel.hpp"
#include "perch2/search/sixdof/context.hpp"
#include "perch2/search/sixdof/first_pass.hpp"
#include "perch2/search/sixdof/observed.hpp"
#include "perch2/search/sixdof/proposals.hpp"
#include "perch2/search/sixdof/result.hpp"
#include "perch2/search/sixdof/scene.hpp"
#include "perch2/search/sixdof/second_pass.hpp"
#include "perch2/search/sixdof/select.hpp"
#include "perch2/search/sixdof/settings.hpp"
#include "perch2/search/sixdof/surface_fit.hpp"
#include "perch2/search/sixdof/turn_search.hpp"
#include "perch2/search/sixdof/validate.hpp"

namespace perch2 {

namespace sixdof_detail {

/// The search of every job: proposals, the screen (if screen_proposals), the first pass, keep, the second
/// pass, then the best few of each job searched around (local search) and one finalist per job, in job order.
/// Fills the per-job counts of `result` and points_estimate (per job: a rendered-point bound for the chunk
/// sizes). defer_local: no local search; each finalist carries the poses it would have started from
/// (Finalist::local_starts) for the caller's local_stage().
template <class Backend>
std::vector<Finalist> search(const Context<Backend>& ctx, const std::vector<Job>& jobs,
                             const std::vector<std::size_t>& segment_points,
                             std::vector<std::size_t>& points_estimate, SixDofResult& result,
                             bool defer_local, bool screen_proposals) {
  const SixDofSettings& s = ctx.shared.settings;
  const std::size_t K = jobs.size();
  std::vector<Hypothesis> hyps = propose(ctx, jobs, s.proposals, points_estimate, result);

  // ---- the screen (a coarser, cheaper pass; the best fraction go on), then the first pass over the rest
  // (chunks): render, refine, re-render, cheap cost
  const std::vector<int> first_stride = first_pass_strides(s, jobs, segment_points);
  if (screen_proposals)
    screen(ctx, ctx.shared.settings.screen, jobs, segment_points, first_stride, hyps, points_estimate,
           result);
  auto t = Clock::now();
  const std::vector<CostBreakdown> first_costs = first_pass(ctx, first_stride, hyps, points_estimate, result);
  result.timings.first_pass += seconds_since(t);

  // ---- second pass over the best distinct poses of each job: tighter refinement, final cost
  std::vector<Hypothesis> kept = keep_best(ctx.shared, hyps, first_costs, first_stride, K);
  t = Clock::now();
  const std::vector<CostBreakdown> costs = second_pass(ctx, kept, points_estimate, result);
  result.timings.second_pass += seconds_since(t);

  // ---- select: the best acceptable hypotheses of each job, refined by the local search
  std::vector<Hypothesis> finalists;
  std::vector<CostBreakdown> final_costs;
  select_finalists(s, kept, costs, K, finalists, final_costs, result);
  std::vector<std::vector<Hypothesis>> local_starts(K);
  if (defer_local && s.local.candidates_per_instance > 0)
    for (const Hypothesis& h : finalists) local_starts[std::size_t(h.label - 1)].push_back(h);
  else if (s.local.candidates_per_instance > 0)
    local_stage(ctx, finalists, final_costs, K, points_estimate, result);
  return one_per_job(jobs, finalists, final_costs, local_starts, result);
}

}  // namespace sixdof_detail

template <class Backend>
class SixDofEstimator {
 public:
  /// Validates the models and uploads them to the backend's renderer. Throws InvalidInput on no models or a
  /// bad mesh.
  explicit SixDofEstimator(std::vector<SixDofModel> models, SixDofSettings settings = {});

  const SixDofSettings& settings() const { return shared_.settings; }
  SixDofSettings& settings() { return shared_.settings; }
  const std::vector<SixDofModel>& models() const { return shared_.models; }

  /// The pose of every instance. Throws InvalidInput on a malformed frame, missing colour for the RGB-D
  /// cost, no instances, an unknown model, a mask of the wrong size, an empty mask or one without valid
  /// depth, and bad settings.
  SixDofResult estimate(const RgbdFrame& frame, const std::vector<SixDofInstance>& instances) const;

  /// The poses of the requested objects in an unsegmented frame (no detector): `objects` says which
  /// models and how many instances of each (BOP's targets give exactly that). See SceneSettings for the
  /// stages. Every placed instance is a pose in SixDofSceneResult::poses; an instance that no acceptable
  /// candidate explains is counted in `missing`, never placed on a distractor to fill the count. Of an
  /// object's placements (SceneSettings::spare_placements beyond its count) the best scored are kept. Throws
  /// InvalidInput on a malformed frame, missing colour for the RGB-D cost, an unknown model, a negative
  /// count and bad settings.
  SixDofSceneResult estimate_scene(const RgbdFrame& frame, const std::vector<SixDofObject>& objects) const;

  /// 6D detection (BOP 2024): every instance of every model in an unsegmented frame, with no model or count
  /// given; estimate_scene() over the whole catalogue, each model up to settings.max_per_model times. An
  /// instance is placed only where an acceptable candidate explains its readings (look-alikes compete
  /// through the RGB-D cost), so a model that is not there is not reported. The poses come best score
  /// first, at most max_per_frame, each with score >= min_score. Throws as estimate_scene() and
  /// InvalidInput on bad DetectSettings.
  SixDofSceneResult detect(const RgbdFrame& frame, const DetectSettings& settings = {}) const;

 private:
  /// estimate_scene(); for detect() (`detecting` set) with acceptable()'s colour test on both sides and
  /// the retrieval of the best models per segment.
  SixDofSceneResult explain_scene(const RgbdFrame& frame, const std::vector<SixDofObject>& objects,
                                  const DetectSettings* detecting) const;

  sixdof_detail::Shared<Backend> shared_;  ///< models, settings, per-model sizes and colours, renderer, fit
};

// The members are defined out of the class (not inline): a translation unit that includes
// perch2/cpu/estimators.hpp or perch2/cuda/estimators.hpp (extern template) then compiles none of the
// passes; the backend libraries hold the one instantiation.

template <class Backend>
SixDofEstimator<Backend>::SixDofEstimator(std::vector<SixDofModel> models, SixDofSettings settings)
    : shared_(std::move(models), std::move(settings)) {}

template <class Backend>
SixDofResult SixDofEstimator<Backend>::estimate(const RgbdFrame& frame,
                                                const std::vector<SixDofInstance>& instances) const {
  using namespace sixdof_detail;
  const auto t_start = Clock::now();
  validate_instances(shared_.settings, shared_.models, frame, instances);
  const SixDofSettings& s = shared_.settings;
  SixDofResult result;
  const std::size_t K = instances.size();

  // ---- observed: labels, trimming, segments (GICP targets, J_o's points), occluders
  auto t = Clock::now();
  const ObservedInstances in = observe_instances(shared_, frame, instances, result);
  const std::size_t n = in.observed.size();
  const auto registration = build_index(n, [&] { return typename Backend::Registration(in.observed); });
  const auto first_pass_registration =
      build_index(n, [&] { return first_pass_targets(shared_, frame, in.observed); });
  const auto cost = build_index(n, [&] { return typename Backend::Cost(in.observed); });
  const Occluders occluders{frame.depth_m, in.labels};
  result.timings.observed = seconds_since(t);

  // ---- one job per instance: its model's proposals around its box, refined against its own segment
  t = Clock::now();
  const std::vector<Job> jobs = instance_jobs(shared_, frame, instances, in.labels);
  result.timings.proposals = seconds_since(t);
  std::vector<std::int32_t> job_cloud(K), job_label(K);
  for (std::size_t k = 0; k < K; ++k) job_cloud[k] = std::int32_t(k), job_label[k] = std::int32_t(k + 1);
  const Context<Backend> ctx{
      shared_, frame,     occluders, &registration, or_same(first_pass_registration, registration),
      cost,    job_cloud, job_label, job_cloud};
  std::vector<std::size_t> points_estimate;  // per job: rendered points bound for the chunk sizes
  const std::vector<Finalist> finalists =
      search(ctx, jobs, result.segment_points, points_estimate, result, /*defer_local=*/false,
             /*screen_proposals=*/true);

  // ---- select: each instance's finalist; then the surface fit and the score
  t = Clock::now();
  std::vector<SixDofPose> best(K);
  for (std::size_t k = 0; k < K; ++k) {
    best[k].instance = int(k), best[k].model = instances[k].model;
    best[k].T_cam_obj = finalists[k].hypothesis.T_cam_obj;
    best[k].found = finalists[k].cost.rendered_points >= s.min_rendered_points;
    best[k].cost = finalists[k].cost;
  }
  result.timings.select += seconds_since(t);
  fit_and_score(ctx, in.labels, points_estimate, best, result);
  result.poses = std::move(best);
  result.timings.total = seconds_since(t_start);
  return result;
}

template <class Backend>
SixDofSceneResult SixDofEstimator<Backend>::estimate_scene(const RgbdFrame& frame,
                                                           const std::vector<SixDofObject>& objects) const {
  using namespace sixdof_detail;
  SixDofSceneResult out = explain_scene(frame, objects, nullptr);
  if (shared_.settings.scene.spare_placements == 0) return out;
  // Each object keeps its `count` placements with the best detection score, in placement order.
  const float half_evidence = DetectSettings{}.half_evidence_readings;
  std::vector<std::vector<std::pair<float, std::size_t>>> ranked(objects.size());
  for (std::size_t j = 0; j < out.poses.size(); ++j) {
    const SixDofPose& p = out.poses[j];
    ranked[std::size_t(p.instance)].push_back(
        {-detection_score(p.cost, p.depth_agreement, half_evidence), j});
  }
  std::vector<bool> keep(out.poses.size(), false);
  for (std::size_t i = 0; i < objects.size(); ++i) {
    std::stable_sort(ranked[i].begin(), ranked[i].end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    const std::size_t n = std::min(ranked[i].size(), std::size_t(std::max(objects[i].count, 0)));
    for (std::size_t r = 0; r < n; ++r) keep[ranked[i][r].second] = true;
    out.missing[i] = std::max(objects[i].count, 0) - int(n);
  }
  std::vector<SixDofPose> kept;
  for (std::size_t j = 0; j < out.poses.size(); ++j)
    if (keep[j]) kept.push_back(out.poses[j]);
  out.poses = std::move(kept);
  return out;
}

template <class Backend>
SixDofSceneResult SixDofEstimator<Backend>::explain_scene(const RgbdFrame& frame,
                                                          const std::vector<SixDofObject>& objects,
                                                          const DetectSettings* detecting) const {
  using namespace sixdof_detail;
  const auto t_start = Clock::now();
  validate_scene(shared_.settings, shared_.models, frame, objects);
  const SceneSettings& ss = shared_.settings.scene;
  SixDofSceneResult out;
  SixDofResult& result = out.search;
  SceneState scene = scene_state(shared_.models.size(), objects);
  if (!detecting)
    for (std::size_t i = 0; i < objects.size(); ++i)
      if (objects[i].count > 0) scene.spare[i] = ss.spare_placements;
  // The retrieval: detect()'s settings, or for estimate_scene() their defaults with
  // SceneSettings::retrieval_jobs_per_object.
  DetectSettings localization;
  localization.retrieval_jobs_per_object = ss.retrieval_jobs_per_object;
  const DetectSettings* ranking = detecting ? detecting : &localization;
  if (ranking) {
    RetrievalPlan& plan = scene.retrieval;
    plan.jobs_per_object = ranking->retrieval_jobs_per_object;
    plan.seed_depth = ranking->seed_depth;
    plan.acceptable_only = ranking->retrieval_acceptable_only;
    plan.align_inplane = ranking->retrieval_align_inplane;
    plan.align_min_elongation = ranking->retrieval_align_min_elongation;
    plan.coarse = shared_.settings.proposals;  // its hemisphere and symmetry rule, fewer rotations
    plan.coarse.viewpoints = ranking->retrieval_viewpoints;
    plan.coarse.inplane_rotations = ranking->retrieval_inplane_rotations;
    plan.screen_keep = ranking->retrieval_screen_keep;
  }
  if (detecting) scene.detect_colour_mismatch = detecting->max_colour_mismatch;
  out.missing = scene.remaining;

  // ---- segment: support plane, connected components, size rule
  auto t = Clock::now();
  const float smallest_face = smallest_face_m2(shared_, objects);
  if (!std::isfinite(smallest_face)) return finish(out, t_start);  // nothing requested
  const FrameSegments segments = segment_frame(frame, ss.segmentation, smallest_face);
  out.segments = segments.segments;
  out.plane = segments.plane;
  result.timings.segment = seconds_since(t);
  if (segments.segments.empty()) return finish(out, t_start);
  scene.labels = segments.labels;
  scene.segments = segments.segments.size();
  out.segment_points = explain_segments(shared_, frame, segments, scene, out);

  // ---- the readings left unexplained, segmented again, for the instances still missing
  if (ss.residual_pass && !scene.placed.empty() &&
      std::any_of(scene.remaining.begin(), scene.remaining.end(), [](int r) { return r > 0; })) {
    t = Clock::now();
    std::fill(scene.spare.begin(), scene.spare.end(), 0);  // only the missing instances are searched for
    const FrameSegments residual = residual_segments(shared_.settings, frame, scene, smallest_face);
    result.timings.segment += seconds_since(t);
    out.residual_segments = residual.segments.size();
    if (!residual.segments.empty()) explain_segments(shared_, frame, residual, scene, out);
  }

  // ---- the placed objects on their own readings: final cost, surface fit, score
  fit_placed(shared_, frame, scene, out);
  out.missing = scene.remaining;
  return finish(out, t_start);
}

template <class Backend>
SixDofSceneResult SixDofEstimator<Backend>::detect(const RgbdFrame& frame,
                                                   const DetectSettings& settings) const {
  sixdof_detail::validate_detect(settings);
  std::vector<SixDofObject> catalogue;
  for (std::size_t m = 0; m < shared_.models.size(); ++m)
    catalogue.push_back({int(m), settings.max_per_model});
  SixDofSceneResult out = explain_scene(frame, catalogue, &settings);
  std::vector<SixDofPose>& poses = out.poses;
  // Ranked across frames and models (AP), and thresholded: a robot acts on what it reports.
  for (SixDofPose& p : poses)
    p.score = sixdof_detail::detection_score(p.cost, p.depth_agreement, settings.half_evidence_readings);
  poses.erase(std::remove_if(poses.begin(), poses.end(),
                             [&](const SixDofPose& p) { return !(p.score >= settings.min_score); }),
              poses.end());
  if (out.plane) {  // nothing rests inside the table
    const std::size_t before = poses.size();
    poses.erase(std::remove_if(poses.begin(), poses.end(),
                               [&](const SixDofPose& p) {
                                 return sixdof_detail::height_above(
                                            *out.plane, shared_.models[std::size_t(p.model)].mesh,
                                            p.T_cam_obj) < -settings.max_below_plane_m;
                               }),
                poses.end());
    out.below_plane = before - poses.size();
  }
  std::stable_sort(poses.begin(), poses.end(),
                   [](const SixDofPose& a, const SixDofPose& b) { return a.score > b.score; });
  if (poses.size() > std::size_t(settings.max_per_frame)) poses.resize(std::size_t(settings.max_per_frame));
  out.missing.clear();
  return out;
}

}  // namespace perch2
