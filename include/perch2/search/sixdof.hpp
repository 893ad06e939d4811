// 6-DoF PERCH 2.0 (Section V, Fig. 4): the full pose of each detected instance (model, mask, box) in one
// RGB-D frame, by rendering mask-driven pose proposals, refining every one with GICP against its own
// instance's observed points, re-rendering and scoring them with the RGB-D explanation cost.
//
//   perch2::SixDofEstimator<perch2::cpu::Backend> estimator({{mesh, symmetries}, ...});
//   perch2::SixDofResult r = estimator.estimate(frame, {{model, mask, box_xywh}, ...});
//   for (const auto& p : r.poses) use(p.instance, p.model, p.T_cam_obj, p.score);
//
// Pipeline per frame (timed per stage in SixDofResult::timings):
//   observed   instance k's pixels carry label k + 1 (later instances win overlaps). Each segment is
//              trimmed for depth consistency: mask pixels whose depth lies outside the segment's robust
//              range [q_lo - trim_margin_m, min(q_hi + trim_margin_m, q_lo + diameter)] (a mask bleeding
//              onto the table behind or a neighbour in front) lose the label and count as background.
//              The labelled points on the observed stride grid are the per-instance segments (GICP
//              targets, J_o's points).
//   proposals  rotations (viewpoints x in-plane, symmetry de-duplicated) x depths on the box centre's ray
//              (perch2/search/proposals.hpp)
//   first pass, every proposal, in chunks (sized to memory_budget_bytes: 10x the proposals run in the same
//   memory, just slower):
//     render   at render.stride (8), occluders = observed depth with labels: only other instances' or
//              background pixels hide a hypothesis (its own label never does)
//     refine   GICP (ICP warm-up first: starts are up to half a proposal spacing off) against the
//              hypothesis' own segment
//              (dedupe_after_warmup, off by default: GICP only the distinct poses the warm-up reached)
//     cost     re-rendered at render.stride and scored with the RGB-D cost: a cheap ranking
//   keep       the best keep_per_instance distinct poses per instance (many proposals converge to one pose)
//   second pass, the kept hypotheses only:
//     refine   re-rendered at second_pass_stride (4), GICP with a tighter cap, so a badly trimmed mask's
//              remaining stray points cannot pull the converged pose
//     cost     re-rendered at score_stride; RGB-D cost (perch2/cost/cost.hpp) with J_o over the whole
//              segment of the instance (volume -1)
//   local search, the best local.candidates_per_instance acceptable hypotheses of each instance (3):
//              coarse-to-fine hill climbing over turns about the model's own axes, scored with the
//              nearest-neighbour colour test (LocalSearchSettings): recovers the turn of a printed can
//              or bottle about its axis, which GICP cannot see
//              then one more tight GICP pass (polish) and a re-render
//   select     the lowest final cost per instance at the searched poses (acceptable first)
//   fit        the selected pose of each instance fitted onto its observed points at full resolution
//              (fit_stride): robust point-to-surface, observed -> model
//              (perch2/registration/surface_fit.hpp), re-scored there and kept unless the final cost rose
//              (fit_cost_slack)
//   score      1 - (rendered outliers + unexplained observed points) / (rendered + observed points), in
//              [0, 1]: the fraction of both clouds that the pose explains (BOP's score column)
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/observed.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/cost/appearance.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/registration/registration.hpp"
#include "perch2/registration/surface_fit.hpp"
#include "perch2/render/render.hpp"
#include "perch2/search/local_search.hpp"
#include "perch2/search/proposals.hpp"
#include "perch2/search/segmentation.hpp"

