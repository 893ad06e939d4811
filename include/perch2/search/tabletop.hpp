// 3-DoF tabletop search (PERCH 2.0, Sections III-IV): find (x, y, yaw) on a known or estimated table plane
// of every requested object by rendering a grid of hypotheses, refining them by (x, y, yaw) ICP,
// re-rendering and scoring them with the explanation cost, and selecting the best per object.
//
//   perch2::TabletopEstimator<perch2::cpu::Backend> estimator({{can_a_mesh}, {can_b_mesh}});
//   perch2::TabletopResult r = estimator.estimate(frame, {{0, 1}, {1, 2}});  // model 0 once, model 1 twice
//   for (const auto& p : r.poses) use(p.model, p.T_cam_obj, p.T_world_obj);
//
// Frames: the table ("world") frame has z up (towards the camera side) and the table top at z = 0, as the
// BOP world frame of tabletop scenes. A model stands on the table in its rest pose T_place_obj (object ->
// placement frame; default: the model's own z axis up and its lowest vertex on the table); a hypothesis is
// T_world_obj = Trans(x, y, 0) * RotZ(yaw) * T_place_obj.
//
// Pipeline per frame (timed per stage in TabletopResult::timings):
//   table     T_cam_world given, or estimate_table_plane() (RANSAC on the depth)
//   observed  the frame's points at settings.observed (stride 2); those between min_height_m and
//             max_height_m above the table are the object readings (ICP target, support, workspace)
//   grid      x, y every xy_step_m over the workspace, yaw every yaw_step_rad (one yaw if yaw_symmetric);
//             a position needs min_support_points object readings within the footprint's circumradius +
//             support_margin_m
//   render    every hypothesis at render.stride, occluders marked from the observed depth (C-PERCH)
//   refine    (x, y, yaw) ICP against the object readings (Dof::TableXYYaw), then back onto the grid's
//             manifold exactly
//   cost      re-rendered and scored (perch2/cost/cost.hpp), coarse to fine: all at coarse_score_stride,
//             the best few yaws at each model's best places again at score_stride; J_o's volume is the
//             model's convex footprint prism from min_height_m to its top, posed by the hypothesis
//   select    per model, the lowest-cost acceptable poses (min_rendered_points, min_inlier_fraction) whose
//             footprints do not interpenetrate by more than overlap_tolerance_m, `count` of them; where
//             some are missing, a second look over the readings no selected footprint explains (second_look)
//   polish    each selected pose refined again by (x, y, yaw) ICP with all its points (polish_rounds)
//   yaw       the yaw (and x, y by a millimetre or two) of every selected pose of a model whose colours a
//             turn changes, by a sweep and hill climbing over turns about the table normal scored by the
//             print's appearance (YawSearchSettings, perch2/search/local_search.hpp): ICP cannot turn a
//             printed can or bottle, and the grid's yaws and the tolerant colour test leave its label up to
//             tens of degrees off
//
// Variants (the paper's Table I, see tabletop_variant()):
//   Perch2C  parallel per-object search, occluders marked from the observed depth, RGB-D cost (default)
//   Perch2A  as C without occluder marking
//   Perch2B  Monotone Scene Generation: objects placed one per level, a new object may not occlude the
//            ones already placed, which hide it when it is rendered; RGB-D cost. Greedy: each level keeps
//            the single best placement (a beam of width 1, not PERCH's full tree search).
//   Perch    as B with the depth-only cost (PERCH)
//   DepthOnlyC  as C with the depth-only cost
//   BfIcp    brute-force ICP baseline (PERCH's): every grid hypothesis' visible surface refined by ICP; the
//            lowest truncated mean squared correspondence distance wins (no rendering cost)
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <optional>
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
#include "perch2/render/render.hpp"
#include "perch2/search/local_search.hpp"
#include "perch2/search/table_plane.hpp"

namespace perch2 {

/// A model the tabletop search can place.
struct TabletopModel {
  Mesh mesh;  ///< object frame, metres
  /// Symmetric about the table normal in shape: one yaw per position instead of a yaw grid. An untextured
  /// model is taken to be symmetric in appearance too; a textured one (a can whose shape is symmetric but
  /// whose label is not) still gets the yaw search (YawSearchSettings), which turns its label right.
  bool yaw_symmetric = false;
  /// Object -> placement frame (z up, table at z = 0, yaw 0). Unset: the object's z axis up, its lowest
  /// vertex on the table, its origin above the placement origin.
  std::optional<Pose> T_place_obj;
};

/// How many instances of a model (index into the estimator's models) the frame shows.
struct ObjectCount {
  int model = 0;
  int count = 1;
};

enum class SearchMode : std::uint8_t {
  Parallel,       ///< every object searched independently (PERCH 2.0)
  Tree,           ///< Monotone Scene Generation, greedy level by level (PERCH, PERCH 2.0-B)
  BruteForceIcp,  ///< ICP fitness instead of the rendering cost (BF-ICP baseline)
};

enum class SearchVariant : std::uint8_t { Perch2C, Perch2A, Perch2B, Perch, DepthOnlyC, BfIcp };

inline const char* to_string(SearchVariant v) {
  switch (v) {
    case SearchVariant::Perch2C:
      return "perch2-c";
    case SearchVariant::Perch2A:
      return "perch2-a";
    case SearchVariant::Perch2B:
      return "perch2-b";
    case SearchVariant::Perch:
      return "perch";
    case SearchVariant::DepthOnlyC:
      return "depth-only-c";
    case SearchVariant::BfIcp:
      return "bf-icp";
  }
  return "?";
}

/// The yaw search after selection (see the file comment and perch2/search/local_search.hpp). ICP aligns what
/// the depth shows; a printed can or bottle turned about its axis shows the same depth, so its yaw stays
/// near the grid yaw it started from (yaw_step_rad apart), and the final cost's colour test
/// (ColorRule::AnyNeighbour) tolerates a label a few millimetres off by design. Here each selected pose is
/// turned about the table normal through its placement origin: the turns whose depth-only cost (J_r + J_o
/// as fractions, the cost's delta) stays within turns.geometry_tolerance are the look-alikes (every turn of
/// a can, a box's half turn), and among them the print decides, by the correlation of rendered and
/// observed colours (perch2/cost/appearance.hpp). Models a turn cannot change in colour keep their pose:
/// single-coloured ones (their yaw is the geometry's, ICP's) and untextured ones declared yaw-symmetric
/// (TabletopModel::yaw_symmetric).
struct YawSearchSettings {
  bool enabled = true;  ///< false: the selected yaws are returned as they are (the paper's search)
  /// Sweep, climb and final comparison (local_search.hpp). The fine sweep and the climb run at every pixel
  /// (turns.fine_stride 1; the 6-DoF local search's default is 2): a partly hidden label shows a few letters,
  /// and every pixel of them counts. bench_tabletop (perch2c, thrust_omp, 2 cores), stride 2 -> 1: ADD(-S)
  /// AUC 95.2 -> 95.3 (seed 2020) and 94.2 -> 95.0 (`perch2 generate --seed 77`), at 0.78 -> 1.05 and
  /// 0.71 -> 0.96 s per image. fine_stride 2 is the faster choice.
  TurnSearchSettings turns = [] {
    TurnSearchSettings t;
    t.fine_stride = 1;
    return t;
  }();
};

struct TabletopSettings {
  // ---- hypotheses
  float xy_step_m = 0.08f;           ///< grid step in x and y on the table, metres (paper: 0.08)
  float yaw_step_rad = 0.39269908f;  ///< yaw grid step, radians (paper: 22.5 deg)
  /// Table-frame x-y bounds of the grid (metres). Unset: the bounding box of the observed points above the
  /// table (between min_height_m and max_height_m), grown by workspace_margin_m.
  std::optional<Eigen::AlignedBox2f> workspace_xy_m;
  float workspace_margin_m = 0.02f;  ///< see workspace_xy_m, metres
  /// Automatic workspace only: also clip it to the bounding box of the table readings (within
  /// min_height_m of z = 0) grown by workspace_margin_m, so walls or shelves above the table's height
  /// elsewhere in the room do not spread the grid.
  bool clip_workspace_to_table = true;
  float min_height_m = 0.01f;  ///< readings higher than this above the table belong to objects, metres;
                               ///< also the floor of each hypothesis' J_o volume (table noise stays out)
  float max_height_m = 0.6f;   ///< readings higher than this above the table are ignored, metres
  /// A grid position is kept only if this many object readings lie within (footprint circumradius +
  /// support_margin_m) of it in the table plane.
  int min_support_points = 10;
  float support_margin_m = 0.06f;  ///< covers the grid cell (0.75 * xy_step_m at the default step), metres

