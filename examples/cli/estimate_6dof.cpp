// perch2 estimate --mode 6dof: full-pose estimation of every target instance of a BOP dataset from its masks
// (ground-truth mask_visib or a detection file), written as BOP results.
#include "estimate_6dof.hpp"

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <map>
#include <set>

#include "perch2/cpu/backend.hpp"
#include "perch2/cuda/backend.hpp"
#include "perch2/io/image_io.hpp"
#include "perch2/search/sixdof_bop.hpp"

namespace perch2::cli {
namespace {

template <class Backend>
int run(const dataset::BopDataset& data,
        const std::map<std::pair<int, int>, std::vector<dataset::Target>>& images, const SixDofOptions& o) {
  std::set<int> ids;
  for (const auto& [key, targets] : images)
    for (const auto& t : targets) ids.insert(t.obj_id);
  std::map<int, int> model_of;
  std::vector<SixDofModel> models;
  std::vector<Mesh> meshes;  // for the overlays
  for (const int id : ids) {
    model_of[id] = int(models.size());
    models.push_back(sixdof_model(data.load_model(id), data.model_info(id)));
    meshes.push_back(models.back().mesh);
  }
  const SixDofEstimator<Backend> estimator(std::move(models));
  std::vector<dataset::Detection> detections;
  std::map<std::pair<int, int>, std::vector<std::size_t>> detections_of;
  if (o.masks != "gt") {
    detections = dataset::load_detections(o.masks);
    detections_of = dataset::detections_by_image(detections);
  }
  if (!o.overlays.empty()) std::filesystem::create_directories(o.overlays);
  dataset::save_results_csv(o.out, {});  // fail early if unwritable; header only
  std::fprintf(stderr, "perch2 estimate: %zu images, %zu objects, 6dof, masks %s, %s boxes\n", images.size(),
               ids.size(), o.masks.c_str(), o.box_full ? "full" : "visible");

  std::vector<dataset::PoseEstimate> rows;
  SixDofTimings sum;
  int done = 0, instances = 0, unusable = 0;
  double seconds = 0;
  dataset::ImageLoadOptions load;
  load.masks_visib = o.masks == "gt";
  for (const auto& [key, targets] : images) {
    const dataset::BopImage image = data.load_image(key.first, key.second, load);
    const BopInstances all =
        o.masks == "gt"
            ? bop_instances_from_gt(image, model_of, o.box_full ? BoxKind::Full : BoxKind::Visible)
            : bop_instances_from_detections(image, detections, detections_of[key], model_of);
    const BopInstances in =
        usable_instances(only_targets(all, targets), image.frame, estimator.settings().observed);
    unusable += int(in.skipped.size() - all.skipped.size());
    SixDofResult result;
    const auto image_rows = estimate_bop_image(estimator, image, in, &result);
    rows.insert(rows.end(), image_rows.begin(), image_rows.end());
    const SixDofTimings& t = result.timings;
    sum.observed += t.observed, sum.proposals += t.proposals, sum.render += t.render, sum.refine += t.refine;
    sum.cost += t.cost, sum.select += t.select, sum.total += t.total;
    instances += int(in.instances.size());
    seconds += t.total;
    if (!o.overlays.empty()) {
      std::vector<int> model_of_pose;
      std::vector<Pose> poses;
      for (std::size_t k = 0; k < result.poses.size(); ++k)
        if (result.poses[k].found)
          model_of_pose.push_back(in.instances[k].model), poses.push_back(result.poses[k].T_cam_obj);
      io::save_color_image(
          o.overlays + "/" + dataset::bop_id(key.first) + "_" + dataset::bop_id(key.second) + ".png",
          draw_overlay(image.frame.rgb, image.frame.camera, meshes, model_of_pose, poses));
    }
    ++done;
    print_progress(stderr, done, int(images.size()), seconds / done, t.total);
  }
  dataset::save_results_csv(o.out, rows);
  std::printf("perch2 estimate: %zu poses for %d instances in %d images -> %s\n", rows.size(), instances,
              done, o.out.c_str());
  if (unusable > 0)
    std::printf("  %d instance(s) skipped: too few valid depth readings inside the mask\n", unusable);
  const double n = done > 0 ? double(done) : 1.0;
  std::printf(
      "per-stage wall-clock seconds per image: observed %.3f, proposals %.3f, render %.3f, refine %.3f, "
      "cost %.3f, select %.3f, total %.3f\n",
      sum.observed / n, sum.proposals / n, sum.render / n, sum.refine / n, sum.cost / n, sum.select / n,
      sum.total / n);
  if (!o.overlays.empty()) std::printf("overlays in %s/\n", o.overlays.c_str());
  return 0;
}

}  // namespace

int estimate_6dof(const dataset::BopDataset& data,
                  const std::map<std::pair<int, int>, std::vector<dataset::Target>>& images,
                  const SixDofOptions& options, BackendKind backend) {
  if (options.masks != "gt" && !std::filesystem::is_regular_file(options.masks))
    throw FileError(options.masks, "is not a detection file (--masks gt|FILE)");
  return backend == BackendKind::Cpu ? run<cpu::Backend>(data, images, options)
                                     : run<thrust_omp::Backend>(data, images, options);
}

}  // namespace perch2::cli