namespace perch2 {

/// A model the 6-DoF search can pose: the mesh (metres, BOP frame: origin at the bounding-box centre) and
/// its symmetries (models_info.json).
struct SixDofModel {
  Mesh mesh;
  ModelSymmetries symmetries;
};

/// One detected instance: which model, its mask (non-zero = the instance, full resolution) and its box
/// (x, y, w, h in pixels; "full"/amodal or visible). A box with w or h < 0 is taken from the mask.
struct SixDofInstance {
  int model = 0;
  Image<std::uint8_t> mask;
  Eigen::Vector4i box_xywh{-1, -1, -1, -1};
};

/// The local search after the second pass (see the file comment and perch2/search/local_search.hpp). GICP
/// cannot see what its geometry does not show: a printed can or bottle turned about its axis, or a box
/// turned to show its back, fits the depth equally well, so its turn stays whatever the proposal had and
/// the final cost's colour test (ColorRule::AnyNeighbour, tolerant by design) barely tells the turns apart.
/// Here each of the best few poses of an instance is turned about its model's x, y and z axes (through the
/// model origin): the turns whose depth-only cost (J_r + J_o as fractions, the final cost's delta) stays
/// within turns.geometry_tolerance are the look-alikes, and among them the print decides, by the
/// correlation of rendered and observed colours (perch2/cost/appearance.hpp), which a change of lighting
/// or of the camera's colour pipeline does not move. A pose the geometry fixes, or an untextured one,
/// keeps its pose.
struct LocalSearchSettings {
  /// The best hypotheses (by the final cost) of each instance that are searched around (then the winner is
  /// chosen by the final cost at the moved poses). 0 turns the stage off (the final cost's best is selected).
  int candidates_per_instance = 1;
  /// Sweep, climb and final comparison (local_search.hpp), without shifts in the climb: the polish below
  /// fixes the position (on bench_sixdof, ADD(-S) AUC 97.1 without, 96.4 with 1 mm shifts, GT masks).
  TurnSearchSettings turns = [] {
    TurnSearchSettings t;
    t.climb_shift_m = 0.f;
    return t;
  }();
  /// The searched poses get one more GICP pass (second_pass_* settings) at second_pass_stride: it restores
  /// any tilt the turns brought while it cannot undo a turn about a symmetry axis it does not see.
  bool polish = true;
};

/// estimate_scene() (no detector): the frame's segments (perch2/search/segmentation.hpp), a search of every
/// requested model on every segment of a compatible size, then the scene explained object by object.
///   jobs     model m on segment k unless k's area is below min_area_fraction x m's smallest bounding-box
///            face (it cannot show m) or above max_area_faces x m's largest face (a wall, a shelf side);
///            around k's box, or, if k is wider than piece_extent_factor x m's size or shows more than
///            piece_area_faces x m's largest face (two objects touching, a distractor on top of one),
///            around each of ceil(area / m's largest face) pieces of it (at least 2) (k-means on its
///            readings, at most max_pieces); a job whose readings' colours its model lacks is dropped
///            (min_colour_fraction)
///   search   per job: proposals, both passes and the local search as estimate(), GICP against its piece
///            or its segment (with the nearby small segments an occluder may have cut from it)
///   explain  every job's best pose is a candidate; each round scores all candidates against the readings
///            still unexplained (placed objects' readings hide what is behind them and explain nothing
///            more) and places, among the acceptable ones (at least min_inlier_fraction of its rendered
///            points explained by the RGB-D test, min_explained_points readings of its own, at most
///            max_colour_mismatch of the readings at its surface of colours it lacks), the one
///            that explains most readings; its readings within explain_distance_m of its full-resolution
///            render become its own, and the candidates it took readings from are refined again
///            (refine_after_placing; a refined pose that explains fewer readings, or is no longer
///            acceptable, is undone). Until every requested instance is placed or none is acceptable.
///   residual the readings still unexplained, segmented again; jobs, search and explanation as above for
///            the instances still missing (residual_pass); the rest is missing.
///   fit      each placed object's final cost and surface fit on its own readings, as estimate()'s.
struct SceneSettings {
  SegmentationSettings segmentation;
  /// See above (a mostly hidden object shows little). On bench_sixdof --masks none (20 scenes): 0.15 gave
  /// ADD-S / ADD(-S) AUC 92.8 / 85.9, 0.1 97.1 / 89.1 (a bowl under a box, cans and a block behind others
  /// found: with residual_pass their leftover readings are what a mask would show), 6 % more hypotheses.
  float min_area_fraction = 0.1f;
  float max_area_faces = 10.f;       ///< see above
  float piece_extent_factor = 1.4f;  ///< see above
  /// See above. On bench_sixdof --masks none (20 scenes, before residual_pass and min_area_fraction 0.1):
  /// the extent rule alone ADD-S / ADD(-S) AUC 89.8 / 83.1; with 1.0 91.8 / 85.0 (a lying bottle beside a
  /// distractor can, a block under one, found), 7,800 hypotheses instead of 7,000; 0.7 91.8 / 85.7 with
  /// 8,600.
  float piece_area_faces = 1.f;
  int max_pieces = 6;           ///< see above (>= 1)
  int min_segment_points = 20;  ///< segments with fewer observed points (observed grid) get no job
  /// See above, in [0, 1]. On bench_sixdof --masks none (20 scenes): 0.7 gave ADD-S / ADD(-S) AUC
  /// 87.0 / 81.8, 0.55 89.0 / 83.4 (two partly hidden objects found, none placed on a distractor), 0.4
  /// 89.8 / 83.4 (one more can placed, 2-10 cm off).
  float min_inlier_fraction = 0.55f;
  int min_explained_points = 15;  ///< see above (observed grid)
  /// And at most this fraction, in [0, 1], of the observed readings within delta of its rendered surface
  /// may fail the colour test (RGB-D cost only): a can placed on a purple ball of its size explains most
  /// of what it renders (the colour test asks one matching neighbour per rendered point), but most of the
  /// ball's readings next to it have colours it does not show. On bench_sixdof --masks none (20 scenes) the
  /// placed objects reached at most 0.29, the cherry can taken for a ball 0.60 (with 0.5: ADD-S / ADD(-S)
  /// AUC 97.1 / 89.1 -> 98.0 / 89.4, the can then found where it is); on the 29 real LINEMOD-cat frames
  /// at most 0.32 (0.3 lost two cats).
  float max_colour_mismatch = 0.5f;
  float explain_distance_m = 0.01f;  ///< see above, metres
  /// Colour screening, before any job is searched: a job goes on only if at least this fraction of its
  /// segment's (piece's) readings have a colour its model shows somewhere (CIEDE2000 within the cost's
  /// tau_c, on the cost's comparison colours): a segment of other colours cannot be this model whatever
  /// its pose, so its proposals are never rendered. Loose on purpose: the part of a segment a touching
  /// neighbour or an unmodelled object holds does not match, and the RGB-D cost decides among the jobs
  /// that pass. 0 (or a depth-only cost) = every job is searched.
  float min_colour_fraction = 0.3f;
  int colour_samples = 256;  ///< readings per job the screening tests, evenly spread (>= 1)
  /// After the explanation, the readings of the segments that no placed object explains are segmented
  /// again (the same components and size rule) and the instances still missing are searched for on these
  /// residual segments and placed the same way: an object that shared its segment with a placed
  /// neighbour (behind it, under it) is then searched for on its own readings, as with a mask. On
  /// bench_sixdof --masks none (20 scenes): without it ADD-S / ADD(-S) AUC 94.1 / 86.3, with it 97.1 / 89.1.
  bool residual_pass = true;
  /// After an object is placed, the candidates whose segments lost readings to it are refined again (both
  /// GICP passes) against the readings still unexplained: a touching neighbour's readings pulled them.
  /// The earlier pose is kept where it explains the scene better (about half the time: GICP on what is
  /// left of a segment can slide onto a distractor). On bench_sixdof --masks none (20 scenes, thrust_omp)
  /// keeping the better pose gave ADD-S / ADD(-S) AUC 89.0 / 83.0 -> 89.8 / 83.1.
  bool refine_after_placing = true;
  /// The local search (SixDofSettings::local) runs only for the candidate about to be placed, from its
  /// job's best hypotheses, instead of for every job: it turns a pose about its axes (a printed label's
  /// turn), which rarely changes which candidate explains the most, and most jobs are never placed.
  bool local_search_placed_only = true;
};

struct SixDofSettings {
  ProposalSettings proposals;  ///< 40 viewpoints x 4 in-plane x <= 3 depths every 0.02 m (proposals.hpp)
  ObservedCloudSettings observed{2};  ///< observed points (GICP targets, J_o) on this stride grid
  /// Renders of the first (coarse) pass, which every proposal goes through: stride 8 at 640 x 480 as the
  /// authors' (~100 points on a 10 cm object at 0.8 m, enough to pull a start 2-4 cm off onto the
  /// object; GICP's time is about proportional to the points). The second pass refines at
  /// second_pass_stride.
  RenderSettings render = [] {
    RenderSettings r;
    r.stride = 8;
    return r;
  }();
  /// An instance whose segment would show fewer than this many points at render.stride (estimated from
  /// its observed points: segment x (observed.stride / stride)^2) has its first pass at half the stride,
  /// down to second_pass_stride: a mostly hidden object keeps enough points for GICP and the ranking.
  int first_pass_min_points = 40;
  /// The first pass' GICP targets (and its ICP warm-up's): each segment's observed points on this coarser
  /// pixel grid (>= 1; <= observed.stride = all of them). A segment that would keep fewer than
  /// kFirstPassMinTargets keeps all. The first pass only has to bring a proposal into its basin, and GICP's
  /// time is in the nearest-neighbour searches and target covariances. 4, measured side by side on
  /// bench_sixdof (thrust_omp, Intel Xeon, 2 cores; ADD-S / ADD(-S) AUC) against 2: --masks none 98.1 /
  /// 90.0 -> 98.2 / 90.0 at 4.95 -> 4.21 s per image; gt 99.2 / 92.5 -> 99.1 / 93.6 and det 95.0 / 90.0 ->
  /// 95.1 / 88.3 (two printed objects turned the other way about their axis) at 1.44 -> 1.23 s per scene;
  /// the real LINEMOD-cat frames AR 0.941 both (--masks none, 2.04 -> 1.82 s per image), 0.958 both (GT
  /// masks), 0.916 -> 0.921 (degraded masks).
  int first_pass_target_stride = 4;
  static constexpr std::size_t kFirstPassMinTargets = 100;
  /// After the first pass every hypothesis is re-rendered at its stride and scored with first_pass_cost (a
  /// cheap ranking); only the best keep_per_instance distinct poses of each instance go on to the second
  /// pass, the re-render at score_stride and the final cost (0 = all; an instance whose first pass ran on a
  /// finer grid, see first_pass_min_points, keeps all its distinct poses). Many proposals converge to the
  /// same pose: two poses are distinct unless their translations differ by less than distinct_translation_m
  /// and their rotations (under the model's symmetries) by less than distinct_rotation_rad. 6 (was 12),
  /// measured side by side on bench_sixdof (thrust_omp, ADD-S / ADD(-S) AUC): ground-truth masks
  /// 99.2 / 92.4 -> 99.2 / 92.5, 3 % less time; degraded detections 95.0 / 89.9 -> 95.0 / 90.0; --masks
  /// none 98.0 / 89.4 -> 98.1 / 90.0 at 5.5 -> 5.2 s per image; the real LINEMOD-cat frames the same (GT
  /// masks AR 0.958 both; --masks none 0.939 -> 0.941). 4 lost ADD-S without masks (96.3).
  int keep_per_instance = 6;
  float distinct_translation_m = 0.005f;  ///< metres
  float distinct_rotation_rad = 0.1f;     ///< radians (~6 deg)
  /// First pass: after the ICP warm-up (gicp.icp_warmup_iterations > 0), hypotheses that reached the same
  /// pose as an earlier one of their instance (distinct_* above) are dropped and the rest re-rendered
  /// there before GICP: proposals a spacing apart often fall into one basin, and GICP, the re-render and
  /// the cost then run once for it. Off by default: on bench_sixdof's 20 scenes (ground-truth masks) it
  /// saved 13% CPU time but lost ADD(-S) AUC (93.6 -> 90.9): the first of a basin's hypotheses is kept,
  /// not the one whose GICP would end best.
  bool dedupe_after_warmup = false;
  /// Stride of the second pass's render (>= 1): 4 at 640 x 480 keeps ~300-500 points on a YCB-sized object
  /// at 0.8 m for the final, tighter refinement.
  int second_pass_stride = 4;
  /// Stride of the re-render that is scored (>= 1). 4 at 640 x 480: on two generated 640 x 480 scenes
  /// (9 instances) every pose had the same ADD-S (< 3 mm) as with stride 2, at a third of the cost time.
  int score_stride = 4;
  /// First refinement: ICP warm-up then GICP. The cap covers the proposal error: a viewpoint/in-plane step
  /// of ~23-90 deg moves a 10 cm object's points by up to ~4 cm, and the depth step by up to 1 cm.
  /// 8 warm-up + 12 GICP passes: on bench_sixdof's 20 scenes (ground-truth masks, run side by side) 22%
  /// less CPU time than 15 + 20 at ADD-S AUC 98.6 vs 98.5, ADD(-S) AUC 92.6 vs 93.9, ADD-S < 2 cm 100% both
  /// (the first pass only ranks; the second pass and the local search finish the pose).
  GicpSettings gicp = [] {
    GicpSettings s;
    s.max_correspondence_distance_m = 0.04f;
    s.max_iterations = 12;
    s.icp_warmup_iterations = 8;
    return s;
  }();
  /// Second refinement (after a re-render at the refined pose) with this tighter cap, metres; 0 = none.
  float second_pass_cap_m = 0.012f;
  int second_pass_iterations = 15;  ///< GICP passes of the second refinement (>= 1)
  /// The final cost (second pass, at score_stride), which selects the pose.
  CostSettings cost = [] {
    CostSettings c;
    c.delta_m = 0.01f;  // authors' 6-DoF delta
    return c;
  }();
  /// The first pass' cheap ranking cost (at the first pass' stride).
  CostSettings first_pass_cost = [] {
    CostSettings c;
    c.delta_m = 0.01f;
    return c;
  }();
  /// Depth-consistency trimming (see the file comment): quantiles of the mask's depths and the margin.
  float trim_quantile_low = 0.1f, trim_quantile_high = 0.9f;
  float trim_margin_m = 0.03f;   ///< metres; < 0 turns trimming off
  int min_rendered_points = 10;  ///< a hypothesis showing fewer points (at score_stride) is not selected
  LocalSearchSettings local;     ///< after the second pass: turns about the model's axes (see above)
  SceneSettings scene;           ///< estimate_scene() only: segments, jobs and the scene explanation
  /// The last step (file comment, "fit"): the selected pose's robust fit onto the instance's observed
  /// points on the fit_stride grid (fit.iterations = 0: off). The rest of the search works on stride
  /// 2-8 grids and rendered clouds, whose sampling and silhouettes leave the pose a few millimetres off;
  /// every reading of the object constrains this fit. On the 29 real Kinect frames of the LINEMOD cat
  /// (ground-truth masks) it took the mean ADD from 3.6 to 3.0 mm and BOP AR from 0.938 to 0.958.
  SurfaceFitSettings fit;
  int fit_stride = 1;  ///< observed pixels of the fit on this grid (>= 1; 1 = every reading)
  /// Model surface samples of the fit about this far apart, metres (> 0). Read when the estimator is built.
  float fit_sample_spacing_m = 0.0015f;
  /// The fitted pose is kept only if its final cost (SixDofSettings::cost at score_stride) is at most the
  /// selected pose's plus this fraction of the points that cost counts (>= 0). The fit pulls every reading
  /// onto the model but nothing pulls the model onto the readings: with one face of a block in view it may
  /// slide along the face while the readings stay on it, and the cost's rendered-point term sees that.
  float fit_cost_slack = 0.01f;
  /// Working memory of the hypotheses in flight (rendered, refined and scored clouds and the registration's
  /// per-point state), bytes; the hypotheses are processed in chunks that fit (at least one hypothesis per
  /// chunk). The renderer's own working memory is RenderSettings::memory_budget_bytes.
  std::size_t memory_budget_bytes = std::size_t(256) << 20;
  /// Estimated bytes per rendered point in flight (clouds x3 renders, GICP covariances and correspondences).
  std::size_t bytes_per_point = 256;
};

struct SixDofPose {
  int instance = 0;  ///< index into the instances given
  int model = 0;
  Pose T_cam_obj = Pose::Identity();
  float score = 0;     ///< in [0, 1], higher is better (see the file comment)
  bool found = false;  ///< false: no hypothesis showed min_rendered_points (pose = the lowest cost anyway)
  CostBreakdown cost;
};

struct SixDofTimings {  ///< seconds, wall clock
  double observed = 0, proposals = 0, render = 0, refine = 0, cost = 0, select = 0, total = 0;
  double local = 0;    ///< the local search (its renders and costs are also in render and cost)
  double fit = 0;      ///< the final surface fit (its re-score's render and cost are in render and cost)
  double segment = 0;  ///< estimate_scene: the frame's segmentation (plane, components)
  double explain =
      0;  ///< estimate_scene: placing objects one by one (its renders and costs also in render, cost)
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
  /// Largest chunk's estimated working memory (its rendered points x bytes_per_point), bytes.
  std::size_t peak_chunk_bytes = 0;
  SixDofTimings timings;
};

/// An object estimate_scene() looks for: a model and how many instances of it the frame holds.
struct SixDofObject {
  int model = 0;
  int count = 1;
};

/// estimate_scene()'s answer.
struct SixDofSceneResult {
  /// Placed instances, in placement order; SixDofPose::instance = index into the objects given.
  std::vector<SixDofPose> poses;
  std::vector<int> missing;                 ///< per object given: requested instances not placed
  std::vector<FrameSegment> segments;       ///< the frame's segments (largest first)
  std::vector<std::size_t> segment_points;  ///< per segment: its readings on the observed grid
  std::optional<TablePlane> plane;          ///< the support plane, if one was found
  std::size_t jobs = 0;                     ///< (model, segment or piece) searches, after screening
  std::size_t screened_out = 0;  ///< jobs whose segment's colours the model lacks (min_colour_fraction)
  std::size_t candidates = 0;    ///< jobs whose best pose showed min_rendered_points
  std::size_t rounds = 0;        ///< scoring rounds of the explanation
  std::size_t refined = 0;   ///< candidates refined again after a neighbour took readings of their segment
  std::size_t reverted = 0;  ///< of those, how many kept their earlier pose (it explained the scene better)
  std::size_t residual_segments =
      0;  ///< segments of the readings left unexplained (SceneSettings::residual_pass)
  /// The search's counts per job (hypotheses, rotations, depths), segment_points per job group, totals
  /// and the timings of every stage (segment and explain included); its `poses` is empty.
  SixDofResult search;
};

namespace sixdof_detail {

using Clock = std::chrono::steady_clock;
inline double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

/// Bounding box (x, y, w = x_max - x_min, h) of a mask's non-zero pixels; w = -1 if none.
inline Eigen::Vector4i mask_box(const Image<std::uint8_t>& mask) {
  const std::array<int, 4> b = mask_bbox(mask);
  return {b[0], b[1], b[2], b[3]};
}

/// A model's colours (packed sRGB), one per bin of 6 bits per channel: its vertex colours, its texture's
/// texels (at most ~65k of them, evenly spread) or its base colour.
inline std::vector<std::uint32_t> model_colours(const Mesh& m) {
  std::vector<std::uint8_t> seen(std::size_t(1) << 18, 0);
  std::vector<std::uint32_t> out;
  auto add = [&](Rgb8 c) {
    const std::size_t bin = std::size_t(c.r >> 2) << 12 | std::size_t(c.g >> 2) << 6 | std::size_t(c.b >> 2);
    if (!seen[bin]) seen[bin] = 1, out.push_back(pack_rgb(c));
  };
  if (m.has_vertex_colors()) {
    for (const Rgb8 c : m.vertex_colors) add(c);
  } else if (m.has_texture()) {
    const int w = m.texture.width, h = m.texture.height;
    const int step = std::max(1, int(std::ceil(std::sqrt(double(w) * double(h) / 65536.0))));
    for (int v = 0; v < h; v += step)
      for (int u = 0; u < w; u += step) add(m.texture(u, v));
  } else {
    add(m.base_color);
  }
  return out;
}

inline float model_diameter_bound(const Mesh& m) {
  float r = 0;
  for (const auto& p : m.vertices) r = std::max(r, p.norm());
  return 2.f * r;  // >= the diameter; exact for a model symmetric about its centre
}

/// Moves every point of cloud c by T[c].
inline void transform_clouds(CloudBatch& b, const std::vector<Pose>& T) {
  for (std::size_t c = 0; c < b.num_clouds(); ++c)
    for (auto i = b.offsets[c]; i < b.offsets[c + 1]; ++i) {
      const Eigen::Vector3f p = T[c] * Eigen::Vector3f(b.x[i], b.y[i], b.z[i]);
      b.x[i] = p.x(), b.y[i] = p.y(), b.z[i] = p.z();
    }
}

/// Segment `seg`'s pixels split into `pieces` parts by k-means on their camera-frame points (k-means++
/// seeding with a fixed seed, so results are deterministic); one mask (full resolution) per part.
inline std::vector<Image<std::uint8_t>> segment_pieces(const RgbdFrame& frame, const LabelImage& labels,
                                                       const FrameSegment& seg, int pieces) {
  const int w = frame.camera.width;
  std::vector<std::size_t> pix;
  std::vector<Eigen::Vector3f> pts;
  const Eigen::Vector4i& b = seg.box_xywh;
  for (int v = b[1]; v <= b[1] + b[3]; ++v)
    for (int u = b[0]; u <= b[0] + b[2]; ++u) {
      const std::size_t i = std::size_t(v) * std::size_t(w) + std::size_t(u);
      if (labels.data[i] != seg.label) continue;
      pix.push_back(i);
      pts.push_back(segmentation_detail::point_at(frame.camera, u, v, frame.depth_m.data[i]));
    }
  std::vector<Image<std::uint8_t>> out;
  if (pieces <= 1 || pts.size() < std::size_t(pieces)) {
    out.emplace_back(labels.width, labels.height, 0);
    for (const std::size_t i : pix) out.back().data[i] = 1;
    return out;
  }
  std::mt19937 rng(7);
  std::vector<Eigen::Vector3f> centre{
      pts[std::uniform_int_distribution<std::size_t>(0, pts.size() - 1)(rng)]};
  std::vector<float> d2(pts.size(), INFINITY);
  while (int(centre.size()) < pieces) {  // k-means++: the next centre with probability ~ squared distance
    double total = 0;
    for (std::size_t i = 0; i < pts.size(); ++i)
      total += d2[i] = std::min(d2[i], (pts[i] - centre.back()).squaredNorm());
    double r = std::uniform_real_distribution<double>(0, total)(rng);
    std::size_t pick = 0;
    while (pick + 1 < pts.size() && (r -= d2[pick]) > 0) ++pick;
    centre.push_back(pts[pick]);
  }
  std::vector<int> owner(pts.size(), 0);
  for (int it = 0; it < 10; ++it) {
    std::vector<Eigen::Vector3f> sum(centre.size(), Eigen::Vector3f::Zero());
    std::vector<int> n(centre.size(), 0);
    for (std::size_t i = 0; i < pts.size(); ++i) {
      float best = INFINITY;
      for (std::size_t c = 0; c < centre.size(); ++c)
        if (const float d = (pts[i] - centre[c]).squaredNorm(); d < best) best = d, owner[i] = int(c);
      sum[std::size_t(owner[i])] += pts[i], ++n[std::size_t(owner[i])];
    }
    for (std::size_t c = 0; c < centre.size(); ++c)
      if (n[c] > 0) centre[c] = sum[c] / float(n[c]);
  }
  out.assign(centre.size(), Image<std::uint8_t>(labels.width, labels.height, 0));
  for (std::size_t i = 0; i < pix.size(); ++i) out[std::size_t(owner[i])].data[pix[i]] = 1;
  return out;
}
}  // namespace sixdof_detail

template <class Backend>
class SixDofEstimator {
 public:
  /// Validates the models and uploads them to the backend's renderer. Throws InvalidInput on no models or a
  /// bad mesh.
  explicit SixDofEstimator(std::vector<SixDofModel> models, SixDofSettings settings = {})
      : models_(std::move(models)),
        settings_(std::move(settings)),
        renderer_(meshes_of(models_)),
        surface_fit_(meshes_of(models_), settings_.fit_sample_spacing_m) {
    for (const auto& m : models_) {
      diameter_.push_back(sixdof_detail::model_diameter_bound(m.mesh));
      Eigen::Vector3f e = m.mesh.bounds().sizes();
      std::sort(e.data(), e.data() + 3);
      size_m_.push_back(e.norm());
      face_m2_.emplace_back(e[0] * e[1], e[1] * e[2]);
      colours_.push_back(sixdof_detail::model_colours(m.mesh));
    }
  }

