// 3-DoF tabletop estimation over a BOP dataset: the glue shared by `perch2 estimate`, `perch2 demo` and
// bench/bench_tabletop.cpp (library target perch2_tabletop_bop, built with the examples).
//
// Assumptions about the dataset (documented in `perch2 estimate --help`):
//  - every model stands upright with its own +z axis up, its lowest vertex on the table (perch2's default
//    rest pose; the built-in synth models and YCB/BOP tabletop models are z-up). The ground truth
//    (scene_gt.json) is never read for estimation.
//  - a model is searched with one yaw per position (yaw_symmetric) when models_info.json lists a continuous
//    symmetry about an axis parallel to the model's z axis through its origin (x, y offset < 1 mm).
//  - the table frame is BOP's world frame (cam_R_w2c / cam_t_w2c: z up, table top at z = 0) when
//    scene_camera.json gives it, else it is estimated from the depth (RANSAC plane).
#pragma once

#include <cstdio>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "perch2/core/image.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/results.hpp"
#include "perch2/search/tabletop.hpp"

namespace perch2::cli {

enum class BackendKind { Cpu, ThrustOmp };

/// "cpu" | "thrust_omp"; InvalidInput naming the value otherwise.
BackendKind parse_backend(const std::string& name);
const char* backend_name(BackendKind b);

/// The CLI spellings: perch2c | perch2a | perch2b | perch | depth-only | bf-icp; InvalidInput otherwise.
SearchVariant parse_variant(const std::string& name);
const char* variant_name(SearchVariant v);
constexpr const char* kVariantNames = "perch2c|perch2a|perch2b|perch|depth-only|bf-icp";

/// Per-stage wall-clock seconds summed over images.
struct StageTimes {
  TabletopTimings sum;
  int images = 0;
  void add(const TabletopTimings& t);
  /// One line per stage: total seconds, mean per image and share of the total.
  void print(std::FILE* out, const char* indent = "  ") const;
};

/// Targets grouped by image, (scene_id, im_id) ascending; scenes outside [first, last] dropped.
std::map<std::pair<int, int>, std::vector<dataset::Target>> targets_by_image(const dataset::BopDataset& data,
                                                                             int first_scene = 0,
                                                                             int last_scene = 1 << 30);

/// One image's estimate.
struct ImageEstimate {
  int scene_id = 0, im_id = 0;
  TabletopResult result;
  std::vector<int> pose_obj_ids;             ///< obj_id of each result.poses entry
  std::vector<dataset::PoseEstimate> rows;   ///< BOP results rows (score = 1 / (1 + selection score))
  std::vector<std::pair<int, int>> missing;  ///< (obj_id, instances) requested but not found
  double seconds = 0;                        ///< estimate() wall clock (the BOP "time" column)
};

/// Estimates every target object of a BOP dataset's images with one TabletopEstimator (all target objects'
/// models loaded once, converted to metres). Non-strict: a missing instance is reported, not thrown.
class BopTabletop {
 public:
  BopTabletop(const dataset::BopDataset& data, const std::vector<int>& obj_ids, SearchVariant variant,
              BackendKind backend, TabletopSettings base = {});
  ~BopTabletop();

  /// Estimates the targets of one image (all of the same scene_id, im_id). `image` must hold rgb and depth.
  ImageEstimate estimate(const dataset::BopImage& image, const std::vector<dataset::Target>& targets) const;

  const std::vector<Mesh>& meshes() const { return meshes_; }
  const std::vector<int>& obj_ids() const { return obj_ids_; }
  int model_index(int obj_id) const;
  bool yaw_symmetric(int obj_id) const;

 private:
  struct Impl;
  std::vector<int> obj_ids_;
  std::vector<Mesh> meshes_;
  std::vector<bool> yaw_symmetric_;
  std::unique_ptr<Impl> impl_;
};

/// The RGB image with the given models drawn at their poses (rendered at full resolution by perch2's CPU
/// renderer): each object's visible surface tinted in its own colour and outlined. `model_of_pose[i]`
/// indexes `meshes`.
ColorImage draw_overlay(const ColorImage& rgb, const Intrinsics& camera, const std::vector<Mesh>& meshes,
                        const std::vector<int>& model_of_pose, const std::vector<Pose>& T_cam_obj);

/// A distinct colour for overlay index i (also printed as a legend).
Rgb8 overlay_color(int i);
const char* overlay_color_name(int i);

/// Progress on one line of `out`: "[#####.....] 3/10 images  2.1 s/image (last 1.9 s)".
void print_progress(std::FILE* out, int done, int total, double mean_s, double last_s);

}  // namespace perch2::cli