  // ---- observed cloud, rendering, refinement, cost
  ObservedCloudSettings observed{2};  ///< pixels of the frame used as observed points (stride 2)
  RenderSettings render;              ///< renders before refinement (stride 4 by default)
  int score_stride = 2;               ///< stride of the re-render that is scored (>= 1)
  /// Coarse-to-fine scoring (parallel modes): every refined hypothesis is first scored at this stride;
  /// per model, the best places (by that coarse cost) are re-rendered and scored at score_stride, and only
  /// those are selected from. 0 (or <= score_stride) scores everything at score_stride.
  int coarse_score_stride = 4;
  /// Places kept per model by the coarse pass: the requested instances of all models in the frame plus
  /// this many. A model fits the places of other objects too (same-shape cans fit each other's, a can
  /// fits a bottle's), and those places compete with its own until selection; keeping one place per
  /// object in the scene keeps its own.
  int rescore_extra_places = 2;
  /// Per kept place, the best this many yaws (refined hypotheses within rescore_place_radius_m in x and y)
  /// are rescored: the coarse stride decides where, the fine one which way a label faces.
  int rescore_yaws = 4;
  float rescore_place_radius_m = 0.02f;  ///< see rescore_yaws, metres
  bool occluder_marking = true;          ///< observed depth nearer than a rendered pixel hides it (C-PERCH)
  /// With occluder marking: a pixel without a depth reading hides the rendered point there too. It is
  /// unseen, not unexplained: the selection counts it through hidden_point_weight, not as an outlier. A
  /// depth sensor has no reading at depth edges, grazing angles, in its projector's shadow and at specular
  /// highlights, and most of all on a partly hidden object (the occluder's edge band and shadow fall on
  /// it). Counted as outliers, those pixels cost the right pose of such an object most of its points:
  /// on `perch2 generate --seed 77`'s 80 images, 10 of 409 targets (visible fraction 0.11-0.45) failed
  /// the acceptance tests at every pose and got no estimate (e.g. a can 45% visible: 260 of its 613
  /// rendered points fell on pixels without a reading).
  bool missing_depth_hides = true;
  bool refine = true;  ///< (x, y, yaw) ICP of every hypothesis before scoring
  /// ICP aligns at most this many of a hypothesis' rendered points (evenly spread over its render; 0 =
  /// all; BF-ICP always uses all, its fitness is over every point): three parameters need far fewer than
  /// a large object shows, and refinement then no longer grows with the object's size in the image. On
  /// bench_tabletop's 30 scenes 128 gave the same poses within 1 cm as 192 in 13% less CPU time.
  int icp_max_points = 128;
  /// After refinement, hypotheses whose ICP found a correspondence (within the ICP cap) for less than this
  /// fraction of its points are dropped before scoring: they lie on bare table or beside the objects, and a
  /// pose needs min_inlier_fraction of its points within delta (< the cap) to be accepted anyway. 0 keeps
  /// all.
  float min_icp_inlier_fraction = 0.5f;
  /// After refinement, hypotheses of one model that ICP moved to the same placement (within dedupe_xy_m
  /// in x and y and dedupe_yaw_rad in yaw; yaw ignored for yaw-symmetric models) are scored once: from a
  /// 0.08 m / 22.5 deg grid most starts near an object converge to a few placements. 0 turns it off.
  float dedupe_xy_m = 0.002f;
  float dedupe_yaw_rad = 0.0175f;  ///< see dedupe_xy_m (1 deg)
  IcpSettings icp = [] {
    IcpSettings s;
    s.max_correspondence_distance_m = 0.04f;
    s.max_iterations = 20;
    return s;
  }();  ///< dof, up_cam and origin_cam are set from the table frame
  /// The cost. Normalised by default (Normalization::Fractions): raw counts favour poses that show few
  /// points (far away, at the image border, mostly hidden behind an occluder, where few points can be
  /// outliers) over a whole object in view; on bench_tabletop's 30 scenes that lost 5 fully visible
  /// objects to such poses (Counts: ADD-S < 1 cm 94.6%, Fractions 95.2%).
  CostSettings cost = [] {
    CostSettings c;
    c.normalization = Normalization::Fractions;
    return c;
  }();
  SearchMode mode = SearchMode::Parallel;

  // ---- selection
  int min_rendered_points = 10;      ///< a pose must show at least this many points at score_stride
  float min_inlier_fraction = 0.5f;  ///< ... and explain this fraction of them (rendered inliers / rendered)
  /// Parallel modes with occluder marking: selection minimises cost total + hidden_point_weight * (share of
  /// the pose's samples hidden by nearer observed depth, by a missing reading (missing_depth_hides) or
  /// outside the image), as if each unseen point were an outlier with this probability. Occluder marking
  /// drops hidden points from J_r, so without this term a pose almost entirely hidden or out of view (a few
  /// points left, all explained) costs ~0 and beats an object in full view. On bench_tabletop's 30 scenes:
  /// ADD-S < 1 cm 95.2% at 0, 95.9% at 0.1 and 0.25; 0.25 still lets a pose in full view with up to a quarter
  /// of its points unexplained win over a zero-cost one that is hidden. 0: the cost alone.
  float hidden_point_weight = 0.25f;
  /// ... and hold at least this many observed readings in its volume: a hypothesis hidden behind another
  /// object shows a few points and has an empty volume, so its raw-count cost would be near 0 (not used by
  /// BruteForceIcp, which has no volume).
  int min_observed_in_volume = 10;
  /// Parallel mode: when selection leaves requested instances missing, look again where the selected poses
  /// leave readings unexplained (readings farther than second_look_margin_m outside every selected
  /// footprint): a grid at half xy_step_m over them, refined against them alone. A mostly hidden object shows
  /// a sliver of readings between 8 cm grid positions, and ICP from there slides onto the larger
  /// neighbour beside it; on `perch2 generate --seed 77`'s 80 images 5 of 409 targets (visible fraction
  /// 0.11-0.45) had no pose. Runs only for images with a shortfall.
  bool second_look = true;
  float second_look_margin_m = 0.01f;  ///< see second_look, metres
  /// Two footprints overlap when they interpenetrate by more than this (separating-axis depth), metres.
  float overlap_tolerance_m = 0.01f;
  /// Parallel modes: placements of different models may not overlap either. Where two models' best
  /// placements collide (same-shape cans finding the same can), the one leaving the smaller share of its
  /// points unexplained keeps it and the other takes its next best placement. false: every model is
  /// selected on its own, as in the paper's PERCH 2.0 (two models may then claim one object).
  bool exclusive_placements = true;
  /// Tree mode: a placement may hide at most this fraction of its points' pixels of objects already placed.
  float tree_max_occluding_fraction = 0.02f;
  /// Fewer acceptable, non-overlapping poses than requested instances: throw InvalidInput (true) or return
  /// the poses found and list the shortfall in TabletopResult::missing (false; e.g. for batch evaluation).
  bool strict_instances = true;
  /// Return every scored hypothesis (pose + cost) in TabletopResult::scored, e.g. to inspect the cost
  /// landscape or draw it; off by default (thousands of entries).
  bool keep_scored = false;

  /// After selection (Parallel mode): every selected pose is refined again, polish_rounds times rendered
  /// at polish_stride and aligned by (x, y, yaw) ICP with all its points, pairs within
  /// polish_max_distance_m. The search's refinement starts from the grid with a few points of a coarse
  /// render and a wide pair distance (icp_max_points, render.stride, icp): it finds the place but stops a
  /// few millimetres or degrees short, and the tolerant cost cannot tell; a block 5-10 mm off in full
  /// view was typical. On `perch2 generate`'s seeds 77 / 2020 (bench_tabletop): ADD-S AUC 97.7 -> 98.6 /
  /// 97.0 -> 97.7, ADD(-S) 95.6 -> 97.3 / 95.3 -> 97.2, for 0.05-0.07 s per image. Not guarded by the cost
  /// (only by the acceptance tests): keeping a polished pose only where its cost did not rise kept less
  /// than half the gain; polishing after the yaw search instead of before it lost 0.8-1.3 ADD(-S) (the
  /// appearance test reads a label better from the polished place). 0 rounds: off.
  int polish_rounds = 2;
  int polish_stride = 1;                ///< see polish_rounds (>= 1)
  float polish_max_distance_m = 0.01f;  ///< see polish_rounds, metres (> 0)
  int polish_iterations = 30;           ///< ICP passes per round (>= 1)

  /// After selection (Parallel and Tree modes): the yaw of textured objects (see YawSearchSettings).
  YawSearchSettings yaw_search;