  const SixDofSettings& settings() const { return settings_; }
  SixDofSettings& settings() { return settings_; }
  const std::vector<SixDofModel>& models() const { return models_; }

  /// The pose of every instance. Throws InvalidInput on a malformed frame, missing colour for the RGB-D
  /// cost, no instances, an unknown model, a mask of the wrong size, an empty mask or one without valid
  /// depth, and bad settings.
  SixDofResult estimate(const RgbdFrame& frame, const std::vector<SixDofInstance>& instances) const {
    using namespace sixdof_detail;
    const auto t_start = Clock::now();
    validate(frame, instances);
    const SixDofSettings& s = settings_;
    SixDofResult result;
    const std::size_t K = instances.size();

    // ---- observed: labels, trimming, segments
    auto t = Clock::now();
    LabelImage labels(frame.camera.width, frame.camera.height, 0);
    for (std::size_t k = 0; k < K; ++k)
      for (std::size_t i = 0; i < labels.data.size(); ++i)
        if (instances[k].mask.data[i]) labels.data[i] = std::int32_t(k + 1);
    std::vector<std::int32_t> segment_labels;
    for (std::size_t k = 0; k < K; ++k) {
      result.trimmed_pixels.push_back(trim(frame.depth_m, labels, std::int32_t(k + 1), instances[k]));
      segment_labels.push_back(std::int32_t(k + 1));
    }
    const CloudBatch observed = observed_segments(frame, labels, segment_labels, s.observed);
    for (std::size_t k = 0; k < K; ++k) {
      result.segment_points.push_back(observed.cloud_size(k));
      if (observed.cloud_size(k) == 0)
        throw InvalidInput("instances[" + std::to_string(k) + "]",
                           "has no observed point on the stride-" + std::to_string(s.observed.stride) +
                               " grid (mask too small or without depth there)");
    }
    const typename Backend::Registration registration(observed);
    const auto first_pass_registration = first_pass_targets(frame, observed);
    const typename Backend::Cost cost(observed);
    const Occluders occluders{frame.depth_m, labels};
    result.timings.observed = seconds_since(t);

    // ---- one job per instance: its model's proposals around its box, refined against its own segment
    t = Clock::now();
    std::vector<Job> jobs;
    for (std::size_t k = 0; k < K; ++k) {
      const SixDofInstance& in = instances[k];
      Image<std::uint8_t> trimmed(labels.width, labels.height, 0);  // the mask after trimming
      for (std::size_t i = 0; i < labels.data.size(); ++i) trimmed.data[i] = labels.data[i] == int(k + 1);
      Job job;
      job.model = in.model, job.segment = std::int32_t(k), job.label = std::int32_t(k + 1);
      job.depths = proposal_depths(frame.depth_m, trimmed, models_[std::size_t(in.model)].mesh, s.proposals,
                                   "instances[" + std::to_string(k) + "] mask");
      job.box_xywh = in.box_xywh;
      if (job.box_xywh[2] < 0 || job.box_xywh[3] < 0) job.box_xywh = mask_box(in.mask);
      jobs.push_back(std::move(job));
    }
    result.timings.proposals = seconds_since(t);
    std::vector<std::int32_t> job_cloud(K), job_label(K);
    for (std::size_t k = 0; k < K; ++k) job_cloud[k] = std::int32_t(k), job_label[k] = std::int32_t(k + 1);
    const Context ctx{frame, occluders, &registration, or_same(first_pass_registration, registration),
                      cost,  job_cloud, job_label,     job_cloud};
    std::vector<std::size_t> points_estimate;  // per job: rendered points bound for the chunk size
    const std::vector<Finalist> finalists = search(ctx, jobs, result.segment_points, points_estimate, result);

    t = Clock::now();
    std::vector<SixDofPose> best(K);
    for (std::size_t k = 0; k < K; ++k) {
      best[k].instance = int(k), best[k].model = instances[k].model;
      best[k].T_cam_obj = finalists[k].hypothesis.T_cam_obj;
      best[k].found = finalists[k].cost.rendered_points >= s.min_rendered_points;
      best[k].cost = finalists[k].cost;
    }
    result.timings.select += seconds_since(t);
    if (s.fit.iterations > 0) {
      t = Clock::now();
      fit_poses(ctx, labels, points_estimate, best, result);
      result.timings.fit += seconds_since(t);
    }
    for (auto& p : best) p.score = pose_score(p.cost);
    result.poses = std::move(best);
    result.timings.total = seconds_since(t_start);
    return result;
  }

  /// The poses of the requested objects in an unsegmented frame (no detector): `objects` says which
  /// models and how many instances of each (BOP's targets give exactly that). See SceneSettings for the
  /// stages. Every placed instance is a pose in SixDofSceneResult::poses; an instance that no acceptable
  /// candidate explains is counted in `missing`, never placed on a distractor to fill the count. Throws
  /// InvalidInput on a malformed frame, missing colour for the RGB-D cost, an unknown model, a negative
  /// count and bad settings.
  SixDofSceneResult estimate_scene(const RgbdFrame& frame, const std::vector<SixDofObject>& objects) const {
    using namespace sixdof_detail;
    const auto t_start = Clock::now();
    validate_scene(frame, objects);
    const SceneSettings& ss = settings_.scene;
    SixDofSceneResult out;
    SixDofResult& result = out.search;
    SceneState scene;
    scene.object_of_model.assign(models_.size(), -1);
    for (std::size_t i = 0; i < objects.size(); ++i) {
      scene.remaining.push_back(objects[i].count), scene.model_of_object.push_back(objects[i].model);
      if (objects[i].count > 0) scene.object_of_model[std::size_t(objects[i].model)] = int(i);
    }
    out.missing = scene.remaining;

    // ---- segment: support plane, connected components, size rule
    auto t = Clock::now();
    float smallest_face = INFINITY;
    for (const auto& o : objects)
      if (o.count > 0) smallest_face = std::min(smallest_face, face_m2_[std::size_t(o.model)].first);
    if (!std::isfinite(smallest_face)) return finish(out, t_start);  // nothing requested
    const FrameSegments segments = segment_frame(frame, ss.segmentation, smallest_face);
    out.segments = segments.segments;
    out.plane = segments.plane;
    result.timings.segment = seconds_since(t);
    if (segments.segments.empty()) return finish(out, t_start);
    scene.labels = segments.labels;
    scene.segments = segments.segments.size();
    out.segment_points = explain_segments(frame, segments, scene, out);

    // ---- the readings left unexplained, segmented again, for the instances still missing
    if (ss.residual_pass && !scene.placed.empty() &&
        std::any_of(scene.remaining.begin(), scene.remaining.end(), [](int r) { return r > 0; })) {
      t = Clock::now();
      const FrameSegments residual = residual_segments(frame, scene, smallest_face);
      result.timings.segment += seconds_since(t);
      out.residual_segments = residual.segments.size();
      if (!residual.segments.empty()) explain_segments(frame, residual, scene, out);
    }

    // ---- the placed objects on their own readings: final cost, surface fit, score
    fit_placed(frame, scene, out);
    out.missing = scene.remaining;
    return finish(out, t_start);
  }

