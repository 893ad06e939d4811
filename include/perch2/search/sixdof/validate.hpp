// The checks of both entry points' inputs, before any work: the settings (each stage's own validate()
// and the ranges SixDofSettings documents), the frame (and its colour image where the RGB-D cost needs
// one), estimate()'s instances (known models, masks of the frame's size) and estimate_scene()'s objects
// (known models, counts >= 0, each model once). Bad input throws InvalidInput naming it.
#pragma once

#include <cmath>
#include <string>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/observed.hpp"
#include "perch2/search/sixdof/result.hpp"
#include "perch2/search/sixdof/settings.hpp"

namespace perch2 {
namespace sixdof_detail {

/// The settings and the frame (what both entry points need).
inline void validate_settings(const SixDofSettings& s, const RgbdFrame& frame) {
  perch2::validate(s.proposals);
  perch2::validate(s.gicp);
  if (s.score_stride < 1) throw InvalidInput("SixDofSettings::score_stride", "must be >= 1");
  if (s.second_pass_stride < 1) throw InvalidInput("SixDofSettings::second_pass_stride", "must be >= 1");
  if (s.render.stride < 1) throw InvalidInput("SixDofSettings::render.stride", "must be >= 1");
  if (s.keep_per_instance < 0) throw InvalidInput("SixDofSettings::keep_per_instance", "must be >= 0");
  if (s.screen.stride != 0 && s.screen.stride <= s.render.stride)
    throw InvalidInput("SixDofSettings::screen.stride",
                       "must be 0 (no screen) or > render.stride, got " + std::to_string(s.screen.stride));
  if (s.coarse_mesh.min_stride < 0)
    throw InvalidInput("SixDofSettings::coarse_mesh.min_stride", "must be >= 0 (0 = never)");
  if (s.screen.icp_iterations < 1)
    throw InvalidInput("SixDofSettings::screen.icp_iterations", "must be >= 1");
  if (!(s.screen.keep_fraction > 0.f && s.screen.keep_fraction <= 1.f))
    throw InvalidInput("SixDofSettings::screen.keep_fraction", "must be in (0, 1]");
  if (s.screen.min_keep < 1) throw InvalidInput("SixDofSettings::screen.min_keep", "must be >= 1");
  if (s.first_pass_target_stride < 1)
    throw InvalidInput("SixDofSettings::first_pass_target_stride",
                       "must be >= 1, got " + std::to_string(s.first_pass_target_stride));
  if (!(s.distinct_translation_m >= 0) || !(s.distinct_rotation_rad >= 0))
    throw InvalidInput("SixDofSettings::distinct_*", "must be >= 0");
  if (!(s.second_pass_cap_m >= 0)) throw InvalidInput("SixDofSettings::second_pass_cap_m", "must be >= 0");
  if (s.second_pass_iterations < 1)
    throw InvalidInput("SixDofSettings::second_pass_iterations", "must be >= 1");
  if (s.local.candidates_per_instance < 0)
    throw InvalidInput("SixDofSettings::local.candidates_per_instance", "must be >= 0 (0 = off)");
  perch2::validate(s.local.turns, "SixDofSettings::local.turns");
  surface_fit_detail::check(s.fit);
  if (s.fit_stride < 1) throw InvalidInput("SixDofSettings::fit_stride", "must be >= 1");
  if (!(std::isfinite(s.fit_cost_slack) && s.fit_cost_slack >= 0))
    throw InvalidInput("SixDofSettings::fit_cost_slack", "must be finite and >= 0");
  if (!(s.trim_quantile_low >= 0 && s.trim_quantile_low <= s.trim_quantile_high && s.trim_quantile_high <= 1))
    throw InvalidInput("SixDofSettings::trim_quantile_*", "need 0 <= low <= high <= 1");
  if (s.memory_budget_bytes == 0 || s.bytes_per_point == 0)
    throw InvalidInput("SixDofSettings", "memory_budget_bytes and bytes_per_point must be > 0");
  frame.validate("6-DoF frame");
  if ((s.cost.use_color || s.first_pass_cost.use_color) && frame.rgb.empty())
    throw InvalidInput("6-DoF frame",
                       "has no colour image, which the RGB-D cost needs (set cost.use_color and "
                       "first_pass_cost.use_color = false for the depth-only cost)");
}

/// estimate()'s inputs: the settings, the frame and the instances (over `models`).
inline void validate_instances(const SixDofSettings& s, const std::vector<SixDofModel>& models,
                               const RgbdFrame& frame, const std::vector<SixDofInstance>& instances) {
  validate_settings(s, frame);
  if (instances.empty()) throw InvalidInput("instances", "no instances given");
  for (std::size_t k = 0; k < instances.size(); ++k) {
    const std::string who = "instances[" + std::to_string(k) + "]";
    const SixDofInstance& in = instances[k];
    if (in.model < 0 || std::size_t(in.model) >= models.size())
      throw InvalidInput(who, "unknown model id " + std::to_string(in.model) + " (" +
                                  std::to_string(models.size()) + " models)");
    check_size(in.mask, frame.camera.width, frame.camera.height, who + " mask");
  }
}

/// estimate_scene()'s inputs: the settings (the scene's too), the frame and the objects (over `models`).
inline void validate_scene(const SixDofSettings& s, const std::vector<SixDofModel>& models,
                           const RgbdFrame& frame, const std::vector<SixDofObject>& objects) {
  validate_settings(s, frame);
  const SceneSettings& ss = s.scene;
  if (!(ss.min_area_fraction >= 0) || !(ss.max_area_faces > 0) || !(ss.piece_extent_factor > 0) ||
      !(ss.piece_area_faces > 0) || ss.max_pieces < 1 ||
      !(ss.min_inlier_fraction >= 0 && ss.min_inlier_fraction <= 1) ||
      !(ss.max_colour_mismatch >= 0 && ss.max_colour_mismatch <= 1) || !(ss.explain_distance_m > 0) ||
      ss.min_segment_points < 1 || !(ss.min_colour_fraction >= 0) || ss.colour_samples < 1 ||
      ss.spare_placements < 0 || ss.retrieval_jobs_per_object < 0)
    throw InvalidInput(
        "SixDofSettings::scene",
        "needs min_area_fraction >= 0, max_area_faces > 0, piece_extent_factor > 0, "
        "piece_area_faces > 0, max_pieces >= 1, min_inlier_fraction and max_colour_mismatch in [0, 1], "
        "explain_distance_m > 0, "
        "min_segment_points >= 1, min_colour_fraction >= 0, colour_samples >= 1, spare_placements >= 0 and "
        "retrieval_jobs_per_object >= 0");
  for (std::size_t i = 0; i < objects.size(); ++i) {
    const std::string who = "objects[" + std::to_string(i) + "]";
    if (objects[i].model < 0 || std::size_t(objects[i].model) >= models.size())
      throw InvalidInput(who, "unknown model id " + std::to_string(objects[i].model) + " (" +
                                  std::to_string(models.size()) + " models)");
    if (objects[i].count < 0) throw InvalidInput(who, "count must be >= 0");
    for (std::size_t j = 0; j < i; ++j)
      if (objects[j].model == objects[i].model)
        throw InvalidInput(who, "model " + std::to_string(objects[i].model) + " is listed twice");
  }
}

inline void validate_detect(const DetectSettings& d) {
  if (d.max_per_model < 1 || d.max_per_frame < 1 || !(d.min_score >= 0 && d.min_score <= 1) ||
      !(d.max_colour_mismatch >= 0 && d.max_colour_mismatch <= 1) || d.retrieval_jobs_per_object < 0 ||
      d.retrieval_viewpoints < 0 || d.retrieval_inplane_rotations < 1 || d.retrieval_screen_keep < 0 ||
      !(d.retrieval_align_min_elongation >= 1) ||
      !(std::isfinite(d.half_evidence_readings) && d.half_evidence_readings >= 0) ||
      !(d.max_below_plane_m >= 0))
    throw InvalidInput(
        "DetectSettings",
        "needs max_per_model >= 1, max_per_frame >= 1, retrieval_jobs_per_object >= 0, "
        "retrieval_viewpoints >= 0, retrieval_inplane_rotations >= 1, retrieval_screen_keep >= 0, "
        "retrieval_align_min_elongation >= 1, "
        "min_score and "
        "max_colour_mismatch in [0, 1], half_evidence_readings finite and >= 0, "
        "max_below_plane_m >= 0 (inf: no test)");
}

}  // namespace sixdof_detail
}  // namespace perch2