  TablePlaneSettings table;  ///< used when no table frame is given
};

/// The settings of one of the paper's variants (see the file comment), on top of `base`.
inline TabletopSettings tabletop_variant(SearchVariant v, TabletopSettings base = {}) {
  const bool parallel =
      v == SearchVariant::Perch2C || v == SearchVariant::Perch2A || v == SearchVariant::DepthOnlyC;
  base.mode = parallel                    ? SearchMode::Parallel
              : v == SearchVariant::BfIcp ? SearchMode::BruteForceIcp
                                          : SearchMode::Tree;
  base.occluder_marking = v == SearchVariant::Perch2C || v == SearchVariant::DepthOnlyC;
  base.cost.use_color =
      v == SearchVariant::Perch2C || v == SearchVariant::Perch2A || v == SearchVariant::Perch2B;
  base.yaw_search.enabled = base.yaw_search.enabled && base.cost.use_color;  // depth-only: no label seen
  return base;
}

struct TabletopPose {
  int model = 0;     ///< index into the estimator's models
  int instance = 0;  ///< 0 .. count - 1 among this model's poses, best first
  Pose T_cam_obj = Pose::Identity();
  Pose T_world_obj = Pose::Identity();
  float x_m = 0, y_m = 0, yaw_rad = 0;  ///< table frame placement (see the file comment)
  float score = 0;     ///< what selection minimised: cost total, or ICP fitness (m^2) for BruteForceIcp
  CostBreakdown cost;  ///< the explanation cost at this pose (scored as in Parallel mode)
};

struct TabletopTimings {  ///< seconds, wall clock
  double table = 0, observed = 0, hypotheses = 0, render = 0, refine = 0, cost = 0, select = 0, total = 0;
  double yaw = 0;  ///< the yaw search (its renders and costs are also in render and cost)
};

struct TabletopResult {
  std::vector<TabletopPose> poses;  ///< grouped by request order, best first within a model
  Pose T_cam_world = Pose::Identity();
  bool table_estimated = false;        ///< true if T_cam_world came from estimate_table_plane
  std::size_t hypotheses_grid = 0;     ///< grid hypotheses before pruning
  std::size_t hypotheses_kept = 0;     ///< ... with enough observed support
  std::size_t hypotheses_refined = 0;  ///< refined by ICP (Tree mode: summed over levels)
  std::size_t hypotheses_coarse = 0;   ///< scored at coarse_score_stride (after de-duplication)
  std::size_t hypotheses_scored = 0;   ///< scored at score_stride (Tree mode: summed over levels)
  std::size_t yaw_candidates = 0;      ///< turned poses the yaw search scored
  std::vector<ObjectCount> missing;    ///< non-strict mode: instances requested but not found
  /// With TabletopSettings::keep_scored: every scored hypothesis after refinement (Tree mode: every level),
  /// instance = -1; score as in TabletopPose.
  std::vector<TabletopPose> scored;
  TabletopTimings timings;
};

/// The rest pose T_place_obj of a model from any pose T_world_obj in which it stands on the table (e.g. a
/// dataset's ground truth or a generator's placement): the pose with its table-plane position and its yaw
/// removed, keeping its height, roll and pitch. Yaw is measured by the object's x axis projected onto the
/// table (its y axis if x is vertical). Then T_world_obj = Trans(x, y, 0) * RotZ(yaw) * T_place_obj.
inline Pose rest_pose_from(const Pose& T_world_obj) {
  Eigen::Vector3f axis = T_world_obj.linear().col(0);
  if (Eigen::Vector2f(axis.x(), axis.y()).norm() < 1e-3f) axis = T_world_obj.linear().col(1);
  const float yaw = std::atan2(axis.y(), axis.x());
  Pose T_world_place = Pose::Identity();
  T_world_place.linear() = Eigen::AngleAxisf(yaw, Eigen::Vector3f::UnitZ()).toRotationMatrix();
  T_world_place.translation() =
      Eigen::Vector3f(T_world_obj.translation().x(), T_world_obj.translation().y(), 0.f);
  return T_world_place.inverse() * T_world_obj;
}

namespace tabletop_detail {

using Clock = std::chrono::steady_clock;
inline double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

inline Pose placement(float x, float y, float yaw) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisf(yaw, Eigen::Vector3f::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3f(x, y, 0.f);
  return T;
}

inline Pose default_rest_pose(const Mesh& m) {
  Pose T = Pose::Identity();
  T.translation().z() = -m.bounds().min().z();
  return T;
}

struct Candidate {
  int model;
  float x, y, yaw;
};

/// Footprint polygon of a candidate in table coordinates.
inline std::vector<Eigen::Vector2f> posed_polygon(const Footprint& f, const Candidate& c) {
  const Eigen::Rotation2Df R(c.yaw);
  std::vector<Eigen::Vector2f> out;
  for (const auto& p : f.polygon_xy_m) out.push_back(R * p + Eigen::Vector2f(c.x, c.y));
  return out;
}

/// Interpenetration depth of two convex polygons (separating axis theorem): the smallest overlap of their
/// projections over both polygons' edge normals; <= 0 if they are separated.
inline float penetration_m(const std::vector<Eigen::Vector2f>& a, const std::vector<Eigen::Vector2f>& b) {
  float depth = std::numeric_limits<float>::infinity();
  for (const auto* poly : {&a, &b})
    for (std::size_t i = 0; i < poly->size(); ++i) {
      const Eigen::Vector2f e = (*poly)[(i + 1) % poly->size()] - (*poly)[i];
      if (!(e.squaredNorm() > 1e-12f)) continue;  // a (near-)repeated vertex has no normal
      const Eigen::Vector2f n = Eigen::Vector2f(e.y(), -e.x()).normalized();
      float a0 = INFINITY, a1 = -INFINITY, b0 = INFINITY, b1 = -INFINITY;
      for (const auto& p : a) a0 = std::min(a0, n.dot(p)), a1 = std::max(a1, n.dot(p));
      for (const auto& p : b) b0 = std::min(b0, n.dot(p)), b1 = std::max(b1, n.dot(p));
      depth = std::min(depth, std::min(a1, b1) - std::max(a0, b0));
    }
  return depth;
}

/// Distance of p from a convex polygon (either winding), metres; 0 inside.
inline float distance_outside_m(const std::vector<Eigen::Vector2f>& poly, const Eigen::Vector2f& p) {
  bool pos = false, neg = false;
  float nearest = INFINITY;
  for (std::size_t i = 0; i < poly.size(); ++i) {
    const Eigen::Vector2f a = poly[i], e = poly[(i + 1) % poly.size()] - a;
    const float cross = e.x() * (p.y() - a.y()) - e.y() * (p.x() - a.x());
    (cross > 0.f ? pos : neg) |= cross != 0.f;
    const float t = e.squaredNorm() > 0.f ? std::clamp((p - a).dot(e) / e.squaredNorm(), 0.f, 1.f) : 0.f;
    nearest = std::min(nearest, (a + t * e - p).norm());
  }
  return pos && neg ? nearest : 0.f;
}

/// Keeps the points of a batch for which keep(global index) is true (offsets recomputed).
template <class Keep>
CloudBatch filter_points(const CloudBatch& in, Keep&& keep) {
  CloudBatch out;
  out.offsets = {0};
  for (std::size_t c = 0; c < in.num_clouds(); ++c) {
    for (auto i = std::size_t(in.offsets[c]); i < std::size_t(in.offsets[c + 1]); ++i)
      if (keep(i)) {
        out.x.push_back(in.x[i]), out.y.push_back(in.y[i]), out.z.push_back(in.z[i]);
        out.rgb.push_back(in.rgb[i]), out.pixel.push_back(in.pixel[i]), out.cloud.push_back(in.cloud[i]);
      }
    out.offsets.push_back(std::int64_t(out.size()));
  }
  return out;
}

/// Candidates that landed on the same placement, kept once (the first of each): x, y quantised to
/// `xy_m`, yaw (wrapped to [0, 2 pi)) to `yaw_rad`, yaw ignored where symmetric[model]. xy_m <= 0: all kept.
inline std::vector<Candidate> dedupe(const std::vector<Candidate>& in, float xy_m, float yaw_rad,
                                     const std::vector<bool>& symmetric) {
  if (!(xy_m > 0.f)) return in;
  constexpr float kTwoPi = 6.28318531f;
  const std::int64_t yaw_bins = yaw_rad > 0.f ? std::max<std::int64_t>(1, std::llround(kTwoPi / yaw_rad)) : 1;
  std::vector<std::array<std::int64_t, 4>> key(in.size());
  for (std::size_t i = 0; i < in.size(); ++i) {
    const Candidate& c = in[i];
    float yaw = std::fmod(c.yaw, kTwoPi);
    if (yaw < 0.f) yaw += kTwoPi;
    const bool no_yaw = symmetric[std::size_t(c.model)] || yaw_bins == 1;
    key[i] = {c.model, std::llround(c.x / xy_m), std::llround(c.y / xy_m),
              no_yaw ? 0 : std::llround(yaw / yaw_rad) % yaw_bins};  // 2 pi wraps to bin 0
  }
  std::vector<std::size_t> order(in.size());
  std::iota(order.begin(), order.end(), std::size_t(0));
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return key[a] < key[b]; });
  std::vector<char> keep(in.size(), 0);
  for (std::size_t k = 0; k < order.size(); ++k)
    keep[order[k]] = k == 0 || key[order[k]] != key[order[k - 1]];
  std::vector<Candidate> out;
  for (std::size_t i = 0; i < in.size(); ++i)
    if (keep[i]) out.push_back(in[i]);
  return out;
}

/// At most `max_points` points of every cloud, evenly spread over its points (every ceil(n / max_points)-th).
inline CloudBatch thin_clouds(const CloudBatch& in, int max_points) {
  if (max_points <= 0) return in;
  CloudBatch out;
  out.offsets = {0};
  for (std::size_t c = 0; c < in.num_clouds(); ++c) {
    const auto begin = std::size_t(in.offsets[c]), end = std::size_t(in.offsets[c + 1]);
    const std::size_t step =
        std::max<std::size_t>(1, (end - begin + std::size_t(max_points) - 1) / std::size_t(max_points));
    for (std::size_t i = begin; i < end; i += step) {
      out.x.push_back(in.x[i]), out.y.push_back(in.y[i]), out.z.push_back(in.z[i]);
      out.rgb.push_back(in.rgb[i]), out.pixel.push_back(in.pixel[i]), out.cloud.push_back(in.cloud[i]);
    }
    out.offsets.push_back(std::int64_t(out.size()));
  }
  return out;
}

/// Whether a turn of the model can change what the colour test sees: it has a texture, or vertex colours
/// that differ, and is not declared symmetric about the table normal without a texture (e.g. an untextured
/// bowl). A single-coloured model's yaw is decided by its geometry (ICP) alone.
inline bool yaw_visible_in_colour(const TabletopModel& m) {
  if (m.mesh.has_texture()) return true;
  if (m.yaw_symmetric || m.mesh.vertex_colors.empty()) return false;
  const Rgb8 c0 = m.mesh.vertex_colors.front();
  return std::any_of(m.mesh.vertex_colors.begin(), m.mesh.vertex_colors.end(),
                     [&](const Rgb8& c) { return c.r != c0.r || c.g != c0.g || c.b != c0.b; });
}