 private:
  /// One search of the pipeline: a model's proposals (rotations x depths on the ray through the box centre)
  /// refined against one observed segment. estimate(): one per instance; estimate_scene(): one per
  /// (model, segment or piece of one).
  struct Job {
    int model = 0;
    std::int32_t segment = 0;  ///< observed cloud of the cost (J_o's points; in estimate() GICP's too)
    std::int32_t target = 0;   ///< observed cloud of GICP's targets
    std::int32_t label = 0;    ///< the label of its own pixels in the occluders (they never hide it)
    std::vector<std::int32_t> piece_pixels;  ///< estimate_scene, a piece of a segment: its pixels (targets)
    Eigen::Vector4i box_xywh{0, 0, 0, 0};
    std::vector<float> depths;  ///< proposal depths, metres
  };

  /// A job's selected hypothesis (label = job + 1) and its final cost; with the local search deferred
  /// (search()'s defer_local), also the job's best hypotheses it would have searched around, best first.
  struct Finalist {
    Hypothesis hypothesis;
    CostBreakdown cost;
    std::vector<Hypothesis> local_starts;
  };

  /// What the passes over one frame share: the frame, its occluders, the observed segments (GICP targets,
  /// J_o's points) and the segment each job's hypotheses explain (Hypothesis::label = job + 1).
  struct Context {
    const RgbdFrame& frame;
    const Occluders& occ;
    const typename Backend::Registration* registration;  ///< null where nothing is refined
    /// The first pass' targets (SixDofSettings::first_pass_target_stride); may be `registration`.
    const typename Backend::Registration* first_pass_registration;
    const typename Backend::Cost& cost;
    const std::vector<std::int32_t>& job_cloud;   ///< per job: its cost's observed cloud (J_o)
    const std::vector<std::int32_t>& job_label;   ///< per job: the label of its own pixels (never hide it)
    const std::vector<std::int32_t>& job_target;  ///< per job: its registration cloud (GICP targets)
    std::int32_t segment_of(const Hypothesis& h) const { return job_cloud[std::size_t(h.label - 1)]; }
    std::int32_t target_of(const Hypothesis& h) const { return job_target[std::size_t(h.label - 1)]; }
    std::int32_t label_of(const Hypothesis& h) const { return job_label[std::size_t(h.label - 1)]; }
    CostRequest request(const std::vector<Hypothesis>& hyps) const {
      CostRequest r;
      for (const auto& h : hyps) r.add(segment_of(h));
      return r;
    }
  };

  static std::vector<Mesh> meshes_of(const std::vector<SixDofModel>& models) {
    if (models.empty()) throw InvalidInput("6-DoF models", "no models given");
    std::vector<Mesh> out;
    for (const auto& m : models) out.push_back(m.mesh);
    return out;
  }

  void validate(const RgbdFrame& frame, const std::vector<SixDofInstance>& instances) const {
    validate_settings(frame);
    if (instances.empty()) throw InvalidInput("instances", "no instances given");
    for (std::size_t k = 0; k < instances.size(); ++k) {
      const std::string who = "instances[" + std::to_string(k) + "]";
      const SixDofInstance& in = instances[k];
      if (in.model < 0 || std::size_t(in.model) >= models_.size())
        throw InvalidInput(who, "unknown model id " + std::to_string(in.model) + " (" +
                                    std::to_string(models_.size()) + " models)");
      check_size(in.mask, frame.camera.width, frame.camera.height, who + " mask");
    }
  }

  /// The settings and the frame (what both entry points need).
  void validate_settings(const RgbdFrame& frame) const {
    const SixDofSettings& s = settings_;
    perch2::validate(s.proposals);
    perch2::validate(s.gicp);
    if (s.score_stride < 1) throw InvalidInput("SixDofSettings::score_stride", "must be >= 1");
    if (s.second_pass_stride < 1) throw InvalidInput("SixDofSettings::second_pass_stride", "must be >= 1");
    if (s.render.stride < 1) throw InvalidInput("SixDofSettings::render.stride", "must be >= 1");
    if (s.keep_per_instance < 0) throw InvalidInput("SixDofSettings::keep_per_instance", "must be >= 0");
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
    if (!(s.trim_quantile_low >= 0 && s.trim_quantile_low <= s.trim_quantile_high &&
          s.trim_quantile_high <= 1))
      throw InvalidInput("SixDofSettings::trim_quantile_*", "need 0 <= low <= high <= 1");
    if (s.memory_budget_bytes == 0 || s.bytes_per_point == 0)
      throw InvalidInput("SixDofSettings", "memory_budget_bytes and bytes_per_point must be > 0");
    frame.validate("6-DoF frame");
    if ((s.cost.use_color || s.first_pass_cost.use_color) && frame.rgb.empty())
      throw InvalidInput("6-DoF frame",
                         "has no colour image, which the RGB-D cost needs (set cost.use_color and "
                         "first_pass_cost.use_color = false for the depth-only cost)");
  }

  /// Depth-consistency trimming of instance `label`'s pixels (see the file comment); returns the pixels
  /// dropped. Throws InvalidInput for an empty mask or one without valid depth.
  std::size_t trim(const DepthImage& depth, LabelImage& labels, std::int32_t label,
                   const SixDofInstance& in) const {
    const SixDofSettings& s = settings_;
    const std::string who = "instances[" + std::to_string(label - 1) + "] mask";
    std::vector<float> z;
    bool any = false;
    for (std::size_t i = 0; i < labels.data.size(); ++i)
      if (in.mask.data[i]) {
        any = true;
        if (labels.data[i] == label && depth.data[i] > 0) z.push_back(depth.data[i]);
      }
    if (!any) throw InvalidInput(who, "is empty (no pixel inside)");
    if (z.empty()) throw InvalidInput(who, "has no valid depth reading inside it (or other masks cover it)");
    if (s.trim_margin_m < 0) return 0;
    std::sort(z.begin(), z.end());
    auto quantile = [&](float q) { return z[std::size_t(std::lround(q * float(z.size() - 1)))]; };
    const float lo = quantile(s.trim_quantile_low) - s.trim_margin_m;
    const float hi = std::min(quantile(s.trim_quantile_high) + s.trim_margin_m,
                              quantile(s.trim_quantile_low) + diameter_[std::size_t(in.model)]);
    std::size_t dropped = 0;
    for (std::size_t i = 0; i < labels.data.size(); ++i)
      if (labels.data[i] == label && depth.data[i] > 0 && (depth.data[i] < lo || depth.data[i] > hi))
        labels.data[i] = 0, ++dropped;
    return dropped;
  }

  /// The final fit (SixDofSettings::fit) of every found pose onto its instance's observed points on the
  /// fit_stride grid (the pixels labelled with it after trimming), then the cost at the fitted pose.
  void fit_poses(const Context& ctx, const LabelImage& labels,
                 const std::vector<std::size_t>& points_estimate, std::vector<SixDofPose>& best,
                 SixDofResult& result) const {
    const SixDofSettings& s = settings_;
    const RgbdFrame& frame = ctx.frame;
    CloudBatch support;
    std::vector<int> model;
    std::vector<Pose> start;
    std::vector<std::size_t> which;
    for (std::size_t k = 0; k < best.size(); ++k) {
      if (!best[k].found) continue;
      for (int v = 0; v < frame.camera.height; v += s.fit_stride)
        for (int u = 0; u < frame.camera.width; u += s.fit_stride)
          if (const float d = frame.depth_m(u, v);
              labels(u, v) == std::int32_t(k + 1) && observed_detail::keep(d, s.observed))
            observed_detail::append_pixel(frame, u, v, d, std::int32_t(which.size()), support);
      support.offsets.push_back(std::int64_t(support.size()));
      model.push_back(best[k].model), start.push_back(best[k].T_cam_obj), which.push_back(k);
    }
    if (which.empty()) return;
    const SurfaceFitResult r = surface_fit_.fit(support, model, start, s.fit);
    std::vector<Hypothesis> fitted;
    for (std::size_t i = 0; i < which.size(); ++i)
      fitted.push_back({model[i], r.T_cam_obj[i], std::int32_t(which[i] + 1)});
    const std::vector<CostBreakdown> c = score(ctx, fitted, s.score_stride, s.cost, points_estimate, result);
    for (std::size_t i = 0; i < which.size(); ++i) {
      SixDofPose& p = best[which[i]];
      const float slack = s.fit_cost_slack * float(p.cost.rendered_points + p.cost.observed_in_volume);
      if (c[i].rendered_points < s.min_rendered_points || c[i].total > p.cost.total + slack) continue;
      p.T_cam_obj = r.T_cam_obj[i], p.cost = c[i];
      ++result.fits_kept;
    }
  }

  /// Renders the hypotheses (of jobs) as their segments' own: pixels of a hypothesis' segment never hide it.
  CloudBatch render(const Context& ctx, const std::vector<Hypothesis>& h, int stride,
                    SixDofResult& result) const {
    const auto t = sixdof_detail::Clock::now();
    RenderSettings rs = settings_.render;
    rs.stride = stride;
    std::vector<Hypothesis> as_segments = h;
    for (auto& x : as_segments) x.label = ctx.label_of(x);
    CloudBatch out = renderer_.render(as_segments, ctx.frame.camera, rs, &ctx.occ);
    result.timings.render += sixdof_detail::seconds_since(t);
    return out;
  }

  /// estimate_scene()'s state across its passes.
  struct SceneState {
    /// Full resolution: 1..segments = the pass' segments (readings not yet explained), segments + 1 + j =
    /// placed object j's readings, 0 = support, background or dropped.
    LabelImage labels;
    std::size_t segments = 0;
    std::vector<int> remaining;        ///< per object given: instances still to place
    std::vector<int> model_of_object;  ///< per object given: its model
    std::vector<int> object_of_model;  ///< per model: its object's index, -1 if not requested
    std::vector<Hypothesis> placed;    ///< in placement order
    std::vector<int> placed_object;
    std::vector<std::size_t> placed_estimate;  ///< per placed object: its job's rendered-points estimate
  };

