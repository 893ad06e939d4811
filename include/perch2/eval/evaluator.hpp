// Evaluating BOP results (perch2::dataset::PoseEstimate rows) against a BOP dataset's ground truth.
//
// Targets and matching follow bop_toolkit (scripts/eval_bop19_pose.py, eval_calc_errors.py,
// eval_calc_scores.py, bop_toolkit_lib/pose_matching.py match_poses(), score.py calc_localization_scores()):
//  - Targets come from test_targets_bop19.json (inst_count instances of obj_id per image). In each image the
//    inst_count most visible instances of a target object (scene_gt_info visib_fract, ties in GT order) are
//    the valid ground truth (visib_gt_min = -1 in eval_bop19_pose.py).
//  - Per image and object only the inst_count best-scored estimates are kept (n_top = -1); estimates of
//    images or objects that are not targets are ignored and counted.
//  - BOP metrics: for each threshold, estimates are matched greedily in order of decreasing score, each to
//  the
//    unmatched valid GT instance (same object) with the smallest error below the threshold. Recall = matched
//    / targets over the whole dataset; AR_X = mean recall over X's thresholds (VSD: over taus x thresholds);
//    AR = mean(AR_VSD, AR_MSSD, AR_MSPD). An instance without a matching estimate counts as a miss.
//  - ADD / ADD-S / ADD(-S): the same greedy matching without a threshold (each estimate takes the unmatched
//    valid instance with the smallest error); an instance left without an estimate has error infinity.
//    AUC over [0, 0.1 m] as the YCB-Video toolbox; ADD-S < 1 cm and < 2 cm as fractions of instances.
//    ADD(-S) uses ADD-S for models with symmetries in models_info.json, ADD otherwise.
//
// 6D detection (test_targets_bop24.json: images only) is scored in addition as BOP 2024 does
// (scripts/eval_bop24_pose.py; eval_calc_errors.py and eval_calc_scores.py in "detection" mode,
// score.calc_pose_detection_scores(), calc_ap()):
//  - Per image only the 100 best-scored estimates count (load_bop_results, stable on equal scores).
//  - Errors are computed for the objects annotated in the image only, so an estimate of an object that is
//    not there is not scored at all (the toolkit's rule; counted in num_ignored_object_absent).
//  - Per error type and threshold, in each image and object, estimates by decreasing score each take the
//    unmatched GT instance (any visibility) with the smallest error strictly below the threshold. An
//    estimate matched to an instance less than visib_gt_min (10 %) visible is ignored; the instances at
//    least that visible are the positives; every other estimate is a true or a false positive.
//  - AP per object and threshold: its estimates over all images by decreasing score (stable: images in
//    (scene, image) order), COCO's 101-point interpolated precision (metrics.hpp average_precision()).
//    An object's AP = mean over thresholds; mAP = mean over objects with a positive; bop24_mAP =
//    mean(mAP_MSSD, mAP_MSPD) (MSSD 0.05-0.5 of the diameter, MSPD 5-50 px at 640 px width); MSSD in mm
//    (2-20 mm, bop25_mAP_mm) is reported too.
#pragma once

#include <functional>
#include <map>
#include <string>
#include <vector>

#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/results.hpp"