/// The share of a hypothesis' points (rendered and observed in its volume) it leaves unexplained: comparable
/// across models of different sizes, unlike the raw-count total.
inline float unexplained_fraction(const CostBreakdown& b) {
  return float(b.rendered_outliers() + b.observed_unexplained()) /
         float(std::max(1, b.rendered_points + b.observed_in_volume));
}

}  // namespace tabletop_detail

template <class Backend>
class TabletopEstimator {
 public:
  /// Validates the models and uploads them to the backend's renderer. Throws InvalidInput on no models,
  /// a bad mesh or a bad rest pose.
  explicit TabletopEstimator(std::vector<TabletopModel> models, TabletopSettings settings = {})
      : models_(std::move(models)), settings_(std::move(settings)), renderer_(meshes_of(models_)) {
    for (auto& m : models_) {
      if (!m.T_place_obj) m.T_place_obj = tabletop_detail::default_rest_pose(m.mesh);
      if (!is_valid_pose(*m.T_place_obj))
        throw InvalidInput("model '" + m.mesh.name + "'", "T_place_obj is not a finite rigid transform");
      footprints_.push_back(table_footprint(m.mesh, *m.T_place_obj, 0.f));  // floor set per call
      float r2 = 0;
      for (const auto& p : footprints_.back().polygon_xy_m) r2 = std::max(r2, p.squaredNorm());
      circumradius_.push_back(std::sqrt(r2));
      yaw_symmetric_.push_back(m.yaw_symmetric);
      yaw_searched_.push_back(tabletop_detail::yaw_visible_in_colour(m));
    }
  }

  const TabletopSettings& settings() const { return settings_; }
  TabletopSettings& settings() { return settings_; }
  const std::vector<TabletopModel>& models() const { return models_; }

  /// Index of the model whose mesh is called `name`. Throws InvalidInput if there is none.
  int model_index(const std::string& name) const {
    for (std::size_t i = 0; i < models_.size(); ++i)
      if (models_[i].mesh.name == name) return int(i);
    throw InvalidInput("model name", "no model called '" + name + "'");
  }

  /// Estimates the poses of the requested objects in one frame. T_cam_world (table frame -> camera) is
  /// estimated from the depth when not given. Throws InvalidInput on a malformed frame (sizes, NaN depth),
  /// missing colour for the RGB-D cost, an unknown model, no table visible, an empty scene, and (strict
  /// mode) fewer acceptable poses than requested instances.
  TabletopResult estimate(const RgbdFrame& frame, const std::vector<ObjectCount>& objects,
                          const std::optional<Pose>& T_cam_world = std::nullopt) const {
    using namespace tabletop_detail;
    const auto t_start = Clock::now();
    validate(frame, objects);
    TabletopResult result;
    Frame f{frame};
    auto t = Clock::now();
    if (T_cam_world) {
      if (!is_valid_pose(*T_cam_world)) throw InvalidInput("T_cam_world", "is not a finite rigid transform");
      f.T_cam_world = *T_cam_world;
      if (!(f.T_cam_world.inverse().translation().z() > 0))
        throw InvalidInput("T_cam_world",
                           "puts the camera at or below the table plane (the table frame's z "
                           "must point up, towards the camera)");
    } else {
      f.T_cam_world = estimate_table_plane(frame, settings_.table).T_cam_world;
      result.table_estimated = true;
    }
    result.T_cam_world = f.T_cam_world;
    result.timings.table = seconds_since(t);

    t = Clock::now();
    prepare_observed(f);
    result.timings.observed = seconds_since(t);

    t = Clock::now();
    std::vector<Candidate> grid;
    for (const auto& o : objects) {
      const std::vector<Candidate> c = hypotheses(f, o.model, result.hypotheses_grid);
      grid.insert(grid.end(), c.begin(), c.end());
    }
    result.hypotheses_kept = grid.size();
    result.timings.hypotheses = seconds_since(t);

    if (settings_.mode == SearchMode::Tree)
      search_tree(f, objects, grid, result);
    else
      search_parallel(f, objects, grid, result);
    if (settings_.mode == SearchMode::Parallel) polish(f, result);
    if (settings_.mode != SearchMode::BruteForceIcp) search_yaws(f, result);
    if (!result.missing.empty() && settings_.strict_instances) {
      const ObjectCount& m = result.missing.front();
      throw InvalidInput("objects", "model " + std::to_string(m.model) + " ('" + models_[m.model].mesh.name +
                                        "'): " + std::to_string(m.count) +
                                        " requested instance(s) not found (no acceptable, non-overlapping "
                                        "pose: are fewer instances present than requested?)");
    }
    result.timings.total = seconds_since(t_start);
    return result;
  }

 private:
  using Candidate = tabletop_detail::Candidate;
  static constexpr float kTwoPi = 6.28318531f;

  /// Per-frame state.
  struct Frame {
    explicit Frame(const RgbdFrame& f) : rgbd(f) {}
    const RgbdFrame& rgbd;
    Pose T_cam_world = Pose::Identity();
    CloudBatch observed;                     ///< scored against (whole frame at settings.observed)
    CloudBatch objects;                      ///< observed readings above the table (ICP target)
    std::vector<Eigen::Vector2f> object_xy;  ///< their table coordinates
    Eigen::AlignedBox2f workspace;
    std::optional<typename Backend::Cost> cost;
    std::optional<typename Backend::Registration> registration;
    /// The observed depth as occluders (occluder marking): with missing_depth_hides, a pixel without a
    /// reading holds the smallest positive depth, which hides every rendered point.
    Occluders occluders;
  };

  static std::vector<Mesh> meshes_of(const std::vector<TabletopModel>& models) {
    if (models.empty()) throw InvalidInput("tabletop models", "no models given");
    std::vector<Mesh> out;
    for (const auto& m : models) out.push_back(m.mesh);
    return out;
  }

  void validate(const RgbdFrame& frame, const std::vector<ObjectCount>& objects) const {
    const TabletopSettings& s = settings_;
    if (!(s.xy_step_m > 0 && std::isfinite(s.xy_step_m)) ||
        !(s.yaw_step_rad > 0 && std::isfinite(s.yaw_step_rad)))
      throw InvalidInput("TabletopSettings", "xy_step_m and yaw_step_rad must be finite and > 0");
    if (!(s.min_height_m >= 0 && s.max_height_m > s.min_height_m))
      throw InvalidInput("TabletopSettings", "needs 0 <= min_height_m < max_height_m");
    if (s.score_stride < 1) throw InvalidInput("TabletopSettings::score_stride", "must be >= 1");
    if (s.polish_rounds < 0 || s.polish_stride < 1 || s.polish_iterations < 1 ||
        !(s.polish_max_distance_m > 0 && std::isfinite(s.polish_max_distance_m)))
      throw InvalidInput("TabletopSettings",
                         "polish_rounds must be >= 0, polish_stride and polish_iterations >= 1 and "
                         "polish_max_distance_m finite and > 0");
    if (s.icp_max_points < 0) throw InvalidInput("TabletopSettings::icp_max_points", "must be >= 0");
    if (s.coarse_score_stride < 0 || s.rescore_extra_places < 0 || s.rescore_yaws < 1 ||
        !(s.rescore_place_radius_m >= 0))
      throw InvalidInput("TabletopSettings",
                         "coarse_score_stride, rescore_extra_places and rescore_place_radius_m must be >= 0 "
                         "and rescore_yaws >= 1");
    if (s.workspace_xy_m && (s.workspace_xy_m->isEmpty() || !s.workspace_xy_m->min().allFinite() ||
                             !s.workspace_xy_m->max().allFinite()))
      throw InvalidInput("TabletopSettings::workspace_xy_m", "must be a finite, non-empty box");
    if (!(s.hidden_point_weight >= 0) || !(s.min_icp_inlier_fraction >= 0 && s.min_icp_inlier_fraction <= 1))
      throw InvalidInput("TabletopSettings",
                         "hidden_point_weight must be >= 0 and min_icp_inlier_fraction in [0, 1]");
    if (!(s.support_margin_m >= 0) || !(s.workspace_margin_m >= 0) || !(s.overlap_tolerance_m >= 0) ||
        !(s.second_look_margin_m >= 0))
      throw InvalidInput("TabletopSettings", "margins and tolerances must be >= 0");
    perch2::validate(s.yaw_search.turns, "TabletopSettings::yaw_search.turns");
    frame.validate("tabletop frame");
    if (s.cost.use_color && s.mode != SearchMode::BruteForceIcp && frame.rgb.empty())
      throw InvalidInput("tabletop frame",
                         "has no colour image, which the RGB-D cost needs (set "
                         "cost.use_color = false for the depth-only cost)");
    if (yaw_search_runs() && frame.rgb.empty())
      throw InvalidInput("tabletop frame",
                         "has no colour image, which the yaw search's appearance test needs (set "
                         "yaw_search.enabled = false)");
    if (objects.empty()) throw InvalidInput("objects", "no objects requested");
    for (std::size_t i = 0; i < objects.size(); ++i) {
      const auto& o = objects[i];
      if (o.model < 0 || std::size_t(o.model) >= models_.size())
        throw InvalidInput("objects[" + std::to_string(i) + "]",
                           "unknown model id " + std::to_string(o.model) + " (" +
                               std::to_string(models_.size()) + " models)");
      if (o.count < 1) throw InvalidInput("objects[" + std::to_string(i) + "]", "count must be >= 1");
      for (std::size_t j = 0; j < i; ++j)
        if (objects[j].model == o.model)
          throw InvalidInput("objects", "model " + std::to_string(o.model) + " listed twice (use count)");
    }
  }

