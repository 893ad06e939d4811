// 6-DoF estimation on BOP images: models from models_info.json symmetries, instances from ground-truth
// visible masks or a detection file, results as BOP rows. What `perch2 estimate --mode 6dof` calls:
//
//   perch2::dataset::BopDataset ds(root);
//   std::map<int, int> model_of;                        // obj_id -> estimator model index
//   std::vector<perch2::SixDofModel> models;
//   for (const auto& [id, info] : ds.models_info())
//     model_of[id] = int(models.size()), models.push_back(perch2::sixdof_model(ds.load_model(id), info));
//   perch2::SixDofEstimator<perch2::cpu::Backend> estimator(models);
//   const auto image = ds.load_image(scene, im);        // rgb, depth, mask_visib
//   const auto in = perch2::bop_instances_from_gt(image, model_of, perch2::BoxKind::Full);
//   auto rows = perch2::estimate_bop_image(estimator, image, in);   // -> save_results_csv
#pragma once

#include <algorithm>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/detections.hpp"
#include "perch2/dataset/results.hpp"
#include "perch2/search/sixdof.hpp"

namespace perch2 {

/// Which box a ground-truth instance gives the proposals: the full (amodal) box or the visible one. The paper
/// (Section VI-B) finds full boxes help occluded objects: their centre is the object's.
enum class BoxKind { Full, Visible };

/// A model with its BOP symmetries.
inline SixDofModel sixdof_model(Mesh mesh, const dataset::ModelInfo& info) {
  return {std::move(mesh), ModelSymmetries::from(info.symmetries_discrete, info.symmetries_continuous)};
}

/// The instances of one image and where each came from.
struct BopInstances {
  std::vector<SixDofInstance> instances;
  std::vector<int> obj_ids;  ///< per instance
  std::vector<int> sources;  ///< per instance: GT index (from GT) or detection index (from detections)
  std::vector<int> skipped;  ///< GT indices / detections left out (empty mask)
};

namespace sixdof_bop_detail {
inline int model_of(const std::map<int, int>& model_of_obj_id, int obj_id, const std::string& who) {
  const auto it = model_of_obj_id.find(obj_id);
  if (it == model_of_obj_id.end())
    throw InvalidInput(who, "obj_id " + std::to_string(obj_id) + " has no model in the estimator");
  return it->second;
}
inline bool any_set(const Image<std::uint8_t>& m) {
  return std::any_of(m.data.begin(), m.data.end(), [](std::uint8_t v) { return v != 0; });
}
}  // namespace sixdof_bop_detail

/// Instances from the image's ground truth: mask_visib masks (load them: ImageLoadOptions::masks_visib) and
/// the full or visible box of scene_gt_info (the mask's box when scene_gt_info is missing). Instances with
/// an empty visible mask (fully occluded or outside the image) are listed in `skipped`. Throws InvalidInput
/// if the masks were not loaded or an obj_id has no model.
inline BopInstances bop_instances_from_gt(const dataset::BopImage& image,
                                          const std::map<int, int>& model_of_obj_id,
                                          BoxKind box = BoxKind::Full) {
  const auto& gt = image.info.gt;
  if (image.masks_visib.size() != gt.size())
    throw InvalidInput(
        "BOP image " + std::to_string(image.info.scene_id) + "/" + std::to_string(image.info.im_id),
        "has " + std::to_string(image.masks_visib.size()) + " visible masks for " +
            std::to_string(gt.size()) + " ground-truth instances (load mask_visib)");
  BopInstances out;
  for (std::size_t g = 0; g < gt.size(); ++g) {
    const std::string who = "ground-truth instance " + std::to_string(g);
    const int model = sixdof_bop_detail::model_of(model_of_obj_id, gt[g].obj_id, who);
    if (!sixdof_bop_detail::any_set(image.masks_visib[g])) {
      out.skipped.push_back(int(g));
      continue;
    }
    SixDofInstance in{model, image.masks_visib[g], {-1, -1, -1, -1}};
    if (gt[g].has_info) in.box_xywh = box == BoxKind::Full ? gt[g].bbox_obj : gt[g].bbox_visib;
    out.instances.push_back(std::move(in));
    out.obj_ids.push_back(gt[g].obj_id);
    out.sources.push_back(int(g));
  }
  return out;
}

/// Instances from detections of this image (`indices` into `detections`, e.g. from detections_by_image) with
/// a score of at least min_score; the detection's box is used as given. Detections without a mask or with an
/// empty one are listed in `skipped`. Throws InvalidInput if an obj_id has no model or a mask does not match
/// the image size.
inline BopInstances bop_instances_from_detections(const dataset::BopImage& image,
                                                  const std::vector<dataset::Detection>& detections,
                                                  const std::vector<std::size_t>& indices,
                                                  const std::map<int, int>& model_of_obj_id,
                                                  float min_score = 0.f) {
  BopInstances out;
  for (const std::size_t i : indices) {
    const std::string who = "detection " + std::to_string(i);
    if (i >= detections.size()) throw InvalidInput(who, "index out of range");
    const dataset::Detection& d = detections[i];
    if (d.score < min_score) continue;
    const int model = sixdof_bop_detail::model_of(model_of_obj_id, d.category_id, who);
    if (!d.has_mask()) {
      out.skipped.push_back(int(i));
      continue;
    }
    SixDofInstance in{model, d.mask(), {-1, -1, -1, -1}};
    check_size(in.mask, image.frame.camera.width, image.frame.camera.height, who + " mask");
    if (!sixdof_bop_detail::any_set(in.mask)) {
      out.skipped.push_back(int(i));
      continue;
    }
    in.box_xywh = {int(std::lround(d.bbox[0])), int(std::lround(d.bbox[1])), int(std::lround(d.bbox[2])),
                   int(std::lround(d.bbox[3]))};
    out.instances.push_back(std::move(in));
    out.obj_ids.push_back(d.category_id);
    out.sources.push_back(int(i));
  }
  return out;
}

/// Keeps the instances whose object is a target of the image (others are not evaluated: no time on them).
inline BopInstances only_targets(BopInstances in, const std::vector<dataset::Target>& targets) {
  std::set<int> wanted;
  for (const auto& t : targets) wanted.insert(t.obj_id);
  BopInstances out;
  out.skipped = in.skipped;
  for (std::size_t k = 0; k < in.instances.size(); ++k)
    if (wanted.count(in.obj_ids[k])) {
      out.instances.push_back(std::move(in.instances[k]));
      out.obj_ids.push_back(in.obj_ids[k]);
      out.sources.push_back(in.sources[k]);
    }
  return out;
}

/// Drops the instances the estimator could not pose and lists them in `skipped` (their GT index or
/// detection index): those left with fewer than `min_points` valid depth readings on the observed stride
/// grid once later instances' masks have taken the pixels they overlap (SixDofEstimator's label rule). A
/// mask over a region without depth (glass, a dark object, a depth shadow) or a detection buried under
/// another would otherwise stop the whole image with InvalidInput. `stride` and the depth range come from
/// the estimator's settings (SixDofSettings::observed).
inline BopInstances usable_instances(BopInstances in, const RgbdFrame& frame,
                                     const ObservedCloudSettings& observed, int min_points = 10) {
  const int w = frame.camera.width, h = frame.camera.height;
  std::vector<std::int32_t> owner(std::size_t(w) * std::size_t(h), -1);
  for (std::size_t k = 0; k < in.instances.size(); ++k) {
    check_size(in.instances[k].mask, w, h, "instance " + std::to_string(k) + " mask");
    for (std::size_t i = 0; i < owner.size(); ++i)
      if (in.instances[k].mask.data[i]) owner[i] = std::int32_t(k);
  }
  std::vector<int> points(in.instances.size(), 0);
  const int stride = std::max(observed.stride, 1);
  for (int v = 0; v < h; v += stride)
    for (int u = 0; u < w; u += stride) {
      const std::size_t i = std::size_t(v) * std::size_t(w) + std::size_t(u);
      if (owner[i] >= 0 && observed_detail::keep(frame.depth_m.data[i], observed)) ++points[owner[i]];
    }
  BopInstances out;
  out.skipped = in.skipped;
  for (std::size_t k = 0; k < in.instances.size(); ++k) {
    if (points[k] < min_points) {
      out.skipped.push_back(in.sources[k]);
      continue;
    }
    out.instances.push_back(std::move(in.instances[k]));
    out.obj_ids.push_back(in.obj_ids[k]);
    out.sources.push_back(in.sources[k]);
  }
  return out;
}

/// Estimates every instance and returns one BOP row per instance (score = the pose's score in [0, 1], time =
/// the estimator's wall time for the image). `result`, if given, receives the full result (timings, counts).
/// No instances: no rows.
template <class Backend>
std::vector<dataset::PoseEstimate> estimate_bop_image(const SixDofEstimator<Backend>& estimator,
                                                      const dataset::BopImage& image, const BopInstances& in,
                                                      SixDofResult* result = nullptr) {
  std::vector<dataset::PoseEstimate> rows;
  if (in.instances.empty()) return rows;
  SixDofResult r = estimator.estimate(image.frame, in.instances);
  for (std::size_t k = 0; k < r.poses.size(); ++k) {
    dataset::PoseEstimate e;
    e.scene_id = image.info.scene_id, e.im_id = image.info.im_id, e.obj_id = in.obj_ids[k];
    e.score = r.poses[k].score;
    e.T_cam_obj = r.poses[k].T_cam_obj;
    e.time_s = r.timings.total;
    rows.push_back(e);
  }
  if (result) *result = std::move(r);
  return rows;
}

}  // namespace perch2