  /// One pass of estimate_scene() over `segments` (whose labels are scene.labels' 1..scene.segments):
  /// the jobs, their search and the scene explained object by object; places into `scene`. Returns the
  /// segments' readings on the observed grid.
  std::vector<std::size_t> explain_segments(const RgbdFrame& frame, const FrameSegments& segments,
                                            SceneState& scene, SixDofSceneResult& out) const {
    using namespace sixdof_detail;
    const SixDofSettings& s = settings_;
    const SceneSettings& ss = s.scene;
    SixDofResult& result = out.search;
    const std::size_t S = scene.segments;

    // ---- jobs: every model still missing on every segment of a compatible size (pieces of a large one)
    auto t = Clock::now();
    std::vector<std::int32_t> segment_labels(S);
    for (std::size_t k = 0; k < S; ++k) segment_labels[k] = std::int32_t(k + 1);
    std::vector<std::size_t> segment_points;
    {
      const CloudBatch grid = observed_segments(frame, scene.labels, segment_labels, s.observed);
      for (std::size_t k = 0; k < S; ++k) segment_points.push_back(grid.cloud_size(k));
    }
    std::vector<Job> jobs;
    for (std::size_t i = 0; i < scene.remaining.size(); ++i) {
      if (scene.remaining[i] <= 0) continue;
      for (std::size_t k = 0; k < S; ++k)
        if (segment_points[k] >= std::size_t(ss.min_segment_points))
          add_scene_jobs(frame, segments, int(k), scene.model_of_object[i], jobs);
    }
    if (ss.min_colour_fraction > 0 && s.cost.use_color) {
      const std::size_t before = jobs.size();
      screen_colours(frame, scene.labels, jobs);
      out.screened_out += before - jobs.size();
    }
    out.jobs += jobs.size();
    if (jobs.empty()) {
      result.timings.proposals += seconds_since(t);
      return segment_points;
    }
    // Each job's GICP targets and J_o's points: its segment and those that may be other parts of the same
    // object (an occluder in front splits it), as one observed cloud per distinct group.
    const std::vector<std::vector<std::int32_t>> groups = group_segments(segments, jobs);
    result.timings.proposals += seconds_since(t);
    t = Clock::now();
    const CloudBatch observed = group_clouds(frame, scene.labels, groups, S);
    std::vector<std::size_t> group_points;
    for (std::size_t g = 0; g < groups.size(); ++g) group_points.push_back(observed.cloud_size(g));
    result.segment_points.insert(result.segment_points.end(), group_points.begin(), group_points.end());
    const CloudBatch targets = with_pieces(frame, observed, jobs);
    const typename Backend::Registration registration(targets);
    const auto first_pass_registration = first_pass_targets(frame, targets);
    const typename Backend::Cost cost(observed);
    const Occluders occluders{frame.depth_m, scene.labels};
    result.timings.observed += seconds_since(t);
    std::vector<std::int32_t> job_cloud, job_label, job_target;
    for (const Job& j : jobs)
      job_cloud.push_back(j.segment), job_label.push_back(j.label), job_target.push_back(j.target);
    const Context ctx{frame, occluders, &registration, or_same(first_pass_registration, registration),
                      cost,  job_cloud, job_label,     job_target};
    std::vector<std::size_t> points_estimate;
    const std::vector<Finalist> found =
        search(ctx, jobs, group_points, points_estimate, result, ss.local_search_placed_only);

    // ---- explain the scene object by object
    t = Clock::now();
    std::vector<Hypothesis> candidates;
    for (const Finalist& f : found)
      if (f.cost.rendered_points >= s.min_rendered_points) candidates.push_back(f.hypothesis);
    out.candidates += candidates.size();
    std::vector<std::size_t> group_size = group_points;  // unexplained readings per group, last round
    const std::size_t placed_before = scene.placed.size();
    while (!candidates.empty() &&
           std::any_of(scene.remaining.begin(), scene.remaining.end(), [](int r) { return r > 0; })) {
      const Occluders occ_now{frame.depth_m, scene.labels};
      const CloudBatch unexplained = group_clouds(frame, scene.labels, groups, S);
      const typename Backend::Cost cost_now(unexplained);
      const Context now{frame, occ_now, nullptr, nullptr, cost_now, job_cloud, job_label, job_cloud};
      // The candidates whose groups lost readings to the last placement, refined again (their poses
      // before kept in `previous`); a refinement that explains the scene worse is undone.
      std::vector<std::size_t> touched;
      std::vector<Hypothesis> previous;
      if (ss.refine_after_placing && scene.placed.size() > placed_before) {
        for (std::size_t i = 0; i < candidates.size(); ++i) {
          const auto g = std::size_t(job_cloud[std::size_t(candidates[i].label - 1)]);
          if (unexplained.cloud_size(g) != group_size[g] &&
              unexplained.cloud_size(g) >= std::size_t(ss.min_segment_points))
            touched.push_back(i);
        }
        for (const std::size_t i : touched) previous.push_back(candidates[i]);
        if (!touched.empty()) refine_again(now, unexplained, candidates, touched, result);
        out.refined += touched.size();
      }
      for (std::size_t g = 0; g < groups.size(); ++g) group_size[g] = unexplained.cloud_size(g);
      std::vector<CostBreakdown> c = score(now, candidates, s.score_stride, s.cost, points_estimate, result);
      if (!previous.empty()) {
        const std::vector<CostBreakdown> was =
            score(now, previous, s.score_stride, s.cost, points_estimate, result);
        for (std::size_t j = 0; j < previous.size(); ++j)
          if (better_explanation(was[j], c[touched[j]]))
            candidates[touched[j]] = previous[j], c[touched[j]] = was[j], ++out.reverted;
      }
      ++out.rounds;
      std::size_t pick = candidates.size();
      for (std::size_t i = 0; i < candidates.size(); ++i) {
        const int obj = scene.object_of_model[std::size_t(candidates[i].model)];
        if (obj < 0 || scene.remaining[std::size_t(obj)] <= 0 || !acceptable(c[i])) continue;
        if (pick == candidates.size() || explained(c[i]) > explained(c[pick])) pick = i;
      }
      if (pick == candidates.size()) break;  // nothing acceptable is left: the rest is missing
      if (ss.local_search_placed_only && s.local.candidates_per_instance > 0)
        search_placed(ctx, now, found[std::size_t(candidates[pick].label - 1)].local_starts, candidates[pick],
                      points_estimate, result);
      const std::int32_t label = std::int32_t(S + 1 + scene.placed.size());
      explain(now, candidates[pick], label, S, scene.labels, result);
      const int obj = scene.object_of_model[std::size_t(candidates[pick].model)];
      --scene.remaining[std::size_t(obj)];
      scene.placed.push_back(candidates[pick]), scene.placed_object.push_back(obj);
      scene.placed_estimate.push_back(points_estimate[std::size_t(candidates[pick].label - 1)]);
      candidates.erase(candidates.begin() + std::ptrdiff_t(pick));
    }
    result.timings.explain += seconds_since(t);
    return segment_points;
  }

  /// The local search (local_stage) of the candidate about to be placed, from its job's best hypotheses
  /// (`starts`, the first replaced by its current pose), in the search's context `ctx`; the winner
  /// replaces `placed` if it is still acceptable against what is unexplained now (context `now`).
  void search_placed(const Context& ctx, const Context& now, std::vector<Hypothesis> starts,
                     Hypothesis& placed, const std::vector<std::size_t>& points_estimate,
                     SixDofResult& result) const {
    if (starts.empty()) return;
    const auto t = sixdof_detail::Clock::now();
    starts.front() = placed;
    std::vector<CostBreakdown> costs(starts.size());
    local_stage(ctx, starts, costs, std::size_t(placed.label), points_estimate, result);
    const std::vector<CostBreakdown> c =
        score(now, starts, settings_.score_stride, settings_.cost, points_estimate, result);
    if (acceptable(c.front())) placed = starts.front();
    result.timings.explain -= sixdof_detail::seconds_since(t);  // counted in local
  }

  /// The readings of scene's segments that no placed object explains, segmented again
  /// (segment_readings): a neighbour placed in the same segment leaves the part it did not explain, which
  /// can be the whole visible part of a hidden object. Relabels scene.labels to the new segments (placed
  /// objects' readings kept after them).
  FrameSegments residual_segments(const RgbdFrame& frame, SceneState& scene, float smallest_face) const {
    const auto S = std::int32_t(scene.segments);
    std::vector<std::uint8_t> left(scene.labels.data.size(), 0);
    for (std::size_t i = 0; i < left.size(); ++i)
      left[i] = scene.labels.data[i] >= 1 && scene.labels.data[i] <= S;
    FrameSegments residual = segment_readings(frame, left, settings_.scene.segmentation, smallest_face);
    const auto R = std::int32_t(residual.segments.size());
    for (std::size_t i = 0; i < left.size(); ++i)
      if (scene.labels.data[i] > S) residual.labels.data[i] = R + scene.labels.data[i] - S;
    scene.labels = residual.labels;
    scene.segments = std::size_t(R);
    return residual;
  }

  /// Each placed object's final cost and surface fit on its own readings (as estimate()'s), into out.poses.
  void fit_placed(const RgbdFrame& frame, SceneState& scene, SixDofSceneResult& out) const {
    using namespace sixdof_detail;
    const SixDofSettings& s = settings_;
    SixDofResult& result = out.search;
    const std::size_t P = scene.placed.size();
    if (P == 0) return;
    auto t = Clock::now();
    const auto S = std::int32_t(scene.segments);
    LabelImage own(scene.labels.width, scene.labels.height, 0);  // placed object j's readings: j + 1
    for (std::size_t i = 0; i < own.data.size(); ++i)
      if (scene.labels.data[i] > S) own.data[i] = scene.labels.data[i] - S;
    std::vector<std::int32_t> own_labels(P), own_segment(P);  // job j: cloud j, label j + 1
    std::vector<Hypothesis> placed = scene.placed;
    for (std::size_t j = 0; j < P; ++j) {
      own_labels[j] = std::int32_t(j + 1), own_segment[j] = std::int32_t(j);
      placed[j].label = std::int32_t(j + 1);  // job j of the final context
    }
    const CloudBatch own_cloud = observed_segments(frame, own, own_labels, s.observed);
    const typename Backend::Cost own_cost(own_cloud);
    const Occluders own_occ{frame.depth_m, own};
    const Context fin{frame, own_occ, nullptr, nullptr, own_cost, own_segment, own_labels, own_segment};
    const std::vector<CostBreakdown> c =
        score(fin, placed, s.score_stride, s.cost, scene.placed_estimate, result);
    std::vector<SixDofPose> poses(P);
    for (std::size_t j = 0; j < P; ++j) {
      poses[j].instance = scene.placed_object[j], poses[j].model = placed[j].model;
      poses[j].T_cam_obj = placed[j].T_cam_obj, poses[j].cost = c[j], poses[j].found = true;
    }
    result.timings.select += seconds_since(t);
    if (s.fit.iterations > 0) {
      t = Clock::now();
      fit_poses(fin, own, scene.placed_estimate, poses, result);
      result.timings.fit += seconds_since(t);
    }
    for (auto& p : poses) p.score = pose_score(p.cost);
    out.poses = std::move(poses);
  }

  /// Both GICP passes of candidates[touched] again, against `unexplained` (ctx's cost clouds, its
  /// registration unset): the readings a placed neighbour took no longer pull them. The time counts in
  /// observed (the GICP targets), render and refine, not in explain.
  void refine_again(const Context& ctx, const CloudBatch& unexplained, std::vector<Hypothesis>& candidates,
                    const std::vector<std::size_t>& touched, SixDofResult& result) const {
    const auto t = sixdof_detail::Clock::now();
    const typename Backend::Registration registration(unexplained);
    result.timings.observed += sixdof_detail::seconds_since(t);  // as the search's GICP targets
    Context with_targets = ctx;
    // Both passes against every unexplained reading: the candidates are already near their poses.
    with_targets.registration = with_targets.first_pass_registration = &registration;
    std::vector<Hypothesis> moved;
    for (const std::size_t i : touched) moved.push_back(candidates[i]);
    refine(with_targets, moved, render(with_targets, moved, settings_.render.stride, result), settings_.gicp,
           result);
    const Pass second = second_pass();
    if (second.refine)
      refine(with_targets, moved, render(with_targets, moved, settings_.second_pass_stride, result),
             second.gicp, result);
    for (std::size_t j = 0; j < touched.size(); ++j) candidates[touched[j]] = moved[j];
    result.timings.explain -= sixdof_detail::seconds_since(t);
  }

  /// One GICP pass of every hypothesis against its own segment (only gs's ICP warm-up if warmup_only);
  /// moves the hypotheses.
  void refine(const Context& ctx, std::vector<Hypothesis>& chunk, const CloudBatch& rendered,
              const GicpSettings& gs, SixDofResult& result, bool warmup_only = false) const {
    const auto t = sixdof_detail::Clock::now();
    std::vector<std::int32_t> segment(chunk.size());
    for (std::size_t h = 0; h < chunk.size(); ++h) segment[h] = ctx.target_of(chunk[h]);
    const RegistrationResult r = warmup_only
                                     ? ctx.registration->icp(rendered, segment, icp_warmup_settings(gs))
                                     : ctx.registration->gicp(rendered, segment, gs);
    for (std::size_t h = 0; h < chunk.size(); ++h) {
      Pose T = r.T_corr[h] * chunk[h].T_cam_obj;
      T.linear() = Eigen::Quaternionf(T.linear()).normalized().toRotationMatrix();  // keep it rigid
      chunk[h].T_cam_obj = T;
    }
    result.timings.refine += sixdof_detail::seconds_since(t);
  }

  /// Whether two poses of one model are the same (distinct_translation_m, distinct_rotation_rad, under the
  /// model's symmetries).
  bool same_pose(const Hypothesis& a, const Hypothesis& b) const {
    const SixDofSettings& s = settings_;
    return (a.T_cam_obj.translation() - b.T_cam_obj.translation()).norm() < s.distinct_translation_m &&
           symmetric_rotation_distance(a.T_cam_obj.linear(), b.T_cam_obj.linear(),
                                       models_[std::size_t(a.model)].symmetries) < s.distinct_rotation_rad;
  }