  void prepare_observed(Frame& f) const {
    const TabletopSettings& s = settings_;
    f.observed = observed_cloud(f.rgbd, s.observed);
    const Pose T_world_cam = f.T_cam_world.inverse();
    std::vector<char> above(f.observed.size());
    Eigen::AlignedBox2f table_box;
    for (std::size_t i = 0; i < f.observed.size(); ++i) {
      const Eigen::Vector3f p =
          T_world_cam * Eigen::Vector3f(f.observed.x[i], f.observed.y[i], f.observed.z[i]);
      above[i] = p.z() > s.min_height_m && p.z() <= s.max_height_m;
      if (above[i]) f.object_xy.emplace_back(p.x(), p.y()), f.workspace.extend(f.object_xy.back());
      if (std::abs(p.z()) <= s.min_height_m) table_box.extend(Eigen::Vector2f(p.x(), p.y()));
    }
    if (f.object_xy.empty())
      throw InvalidInput("tabletop frame", "empty scene: no depth reading between " +
                                               std::to_string(s.min_height_m) + " and " +
                                               std::to_string(s.max_height_m) + " m above the table");
    f.objects = tabletop_detail::filter_points(f.observed, [&](std::size_t i) { return above[i] != 0; });
    if (s.workspace_xy_m) {
      f.workspace = *s.workspace_xy_m;
    } else {
      f.workspace.min().array() -= s.workspace_margin_m;
      f.workspace.max().array() += s.workspace_margin_m;
      if (s.clip_workspace_to_table && !table_box.isEmpty()) {
        table_box.min().array() -= s.workspace_margin_m;
        table_box.max().array() += s.workspace_margin_m;
        if (table_box.intersects(f.workspace)) f.workspace = f.workspace.intersection(table_box);
      }
    }
    f.cost.emplace(f.observed);
    f.registration.emplace(f.objects);
    f.occluders.depth_m = f.rgbd.depth_m;
    if (s.missing_depth_hides)
      for (float& d : f.occluders.depth_m.data)
        if (!(d > 0.f)) d = std::numeric_limits<float>::min();
  }

  /// Grid hypotheses of one model, pruned by observed support; counts the unpruned ones.
  std::vector<Candidate> hypotheses(const Frame& f, int model, std::size_t& grid_count) const {
    return grid(f, model, f.object_xy, settings_.xy_step_m, grid_count);
  }

