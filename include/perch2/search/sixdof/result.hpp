// What the 6-DoF search returns: a pose, score and cost per instance (SixDofPose), the counts and timings
// of every stage (SixDofResult, SixDofTimings), and for estimate_scene() the objects it looks for
// (SixDofObject) and what it placed and left missing (SixDofSceneResult).
#pragma once

#include <cstddef>
#include <optional>
#include <vector>

#include "perch2/core/pose.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/search/segmentation.hpp"

namespace perch2 {

struct SixDofPose {
  int instance = 0;  ///< index into the instances given
  int model = 0;
  Pose T_cam_obj = Pose::Identity();
  float score = 0;     ///< in [0, 1], higher is better (see the file comment)
  bool found = false;  ///< false: no hypothesis showed min_rendered_points (pose = the lowest cost anyway)
  CostBreakdown cost;
  /// Fraction of its visible surface whose pixel holds a reading within SceneSettings::explain_distance_m
  /// of it, in [0, 1] (0 if not found). detect()'s score is pose_score(cost) x depth_agreement x colour
  /// and evidence factors (sixdof_detail::detection_score).
  float depth_agreement = 0;
};

struct SixDofTimings {  ///< seconds, wall clock
  double observed = 0, proposals = 0, render = 0, refine = 0, cost = 0, select = 0, total = 0;
  double screen = 0;       ///< the screen before the first pass (its renders, ICP, costs also above)
  double first_pass = 0;   ///< the first pass over every proposal (its renders, GICP, costs also above)
  double second_pass = 0;  ///< the second pass and polish of the kept poses (also in render, refine, cost)
  double local = 0;        ///< the local search (its renders and costs are also in render and cost)
  double fit = 0;          ///< the final surface fit (its re-score's render and cost are in render and cost)
  double segment = 0;      ///< estimate_scene: the frame's segmentation (plane, components)
  double explain =
      0;  ///< estimate_scene: placing objects one by one (its renders and costs also in render, cost)
  double retrieve = 0;  ///< detect(): the retrieval's coarse search (its renders, GICP and costs only here)
};

struct SixDofResult {
  std::vector<SixDofPose> poses;            ///< one per instance, in input order
  std::vector<std::size_t> hypotheses;      ///< proposals per instance
  std::vector<std::size_t> rotations;       ///< rotation proposals per instance (after symmetry)
  std::vector<std::size_t> depths;          ///< proposal depths per instance
  std::vector<std::size_t> segment_points;  ///< observed points per instance after trimming
  std::vector<std::size_t> trimmed_pixels;  ///< mask pixels dropped by the depth-consistency trimming
  std::size_t hypotheses_total = 0, chunks = 0, chunk_hypotheses = 0;
  std::size_t second_pass_hypotheses = 0;  ///< hypotheses kept for the second pass (all instances)
  std::size_t local_candidates = 0;        ///< turned poses the local search rendered and scored
  std::size_t fits_kept = 0;               ///< instances whose final surface fit was kept (fit_cost_slack)
  /// First-pass hypotheses refined by GICP after the warm-up's de-duplication (hypotheses_total without it)
  std::size_t first_pass_distinct = 0;
  std::size_t proposals_screened_out = 0;  ///< proposals the screen kept from the first pass (ScreenSettings)
  /// Largest chunk's estimated working memory (its rendered points x bytes_per_point), bytes.
  std::size_t peak_chunk_bytes = 0;
  SixDofTimings timings;
};

/// An object estimate_scene() looks for: a model and how many instances of it the frame holds.
struct SixDofObject {
  int model = 0;
  int count = 1;
};

/// detect()'s limits: no model or count is given, so these bound what it may report.
struct DetectSettings {
  int max_per_model = 8;    ///< instances of one model at most per frame (>= 1)
  int max_per_frame = 100;  ///< detections at most per frame, the best scored (>= 1; BOP 2024 scores 100)
  /// A detection is reported only with at least this score (in [0, 1]). Tuning sets (generated seed 133,
  /// 12 images; 5 odd frames of lm_cat_dev, 20-model catalogue): at 0.2 no true detection lost, and of the
  /// detections of models not in the image 10 of 25 and 66 of 130 kept (all of them without the colour
  /// and evidence factors of the score); 0.3 lost 2 of 57 true ones.
  float min_score = 0.2f;
  /// The score's evidence factor n / (n + half_evidence_readings) for the n readings (observed grid) a
  /// pose explains (>= 0; 0 = no factor): true detections on the tuning sets explained 146-3156 readings,
  /// those of absent models a median of 90.
  float half_evidence_readings = 100.f;
  /// A detection whose model reaches more than this below the support plane (when one was found) is not
  /// reported: a printed box fitted by its top face onto a thin slab would stand inside the table, metres.
  float max_below_plane_m = 0.02f;
  /// Retrieval: on each segment only this many jobs (model, piece; models when ranked by colour) per object
  /// it may hold get the full search, those that fit it best, ties kept (>= 0; 0 = every job the size and
  /// colour screening let through). Tuned on generated decoy sets (32 models): seed 133 (12 images),
  /// with seed_depth, bop24_mAP 0.86 in 3.6 s per image with 2, 0.90 in 3.9 s with 3 (without seed_depth:
  /// 0.83 in 5.8 s with 2); seed 33 (4 images), ranked by colour with 8: 0.84 in 19 s.
  int retrieval_jobs_per_object = 3;
  /// The retrieval's ranking: a coarse search of every screened (model, segment) job with
  /// retrieval_viewpoints x retrieval_inplane_rotations rotations at one depth (the first pass; its best
  /// explanation's choice ranks: acceptable first, then the readings explained), or with
  /// retrieval_viewpoints = 0 the fraction of the segment's readings whose colours the model shows
  /// (cheaper, but a broad palette covers most segments: on a generated decoy set many models covered
  /// 100 %). 20 viewpoints ranked no better than 12 on the tuning set, at more time.
  int retrieval_viewpoints = 12;
  int retrieval_inplane_rotations = 2;  ///< see retrieval_viewpoints (>= 1)
  /// The coarse search's rotations of a job are first screened as the search's proposals are
  /// (SixDofSettings::screen: its stride, ICP passes and colour test) and only the best this many go on
  /// through the first pass (>= 0; 0 = all of them). Generated decoy sets (32 models, 12 images each,
  /// 2-vCPU AMD EPYC VM, with half_jobs off), bop24_mAP and s per image, all 24 -> the best 6: seed 241
  /// 0.769 -> 0.776, 242 0.749 -> 0.791, 243 0.785 -> 0.785, the retrieval's time a third less (1.8 ->
  /// 1.05 s per image on 242). With SceneSettings::half_jobs, 4 / 6 / 10 kept: mean mAP over 241-243
  /// 0.791 / 0.827 / 0.813.
  int retrieval_screen_keep = 6;
  /// Each viewpoint's in-plane rotations start where the model's projected long axis lies along the long
  /// axis of the job's pixels (aligned_rotation_proposals), not at 0: with two fixed in-plane angles an
  /// elongated object seen side-on (a lying bottle) may start up to 90 deg turned, too far for ICP, and its
  /// smaller same-print copy, cut into pieces that fit it, was retrieved instead (generated seed 147).
  /// Generated decoy sets (32 models, thrust_omp, Intel Xeon VM), bop24_mAP without -> with, same time:
  /// seed 147 (tuned on) 0.796 -> 0.844, seed 133 (tuned on) 0.904 -> 0.907, seed 47 0.991 -> 0.994, seed
  /// 241 (never tuned on) 0.741 -> 0.769; lm_cat_dev with a 17-model catalogue, odd frames 0.990 both, even
  /// 0.984 -> 0.974 (one frame's clutter explained by two more cats). Aligning every job (no elongation
  /// rule) lost round and partly hidden objects on seed 133 (0.904 -> 0.859).
  bool retrieval_align_inplane = true;
  /// ... for a job whose pixels are at least this many times as long as wide (>= 1): a round one has no
  /// long axis, and its in-plane angles stay as they are.
  float retrieval_align_min_elongation = 2.f;
  /// A job whose coarse best pose may not be placed (not acceptable: too few inliers or readings
  /// explained, colours it lacks) gets no full search. Tuning sets: generated seed 133 bop24_mAP 0.90 ->
  /// 0.89 (1 of 57 true detections lost), 4.2 -> 3.4 s per image; 5 odd lm_cat_dev frames 1.0 both, 26 ->
  /// 13 s per frame (the real table's clutter segments, explained by no model, are searched no more).
  bool retrieval_acceptable_only = true;
  /// A job the coarse search kept is searched at one depth, its coarse best pose's after GICP, instead of
  /// at up to ProposalSettings::max_depths over its readings' range: a third of the proposals, and GICP
  /// (cap 4 cm) closes the rest. Tuning set (seed 133, 3 jobs per object): bop24_mAP 0.90 in 3.9 s per image
  /// against 0.87 in 7.1 s at 3 depths; real frames (5 odd frames of lm_cat_dev): the same mAP (1.0), 23 s
  /// per frame instead of 37.
  bool seed_depth = true;
  /// A candidate is placed only if at most this fraction of its rendered points near readings show a
  /// colour none of those readings has (in [0, 1]; 1 = no test; the readings near its surface of colours
  /// it lacks are tested as in estimate_scene(), SceneSettings::max_colour_mismatch): where only its shape
  /// fits, a model is not placed. Generated frames: true poses 0-7 %, a can of another print on a plain box
  /// of the can's colours 24-33 %; real Kinect frames (half of lm_cat_dev) true poses 0-4 %. The readings'
  /// side is not tested this tightly: the real cat's reach 33 % (its neighbours' readings at its surface,
  /// the camera's colours), and 0.15 there lost 11 of 29 cats.
  float max_colour_mismatch = 0.15f;
};

/// estimate_scene()'s and detect()'s answer.
struct SixDofSceneResult {
  /// Placed instances, in placement order (detect(): best score first); SixDofPose::instance = index into
  /// the objects given (detect(): the model).
  std::vector<SixDofPose> poses;
  std::vector<int> missing;            ///< per object given: requested instances not placed (detect(): empty)
  std::vector<FrameSegment> segments;  ///< the frame's segments (largest first)
  std::vector<std::size_t> segment_points;  ///< per segment: its readings on the observed grid
  std::optional<TablePlane> plane;          ///< the support plane, if one was found
  std::size_t jobs = 0;                     ///< (model, segment or piece) searches, after screening
  /// detect(): jobs made on segment halves (SceneSettings::half_jobs), before screening
  std::size_t halves = 0;
  std::size_t screened_out = 0;  ///< jobs whose segment's colours the model lacks (min_colour_fraction)
  std::size_t retrieved_out =
      0;  ///< detect(): jobs outside a segment's best (DetectSettings::retrieval_jobs_per_object)
  std::size_t below_plane = 0;  ///< detect(): poses dropped for reaching below the support plane
  std::size_t candidates = 0;   ///< jobs whose best pose showed min_rendered_points
  std::size_t rounds = 0;       ///< scoring rounds of the explanation
  std::size_t refined = 0;      ///< candidates refined again after a neighbour took readings of their segment
  std::size_t reverted = 0;  ///< of those, how many kept their earlier pose (it explained the scene better)
  std::size_t residual_segments =
      0;  ///< segments of the readings left unexplained (SceneSettings::residual_pass)
  /// The search's counts per job (hypotheses, rotations, depths), segment_points per job group, totals
  /// and the timings of every stage (segment and explain included); its `poses` is empty.
  SixDofResult search;
};
}  // namespace perch2