  /// The hypotheses, in order, without those that repeat an earlier one's pose of the same instance
  /// (same_pose). Poses are bucketed by translation (cells of distinct_translation_m), so each is compared
  /// with the kept poses of its 27 neighbouring cells only.
  std::vector<Hypothesis> distinct_poses(const std::vector<Hypothesis>& hyps) const {
    const float cell = settings_.distinct_translation_m;
    if (!(cell > 0) || !(settings_.distinct_rotation_rad > 0)) return hyps;
    std::map<std::array<std::int64_t, 4>, std::vector<std::size_t>> kept_in;  // (label, cell) -> kept
    std::vector<Hypothesis> out;
    for (const Hypothesis& h : hyps) {
      const Eigen::Vector3f c = h.T_cam_obj.translation() / cell;
      const std::array<std::int64_t, 4> key{h.label, std::int64_t(std::floor(c.x())),
                                            std::int64_t(std::floor(c.y())), std::int64_t(std::floor(c.z()))};
      bool duplicate = false;
      for (int dx = -1; dx <= 1 && !duplicate; ++dx)
        for (int dy = -1; dy <= 1 && !duplicate; ++dy)
          for (int dz = -1; dz <= 1 && !duplicate; ++dz) {
            const auto it = kept_in.find({key[0], key[1] + dx, key[2] + dy, key[3] + dz});
            if (it == kept_in.end()) continue;
            duplicate = std::any_of(it->second.begin(), it->second.end(),
                                    [&](std::size_t o) { return same_pose(out[o], h); });
          }
      if (duplicate) continue;
      kept_in[key].push_back(out.size());
      out.push_back(h);
    }
    return out;
  }

  /// The first pass' stride for an instance with `segment_points` observed points (see
  /// SixDofSettings::first_pass_min_points).
  int first_pass_stride(std::size_t segment_points) const {
    const SixDofSettings& s = settings_;
    int stride = s.render.stride;
    auto expected = [&](int st) {
      return double(segment_points) * double(s.observed.stride * s.observed.stride) / double(st * st);
    };
    while (stride / 2 >= s.second_pass_stride && expected(stride) < double(s.first_pass_min_points))
      stride /= 2;
    return stride;
  }

  /// One pass over hypotheses: render at `stride`, refine with `gicp` (if `refine`), re-render at
  /// score_stride and score.
  struct Pass {
    int stride = 4;
    GicpSettings gicp;
    bool refine = true;
    int score_stride = 4;
    const CostSettings* cost = nullptr;
    bool dedupe_after_warmup = false;  ///< GICP only the distinct poses the ICP warm-up reached
    bool first = false;                ///< the first pass (counted in first_pass_distinct)
  };

  /// Runs `pass` over `hyps` in chunks under the memory budget; moves the hypotheses to their refined
  /// poses and returns their costs, in order.
  std::vector<CostBreakdown> run_chunks(const Context& ctx, const Pass& pass, std::vector<Hypothesis>& hyps,
                                        const std::vector<std::size_t>& points_estimate,
                                        SixDofResult& result) const {
    const SixDofSettings& s = settings_;
    // points_estimate is for the finest stride in use; a coarser render has fewer points.
    const int finest = std::min({s.render.stride, s.second_pass_stride, s.score_stride});
    const int coarsest_here = std::min(pass.stride, pass.score_stride);
    const double scale = double(finest * finest) / double(coarsest_here * coarsest_here);
    std::vector<CostBreakdown> costs;
    costs.reserve(hyps.size());
    std::vector<Hypothesis> out;  // the chunks' hypotheses after the pass (without warm-up duplicates)
    out.reserve(hyps.size());
    std::size_t begin = 0;
    while (begin < hyps.size()) {
      const std::size_t end = chunk_end(hyps, begin, scale, points_estimate);
      std::vector<Hypothesis> chunk(hyps.begin() + std::ptrdiff_t(begin), hyps.begin() + std::ptrdiff_t(end));
      const std::size_t points = run_chunk(ctx, pass, chunk, costs, result);
      out.insert(out.end(), chunk.begin(), chunk.end());
      result.peak_chunk_bytes = std::max(result.peak_chunk_bytes, points * s.bytes_per_point);
      result.chunk_hypotheses = std::max(result.chunk_hypotheses, end - begin);
      ++result.chunks;
      begin = end;
    }
    hyps = std::move(out);
    return costs;
  }

  /// The end of the chunk starting at `begin`: as many hypotheses as fit the memory budget (at least one),
  /// each estimated at points_estimate[its instance] x scale points.
  std::size_t chunk_end(const std::vector<Hypothesis>& hyps, std::size_t begin, double scale,
                        const std::vector<std::size_t>& points_estimate) const {
    const SixDofSettings& s = settings_;
    std::size_t end = begin, bytes = 0;
    while (end < hyps.size()) {
      const std::size_t b = std::size_t(double(points_estimate[std::size_t(hyps[end].label - 1)]) * scale *
                                        double(s.bytes_per_point)) +
                            1;
      if (end > begin && bytes + b > s.memory_budget_bytes) break;
      bytes += b, ++end;
    }
    return end;
  }

  /// Renders `hyps` at `stride` and scores them with `cs`, in chunks under the memory budget (counted in
  /// peak_chunk_bytes, not in chunks).
  std::vector<CostBreakdown> score(const Context& ctx, const std::vector<Hypothesis>& hyps, int stride,
                                   const CostSettings& cs, const std::vector<std::size_t>& points_estimate,
                                   SixDofResult& result) const {
    std::vector<CostBreakdown> costs;
    costs.reserve(hyps.size());
    for_rendered_chunks(ctx, hyps, stride, points_estimate, result,
                        [&](const std::vector<Hypothesis>& chunk, const CloudBatch& rendered) {
                          const auto t = sixdof_detail::Clock::now();
                          const std::vector<CostBreakdown> c =
                              ctx.cost.evaluate(rendered, ctx.request(chunk), cs).hypotheses;
                          costs.insert(costs.end(), c.begin(), c.end());
                          result.timings.cost += sixdof_detail::seconds_since(t);
                        });
    return costs;
  }

  /// Renders `hyps` at `stride` in chunks under the memory budget (counted in peak_chunk_bytes, not in
  /// chunks) and calls use(chunk, rendered) for each, in order.
  template <class Use>
  void for_rendered_chunks(const Context& ctx, const std::vector<Hypothesis>& hyps, int stride,
                           const std::vector<std::size_t>& points_estimate, SixDofResult& result,
                           Use&& use) const {
    const int finest =
        std::min({settings_.render.stride, settings_.second_pass_stride, settings_.score_stride});
    const double scale = double(finest * finest) / double(stride * stride);
    for (std::size_t begin = 0; begin < hyps.size();) {
      const std::size_t end = chunk_end(hyps, begin, scale, points_estimate);
      const std::vector<Hypothesis> chunk(hyps.begin() + std::ptrdiff_t(begin),
                                          hyps.begin() + std::ptrdiff_t(end));
      const CloudBatch rendered = render(ctx, chunk, stride, result);
      result.peak_chunk_bytes =
          std::max(result.peak_chunk_bytes, rendered.size() * settings_.bytes_per_point);
      use(chunk, rendered);
      begin = end;
    }
  }

  /// The indices of the best (at most n) hypotheses of each instance, instance by instance, best first:
  /// those showing min_rendered_points (scaled from score_stride to `stride`) before the rest, then by
  /// total cost.
  std::vector<std::size_t> best_per_instance(const std::vector<Hypothesis>& hyps,
                                             const std::vector<CostBreakdown>& costs, std::size_t K,
                                             std::size_t n, int stride) const {
    const SixDofSettings& s = settings_;
    const float ratio = float(s.score_stride) / float(stride);
    const int min_points = std::max(1, int(std::lround(float(s.min_rendered_points) * ratio * ratio)));
    std::vector<std::size_t> order(hyps.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    auto rank = [&](std::size_t i) {
      return std::make_tuple(hyps[i].label, costs[i].rendered_points < min_points, costs[i].total);
    };
    std::stable_sort(order.begin(), order.end(),
                     [&](std::size_t a, std::size_t b) { return rank(a) < rank(b); });
    std::vector<std::size_t> out, count(K, 0);
    for (const std::size_t i : order)
      if (count[std::size_t(hyps[i].label - 1)]++ < n) out.push_back(i);
    return out;
  }

  /// The local search (LocalSearchSettings) around each of `hyps`, which it moves.
  void local_search(const Context& ctx, std::vector<Hypothesis>& hyps,
                    const std::vector<std::size_t>& points_estimate, SixDofResult& result) const {
    auto turn = [](Hypothesis h, int axis, float angle_rad) {  // about the model's own axis
      h.T_cam_obj.linear() =
          h.T_cam_obj.linear() * Eigen::AngleAxisf(angle_rad, Eigen::Vector3f::Unit(axis)).toRotationMatrix();
      return h;
    };
    CostSettings depth_only = settings_.cost;
    depth_only.use_color = false;
    depth_only.normalization = Normalization::Fractions;
    auto measure = [&](const std::vector<Hypothesis>& h, int stride, bool geometry) {
      std::vector<TurnSample> out;
      out.reserve(h.size());
      for_rendered_chunks(ctx, h, stride, points_estimate, result,
                          [&](const std::vector<Hypothesis>& chunk, const CloudBatch& rendered) {
                            const auto t = sixdof_detail::Clock::now();
                            std::vector<AppearanceSamples> a =
                                appearance_samples(rendered, ctx.frame, depth_only.delta_m);
                            std::vector<CostBreakdown> c(chunk.size());
                            if (geometry)
                              c = ctx.cost.evaluate(rendered, ctx.request(chunk), depth_only).hypotheses;
                            for (std::size_t i = 0; i < c.size(); ++i)
                              out.push_back({c[i].total, std::move(a[i])});
                            result.timings.cost += sixdof_detail::seconds_since(t);
                          });
      return out;
    };
    auto shift = [](Hypothesis h, int axis, float m) {  // across the line of sight (camera x or y)
      h.T_cam_obj.translation()[axis] += m;
      return h;
    };
    search_turns(hyps, 3, 2, ctx.frame.camera.width, settings_.local.turns, turn, shift, measure,
                 &result.local_candidates);
  }

  /// Renders, refines, re-renders and scores one chunk (appending its costs). Returns its largest rendered
  /// point count.
  std::size_t run_chunk(const Context& ctx, const Pass& pass, std::vector<Hypothesis>& chunk,
                        std::vector<CostBreakdown>& costs, SixDofResult& result) const {
    using namespace sixdof_detail;
    std::size_t points = 0;
    if (pass.refine && pass.dedupe_after_warmup && pass.gicp.icp_warmup_iterations > 0) {
      // ICP warm-up, then GICP only for the distinct poses it reached (re-rendered there).
      const CloudBatch rendered = render(ctx, chunk, pass.stride, result);
      points = rendered.size();
      refine(ctx, chunk, rendered, pass.gicp, result, /*warmup_only=*/true);
      chunk = distinct_poses(chunk);
      result.first_pass_distinct += chunk.size();
      GicpSettings rest = pass.gicp;
      rest.icp_warmup_iterations = 0;
      const CloudBatch moved = render(ctx, chunk, pass.stride, result);
      points = std::max(points, moved.size());
      refine(ctx, chunk, moved, rest, result);
    } else if (pass.refine) {
      if (pass.first) result.first_pass_distinct += chunk.size();
      const CloudBatch rendered = render(ctx, chunk, pass.stride, result);
      points = rendered.size();
      refine(ctx, chunk, rendered, pass.gicp, result);
    }
    const CloudBatch rendered = render(ctx, chunk, pass.score_stride, result);
    points = std::max(points, rendered.size());
    const auto t = Clock::now();
    const std::vector<CostBreakdown> c =
        ctx.cost.evaluate(rendered, ctx.request(chunk), *pass.cost).hypotheses;
    costs.insert(costs.end(), c.begin(), c.end());
    result.timings.cost += seconds_since(t);
    return points;
  }

  /// The best keep_per_instance distinct hypotheses of each instance by cost (all if 0), in instance then
  /// cost order. A hypothesis showing fewer than min_rendered_points (scaled to the first pass' stride)
  /// ranks after every one that shows enough.
  std::vector<Hypothesis> keep_best(const std::vector<Hypothesis>& hyps,
                                    const std::vector<CostBreakdown>& costs, const std::vector<int>& stride,
                                    std::size_t K) const {
    const SixDofSettings& s = settings_;
    std::vector<int> min_points(K);
    for (std::size_t k = 0; k < K; ++k) {
      const float ratio = float(s.score_stride) / float(stride[k]);
      min_points[k] = std::max(3, int(std::lround(float(s.min_rendered_points) * ratio * ratio)));
    }
    std::vector<std::size_t> order(hyps.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    auto rank = [&](std::size_t i) {  // (shows too few points, cost): showing enough ranks first
      return std::make_pair(costs[i].rendered_points < min_points[std::size_t(hyps[i].label - 1)],
                            costs[i].total);
    };
    std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
      return hyps[a].label != hyps[b].label ? hyps[a].label < hyps[b].label : rank(a) < rank(b);
    });
    std::vector<Hypothesis> kept;
    std::vector<std::size_t> count(K, 0);
    for (const std::size_t i : order) {
      const auto k = std::size_t(hyps[i].label - 1);
      // A mostly hidden instance (first pass on a finer grid) keeps every distinct pose: its ranking rests
      // on few points, and its second pass is cheap for the same reason.
      const bool all = s.keep_per_instance == 0 || stride[k] < s.render.stride;
      if (!all && count[k] >= std::size_t(s.keep_per_instance)) continue;
      const bool duplicate =
          s.keep_per_instance > 0 && std::any_of(kept.end() - std::ptrdiff_t(count[k]), kept.end(),
                                                 [&](const Hypothesis& o) { return same_pose(hyps[i], o); });
      if (duplicate) continue;
      kept.push_back(hyps[i]);
      ++count[k];
    }
    return kept;
  }

