// 3-DoF tabletop search (PERCH 2.0, Sections III-IV): find (x, y, yaw) on a known or estimated table plane
// of every requested object by rendering a grid of hypotheses, refining them by (x, y, yaw) ICP,
// re-rendering and scoring them with the explanation cost, and selecting the best per object.
//
//   perch2::TabletopEstimator<perch2::cpu::Backend> estimator({{can_a_mesh}, {can_b_mesh}});
//   perch2::TabletopResult r = estimator.estimate(frame, {{0, 1}, {1, 2}});  // model 0 once, model 1 twice
//   for (const auto& p : r.poses) use(p.model, p.T_cam_obj, p.T_world_obj);
//
// Frames: the table ("world") frame has z up (towards the camera side) and the table top at z = 0, as the
// BOP world frame of tabletop scenes. A model stands on the table in its rest pose T_place_obj (object ->
// placement frame; default: the model's own z axis up and its lowest vertex on the table); a hypothesis is
// T_world_obj = Trans(x, y, 0) * RotZ(yaw) * T_place_obj.
//
// Pipeline per frame (timed per stage in TabletopResult::timings):
//   table     T_cam_world given, or estimate_table_plane() (RANSAC on the depth)
//   observed  the frame's points at settings.observed (stride 2); those between min_height_m and
//             max_height_m above the table are the object readings (ICP target, support, workspace)
//   grid      x, y every xy_step_m over the workspace, yaw every yaw_step_rad (one yaw if yaw_symmetric);
//             a position needs min_support_points object readings within the footprint's circumradius +
//             support_margin_m
//   render    every hypothesis at render.stride, occluders marked from the observed depth (C-PERCH)
//   refine    (x, y, yaw) ICP against the object readings (Dof::TableXYYaw), then back onto the grid's
//             manifold exactly
//   cost      re-rendered and scored (perch2/cost/cost.hpp), coarse to fine: all at coarse_score_stride,
//             the best few yaws at each model's best places again at score_stride; J_o's volume is the
//             model's convex footprint prism from min_height_m to its top, posed by the hypothesis
//   select    per model, the lowest-cost acceptable poses (min_rendered_points, min_inlier_fraction) whose
//             footprints do not interpenetrate by more than overlap_tolerance_m, `count` of them; where
//             some are missing, a second look over the readings no selected footprint explains (second_look)
//   polish    each selected pose refined again by (x, y, yaw) ICP with all its points (polish_rounds)
//   yaw       the yaw (and x, y by a millimetre or two) of every selected pose of a model whose colours a
//             turn changes, by a sweep and hill climbing over turns about the table normal scored by the
//             print's appearance (YawSearchSettings, perch2/search/local_search.hpp): ICP cannot turn a
//             printed can or bottle, and the grid's yaws and the tolerant colour test leave its label up to
//             tens of degrees off
//
// Variants (the paper's Table I, see tabletop_variant()):
//   Perch2C  parallel per-object search, occluders marked from the observed depth, RGB-D cost (default)
//   Perch2A  as C without occluder marking
//   Perch2B  Monotone Scene Generation: objects placed one per level, a new object may not occlude the
//            ones already placed, which hide it when it is rendered; RGB-D cost. Greedy: each level keeps
//            the single best placement (a beam of width 1, not PERCH's full tree search).
//   Perch    as B with the depth-only cost (PERCH)
//
// Where each pass lives (include/perch2/search/tabletop/, one pass per header; this file is the pipeline):
//   settings.hpp, result.hpp   what the user sets and gets back
//   context.hpp                what the passes share: the estimator's Context, a frame's Frame, a Candidate
//   observed.hpp               the checks of the request, the table, the observed clouds
//   grid.hpp                   the grid hypotheses, their support, de-duplication
//   refine.hpp                 (x, y, yaw) ICP, its correction back onto the table; refine_and_score
//   score.hpp                  the cost, coarse to fine; the score selection ranks by
//   select.hpp                 acceptance, footprint overlap, the Parallel modes' selection
//   second_look.hpp, polish.hpp, yaw_search.hpp   the passes after selection
//   tree.hpp, bf_icp.hpp       the Tree search (Perch2B, Perch) and BF-ICP's fitness
#pragma once

