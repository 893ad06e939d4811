// The 6-DoF search's inputs and settings: the models it can pose (SixDofModel), the detected instances it
// poses (SixDofInstance), and one settings struct per stage (SixDofSettings, with LocalSearchSettings for
// the turn search and SceneSettings for estimate_scene()). Every field has its default, its unit and, where
// it was tuned, the measurement behind it. The pipeline they drive: perch2/search/sixdof.hpp.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>

#include "perch2/core/image.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/observed.hpp"
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
  /// The sweep every 15 deg (sweep_turns 24, was 36 = 10 deg; a third of the local search's renders are the
  /// sweep's, 3 axes x sweep_turns per pose): thrust_omp, Intel Xeon VM, held-out seed 5050 (gt masks)
  /// ADD(-S) AUC 95.8 and BOP AR (no VSD) 0.923 both at 0.99 -> 0.95 s per image; bench_sixdof --masks
  /// none 95.3 / 0.932 both. Climbing only the best two starts (climbed_starts 2) cost --masks none 2.3 AR
  /// (printed cans and boxes turned): ranked at the fine sweep's stride 2, the right start is not always
  /// among them.
  TurnSearchSettings turns = [] {
    TurnSearchSettings t;
    t.climb_shift_m = 0.f;
    t.sweep_turns = 24;
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
  int max_pieces = 6;  ///< see above (>= 1)
  /// A segment some model was cut into pieces for may be two objects: a model that takes it whole also
  /// gets a job on each of its halves (add_half_jobs in perch2/search/sixdof/scene_jobs.hpp), where the
  /// retrieval ranks the jobs (detect(); estimate_scene() with retrieval_jobs_per_object). Generated
  /// decoy sets (32 models, 12 images each, 2-vCPU AMD EPYC VM, DetectSettings::retrieval_screen_keep 0),
  /// bop24_mAP without -> with: seed 241 (where a bowl merged with a distractor was taken for its 0.8x
  /// copy) 0.769 -> 0.774, 242 0.749 -> 0.838, 243 0.785 -> 0.825, 62 % more jobs for the retrieval.
  /// Searched in full without the retrieval they cost bench_sixdof --masks none (20 scenes, objects
  /// given) 50 % more time for nothing (ADD-S / ADD(-S) AUC 98.7 / 95.3 -> 98.7 / 94.8, 3.9 -> 5.9 s).
  bool half_jobs = true;
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
  /// Per requested object, up to this many placements beyond its count once no requested instance can
  /// be placed (>= 0; not in the residual pass); each object then keeps its `count` placements with the
  /// best detection score (sixdof_detail::detection_score: pose score, depth agreement, colours,
  /// evidence). Placing by readings explained can put a partly hidden object on a larger surface of
  /// another; its own candidate is then placed as a spare and outranks it. Tuning: the odd lm_cat_dev
  /// frames with half of the cat hidden by a synthetic unmodelled box (ADD-S < 1 cm 47 % with 0, 53 %
  /// with 1, 73 % with 2 or 3: the cat had been put on objects half a metre away); unchanged on the
  /// plain odd frames (100 %) and on generated seed 301 (90.4 %, once pixels without a reading no longer
  /// counted against a pose's depth agreement).
  int spare_placements = 2;
  /// If > 0, the jobs of each segment are ranked as in detect() and only the best this many per object
  /// the segment may hold are searched in full (detect()'s retrieval with DetectSettings' defaults
  /// otherwise: a coarse search of every screened job, jobs whose coarse best may not be placed dropped,
  /// the full search at the coarse best's depth); 0 = every job. Faster, but on held-out clutter it lost
  /// objects whose job the coarse search ranked low. Generated seed 301 (tuning, 15 images, ADD-S /
  /// ADD(-S) AUC, 2-vCPU AMD EPYC VM): 0: 92.3 / 87.8 in 6.9 s per image, 3: 91.8 / 89.7 in 2.4 s, 5:
  /// 94.4 / 91.0 in 3.5 s, 8: 94.4 / 90.4 in 4.8 s; seed 302 (held out, 15 images, 92 targets): 0: 96.5 /
  /// 91.5 in 11.3 s, 3: 94.4 / 89.5 in 2.7 s, 5: 93.6 / 88.8 in 4.2 s (two objects 56 and 83 % visible
  /// placed 27-30 cm off). lm_cat_dev frames (plain and half hidden): the same with each.
  int retrieval_jobs_per_object = 0;
};