  /// Proposals, both passes, the local search and the selection of every job: one finalist per job, in job
  /// order. Fills the per-job counts of `result` and points_estimate (per job: a rendered-point bound for
  /// the chunk sizes). defer_local: no local search; each finalist carries the poses it would have started
  /// from (Finalist::local_starts) for the caller's local_stage().
  std::vector<Finalist> search(const Context& ctx, const std::vector<Job>& jobs,
                               const std::vector<std::size_t>& segment_points,
                               std::vector<std::size_t>& points_estimate, SixDofResult& result,
                               bool defer_local = false) const {
    using namespace sixdof_detail;
    const SixDofSettings& s = settings_;
    const std::size_t K = jobs.size();

    // ---- proposals
    auto t = Clock::now();
    std::vector<Hypothesis> hyps;
    points_estimate.clear();
    std::map<int, std::vector<Eigen::Matrix3f>> rotations_of;  // per model
    for (std::size_t k = 0; k < K; ++k) {
      const Job& job = jobs[k];
      auto it = rotations_of.find(job.model);
      if (it == rotations_of.end())
        it = rotations_of
                 .emplace(job.model,
                          rotation_proposals(s.proposals, models_[std::size_t(job.model)].symmetries))
                 .first;
      const auto poses =
          pose_proposals(ctx.frame.camera, box_centre_px(job.box_xywh), it->second, job.depths);
      for (const auto& T : poses) hyps.push_back({job.model, T, std::int32_t(k + 1)});
      result.rotations.push_back(it->second.size());
      result.depths.push_back(job.depths.size());
      result.hypotheses.push_back(poses.size());
      // The object's image at the nearest depth covers at most its diameter's projection, squared.
      const float px =
          ctx.frame.camera.fx * diameter_[std::size_t(job.model)] / std::max(job.depths.front(), 1e-3f);
      const int stride = std::min({s.render.stride, s.second_pass_stride, s.score_stride});
      points_estimate.push_back(std::size_t(px * px / float(stride * stride)) + 1);
    }
    result.hypotheses_total += hyps.size();
    result.timings.proposals += seconds_since(t);

    // ---- first pass over every proposal (chunks): render, refine, re-render, cheap cost. Each job at the
    // coarsest stride that still shows it with first_pass_min_points (a mostly hidden object is refined on
    // a finer grid); hypotheses are grouped by job, so each stride is a contiguous run.
    std::vector<int> first_stride(K);
    for (std::size_t k = 0; k < K; ++k)
      first_stride[k] = first_pass_stride(segment_points[std::size_t(jobs[k].segment)]);
    Context first_ctx = ctx;  // against the first pass' coarser targets
    first_ctx.registration = ctx.first_pass_registration;
    std::vector<CostBreakdown> first_costs;
    std::vector<Hypothesis> refined;  // after the first pass (without the warm-up's duplicates), in order
    for (std::size_t begin = 0; begin < hyps.size();) {
      const int stride = first_stride[std::size_t(hyps[begin].label - 1)];
      std::size_t end = begin;
      while (end < hyps.size() && first_stride[std::size_t(hyps[end].label - 1)] == stride) ++end;
      Pass first;
      first.stride = first.score_stride = stride;
      first.gicp = s.gicp;
      first.cost = &s.first_pass_cost;
      first.dedupe_after_warmup = s.dedupe_after_warmup;
      first.first = true;
      std::vector<Hypothesis> run(hyps.begin() + std::ptrdiff_t(begin), hyps.begin() + std::ptrdiff_t(end));
      const auto c = run_chunks(first_ctx, first, run, points_estimate, result);
      refined.insert(refined.end(), run.begin(), run.end());
      first_costs.insert(first_costs.end(), c.begin(), c.end());
      begin = end;
    }
    hyps = std::move(refined);

    // ---- second pass over the best distinct poses of each job: tighter refinement, final cost
    std::vector<Hypothesis> kept = keep_best(hyps, first_costs, first_stride, K);
    result.second_pass_hypotheses += kept.size();
    const Pass second = second_pass();
    const std::vector<CostBreakdown> costs = run_chunks(ctx, second, kept, points_estimate, result);

    // ---- select: the best acceptable hypotheses of each job, refined by the local search
    t = Clock::now();
    const std::size_t n_local = s.local.candidates_per_instance > 0 ? s.local.candidates_per_instance : 1;
    std::vector<std::size_t> top = best_per_instance(kept, costs, K, n_local, s.score_stride);
    result.timings.select += seconds_since(t);
    std::vector<Hypothesis> finalists;
    for (const std::size_t h : top) finalists.push_back(kept[h]);
    std::vector<CostBreakdown> final_costs;
    for (const std::size_t h : top) final_costs.push_back(costs[h]);
    std::vector<std::vector<Hypothesis>> local_starts(K);
    if (defer_local && s.local.candidates_per_instance > 0)
      for (const Hypothesis& h : finalists) local_starts[std::size_t(h.label - 1)].push_back(h);
    else if (s.local.candidates_per_instance > 0)
      local_stage(ctx, finalists, final_costs, K, points_estimate, result);
    t = Clock::now();
    std::vector<Finalist> out(K);
    for (std::size_t k = 0; k < K; ++k) {
      out[k].hypothesis = {jobs[k].model, Pose::Identity(), std::int32_t(k + 1)};
      out[k].cost.rendered_points = -1;  // no finalist (cannot happen: every job has proposals)
    }
    std::vector<bool> seen(K, false);
    for (std::size_t h = 0; h < finalists.size(); ++h) {  // in order: a job's best comes first
      const auto k = std::size_t(finalists[h].label - 1);
      if (seen[k]) continue;
      seen[k] = true;
      out[k] = {finalists[h], final_costs[h], std::move(local_starts[k])};
    }
    result.timings.select += seconds_since(t);
    return out;
  }

  /// The local search (LocalSearchSettings) around `finalists` (the best few hypotheses of each of the K
  /// jobs, in job order, with their final costs), then the second pass' GICP (polish); leaves one winner
  /// per job, in job order, with its final cost.
  void local_stage(const Context& ctx, std::vector<Hypothesis>& finalists,
                   std::vector<CostBreakdown>& final_costs, std::size_t K,
                   const std::vector<std::size_t>& points_estimate, SixDofResult& result) const {
    using namespace sixdof_detail;
    const SixDofSettings& s = settings_;
    const auto t = Clock::now();
    local_search(ctx, finalists, points_estimate, result);
    const Pass second = second_pass();
    if (s.local.polish && second.refine) {  // GICP restores what the turns may have tilted (it cannot undo a
                                            // turn it cannot see)
      const CloudBatch rendered = render(ctx, finalists, s.second_pass_stride, result);
      refine(ctx, finalists, rendered, second.gicp, result);
    }
    // The winner per job (acceptable first) by the final cost, re-evaluated at the moved poses.
    const std::vector<CostBreakdown> moved_costs =
        score(ctx, finalists, s.score_stride, s.cost, points_estimate, result);
    const std::vector<std::size_t> winners = best_per_instance(finalists, moved_costs, K, 1, s.score_stride);
    std::vector<Hypothesis> chosen;
    final_costs.clear();
    for (const std::size_t h : winners) chosen.push_back(finalists[h]), final_costs.push_back(moved_costs[h]);
    finalists = std::move(chosen);
    result.timings.local += seconds_since(t);
  }

  /// The second pass' settings (SixDofSettings::second_pass_*).
  Pass second_pass() const {
    const SixDofSettings& s = settings_;
    Pass second;
    second.stride = s.second_pass_stride;
    second.gicp = s.gicp;
    second.gicp.max_correspondence_distance_m = s.second_pass_cap_m;
    second.gicp.max_iterations = s.second_pass_iterations;
    second.gicp.icp_warmup_iterations = 0;
    second.refine = s.second_pass_cap_m > 0;
    second.score_stride = s.score_stride;
    second.cost = &s.cost;
    return second;
  }

  /// 1 - (rendered outliers + unexplained observed points) / (rendered + observed points), in [0, 1].
  static float pose_score(const CostBreakdown& b) {
    const float n = float(b.rendered_points + b.observed_in_volume);
    return n > 0 ? std::clamp(1.f - float(b.rendered_outliers() + b.observed_unexplained()) / n, 0.f, 1.f)
                 : 0.f;
  }

  /// Whether a scene candidate, scored against what is still unexplained, may be placed (SceneSettings).
  bool acceptable(const CostBreakdown& c) const {
    const SceneSettings& ss = settings_.scene;
    if (c.rendered_points < settings_.min_rendered_points) return false;
    const float inliers = float(c.rendered_points - c.rendered_outliers());
    const float reached = float(c.observed_in_volume - c.observed_depth_outliers);  // near its surface
    return inliers >= ss.min_inlier_fraction * float(c.rendered_points) &&
           explained(c) >= ss.min_explained_points &&
           float(c.observed_color_outliers) <= ss.max_colour_mismatch * reached;
  }

  /// Whether a candidate with cost `a` explains the scene better than with `b`: acceptable before not, then
  /// more readings explained.
  bool better_explanation(const CostBreakdown& a, const CostBreakdown& b) const {
    if (acceptable(a) != acceptable(b)) return acceptable(a);
    return explained(a) > explained(b);
  }

  /// The observed readings a hypothesis explains (in its volume, not unexplained).
  static std::int32_t explained(const CostBreakdown& c) {
    return c.observed_in_volume - c.observed_unexplained();
  }

  /// Labels the readings that `placed` explains (unexplained object readings, labels 1..S, within
  /// explain_distance_m of its render at full resolution, the same pixel) with `label`.
  void explain(const Context& now, const Hypothesis& placed, std::int32_t label, std::size_t S,
               LabelImage& labels, SixDofResult& result) const {
    const CloudBatch r = render(now, {placed}, 1, result);
    const float tol = settings_.scene.explain_distance_m;
    for (std::size_t i = 0; i < r.size(); ++i) {
      const std::int32_t p = r.pixel[i];
      if (p < 0) continue;
      const std::int32_t l = labels.data[std::size_t(p)];
      const float d = now.frame.depth_m.data[std::size_t(p)];
      if (l >= 1 && l <= std::int32_t(S) && d > 0 && std::abs(d - r.z[i]) <= tol)
        labels.data[std::size_t(p)] = label;
    }
  }