#include <algorithm>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/search/tabletop/bf_icp.hpp"
#include "perch2/search/tabletop/context.hpp"
#include "perch2/search/tabletop/grid.hpp"
#include "perch2/search/tabletop/observed.hpp"
#include "perch2/search/tabletop/polish.hpp"
#include "perch2/search/tabletop/refine.hpp"
#include "perch2/search/tabletop/result.hpp"
#include "perch2/search/tabletop/score.hpp"
#include "perch2/search/tabletop/second_look.hpp"
#include "perch2/search/tabletop/select.hpp"
#include "perch2/search/tabletop/settings.hpp"
#include "perch2/search/tabletop/tree.hpp"
#include "perch2/search/tabletop/yaw_search.hpp"

namespace perch2 {

template <class Backend>
class TabletopEstimator {
 public:
  /// Validates the models and uploads them to the backend's renderer. Throws InvalidInput on no models,
  /// a bad mesh or a bad rest pose.
  explicit TabletopEstimator(std::vector<TabletopModel> models, TabletopSettings settings = {});

  const TabletopSettings& settings() const { return ctx_.settings; }
  TabletopSettings& settings() { return ctx_.settings; }
  const std::vector<TabletopModel>& models() const { return ctx_.models; }

  /// Index of the model whose mesh is called `name`. Throws InvalidInput if there is none.
  int model_index(const std::string& name) const {
    for (std::size_t i = 0; i < ctx_.models.size(); ++i)
      if (ctx_.models[i].mesh.name == name) return int(i);
    throw InvalidInput("model name", "no model called '" + name + "'");
  }

  /// Estimates the poses of the requested objects in one frame. T_cam_world (table frame -> camera) is
  /// estimated from the depth when not given. Throws InvalidInput on a malformed frame (sizes, NaN depth),
  /// missing colour for the RGB-D cost, an unknown model, no table visible, an empty scene, and (strict
  /// mode) fewer acceptable poses than requested instances.
  TabletopResult estimate(const RgbdFrame& frame, const std::vector<ObjectCount>& objects,
                          const std::optional<Pose>& T_cam_world = std::nullopt) const;

  /// 3-DoF detection (BOP 2024's task for upright objects): no objects or counts given. Every model is
  /// searched up to max_per_model times (not strict, whatever the settings say); selection places acceptable,
  /// non-overlapping poses, the best explanation first, so a look-alike is placed only where no better model
  /// took the place. Poses best score first (TabletopPose::instance = rank within its model), at most
  /// max_per_frame, each with 1 / (1 + score) >= min_score; `missing` is empty. InvalidInput on bad
  /// settings, and as estimate() on a bad frame.
  TabletopResult detect(const RgbdFrame& frame, const TabletopDetectSettings& settings = {},
                        const std::optional<Pose>& T_cam_world = std::nullopt) const;

 private:
  /// estimate()'s search; `strict`: throw when requested instances are missing.
  TabletopResult search(const RgbdFrame& frame, const std::vector<ObjectCount>& objects,
                        const std::optional<Pose>& T_cam_world, bool strict) const;