namespace perch2::eval {

struct EvalSettings {
  /// Upper end of the ADD/ADD-S AUC, metres (YCB-Video toolbox: 0.1 m).
  double auc_max_m = 0.1;
  /// VSD misalignment tolerances tau, fractions of the object diameter (BOP19: 0.05, 0.10, ..., 0.50).
  std::vector<double> vsd_taus{0.05, 0.10, 0.15, 0.20, 0.25, 0.30, 0.35, 0.40, 0.45, 0.50};
  /// VSD correctness thresholds on the error (unitless; BOP19: 0.05 ... 0.50).
  std::vector<double> vsd_thresholds{0.05, 0.10, 0.15, 0.20, 0.25, 0.30, 0.35, 0.40, 0.45, 0.50};
  /// VSD visibility tolerance delta, metres (BOP19: 15 mm for every dataset except ITODD's 5 mm).
  double vsd_delta_m = 0.015;
  /// MSSD correctness thresholds, fractions of the object diameter (BOP19: 0.05 ... 0.50).
  std::vector<double> mssd_thresholds{0.05, 0.10, 0.15, 0.20, 0.25, 0.30, 0.35, 0.40, 0.45, 0.50};
  /// MSPD correctness thresholds in pixels at 640 px image width (BOP19: 5, 10, ..., 50); errors are scaled
  /// by 640 / image width before comparison.
  std::vector<double> mspd_thresholds_px{5, 10, 15, 20, 25, 30, 35, 40, 45, 50};
  /// Discretisation of continuous symmetries, fraction of the diameter (bop_toolkit max_sym_disc_step).
  double max_sym_disc_step = 0.01;
  /// Compute VSD (renders both poses at stride 1 with perch2's CPU renderer and reads each image's depth).
  /// false: AR_VSD is not computed and AR is the mean of AR_MSSD and AR_MSPD (reported as such).
  bool compute_vsd = true;
  /// Allowed difference of the time column within one image, seconds (bop_toolkit: 0.001).
  double time_tolerance_s = 0.001;
  /// Detection (bop24 targets): estimates kept per image, the best-scored (bop_toolkit: 100).
  int max_estimates_per_image = 100;
  /// Detection: GT instances less visible than this are not positives, and estimates matched to them are
  /// ignored (bop_toolkit visib_gt_min: 0.1).
  double visib_gt_min = 0.1;
  /// Detection: MSSD thresholds in metres (eval_bop24_pose.py: 2, 4, ..., 20 mm; bop25_mAP_mm).
  std::vector<double> mssd_thresholds_m{0.002, 0.004, 0.006, 0.008, 0.010, 0.012, 0.014, 0.016, 0.018, 0.020};
};

/// Scores of one object (or all).
struct Scores {
  int num_targets = 0;                            ///< valid GT instances
  double auc_add = 0;                             ///< AUC of ADD, [0, 1]
  double auc_adds = 0;                            ///< AUC of ADD-S
  double auc_add_or_adds = 0;                     ///< AUC of ADD(-S)
  double adds_below_1cm = 0, adds_below_2cm = 0;  ///< fraction of instances with ADD-S < 1 cm / 2 cm
  double ar_vsd = 0, ar_mssd = 0, ar_mspd = 0;    ///< average recalls, [0, 1]
  double ar = 0;                                  ///< mean of the BOP average recalls computed
};

/// Errors of one valid GT instance with its matched estimates (threshold-free matching; inf = missed).
struct InstanceResult {
  int scene_id = 0, im_id = 0, obj_id = 0, gt_index = 0;
  float visib_fract = 1.f;
  double add_m = 0, adds_m = 0, add_or_adds_m = 0;  ///< ADD, ADD-S, ADD(-S)
  double mssd_m = 0, mspd_px = 0;                   ///< MSSD, MSPD (pixels at the image's own width)
  int add_line = 0, adds_line = 0;                  ///< results line of the matched estimate, 0 if none
};

/// BOP 2024 detection scores of one object; in DetectionReport::overall the means over objects.
struct DetectionScores {
  int num_positives = 0;            ///< GT instances at least visib_gt_min visible (the recall's denominator)
  int num_scored = 0;               ///< estimates in images where the object is annotated (TP, FP or ignored)
  double ap_mssd = 0, ap_mspd = 0;  ///< AP averaged over the thresholds, [0, 1]
  double ap_mssd_mm = 0;            ///< AP over the MSSD thresholds in mm
  double ap = 0;                    ///< mean(ap_mssd, ap_mspd); overall: bop24_mAP
  /// Interpolated precision at recall 0, 0.01, ..., 1 averaged over the MSSD and MSPD thresholds: the
  /// curve whose mean is `ap`.
  std::vector<double> precision_at_recall;
};

struct DetectionReport {
  std::map<int, DetectionScores> per_object;  ///< objects with at least one positive (others do not count)
  DetectionScores overall;                    ///< means over per_object: bop24_mAP(_mssd, _mspd)
  int num_ignored_beyond_max = 0;     ///< estimates beyond the best max_estimates_per_image of an image
  int num_ignored_object_absent = 0;  ///< estimates of objects not annotated in their image (not scored)
};

struct EvalReport {
  std::map<int, Scores> per_object;
  Scores overall;
  std::vector<InstanceResult> instances;
  int num_estimates = 0;              ///< rows read
  int num_estimates_evaluated = 0;    ///< kept among the k best of a target image and object
  int num_ignored_not_target = 0;     ///< estimates for images/objects that are not targets
  int num_ignored_beyond_top_k = 0;   ///< estimates beyond the k best-scored of their image and object
  int num_images_timed = 0;           ///< images with estimates (all with a time >= 0)
  double mean_time_per_image_s = -1;  ///< mean of the per-image times; -1 if any time is missing (< 0)
  bool vsd_computed = false;
  bool detection_computed = false;  ///< the dataset's targets are bop24 (images only): `detection` is set
  DetectionReport detection;
};

/// Progress: called after each evaluated image with (images done, images to do).
using Progress = std::function<void(int done, int total)>;

/// Evaluates estimates against the dataset's targets. `source` names the results (file path) in errors:
/// an unknown obj_id or inconsistent times within an image raise FileError "SOURCE:LINE: ...". A dataset
/// without targets raises FileError; a missing model or depth image raises FileError naming it.
EvalReport evaluate(const dataset::BopDataset& data, const std::vector<dataset::PoseEstimate>& estimates,
                    const EvalSettings& settings = {}, const std::string& source = "results",
                    const Progress& progress = {});

/// Human-readable table: one row per object and an "all" row (AUC and recalls in percent, time).
std::string format_report(const EvalReport& report);

/// The detection scores as a table (one row per object, the mean, bop24_mAP).
std::string format_detection(const DetectionReport& detection);

/// The report's curves as a PNG at `png_path`: with detection scores, interpolated precision against recall
/// (each curve's mean is its AP); else accuracy against the ADD(-S) threshold up to settings.auc_max_m (each
/// curve's area is its AUC). One line per object and a thick one for all. FileError if it cannot be written.
void plot_report(const EvalReport& report, const EvalSettings& settings, const std::string& png_path);

/// The report as JSON (settings echoed, per object, overall, per instance).
std::string report_json(const EvalReport& report, const EvalSettings& settings);

}  // namespace perch2::eval
