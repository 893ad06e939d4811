// Pose error functions, in metres (perch2's units; BOP's definitions are in millimetres, which only scales
// them: every threshold here is converted accordingly).
//
// Definitions followed (cited per function):
//  - ADD, ADD-S: Hinterstoisser et al., ACCV 2012; bop_toolkit_lib/pose_error.py add(), adi().
//  - AUC: YCB-Video toolbox (Xiang et al., PoseCNN, RSS 2018), evaluate_poses_keyframe.m / plot_accuracy_*.m:
//    errors > 0.1 m set to inf, sorted, accuracy = (1..n)/n, VOCap(): area under the running maximum of
//    accuracy over [0, 0.1 m], normalised by 0.1 m.
//  - MSSD, MSPD, VSD: Hodan et al., BOP Challenge 2019/2020 (ECCVW 2020); bop_toolkit_lib/pose_error.py
//  mssd(),
//    mspd(), vsd(); symmetries from misc.get_symmetry_transformations(); visibility from visibility.py
//    ("bop19" mode: an object pixel with no depth reading counts as visible).
#pragma once

#include <memory>
#include <vector>

#include "perch2/core/camera.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/dataset/bop.hpp"

namespace perch2::eval {

/// A model's points (object frame, metres) for exact nearest-point queries: a grid of candidate lists over
/// the model's box (plus 10% of its diagonal), built once, answers queries near the surface by scanning a
/// few dozen points; the rest go to an exact FLANN kd-tree. About 4x faster than the kd-tree alone for
/// estimates a few millimetres off, 1.3-1.6x for centimetres off; ~0.2 s CPU and ~8 MB per 3,000-point model
/// to build.
class ModelPoints {
 public:
  explicit ModelPoints(std::vector<Eigen::Vector3f> points_m);
  ~ModelPoints();
  ModelPoints(ModelPoints&&) noexcept;
  ModelPoints& operator=(ModelPoints&&) noexcept;

  const std::vector<Eigen::Vector3f>& points() const;
  /// Squared distance from each query point to its nearest model point (exact).
  void nearest_sq_distances(const std::vector<float>& xyz_rows, std::vector<float>& d2) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// ADD: mean over model points x of |T_est x - T_gt x| (metres).
double add_error(const Pose& T_est, const Pose& T_gt, const std::vector<Eigen::Vector3f>& points_m);

/// ADD-S: mean over model points x of min_y |T_gt x - T_est y| (metres), nearest y by the kd-tree.
double adds_error(const Pose& T_est, const Pose& T_gt, const ModelPoints& model);

/// The symmetry transformations T_obj_obj' of a model, identity first, as bop_toolkit's
/// misc.get_symmetry_transformations(): every discrete symmetry (plus the identity) combined with each of
/// ceil(pi / max_sym_disc_step) rotations about every continuous-symmetry axis (steps of 2 pi / count).
std::vector<Pose> symmetry_transformations(const dataset::ModelInfo& info, double max_sym_disc_step = 0.01);

/// MSSD: min over symmetries S of max over points |T_est x - T_gt S x| (metres).
double mssd_error(const Pose& T_est, const Pose& T_gt, const std::vector<Eigen::Vector3f>& points_m,
                  const std::vector<Pose>& symmetries);

/// MSPD: min over symmetries S of max over points |proj(T_est x) - proj(T_gt S x)| (pixels).
double mspd_error(const Pose& T_est, const Pose& T_gt, const Intrinsics& K,
                  const std::vector<Eigen::Vector3f>& points_m, const std::vector<Pose>& symmetries);

/// A rendered model as a sparse distance image: pixel indices (v * width + u, increasing) and the distance
/// from the camera centre (metres) of the surface seen there.
struct SparseDistance {
  std::vector<std::int32_t> pixel;
  std::vector<float> dist_m;
};

/// Distance from the camera centre of a planar depth z at pixel (u, v): z * |((u-cx)/fx, (v-cy)/fy, 1)|
/// (bop_toolkit misc.depth_im_to_dist_im_fast).
float depth_to_distance(const Intrinsics& K, int u, int v, float z_m);

/// VSD for each tau (fractions of the diameter; "step" cost, normalised by the diameter as BOP 2019+):
/// e = (sum over visible intersection of [|d_est - d_gt| / diameter >= tau] + |union \ intersection|) /
/// |union|, 1 when the union is empty. Visibility (bop19): visible_gt = d_gt > 0 and (no depth or d_gt -
/// d_test <= delta); visible_est = d_est > 0 and (no depth or d_est - d_test <= delta, or visible_gt).
std::vector<double> vsd_errors(const SparseDistance& est, const SparseDistance& gt,
                               const DepthImage& depth_test_m, const Intrinsics& K, double delta_m,
                               const std::vector<double>& taus, double diameter_m);

/// bop_toolkit misc.overlapping_sphere_projections(): whether the image projections of two spheres of
/// radius_m centred at p1 and p2 (camera frame) overlap, approximated from the projected centres. BOP's
/// eval_calc_errors.py gives VSD = 1 for every tau without rendering when they do not (and MSSD = inf when
/// |t_est - t_gt| >= diameter); the evaluator does the same so that its numbers match bop_toolkit's.
bool sphere_projections_overlap(double radius_m, const Eigen::Vector3d& p1, const Eigen::Vector3d& p2);

/// Area under the accuracy-threshold curve over [0, max_m] exactly as the YCB-Video toolbox computes it
/// (errors > max_m or non-finite are failures). Returns a fraction in [0, 1] (the toolbox prints x100);
/// 0 for no errors.
double auc_ycb(std::vector<double> errors_m, double max_m = 0.1);

/// Precision and recall after each detection of one object, detections in order of decreasing score.
struct PrecisionRecall {
  std::vector<double> recall, precision;
};

/// bop_toolkit score.calc_pose_detection_scores(): recall = true positives so far / `positives`, precision
/// = true positives so far / detections so far, after each entry of `true_positive` (by decreasing score).
PrecisionRecall precision_recall(const std::vector<bool>& true_positive, int positives);

/// Interpolated precision at recall r = 0, 0.01, ..., 1 (101 values) as bop_toolkit score.calc_ap(), which
/// follows COCO's cocoeval: the highest precision reached at any recall >= r, 0 where none is.
std::vector<double> interpolated_precision(const PrecisionRecall& pr);

/// AP: the mean of interpolated_precision() (bop_toolkit score.calc_ap()).
double average_precision(const PrecisionRecall& pr);

}  // namespace perch2::eval