  /// Drops the jobs whose model lacks the colours of their readings (SceneSettings::min_colour_fraction):
  /// up to colour_samples of each job's readings (its piece's, or its segment's), each matched if some
  /// colour of the model is within tau_c (CIEDE2000, the cost's comparison colours).
  void screen_colours(const RgbdFrame& frame, const LabelImage& labels, std::vector<Job>& jobs) const {
    const SceneSettings& ss = settings_.scene;
    const CostSettings& c = settings_.cost;
    std::map<int, std::vector<Lab<float>>> palette;  // per model, its comparison colours
    // (model, reading's colour bin of 6 bits per channel, as model_colours()): matched
    std::map<std::pair<int, std::uint32_t>, bool> known;
    auto matched = [&](int model, std::uint32_t rgb) {
      const auto [it, fresh] = known.try_emplace({model, rgb & 0xfcfcfcu}, false);
      if (!fresh) return it->second;
      auto p = palette.find(model);
      if (p == palette.end()) {  // one colour per CIELAB cell of 2 units: ~1 unit from any model colour
        p = palette.emplace(model, std::vector<Lab<float>>{}).first;
        std::set<std::array<int, 3>> cells;
        for (const std::uint32_t m : colours_[std::size_t(model)]) {
          const Lab<float> lab = comparison_lab(m, c.shading_invariant);
          const std::array<int, 3> cell{int(std::floor(lab.L / 2)), int(std::floor(lab.a / 2)),
                                        int(std::floor(lab.b / 2))};
          if (cells.insert(cell).second) p->second.push_back(lab);
        }
      }
      const Lab<float> lab = comparison_lab(rgb, c.shading_invariant);
      for (const Lab<float>& m : p->second)
        if (ciede2000(lab, m, c.lightness_factor) <= c.tau_c) return it->second = true;
      return false;
    };
    std::map<std::int32_t, std::vector<std::int32_t>> pixels_of;  // segment label -> its pixels
    for (std::size_t i = 0; i < labels.data.size(); ++i)
      if (labels.data[i] > 0 && frame.depth_m.data[i] > 0)
        pixels_of[labels.data[i]].push_back(std::int32_t(i));
    std::vector<Job> kept;
    for (Job& job : jobs) {
      const std::vector<std::int32_t>& px =
          job.piece_pixels.empty() ? pixels_of[job.label] : job.piece_pixels;
      const std::size_t n = std::min(px.size(), std::size_t(ss.colour_samples));
      std::size_t hits = 0;
      for (std::size_t k = 0; k < n; ++k) {
        const std::int32_t p = px[k * px.size() / n];
        hits += matched(job.model, pack_rgb(frame.rgb.data[std::size_t(p)]));
      }
      if (n > 0 && float(hits) >= ss.min_colour_fraction * float(n)) kept.push_back(std::move(job));
    }
    jobs = std::move(kept);
  }

  /// The scene jobs of `model` on segment k (SceneSettings): none if the segment is too small or too
  /// large to hold it, one around the segment's box, or one per model-sized piece of a larger segment
  /// (k-means on its readings).
  void add_scene_jobs(const RgbdFrame& frame, const FrameSegments& segments, int k, int model,
                      std::vector<Job>& jobs) const {
    const SceneSettings& ss = settings_.scene;
    const FrameSegment& seg = segments.segments[std::size_t(k)];
    const auto [small_face, large_face] = face_m2_[std::size_t(model)];
    if (seg.area_m2 < ss.min_area_fraction * small_face) return;
    if (seg.area_m2 > ss.max_area_faces * large_face) return;  // background for this model
    const Mesh& mesh = models_[std::size_t(model)].mesh;
    const std::string who = "segment " + std::to_string(k + 1);
    const int pieces =
        seg.extent_m > ss.piece_extent_factor * size_m_[std::size_t(model)] ||
                seg.area_m2 > ss.piece_area_faces * large_face
            ? std::clamp(int(std::ceil(seg.area_m2 / large_face)), 2, std::max(ss.max_pieces, 2))
            : 1;
    const std::vector<Image<std::uint8_t>> masks =
        sixdof_detail::segment_pieces(frame, segments.labels, seg, pieces);
    for (const auto& mask : masks) {
      const std::array<int, 4> b = mask_bbox(mask);
      if (b[2] < 0) continue;
      Job job;
      job.model = model, job.label = std::int32_t(k + 1);  // segment: group_segments()
      job.box_xywh = {b[0], b[1], b[2], b[3]};
      job.depths = proposal_depths(frame.depth_m, mask, mesh, settings_.proposals, who);
      if (masks.size() > 1)  // a piece: GICP against its own readings, not its neighbour's in the segment
        for (std::size_t i = 0; i < mask.data.size(); ++i)
          if (mask.data[i]) job.piece_pixels.push_back(std::int32_t(i));
      jobs.push_back(std::move(job));
    }
  }

  /// Per job, the segments its object may span: its own and every segment whose centroid lies within the
  /// model's size of it and that is no larger than the model (an occluder in front splits an object into
  /// such parts). Sets each job's `segment` to its group's index; returns the distinct groups (sorted
  /// labels).
  std::vector<std::vector<std::int32_t>> group_segments(const FrameSegments& segments,
                                                        std::vector<Job>& jobs) const {
    std::map<std::vector<std::int32_t>, std::int32_t> index;
    std::vector<std::vector<std::int32_t>> groups;
    for (Job& job : jobs) {
      const float size = size_m_[std::size_t(job.model)];
      const FrameSegment& own = segments.segments[std::size_t(job.label - 1)];
      std::vector<std::int32_t> members;
      for (const FrameSegment& other : segments.segments)
        if (other.label == own.label ||
            (other.extent_m <= size && (other.centroid_cam - own.centroid_cam).norm() <= size))
          members.push_back(other.label);
      auto it = index.find(members);
      if (it == index.end()) {
        it = index.emplace(members, std::int32_t(groups.size())).first;
        groups.push_back(members);
      }
      job.segment = it->second;
    }
    return groups;
  }

  /// The first pass' GICP targets built from `targets` (SixDofSettings::first_pass_target_stride); none
  /// when that grid is not coarser than the observed one (the first pass then uses `targets` itself).
  std::optional<typename Backend::Registration> first_pass_targets(const RgbdFrame& frame,
                                                                   const CloudBatch& targets) const {
    const SixDofSettings& s = settings_;
    if (s.first_pass_target_stride <= s.observed.stride) return std::nullopt;
    return std::optional<typename Backend::Registration>(
        std::in_place, on_stride_grid(targets, frame.camera.width, s.first_pass_target_stride,
                                      SixDofSettings::kFirstPassMinTargets));
  }

  static const typename Backend::Registration* or_same(
      const std::optional<typename Backend::Registration>& coarse,
      const typename Backend::Registration& all) {
    return coarse ? &*coarse : &all;
  }

  /// GICP's targets: the groups' clouds, then one cloud per piece job of its piece's readings on the
  /// observed grid (Job::target set; a piece without readings there keeps its group's).
  CloudBatch with_pieces(const RgbdFrame& frame, const CloudBatch& groups, std::vector<Job>& jobs) const {
    const ObservedCloudSettings& o = settings_.observed;
    CloudBatch out = groups;
    for (Job& job : jobs) {
      job.target = job.segment;
      if (job.piece_pixels.empty()) continue;
      const std::size_t before = out.size();
      const std::int32_t cloud = std::int32_t(out.num_clouds());
      for (const std::int32_t p : job.piece_pixels) {
        const int u = p % frame.camera.width, v = p / frame.camera.width;
        if (u % o.stride || v % o.stride) continue;
        if (const float d = frame.depth_m(u, v); observed_detail::keep(d, o))
          observed_detail::append_pixel(frame, u, v, d, cloud, out);
      }
      if (out.size() == before) continue;
      out.offsets.push_back(std::int64_t(out.size()));
      job.target = cloud;
    }
    return out;
  }

  /// One observed cloud per group of segment labels (1..S): the readings on the observed grid whose
  /// label is in the group (readings relabelled above S, explained ones, belong to none).
  CloudBatch group_clouds(const RgbdFrame& frame, const LabelImage& labels,
                          const std::vector<std::vector<std::int32_t>>& groups, std::size_t S) const {
    const ObservedCloudSettings& o = settings_.observed;
    CloudBatch out;
    std::vector<std::uint8_t> member(S + 1);
    for (std::size_t g = 0; g < groups.size(); ++g) {
      std::fill(member.begin(), member.end(), 0);
      for (const std::int32_t l : groups[g]) member[std::size_t(l)] = 1;
      for (int v = 0; v < frame.camera.height; v += o.stride)
        for (int u = 0; u < frame.camera.width; u += o.stride) {
          const std::int32_t l = labels(u, v);
          if (l < 1 || std::size_t(l) > S || !member[std::size_t(l)]) continue;
          if (const float d = frame.depth_m(u, v); observed_detail::keep(d, o))
            observed_detail::append_pixel(frame, u, v, d, std::int32_t(g), out);
        }
      out.offsets.push_back(std::int64_t(out.size()));
    }
    return out;
  }

  SixDofSceneResult& finish(SixDofSceneResult& out, sixdof_detail::Clock::time_point t_start) const {
    out.search.timings.total = sixdof_detail::seconds_since(t_start);
    return out;
  }

  void validate_scene(const RgbdFrame& frame, const std::vector<SixDofObject>& objects) const {
    validate_settings(frame);
    const SceneSettings& ss = settings_.scene;
    if (!(ss.min_area_fraction >= 0) || !(ss.max_area_faces > 0) || !(ss.piece_extent_factor > 0) ||
        !(ss.piece_area_faces > 0) || ss.max_pieces < 1 ||
        !(ss.min_inlier_fraction >= 0 && ss.min_inlier_fraction <= 1) ||
        !(ss.max_colour_mismatch >= 0 && ss.max_colour_mismatch <= 1) || !(ss.explain_distance_m > 0) ||
        ss.min_segment_points < 1 || !(ss.min_colour_fraction >= 0) || ss.colour_samples < 1)
      throw InvalidInput(
          "SixDofSettings::scene",
          "needs min_area_fraction >= 0, max_area_faces > 0, piece_extent_factor > 0, "
          "piece_area_faces > 0, max_pieces >= 1, min_inlier_fraction and max_colour_mismatch in [0, 1], "
          "explain_distance_m > 0, "
          "min_segment_points >= 1, min_colour_fraction >= 0 and colour_samples >= 1");
    for (std::size_t i = 0; i < objects.size(); ++i) {
      const std::string who = "objects[" + std::to_string(i) + "]";
      if (objects[i].model < 0 || std::size_t(objects[i].model) >= models_.size())
        throw InvalidInput(who, "unknown model id " + std::to_string(objects[i].model) + " (" +
                                    std::to_string(models_.size()) + " models)");
      if (objects[i].count < 0) throw InvalidInput(who, "count must be >= 0");
      for (std::size_t j = 0; j < i; ++j)
        if (objects[j].model == objects[i].model)
          throw InvalidInput(who, "model " + std::to_string(objects[i].model) + " is listed twice");
    }
  }

  std::vector<SixDofModel> models_;
  SixDofSettings settings_;
  typename Backend::Renderer renderer_;
  SurfaceFit<Backend> surface_fit_;
  std::vector<float> diameter_;  ///< per model, an upper bound (2 x the largest vertex distance), metres
  std::vector<float> size_m_;    ///< per model, its bounding box's diagonal, metres
  /// per model, its bounding box's smallest and largest face, m^2 (the scene search's size rules)
  std::vector<std::pair<float, float>> face_m2_;
  std::vector<std::vector<std::uint32_t>> colours_;  ///< per model, sixdof_detail::model_colours()
};

}  // namespace perch2