  /// Positions every step_m over the workspace (centred on it) with at least min_support_points of
  /// readings_xy within the model's reach, each at every grid yaw (one if yaw-symmetric).
  std::vector<Candidate> grid(const Frame& f, int model, const std::vector<Eigen::Vector2f>& readings_xy,
                              float step_m, std::size_t& grid_count) const {
    const TabletopSettings& s = settings_;
    const Eigen::Vector2f lo = f.workspace.min(), hi = f.workspace.max();
    const int nx = int(std::floor((hi.x() - lo.x()) / step_m)) + 1;
    const int ny = int(std::floor((hi.y() - lo.y()) / step_m)) + 1;
    if (double(nx) * double(ny) > 1e6)
      throw InvalidInput("tabletop workspace",
                         "spans " + std::to_string(nx) + " x " + std::to_string(ny) +
                             " grid positions (over a million): give workspace_xy_m or a "
                             "larger xy_step_m");
    const Eigen::Vector2f c = f.workspace.center();
    const int nyaw =
        models_[model].yaw_symmetric ? 1 : std::max(1, int(std::lround(kTwoPi / s.yaw_step_rad)));
    const float reach = circumradius_[model] + s.support_margin_m;
    std::vector<Candidate> out;
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        const Eigen::Vector2f p(c.x() + (float(i) - 0.5f * float(nx - 1)) * step_m,
                                c.y() + (float(j) - 0.5f * float(ny - 1)) * step_m);
        grid_count += std::size_t(nyaw);
        int support = 0;
        for (const auto& q : readings_xy) support += (q - p).squaredNorm() <= reach * reach;
        if (support < s.min_support_points) continue;
        for (int k = 0; k < nyaw; ++k) out.push_back({model, p.x(), p.y(), float(k) * kTwoPi / float(nyaw)});
      }
    return out;
  }

  Pose T_world_obj(const Candidate& c) const {
    return tabletop_detail::placement(c.x, c.y, c.yaw) * *models_[c.model].T_place_obj;
  }

  std::vector<Hypothesis> to_hypotheses(const Frame& f, const std::vector<Candidate>& cands) const {
    std::vector<Hypothesis> h;
    for (const auto& c : cands) h.push_back({c.model, f.T_cam_world * T_world_obj(c), -1});
    return h;
  }

  CloudBatch render(const Frame& f, const std::vector<Candidate>& cands, int stride, const Occluders* occ,
                    TabletopTimings& timings) const {
    const auto t = tabletop_detail::Clock::now();
    RenderSettings rs = settings_.render;
    rs.stride = stride;
    CloudBatch out = renderer_.render(to_hypotheses(f, cands), f.rgbd.camera, rs, occ);
    timings.render += tabletop_detail::seconds_since(t);
    return out;
  }

  IcpSettings icp_settings(const Frame& f) const {
    IcpSettings s = settings_.icp;
    s.dof = Dof::TableXYYaw;
    s.up_cam = f.T_cam_world.linear().col(2);
    s.origin_cam = f.T_cam_world.translation();
    return s;
  }

  /// Renders at the refinement stride, runs (x, y, yaw) ICP and moves every candidate to its result.
  /// Returns the ICP result (BF-ICP selects on it), the rendered point counts and the points ICP aligned.
  RegistrationResult refine(const Frame& f, std::vector<Candidate>& cands, const Occluders* occ,
                            std::vector<std::int64_t>& points, std::vector<std::int64_t>& icp_points,
                            TabletopTimings& timings) const {
    return refine(f, *f.registration, cands, occ, points, icp_points, timings);
  }

  /// As above, aligning to `target` (readings of the frame above the table).
  RegistrationResult refine(const Frame& f, const typename Backend::Registration& target,
                            std::vector<Candidate>& cands, const Occluders* occ,
                            std::vector<std::int64_t>& points, std::vector<std::int64_t>& icp_points,
                            TabletopTimings& timings) const {
    const CloudBatch rendered = render(f, cands, settings_.render.stride, occ, timings);
    points.resize(cands.size());
    for (std::size_t h = 0; h < cands.size(); ++h) points[h] = std::int64_t(rendered.cloud_size(h));
    const auto t = tabletop_detail::Clock::now();
    const std::vector<std::int32_t> seg(cands.size(), 0);
    const int max_points = settings_.mode == SearchMode::BruteForceIcp ? 0 : settings_.icp_max_points;
    const CloudBatch sources = tabletop_detail::thin_clouds(rendered, max_points);
    RegistrationResult r = target.icp(sources, seg, icp_settings(f));
    icp_points.resize(cands.size());
    for (std::size_t h = 0; h < cands.size(); ++h) icp_points[h] = std::int64_t(sources.cloud_size(h));
    for (std::size_t h = 0; h < cands.size(); ++h) cands[h] = corrected(f, cands[h], r.T_corr[h]);
    timings.refine += tabletop_detail::seconds_since(t);
    return r;
  }

  /// A candidate moved by an ICP correction (camera frame), back to exact (x, y, yaw): the rounding that
  /// would tilt the model off the table is dropped.
  Candidate corrected(const Frame& f, Candidate c, const Pose& T_corr_cam) const {
    const Pose T = f.T_cam_world.inverse() * T_corr_cam * f.T_cam_world * T_world_obj(c);
    const Pose T_world_place = T * models_[c.model].T_place_obj->inverse();
    c.x = T_world_place.translation().x(), c.y = T_world_place.translation().y();
    c.yaw = std::atan2(T_world_place.linear()(1, 0), T_world_place.linear()(0, 0));
    return c;
  }

  /// The refined candidates whose ICP matched at least min_icp_inlier_fraction of the points it aligned.
  std::vector<Candidate> well_supported(const std::vector<Candidate>& cands, const RegistrationResult& icp,
                                        const std::vector<std::int64_t>& icp_points) const {
    std::vector<Candidate> out;
    for (std::size_t h = 0; h < cands.size(); ++h)
      if (float(icp.inliers[h]) >= settings_.min_icp_inlier_fraction * float(icp_points[h]) &&
          icp_points[h] > 0)
        out.push_back(cands[h]);
    return out;
  }

  /// Per candidate, the share of its samples at score_stride that are not seen: hidden by nearer observed
  /// depth or a missing reading (Frame::occluders) or outside the image. Rendered once more without occluders
  /// into the image grown by its own size on every side (on the same sample grid; only the counts are used).
  /// Empty without occluder marking or weight.
  std::vector<float> hidden_shares(const Frame& f, const std::vector<Candidate>& cands,
                                   const std::vector<CostBreakdown>& costs, bool marked,
                                   TabletopTimings& timings) const {
    if (!marked || !(settings_.hidden_point_weight > 0.f) || cands.empty()) return {};
    const auto t = tabletop_detail::Clock::now();
    const int stride = settings_.score_stride;
    Intrinsics grown = f.rgbd.camera;
    const int mx = (grown.width + stride - 1) / stride * stride,
              my = (grown.height + stride - 1) / stride * stride;
    grown.width += 2 * mx, grown.height += 2 * my, grown.cx += float(mx), grown.cy += float(my);
    RenderSettings rs = settings_.render;
    rs.stride = stride;
    const CloudBatch all = renderer_.render(to_hypotheses(f, cands), grown, rs, nullptr);
    timings.render += tabletop_detail::seconds_since(t);
    std::vector<float> out(cands.size(), 0.f);
    for (std::size_t h = 0; h < cands.size(); ++h) {
      const auto n = float(all.cloud_size(h));
      if (n > 0.f) out[h] = std::max(0.f, 1.f - float(costs[h].rendered_points) / n);
    }
    return out;
  }

  CostRequest cost_request(const Frame& f, const std::vector<Candidate>& cands) const {
    CostRequest req;
    req.footprints = footprints_;
    for (auto& fp : req.footprints) fp.z_min_m = std::min(settings_.min_height_m, fp.z_max_m);
    for (const auto& c : cands)
      req.add(0, c.model, f.T_cam_world * tabletop_detail::placement(c.x, c.y, c.yaw));
    return req;
  }

  std::vector<CostBreakdown> score(const Frame& f, const std::vector<Candidate>& cands,
                                   const CloudBatch& rendered, TabletopTimings& timings) const {
    return score(f, cands, rendered, settings_.cost, timings);
  }

  std::vector<CostBreakdown> score(const Frame& f, const std::vector<Candidate>& cands,
                                   const CloudBatch& rendered, const CostSettings& cs,
                                   TabletopTimings& timings) const {
    const auto t = tabletop_detail::Clock::now();
    std::vector<CostBreakdown> out = f.cost->evaluate(rendered, cost_request(f, cands), cs).hypotheses;
    timings.cost += tabletop_detail::seconds_since(t);
    return out;
  }

  /// Scored candidates: cost and, when occluders are marked, hidden share; score = what selection ranks by.
  struct Scored {
    std::vector<Candidate> cands;
    std::vector<float> scores, hidden;  ///< hidden: empty unless occluders are marked (hidden_shares)
    std::vector<CostBreakdown> costs;
  };

  /// Renders and scores candidates at score_stride as Parallel selection ranks them: cost total plus
  /// hidden_point_weight times the hidden share (with occluders and hidden_term).
  Scored score_for_selection(const Frame& f, std::vector<Candidate> cands, const Occluders* occ,
                             bool hidden_term, TabletopTimings& timings) const {
    Scored out;
    if (!cands.empty())
      out.costs = score(f, cands, render(f, cands, settings_.score_stride, occ, timings), timings);
    out.hidden = hidden_shares(f, cands, out.costs, hidden_term && occ != nullptr, timings);
    for (std::size_t h = 0; h < cands.size(); ++h)
      out.scores.push_back(out.costs[h].total +
                           (out.hidden.empty() ? 0.f : settings_.hidden_point_weight * out.hidden[h]));
    out.cands = std::move(cands);
    return out;
  }

  bool yaw_search_runs() const {
    return settings_.yaw_search.enabled && settings_.mode != SearchMode::BruteForceIcp;
  }

  /// The yaw search (YawSearchSettings) of every pose in result.poses whose model has a yaw the colour
  /// test can see (tabletop_detail::yaw_visible_in_colour).
  /// A pose it turned is scored again at score_stride as selection scored it (Parallel mode's score, with
  /// the hidden term when occluders are marked).
  void search_yaws(const Frame& f, TabletopResult& result) const {
    using namespace tabletop_detail;
    const YawSearchSettings& ys = settings_.yaw_search;
    if (!yaw_search_runs()) return;
    const auto t = Clock::now();
    std::vector<Candidate> cands;
    std::vector<std::size_t> pose_of;  // index into result.poses
    for (std::size_t k = 0; k < result.poses.size(); ++k) {
      const TabletopPose& p = result.poses[k];
      if (yaw_searched_[std::size_t(p.model)])
        cands.push_back({p.model, p.x_m, p.y_m, p.yaw_rad}), pose_of.push_back(k);
    }
    const Occluders* occ = settings_.occluder_marking ? &f.occluders : nullptr;
    const std::vector<Candidate> start = cands;
    auto turn = [&](Candidate c, int, float angle_rad) {  // about the table normal
      c.yaw = std::remainder(c.yaw + angle_rad, kTwoPi);
      return c;
    };
    CostSettings depth_only = settings_.cost;
    depth_only.use_color = false;
    depth_only.normalization = Normalization::Fractions;
    auto measure = [&](const std::vector<Candidate>& c, int stride, bool geometry) {
      const CloudBatch rendered = render(f, c, stride, occ, result.timings);
      const std::vector<CostBreakdown> g =
          geometry ? score(f, c, rendered, depth_only, result.timings) : std::vector<CostBreakdown>(c.size());
      const auto t_app = Clock::now();
      std::vector<AppearanceSamples> a = appearance_samples(rendered, f.rgbd, depth_only.delta_m);
      result.timings.cost += seconds_since(t_app);
      std::vector<TurnSample> out;
      for (std::size_t i = 0; i < c.size(); ++i) out.push_back({g[i].total, std::move(a[i])});
      return out;
    };
    auto shift = [](Candidate c, int axis, float m) {  // along the table's x or y
      (axis == 0 ? c.x : c.y) += m;
      return c;
    };
    if (!cands.empty())
      search_turns(cands, 1, 2, f.rgbd.camera.width, ys.turns, turn, shift, measure, &result.yaw_candidates);
    std::vector<Candidate> moved;
    std::vector<std::size_t> moved_pose;
    for (std::size_t i = 0; i < cands.size(); ++i)
      if (cands[i].yaw != start[i].yaw || cands[i].x != start[i].x || cands[i].y != start[i].y)
        moved.push_back(cands[i]), moved_pose.push_back(pose_of[i]);
    if (!moved.empty()) {
      const Scored sc =
          score_for_selection(f, moved, occ, settings_.mode == SearchMode::Parallel, result.timings);
      for (std::size_t j = 0; j < moved.size(); ++j) {
        TabletopPose& p = result.poses[moved_pose[j]];
        p = make_pose(f, moved[j], p.instance, sc.scores[j], sc.costs[j]);
      }
    }
    result.timings.yaw += seconds_since(t);
  }

  /// The polish (TabletopSettings::polish_rounds) of every pose in result.poses: rounds of rendering at
  /// polish_stride (occluders marked as in the search) and (x, y, yaw) ICP of all its points against the
  /// object readings, pairs within polish_max_distance_m. A polished pose is scored again at score_stride
  /// as selection scored it and kept if it is still acceptable.
  void polish(const Frame& f, TabletopResult& result) const {
    using namespace tabletop_detail;
    const TabletopSettings& s = settings_;
    if (s.polish_rounds <= 0 || result.poses.empty()) return;
    const Occluders* occ = s.occluder_marking ? &f.occluders : nullptr;
    std::vector<Candidate> cands;
    for (const auto& p : result.poses) cands.push_back({p.model, p.x_m, p.y_m, p.yaw_rad});
    IcpSettings icp = icp_settings(f);
    icp.max_correspondence_distance_m = s.polish_max_distance_m;
    icp.max_iterations = s.polish_iterations;
    for (int round = 0; round < s.polish_rounds; ++round) {
      const CloudBatch rendered = render(f, cands, s.polish_stride, occ, result.timings);
      const auto t = Clock::now();
      const RegistrationResult r =
          f.registration->icp(rendered, std::vector<std::int32_t>(cands.size(), 0), icp);
      for (std::size_t h = 0; h < cands.size(); ++h)
        if (rendered.cloud_size(h) >= std::size_t(s.min_rendered_points))
          cands[h] = corrected(f, cands[h], r.T_corr[h]);
      result.timings.refine += seconds_since(t);
    }
    const Scored sc = score_for_selection(f, cands, occ, true, result.timings);
    for (std::size_t k = 0; k < cands.size(); ++k)
      if (acceptable(sc.costs[k]))
        result.poses[k] = make_pose(f, cands[k], result.poses[k].instance, sc.scores[k], sc.costs[k]);
  }

  bool acceptable(const CostBreakdown& b) const {
    if (settings_.mode != SearchMode::BruteForceIcp &&
        b.observed_in_volume < settings_.min_observed_in_volume)
      return false;
    return b.rendered_points >= settings_.min_rendered_points &&
           float(b.rendered_inliers) >= settings_.min_inlier_fraction * float(b.rendered_points);
  }

  bool overlaps(const Candidate& a, const Candidate& b) const {
    return tabletop_detail::penetration_m(tabletop_detail::posed_polygon(footprints_[a.model], a),
                                          tabletop_detail::posed_polygon(footprints_[b.model], b)) >
           settings_.overlap_tolerance_m;
  }

  TabletopPose make_pose(const Frame& f, const Candidate& c, int instance, float score,
                         const CostBreakdown& b) const {
    TabletopPose p;
    p.model = c.model, p.instance = instance;
    p.T_world_obj = T_world_obj(c);
    p.T_cam_obj = f.T_cam_world * p.T_world_obj;
    p.x_m = c.x, p.y_m = c.y, p.yaw_rad = c.yaw, p.score = score, p.cost = b;
    return p;
  }

  void keep_scored(const Frame& f, const std::vector<Candidate>& cands, const std::vector<float>& scores,
                   const std::vector<CostBreakdown>& costs, TabletopResult& result) const {
    if (!settings_.keep_scored) return;
    for (std::size_t h = 0; h < cands.size(); ++h)
      result.scored.push_back(make_pose(f, cands[h], -1, scores[h], costs[h]));
  }

  /// The coarse pass of coarse-to-fine scoring: scores every candidate at coarse_score_stride and keeps,
  /// per requested model, the acceptable ones at its best places: in order of coarse cost, a candidate
  /// within rescore_place_radius_m of a kept place joins it (at most rescore_yaws per place), any other
  /// opens a new place while the model has fewer than (requested instances + rescore_extra_places).
  /// Returns them in their original order.
  std::vector<Candidate> best_coarse(const Frame& f, const std::vector<Candidate>& cands,
                                     const std::vector<ObjectCount>& objects, const Occluders* occ,
                                     TabletopResult& result) const {
    const TabletopSettings& s = settings_;
    const std::vector<CostBreakdown> coarse =
        score(f, cands, render(f, cands, s.coarse_score_stride, occ, result.timings), result.timings);
    result.hypotheses_coarse += cands.size();
    std::vector<std::size_t> order(cands.size());
    std::iota(order.begin(), order.end(), std::size_t(0));
    std::stable_sort(order.begin(), order.end(),
                     [&](std::size_t a, std::size_t b) { return coarse[a].total < coarse[b].total; });
    int instances = 0;
    for (const auto& o : objects) instances += o.count;
    const std::size_t max_places = std::size_t(instances + s.rescore_extra_places);
    struct Place {
      Eigen::Vector2f xy;
      int kept;
    };
    std::vector<std::vector<Place>> places(models_.size());
    const float r2 = s.rescore_place_radius_m * s.rescore_place_radius_m;
    // The acceptance test at the coarse stride: rendered counts scale with the sample density; the
    // observed points in the volume do not depend on it.
    const float density =
        float(s.score_stride * s.score_stride) / float(s.coarse_score_stride * s.coarse_score_stride);
    const float min_points = std::max(1.f, float(s.min_rendered_points) * density);
    std::vector<char> keep(cands.size(), 0);
    for (const std::size_t h : order) {
      const CostBreakdown& b = coarse[h];
      if (float(b.rendered_points) < min_points || b.observed_in_volume < s.min_observed_in_volume ||
          float(b.rendered_inliers) < s.min_inlier_fraction * float(b.rendered_points))
        continue;
      const Eigen::Vector2f xy(cands[h].x, cands[h].y);
      auto& mine = places[std::size_t(cands[h].model)];
      const auto near = std::find_if(mine.begin(), mine.end(),
                                     [&](const Place& p) { return (p.xy - xy).squaredNorm() <= r2; });
      if (near != mine.end()) {
        if (near->kept < s.rescore_yaws) keep[h] = 1, ++near->kept;
      } else if (mine.size() < max_places) {
        mine.push_back({xy, 1}), keep[h] = 1;
      }
    }
    std::vector<Candidate> out;
    for (std::size_t h = 0; h < cands.size(); ++h)
      if (keep[h]) out.push_back(cands[h]);
    return out;
  }

  /// Selection of the parallel modes. Per model, acceptable candidates in order of score; a candidate is
  /// taken unless it overlaps one already taken of the same model (or, with exclusive_placements, of any
  /// model). Across models, the model whose next candidate explains its points best (smallest unexplained
  /// share plus the hidden term, see hidden_point_weight; BF-ICP: smallest fitness) takes first. Appends the
  /// poses to result (grouped by request order) and returns the indices of the chosen candidates in that
  /// order.
  std::vector<std::size_t> select_parallel(const Frame& f, const std::vector<Candidate>& cands,
                                           const std::vector<float>& scores,
                                           const std::vector<CostBreakdown>& costs,
                                           const std::vector<float>& hidden,
                                           const std::vector<ObjectCount>& objects,
                                           TabletopResult& result) const {
    const bool bf = settings_.mode == SearchMode::BruteForceIcp;
    std::vector<std::size_t> order(cands.size());
    std::iota(order.begin(), order.end(), std::size_t(0));
    std::stable_sort(order.begin(), order.end(),
                     [&](std::size_t a, std::size_t b) { return scores[a] < scores[b]; });
    std::vector<std::vector<std::size_t>> ranked(models_.size());  // acceptable, best first
    for (const std::size_t h : order)
      if (acceptable(costs[h])) ranked[std::size_t(cands[h].model)].push_back(h);
    std::vector<int> need(models_.size(), 0);
    for (const auto& o : objects) need[std::size_t(o.model)] = o.count;
    std::vector<std::size_t> next(models_.size(), 0);
    std::vector<std::vector<std::size_t>> taken(models_.size());
    std::vector<std::size_t> all_taken;
    auto blocked = [&](std::size_t h) {
      const auto& others = settings_.exclusive_placements ? all_taken : taken[std::size_t(cands[h].model)];
      return std::any_of(others.begin(), others.end(),
                         [&](std::size_t k) { return overlaps(cands[k], cands[h]); });
    };
    for (;;) {
      std::ptrdiff_t best = -1;
      float best_key = INFINITY;
      for (const auto& o : objects) {
        const auto m = std::size_t(o.model);
        if (need[m] == 0) continue;
        while (next[m] < ranked[m].size() && blocked(ranked[m][next[m]])) ++next[m];
        if (next[m] == ranked[m].size()) continue;
        const std::size_t h = ranked[m][next[m]];
        const float key = bf ? scores[h]
                             : tabletop_detail::unexplained_fraction(costs[h]) +
                                   (hidden.empty() ? 0.f : settings_.hidden_point_weight * hidden[h]);
        if (best < 0 || key < best_key) best = std::ptrdiff_t(h), best_key = key;
      }
      if (best < 0) break;
      const auto m = std::size_t(cands[std::size_t(best)].model);
      taken[m].push_back(std::size_t(best)), all_taken.push_back(std::size_t(best));
      --need[m], ++next[m];
    }
    std::vector<std::size_t> chosen;
    for (const auto& o : objects) {
      const auto m = std::size_t(o.model);
      for (std::size_t k = 0; k < taken[m].size(); ++k) {
        const std::size_t h = taken[m][k];
        result.poses.push_back(make_pose(f, cands[h], int(k), scores[h], costs[h]));
        chosen.push_back(h);
      }
      if (need[m] > 0) result.missing.push_back({o.model, need[m]});
    }
    return chosen;
  }

  Scored refine_and_score(const Frame& f, const typename Backend::Registration& target,
                          std::vector<Candidate> cands, const std::vector<ObjectCount>& objects,
                          TabletopResult& result) const {
    using namespace tabletop_detail;
    const TabletopSettings& s = settings_;
    const bool bf = s.mode == SearchMode::BruteForceIcp;
    const Occluders* occ = s.occluder_marking ? &f.occluders : nullptr;
    Scored out;
    if (cands.empty()) return out;
    std::vector<std::int64_t> points, icp_points;
    RegistrationResult icp;
    if (s.refine || bf) icp = refine(f, target, cands, occ, points, icp_points, result.timings);
    result.hypotheses_refined += cands.size();
    if (s.refine && !bf) cands = well_supported(cands, icp, icp_points);
    if (bf) {  // truncated mean squared distance: points without a correspondence count as the cap
      out.scores.assign(cands.size(), 0.f);
      out.costs.resize(cands.size());
      const float cap2 = s.icp.max_correspondence_distance_m * s.icp.max_correspondence_distance_m;
      for (std::size_t h = 0; h < cands.size(); ++h) {
        const float n = float(points[h]), in = float(icp.inliers[h]);
        const float e = std::isfinite(icp.final_error[h]) ? icp.final_error[h] : 0.f;
        out.scores[h] = n > 0 ? (in * e * e + (n - in) * cap2) / n : INFINITY;
        out.costs[h].rendered_points = std::int32_t(points[h]);
        out.costs[h].rendered_inliers = icp.inliers[h];
      }
    } else {
      cands = dedupe(cands, s.dedupe_xy_m, s.dedupe_yaw_rad, yaw_symmetric_);
      if (s.coarse_score_stride > s.score_stride && !cands.empty())
        cands = best_coarse(f, cands, objects, occ, result);
      out = score_for_selection(f, cands, occ, true, result.timings);
    }
    result.hypotheses_scored += cands.size();
    keep_scored(f, cands, out.scores, out.costs, result);
    out.cands = std::move(cands);
    return out;
  }

  /// Parallel (and BF-ICP) search: every candidate refined and scored at once; per model the best `count`
  /// acceptable, non-overlapping ones by score. Then the second look (TabletopSettings::second_look) for
  /// instances still missing.
  void search_parallel(const Frame& f, const std::vector<ObjectCount>& objects, std::vector<Candidate> cands,
                       TabletopResult& result) const {
    using namespace tabletop_detail;
    const TabletopSettings& s = settings_;
    const bool bf = s.mode == SearchMode::BruteForceIcp;
    Scored scored = refine_and_score(f, *f.registration, std::move(cands), objects, result);
    auto t = Clock::now();
    std::vector<std::size_t> chosen_index =
        select_parallel(f, scored.cands, scored.scores, scored.costs, scored.hidden, objects, result);
    result.timings.select += seconds_since(t);
    if (!bf && s.second_look && !result.missing.empty())
      second_look(f, objects, scored, chosen_index, result);
    std::vector<Candidate> chosen;
    for (const std::size_t h : chosen_index) chosen.push_back(scored.cands[h]);
    if (bf && !chosen.empty()) {  // report the explanation cost of the chosen poses too
      const Occluders* occ = s.occluder_marking ? &f.occluders : nullptr;
      const std::vector<CostBreakdown> b =
          score(f, chosen, render(f, chosen, s.score_stride, occ, result.timings), result.timings);
      for (std::size_t k = 0; k < chosen.size(); ++k) result.poses[k].cost = b[k];
    }
  }

  /// The second look (TabletopSettings::second_look): the object readings outside every selected pose's
  /// footprint (grown by second_look_margin_m) are what the selection left unexplained; a grid at half the
  /// step over them, supported by them alone, is refined against them alone (so a neighbour's readings
  /// cannot pull a start onto the neighbour), scored as the first pass scored, and selection runs again over
  /// both passes' candidates. Replaces result.poses / missing and `chosen` (indices into `scored`, which
  /// gains the new candidates).
  void second_look(const Frame& f, const std::vector<ObjectCount>& objects, Scored& scored,
                   std::vector<std::size_t>& chosen, TabletopResult& result) const {
    using namespace tabletop_detail;
    const TabletopSettings& s = settings_;
    std::vector<std::vector<Eigen::Vector2f>> taken;
    for (const std::size_t h : chosen)
      taken.push_back(posed_polygon(footprints_[std::size_t(scored.cands[h].model)], scored.cands[h]));
    std::vector<char> residual(f.object_xy.size(), 0);
    std::vector<Eigen::Vector2f> residual_xy;
    for (std::size_t i = 0; i < f.object_xy.size(); ++i) {
      residual[i] = std::none_of(taken.begin(), taken.end(), [&](const auto& poly) {
        return distance_outside_m(poly, f.object_xy[i]) <= s.second_look_margin_m;
      });
      if (residual[i]) residual_xy.push_back(f.object_xy[i]);
    }
    if (int(residual_xy.size()) < s.min_support_points) return;
    std::vector<Candidate> cands;
    for (const ObjectCount& m : result.missing) {
      const std::vector<Candidate> c =
          grid(f, m.model, residual_xy, 0.5f * s.xy_step_m, result.hypotheses_grid);
      cands.insert(cands.end(), c.begin(), c.end());
    }
    if (cands.empty()) return;
    result.hypotheses_kept += cands.size();
    const typename Backend::Registration target(
        filter_points(f.objects, [&](std::size_t i) { return residual[i] != 0; }));
    Scored more = refine_and_score(f, target, std::move(cands), result.missing, result);
    if (more.cands.empty()) return;
    const auto t = Clock::now();
    scored.cands.insert(scored.cands.end(), more.cands.begin(), more.cands.end());
    scored.scores.insert(scored.scores.end(), more.scores.begin(), more.scores.end());
    scored.costs.insert(scored.costs.end(), more.costs.begin(), more.costs.end());
    scored.hidden.insert(scored.hidden.end(), more.hidden.begin(), more.hidden.end());
    result.poses.clear(), result.missing.clear();
    chosen = select_parallel(f, scored.cands, scored.scores, scored.costs, scored.hidden, objects, result);
    result.timings.select += seconds_since(t);
  }

  /// Monotone Scene Generation, greedily: each level refines and scores every remaining model's candidates
  /// in the scene rendered so far (placed objects hide them), drops placements that would hide placed
  /// objects, and places the model whose best placement explains the largest fraction of its points.
  void search_tree(const Frame& f, const std::vector<ObjectCount>& objects,
                   const std::vector<Candidate>& grid, TabletopResult& result) const {
    using namespace tabletop_detail;
    const TabletopSettings& s = settings_;
    const Intrinsics& cam = f.rgbd.camera;
    DepthImage placed_depth(cam.width, cam.height, 0.f);  // nearest placed surface, 0 = none
    std::vector<Candidate> placed;
    std::vector<int> remaining(models_.size(), 0);
    for (const auto& o : objects) remaining[std::size_t(o.model)] = o.count;
    std::vector<std::vector<TabletopPose>> found(models_.size());
    const float margin = s.render.occlusion_margin_m;
    auto hides = [margin](float occluder, float z) { return occluder > 0.f && occluder < z - margin; };
    for (;;) {
      std::vector<Candidate> cands;
      for (const auto& c : grid)
        if (remaining[std::size_t(c.model)] > 0) cands.push_back(c);
      if (cands.empty()) break;
      // Occluders: the placed objects (and the observed depth if marking is on).
      Occluders occ{placed_depth, {}};
      if (s.occluder_marking)
        for (std::size_t i = 0; i < occ.depth_m.data.size(); ++i) {
          const float d = f.occluders.depth_m.data[i], p = occ.depth_m.data[i];
          occ.depth_m.data[i] = p > 0.f && (d <= 0.f || p < d) ? p : d;
        }
      std::vector<std::int64_t> points, icp_points;
      if (s.refine) {
        const RegistrationResult icp = refine(f, cands, &occ, points, icp_points, result.timings);
        result.hypotheses_refined += cands.size();
        cands = well_supported(cands, icp, icp_points);
        if (cands.empty()) break;
      } else {
        result.hypotheses_refined += cands.size();
      }
      cands = dedupe(cands, s.dedupe_xy_m, s.dedupe_yaw_rad, yaw_symmetric_);
      const CloudBatch all = render(f, cands, s.score_stride, nullptr, result.timings);
      std::vector<std::int32_t> hiding(cands.size(), 0);
      for (std::size_t h = 0; h < cands.size(); ++h)
        for (auto i = std::size_t(all.offsets[h]); i < std::size_t(all.offsets[h + 1]); ++i)
          hiding[h] += hides(all.z[i], placed_depth.data[std::size_t(all.pixel[i])]);
      const CloudBatch visible = filter_points(
          all, [&](std::size_t i) { return !hides(occ.depth_m.data[std::size_t(all.pixel[i])], all.z[i]); });
      const std::vector<CostBreakdown> costs = score(f, cands, visible, result.timings);
      result.hypotheses_scored += cands.size();
      std::vector<float> totals(costs.size());
      for (std::size_t h = 0; h < costs.size(); ++h) totals[h] = costs[h].total;
      keep_scored(f, cands, totals, costs, result);

      const auto t = Clock::now();
      std::ptrdiff_t best = -1;
      float best_fraction = INFINITY;
      std::vector<float> best_total(models_.size(), INFINITY);
      std::vector<std::ptrdiff_t> best_of(models_.size(), -1);
      for (std::size_t h = 0; h < cands.size(); ++h) {
        const auto m = std::size_t(cands[h].model);
        const CostBreakdown& b = costs[h];
        if (!acceptable(b) || float(hiding[h]) > s.tree_max_occluding_fraction * float(all.cloud_size(h)))
          continue;
        if (std::any_of(placed.begin(), placed.end(),
                        [&](const Candidate& c) { return overlaps(c, cands[h]); }))
          continue;
        if (b.total < best_total[m]) best_total[m] = b.total, best_of[m] = std::ptrdiff_t(h);
      }
      for (std::size_t m = 0; m < models_.size(); ++m) {
        if (best_of[m] < 0) continue;
        const CostBreakdown& b = costs[std::size_t(best_of[m])];
        const float fraction = float(b.rendered_outliers() + b.observed_unexplained()) /
                               float(std::max(1, b.rendered_points + b.observed_in_volume));
        if (fraction < best_fraction) best_fraction = fraction, best = best_of[m];
      }
      result.timings.select += seconds_since(t);
      if (best < 0) break;  // no model can be placed any more
      const Candidate& c = cands[std::size_t(best)];
      found[std::size_t(c.model)].push_back(make_pose(f, c, int(found[std::size_t(c.model)].size()),
                                                      costs[std::size_t(best)].total,
                                                      costs[std::size_t(best)]));
      placed.push_back(c);
      --remaining[std::size_t(c.model)];
      const CloudBatch full = render(f, {c}, 1, nullptr, result.timings);  // full-resolution depth of it
      for (std::size_t i = 0; i < full.size(); ++i) {
        float& d = placed_depth.data[std::size_t(full.pixel[i])];
        d = d > 0.f ? std::min(d, full.z[i]) : full.z[i];
      }
    }
    for (const auto& o : objects) {
      auto& poses = found[std::size_t(o.model)];
      result.poses.insert(result.poses.end(), poses.begin(), poses.end());
      if (remaining[std::size_t(o.model)] > 0)
        result.missing.push_back({o.model, remaining[std::size_t(o.model)]});
    }
  }

  std::vector<TabletopModel> models_;
  TabletopSettings settings_;
  typename Backend::Renderer renderer_;
  std::vector<Footprint> footprints_;  ///< per model, placement frame (floor: min_height_m, per call)
  std::vector<float> circumradius_;    ///< per model, of the footprint about the placement origin, metres
  std::vector<bool> yaw_symmetric_;    ///< per model (TabletopModel::yaw_symmetric)
  std::vector<bool> yaw_searched_;     ///< per model: the yaw search turns it (yaw_visible_in_colour)
};

}  // namespace perch2