  tabletop_detail::Context<Backend> ctx_;  ///< models, settings, renderer, footprints
};

// The members are defined out of the class (not inline): a translation unit that includes
// perch2/cpu/estimators.hpp or perch2/cuda/estimators.hpp (extern template) then compiles none of the
// passes; the backend libraries hold the one instantiation.

template <class Backend>
TabletopEstimator<Backend>::TabletopEstimator(std::vector<TabletopModel> models, TabletopSettings settings)
    : ctx_(std::move(models), std::move(settings)) {}

template <class Backend>
TabletopResult TabletopEstimator<Backend>::estimate(const RgbdFrame& frame,
                                                    const std::vector<ObjectCount>& objects,
                                                    const std::optional<Pose>& T_cam_world) const {
  return search(frame, objects, T_cam_world, ctx_.settings.strict_instances);
}

template <class Backend>
TabletopResult TabletopEstimator<Backend>::detect(const RgbdFrame& frame, const TabletopDetectSettings& d,
                                                  const std::optional<Pose>& T_cam_world) const {
  if (d.max_per_model < 1) throw InvalidInput("TabletopDetectSettings::max_per_model", "must be >= 1");
  if (d.max_per_frame < 1) throw InvalidInput("TabletopDetectSettings::max_per_frame", "must be >= 1");
  if (!(d.min_score >= 0.f && d.min_score <= 1.f))
    throw InvalidInput("TabletopDetectSettings::min_score", "must be in [0, 1]");
  std::vector<ObjectCount> every;
  for (std::size_t m = 0; m < ctx_.models.size(); ++m) every.push_back({int(m), d.max_per_model});
  TabletopResult r = search(frame, every, T_cam_world, false);
  r.missing.clear();
  std::stable_sort(r.poses.begin(), r.poses.end(),
                   [](const TabletopPose& a, const TabletopPose& b) { return a.score < b.score; });
  std::vector<TabletopPose> kept;
  std::vector<int> rank(ctx_.models.size(), 0);
  for (TabletopPose& p : r.poses) {
    if (int(kept.size()) == d.max_per_frame || 1.f / (1.f + std::max(0.f, p.score)) < d.min_score) break;
    p.instance = rank[std::size_t(p.model)]++;
    kept.push_back(std::move(p));
  }
  r.poses = std::move(kept);
  return r;
}

template <class Backend>
TabletopResult TabletopEstimator<Backend>::search(const RgbdFrame& frame,
                                                  const std::vector<ObjectCount>& objects,
                                                  const std::optional<Pose>& T_cam_world, bool strict) const {
  using namespace tabletop_detail;
  const TabletopSettings& s = ctx_.settings;
  const auto t_start = Clock::now();
  validate_request(ctx_, frame, objects);
  TabletopResult result;
  Frame<Backend> f{frame};
  auto t = Clock::now();
  find_table(ctx_, f, T_cam_world, result);
  result.timings.table = seconds_since(t);

  t = Clock::now();
  prepare_observed(ctx_, f);
  result.timings.observed = seconds_since(t);

  t = Clock::now();
  std::vector<Candidate> grid = hypotheses(ctx_, f, objects, result);
  result.timings.hypotheses = seconds_since(t);

  if (s.mode == SearchMode::Tree) {
    search_tree(ctx_, f, objects, grid, result);
  } else {  // Parallel, BruteForceIcp: every hypothesis refined and scored at once
    Scored scored = refine_and_score(ctx_, f, *f.registration, std::move(grid), objects, result);
    t = Clock::now();
    std::vector<std::size_t> chosen =
        select_parallel(ctx_, f, scored.cands, scored.scores, scored.costs, scored.hidden, objects, result);
    result.timings.select += seconds_since(t);
    if (s.mode == SearchMode::Parallel && s.second_look && !result.missing.empty())
      second_look(ctx_, f, objects, scored, chosen, result);
    if (s.mode == SearchMode::BruteForceIcp) report_costs(ctx_, f, scored, chosen, result);
  }
  if (s.mode == SearchMode::Parallel) polish(ctx_, f, result);
  if (s.mode != SearchMode::BruteForceIcp) search_yaws(ctx_, f, result);

  if (!result.missing.empty() && strict) {
    const ObjectCount& m = result.missing.front();
    throw InvalidInput("objects", "model " + std::to_string(m.model) + " ('" +
                                      ctx_.models[m.model].mesh.name + "'): " + std::to_string(m.count) +
                                      " requested instance(s) not found (no acceptable, non-overlapping "
                                      "pose: are fewer instances present than requested?)");
  }
  result.timings.total = seconds_since(t_start);
  return result;
}

}  // namespace perch2