/// The screen before the first pass (SixDofSettings::screen): every proposal of an instance whose
/// segment shows at least min_points at `stride` is rendered at that coarser stride, pulled by `icp_
/// iterations` ICP passes and scored with first_pass_cost; only the instance's best keep_fraction (at
/// least min_keep) go on to the first pass, from where the screen left them. The first pass then runs
/// on a fraction of the proposals at a fraction of their cost each.
struct ScreenSettings {
  int stride = 16;              ///< render stride of the screen (> render.stride; 0 = no screen)
  int min_points = 12;          ///< instances expected to show fewer points at `stride` are not screened
  int icp_iterations = 8;       ///< ICP passes (first pass' cap and targets), >= 1
  float keep_fraction = 0.34f;  ///< of each screened instance's proposals, in (0, 1]
  int min_keep = 24;            ///< ... but at least this many (>= 1)
  /// Rank by first_pass_cost with its colour test (true) or by depth only (false; on generated clutter
  /// without masks it lost an instance and ADD-S AUC 0.9).
  bool use_color = true;
  /// estimate_scene() and detect() screen too. Off by default: on generated clutter without masks the
  /// screen made the search 30 % faster at the same ADD-S and ADD(-S) AUC but BOP AR 1.0-1.2 lower (printed
  /// cans found turned a few degrees; docs/benchmarks.md, "Where the time goes").
  bool in_scene = false;
  /// Screen a mostly hidden instance too (one whose first pass runs on a finer grid, first_pass_min_points),
  /// at the same ratio finer (stride 8 for a first pass at 4). Off: on bench_sixdof's scenes (gt masks) it
  /// took 16 % more off (1.01 -> 0.84 s per scene) but ranked hidden objects on too few points (ADD(-S)
  /// AUC 96.9 -> 96.1, BOP AR 0.963 -> 0.942).
  bool hidden = false;
};

/// The coarse renders of a large mesh (the screen's and the first pass' strides) use a simplified copy
/// (perch2/render/simplify.hpp: vertices clustered on a grid of cell_fraction x the model's diameter): a
/// render's cost is mostly its mesh's triangles whatever the stride, and at stride 8 a sample covers a
/// centimetre of an object a metre away. On the 29 real LINEMOD-cat frames (a 31,468-triangle scan;
/// thrust_omp, Intel Xeon VM, s per frame): gt masks 0.157 -> 0.127 s, degraded masks 0.188 -> 0.160 s, the
/// same poses (ADD 97.2 / 96.9); without masks 1.41 -> 1.18 s, ADD-S AUC 98.3 -> 98.2, ADD 96.7 both, AR (no
/// VSD) 0.993 -> 0.990. The generated sets' models (at most 3,456 triangles) are rendered as they are. Read
/// when the estimator is built, but min_stride (0 turns the copy off at any time).
struct CoarseMeshSettings {
  int min_stride = 8;                ///< renders at this stride or coarser use the copy (0 = never)
  std::size_t min_triangles = 8000;  ///< meshes with fewer triangles are rendered as they are
  float cell_fraction = 0.025f;      ///< the clustering cell, a fraction of the model's diameter (> 0)
  int texture_factor = 2;            ///< the copy's texture, shrunk this much per axis (>= 1)
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
  /// down to second_pass_stride: a mostly hidden object keeps enough points for GICP and the ranking. 24
  /// (was 40; with the screen, thrust_omp, Intel Xeon VM, ADD(-S) AUC / BOP AR without VSD, s per image):
  /// bench_sixdof gt 96.9 / 0.963 -> 96.7 / 0.958 at 1.01 -> 0.81 s; held-out seed 5050 gt 96.1 / 0.929 ->
  /// 95.8 / 0.923 at 1.23 -> 1.03 s, det 87.4 / 0.843 -> 86.7 / 0.841 at 1.30 -> 1.01 s; seed 4040 gt 95.9 /
  /// 0.951 -> 96.5 / 0.960 at 1.03 -> 0.75 s; without masks 94.8 / 0.931 -> 95.3 / 0.932 at 4.25 -> 3.57 s
  /// (seed 2020) and 91.7 / 0.885 both at 4.33 -> 3.84 s (seed 4040); the real LINEMOD-cat frames AR 0.958
  /// both at 0.27 -> 0.17 s (gt masks), 0.947 -> 0.948 at 0.31 -> 0.20 s (degraded masks).
  int first_pass_min_points = 24;
  ScreenSettings screen;           ///< the cheaper pass before the first one (see ScreenSettings)
  CoarseMeshSettings coarse_mesh;  ///< simplified meshes for coarse renders (see CoarseMeshSettings)
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

}  // namespace perch2
