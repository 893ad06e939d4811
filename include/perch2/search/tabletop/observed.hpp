// The tabletop search's first passes (perch2/search/tabletop.hpp): the checks of the request (settings,
// frame, objects) before any work, the table (T_cam_world given, or estimated from the depth by RANSAC), and
// the observed clouds: the frame's points at settings.observed (scored against), those between min_height_m
// and max_height_m above the table (the object readings: ICP target, grid support, workspace), the
// workspace the grid covers, and the observed depth as occluders.
#pragma once

#include <Eigen/Geometry>
#include <cmath>
#include <cstddef>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/observed.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/search/local_search.hpp"
#include "perch2/search/table_plane.hpp"
#include "perch2/search/tabletop/context.hpp"

namespace perch2::tabletop_detail {

/// Throws InvalidInput on bad settings, a malformed frame (sizes, NaN depth), missing colour for the RGB-D
/// cost or the yaw search, and an empty or malformed request (unknown model, count < 1, a model twice).
template <class Backend>
void validate_request(const Context<Backend>& ctx, const RgbdFrame& frame,
                      const std::vector<ObjectCount>& objects) {
  const TabletopSettings& s = ctx.settings;
  if (!(s.xy_step_m > 0 && std::isfinite(s.xy_step_m)) ||
      !(s.yaw_step_rad > 0 && std::isfinite(s.yaw_step_rad)))
    throw InvalidInput("TabletopSettings", "xy_step_m and yaw_step_rad must be finite and > 0");
  if (!(s.min_height_m >= 0 && s.max_height_m > s.min_height_m))
    throw InvalidInput("TabletopSettings", "needs 0 <= min_height_m < max_height_m");
  if (s.score_stride < 1) throw InvalidInput("TabletopSettings::score_stride", "must be >= 1");
  if (s.polish_rounds < 0 || s.polish_stride < 1 || s.polish_iterations < 1 ||
      !(s.polish_max_distance_m > 0 && std::isfinite(s.polish_max_distance_m)))
    throw InvalidInput("TabletopSettings",
                       "polish_rounds must be >= 0, polish_stride and polish_iterations >= 1 and "
                       "polish_max_distance_m finite and > 0");
  if (s.icp_max_points < 0) throw InvalidInput("TabletopSettings::icp_max_points", "must be >= 0");
  if (s.coarse_score_stride < 0 || s.rescore_extra_places < 0 || s.rescore_yaws < 1 ||
      !(s.rescore_place_radius_m >= 0))
    throw InvalidInput("TabletopSettings",
                       "coarse_score_stride, rescore_extra_places and rescore_place_radius_m must be >= 0 "
                       "and rescore_yaws >= 1");
  if (s.workspace_xy_m && (s.workspace_xy_m->isEmpty() || !s.workspace_xy_m->min().allFinite() ||
                           !s.workspace_xy_m->max().allFinite()))
    throw InvalidInput("TabletopSettings::workspace_xy_m", "must be a finite, non-empty box");
  if (!(s.hidden_point_weight >= 0) || !(s.min_icp_inlier_fraction >= 0 && s.min_icp_inlier_fraction <= 1))
    throw InvalidInput("TabletopSettings",
                       "hidden_point_weight must be >= 0 and min_icp_inlier_fraction in [0, 1]");
  if (!(s.support_margin_m >= 0) || !(s.workspace_margin_m >= 0) || !(s.overlap_tolerance_m >= 0) ||
      !(s.second_look_margin_m >= 0))
    throw InvalidInput("TabletopSettings", "margins and tolerances must be >= 0");
  perch2::validate(s.yaw_search.turns, "TabletopSettings::yaw_search.turns");
  frame.validate("tabletop frame");
  if (s.cost.use_color && s.mode != SearchMode::BruteForceIcp && frame.rgb.empty())
    throw InvalidInput("tabletop frame",
                       "has no colour image, which the RGB-D cost needs (set "
                       "cost.use_color = false for the depth-only cost)");
  if (yaw_search_runs(s) && frame.rgb.empty())
    throw InvalidInput("tabletop frame",
                       "has no colour image, which the yaw search's appearance test needs (set "
                       "yaw_search.enabled = false)");
  if (objects.empty()) throw InvalidInput("objects", "no objects requested");
  for (std::size_t i = 0; i < objects.size(); ++i) {
    const auto& o = objects[i];
    if (o.model < 0 || std::size_t(o.model) >= ctx.models.size())
      throw InvalidInput("objects[" + std::to_string(i) + "]", "unknown model id " + std::to_string(o.model) +
                                                                   " (" + std::to_string(ctx.models.size()) +
                                                                   " models)");
    if (o.count < 1) throw InvalidInput("objects[" + std::to_string(i) + "]", "count must be >= 1");
    for (std::size_t j = 0; j < i; ++j)
      if (objects[j].model == o.model)
        throw InvalidInput("objects", "model " + std::to_string(o.model) + " listed twice (use count)");
  }
}

/// The table pass: f.T_cam_world (table frame -> camera) from `T_cam_world` when given (checked: a finite
/// rigid transform with the camera above the table), else estimated from the depth (estimate_table_plane).
template <class Backend>
void find_table(const Context<Backend>& ctx, Frame<Backend>& f, const std::optional<Pose>& T_cam_world,
                TabletopResult& result) {
  if (T_cam_world) {
    if (!is_valid_pose(*T_cam_world)) throw InvalidInput("T_cam_world", "is not a finite rigid transform");
    f.T_cam_world = *T_cam_world;
    if (!(f.T_cam_world.inverse().translation().z() > 0))
      throw InvalidInput("T_cam_world",
                         "puts the camera at or below the table plane (the table frame's z "
                         "must point up, towards the camera)");
  } else {
    f.T_cam_world = estimate_table_plane(f.rgbd, ctx.settings.table).T_cam_world;
    result.table_estimated = true;
  }
  result.T_cam_world = f.T_cam_world;
}

/// The observed pass: f's observed cloud, object readings (and their table coordinates), workspace, cost,
/// registration target and occluders. Throws InvalidInput on an empty scene (no object readings).
template <class Backend>
void prepare_observed(const Context<Backend>& ctx, Frame<Backend>& f) {
  const TabletopSettings& s = ctx.settings;
  f.observed = observed_cloud(f.rgbd, s.observed);
  const Pose T_world_cam = f.T_cam_world.inverse();
  std::vector<char> above(f.observed.size());
  Eigen::AlignedBox2f table_box;
  for (std::size_t i = 0; i < f.observed.size(); ++i) {
    const Eigen::Vector3f p =
        T_world_cam * Eigen::Vector3f(f.observed.x[i], f.observed.y[i], f.observed.z[i]);
    above[i] = p.z() > s.min_height_m && p.z() <= s.max_height_m;
    if (above[i]) f.object_xy.emplace_back(p.x(), p.y()), f.workspace.extend(f.object_xy.back());
    if (std::abs(p.z()) <= s.min_height_m) table_box.extend(Eigen::Vector2f(p.x(), p.y()));
  }
  if (f.object_xy.empty())
    throw InvalidInput("tabletop frame", "empty scene: no depth reading between " +
                                             std::to_string(s.min_height_m) + " and " +
                                             std::to_string(s.max_height_m) + " m above the table");
  f.objects = filter_points(f.observed, [&](std::size_t i) { return above[i] != 0; });
  if (s.workspace_xy_m) {
    f.workspace = *s.workspace_xy_m;
  } else {
    f.workspace.min().array() -= s.workspace_margin_m;
    f.workspace.max().array() += s.workspace_margin_m;
    if (s.clip_workspace_to_table && !table_box.isEmpty()) {
      table_box.min().array() -= s.workspace_margin_m;
      table_box.max().array() += s.workspace_margin_m;
      if (table_box.intersects(f.workspace)) f.workspace = f.workspace.intersection(table_box);
    }
  }
  f.cost.emplace(f.observed);
  f.registration.emplace(f.objects);
  f.occluders.depth_m = f.rgbd.depth_m;
  if (s.missing_depth_hides)
    for (float& d : f.occluders.depth_m.data)
      if (!(d > 0.f)) d = std::numeric_limits<float>::min();
}

}  // namespace perch2::tabletop_detail
