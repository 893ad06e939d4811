// 3-DoF tabletop estimation on BOP images: models with their yaw symmetry from models_info.json, the table
// frame from scene_camera.json, BOP rows out. The 6-DoF counterpart is perch2/search/sixdof_bop.hpp; both are
// run per image by perch2::dataset::BopRunner (perch2/dataset/runner.hpp), which `perch2 estimate` calls.
//
//   perch2::dataset::BopDataset ds(root);
//   std::map<int, int> model_of;                        // obj_id -> estimator model index
//   std::vector<perch2::TabletopModel> models;
//   for (const auto& [id, info] : ds.models_info())
//     model_of[id] = int(models.size()), models.push_back(perch2::tabletop_model(ds.load_model(id), info));
//   perch2::TabletopEstimator<perch2::cpu::Backend> estimator(models, non_strict_settings);
//   const auto image = ds.load_image(scene, im, {true, true, false});   // rgb, depth
//   auto rows = perch2::estimate_bop_image(estimator, image, targets, model_of);  // -> save_results_csv
//
// Assumptions about the dataset:
//  - every model stands upright with its own +z axis up, its lowest vertex on the table (perch2's default
//    rest pose; the built-in synth models and YCB/BOP tabletop models are z-up). The ground truth
//    (scene_gt.json) is never read for estimation.
//  - a model is searched with one yaw per position (yaw_symmetric) when models_info.json lists a continuous
//    symmetry about an axis parallel to the model's z axis through its origin (x, y offset < 1 mm). That is a
//    symmetry of the shape: a textured model listed so (a can with a label) still gets the yaw search
//    (TabletopSettings::yaw_search), which turns its label right; ADD(-S) then scores it by ADD-S.
//  - the table frame is BOP's world frame (cam_R_w2c / cam_t_w2c: z up, table top at z = 0) when
//    scene_camera.json gives it, else it is estimated from the depth (RANSAC plane).
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <string>
#include <vector>

#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/results.hpp"
#include "perch2/search/tabletop.hpp"

namespace perch2 {

/// A continuous symmetry about the model's z axis through its origin (axis within 1e-3 of z, offset < 1 mm
/// from the axis): the model's shape is the same at every yaw.
inline bool symmetric_about_z(const dataset::ModelInfo& info) {
  for (const auto& s : info.symmetries_continuous) {
    const Eigen::Vector3f a = s.axis.normalized();
    if (std::abs(std::abs(a.z()) - 1.f) < 1e-3f && s.offset_m.head<2>().norm() < 1e-3f) return true;
  }
  return false;
}

/// A model standing in its default rest pose (its z axis up), yaw-symmetric when models_info says so.
inline TabletopModel tabletop_model(Mesh mesh, const dataset::ModelInfo& info) {
  return {std::move(mesh), symmetric_about_z(info), std::nullopt};
}

namespace tabletop_detail {

/// One BOP row per pose: score = 1 / (1 + selection score) (BOP: higher is better; the cost is >= 0).
template <class ObjIdOf>
std::vector<dataset::PoseEstimate> bop_rows(const dataset::BopImage& image, TabletopResult r, double seconds,
                                            ObjIdOf obj_id_of, TabletopResult* result) {
  std::vector<dataset::PoseEstimate> rows;
  for (const auto& p : r.poses) {
    dataset::PoseEstimate e;
    e.scene_id = image.info.scene_id, e.im_id = image.info.im_id, e.obj_id = obj_id_of(p.model);
    e.score = 1.0 / (1.0 + std::max(0.0, double(p.score)));
    e.T_cam_obj = p.T_cam_obj;
    e.time_s = seconds;
    rows.push_back(e);
  }
  if (result) *result = std::move(r);
  return rows;
}

}  // namespace tabletop_detail

/// Estimates the targets of one image (all of image.info's scene_id, im_id; their obj_ids must be in
/// model_of_obj_id) with the table frame of scene_camera.json when given. One BOP row per pose found: score =
/// 1 / (1 + selection score), time = the wall clock of estimate(). `result`, if given, receives the full
/// result (poses in row order, timings, `missing` instances when the estimator is not strict).
template <class Backend>
std::vector<dataset::PoseEstimate> estimate_bop_image(const TabletopEstimator<Backend>& estimator,
                                                      const dataset::BopImage& image,
                                                      const std::vector<dataset::Target>& targets,
                                                      const std::map<int, int>& model_of_obj_id,
                                                      TabletopResult* result = nullptr) {
  const int scene_id = image.info.scene_id, im_id = image.info.im_id;
  std::vector<ObjectCount> request;
  std::map<int, int> obj_id_of;  // model index -> obj_id
  for (const auto& t : targets) {
    if (t.scene_id != scene_id || t.im_id != im_id)
      throw InvalidInput("targets", "mix images (" + std::to_string(t.scene_id) + ", " +
                                        std::to_string(t.im_id) + ") and (" + std::to_string(scene_id) +
                                        ", " + std::to_string(im_id) + ")");
    const auto it = model_of_obj_id.find(t.obj_id);
    if (it == model_of_obj_id.end())
      throw InvalidInput("obj_id " + std::to_string(t.obj_id), "has no model in the estimator");
    request.push_back({it->second, t.inst_count});
    obj_id_of[it->second] = t.obj_id;
  }
  const auto t0 = std::chrono::steady_clock::now();
  TabletopResult r = estimator.estimate(image.frame, request, image.info.T_cam_world);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return tabletop_detail::bop_rows(
      image, std::move(r), seconds, [&](int m) { return obj_id_of.at(m); }, result);
}

/// 3-DoF detection on one image (bop24 targets: no objects or counts): TabletopEstimator::detect over every
/// model, model m being obj_ids[m], with the table frame of scene_camera.json when given. Rows as
/// estimate_bop_image's, best score first.
template <class Backend>
std::vector<dataset::PoseEstimate> detect_bop_image(const TabletopEstimator<Backend>& estimator,
                                                    const dataset::BopImage& image,
                                                    const std::vector<int>& obj_ids,
                                                    const TabletopDetectSettings& settings,
                                                    TabletopResult* result = nullptr) {
  if (obj_ids.size() != estimator.models().size())
    throw InvalidInput("obj_ids", std::to_string(obj_ids.size()) + " for " +
                                      std::to_string(estimator.models().size()) + " models");
  const auto t0 = std::chrono::steady_clock::now();
  TabletopResult r = estimator.detect(image.frame, settings, image.info.T_cam_world);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return tabletop_detail::bop_rows(
      image, std::move(r), seconds, [&](int m) { return obj_ids[std::size_t(m)]; }, result);
}

}  // namespace perch2
