// The tabletop search's settings (perch2/search/tabletop.hpp): the models it places and how many of each a
// frame shows, the paper's variants (tabletop_variant) and every parameter of every pass with its default
// and unit, in one struct (TabletopSettings) as the user sets it.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <optional>

#include "perch2/core/mesh.hpp"
#include "perch2/core/observed.hpp"
#include "perch2/core/pose.hpp"
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

/// The yaw search after selection (see perch2/search/tabletop.hpp and local_search.hpp). ICP aligns what
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
  /// Sweep, climb and final comparison (local_search.hpp). The fine sweep ranks the turns at stride 2 and the
  /// climb decides at every pixel (turns.climb_stride 1): a partly hidden label shows a few letters, and
  /// every pixel of them counts where it decides. Before 2026-12-07 both ran at stride 1; bench_tabletop
  /// (perch2c, thrust_omp, 2 cores, Intel Xeon VM), ADD(-S) AUC / BOP AR (no VSD), stride 1 -> 2 + climb 1:
  /// seed 2020 97.2 / 0.957 -> 97.4 / 0.964 at 1.09 -> 0.93 s per image, seed 77 96.0 / 0.932 -> 97.1 /
  /// 0.946 at 1.10 -> 0.92 s, seed 7070 (never tuned on) 98.1 / 0.971 -> 97.6 / 0.969 at 0.96 -> 0.79 s;
  /// the climb at stride 2 too lost 0.7-1.2 ADD(-S) on seeds 77 and 7070.
  /// Only the best two starts (by appearance at stride 1) climb (turns.climbed_starts; with all four the
  /// climb was half the yaw search's time): the same accuracy (see TabletopSettings::render for the
  /// measurements), the yaw search 0.27 -> 0.20 s per image on bench_tabletop.
  TurnSearchSettings turns = [] {
    TurnSearchSettings t;
    t.fine_stride = 2;
    t.climb_stride = 1;
    t.climbed_starts = 2;
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
  /// Renders before refinement: stride 6 (was 4; ICP aligns icp_max_points of them). With icp_max_points
  /// 128 -> 64 and the yaw search's climbed_starts 2 (thrust_omp, Intel Xeon VM, ADD(-S) AUC / BOP AR
  /// without VSD, s per image): held-out seed 123 (80 images, 430 targets) 97.6 / 0.973 -> 97.8 / 0.975 at
  /// 1.03 -> 0.74 s; bench_tabletop (seed 2020) 97.4 / 0.964 -> 97.5 / 0.973 at 0.98 -> 0.65 s; seed 77
  /// 97.1 / 0.946 -> 97.0 / 0.940 at 0.94 -> 0.65 s; seed 7070 97.6 / 0.969 -> 97.4 / 0.965 at 0.78 ->
  /// 0.55 s. Stride 8 lost 1.1 on bench_tabletop.
  RenderSettings render = [] {
    RenderSettings r;
    r.stride = 6;
    return r;
  }();
  int score_stride = 2;  ///< stride of the re-render that is scored (>= 1)
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
  /// bench_tabletop's 30 scenes 128 gave the same poses within 1 cm as 192 in 13% less CPU time; 64 since
  /// 2026-12-07 (see render). 96 was no more accurate than 64.
  int icp_max_points = 64;
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

/// The settings of one of the paper's variants (see perch2/search/tabletop.hpp), on top of `base`.
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

/// TabletopEstimator::detect(): no objects or counts given.
struct TabletopDetectSettings {
  int max_per_model = 8;    ///< instances of one model at most per frame (>= 1)
  int max_per_frame = 100;  ///< detections at most per frame, the best scored (>= 1; BOP 2024 scores 100)
  /// A detection is reported only with at least this score, 1 / (1 + selection score) as in the BOP rows
  /// (in [0, 1]).
  float min_score = 0.f;
};

}  // namespace perch2
