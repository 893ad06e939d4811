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
#include <string>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/observed.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/registration/registration.hpp"
#include "perch2/registration/surface_fit.hpp"
#include "perch2/render/render.hpp"
#include "perch2/search/local_search.hpp"
#include "perch2/search/proposals.hpp"

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

/// Coarse-to-fine local search over rotations after the second pass (see the file comment). GICP cannot
/// see what its geometry does not show: a printed can or bottle turned about its axis fits the depth
/// equally well, so its turn stays whatever the proposal had (quantised by the viewpoint and in-plane
/// spacing, ~30-45 deg) and the final cost only chooses among those turns. Here each of the best few poses
/// of an instance is turned about its model's x, y and z axes (through the model origin) by +-step; the
/// turn that lowers `cost` most is taken, repeatedly (hill climbing), and the step is halved each level.
/// Renders and costs are cheap next to GICP. An untextured object's geometry is already GICP's, so a turn
/// rarely lowers both cost terms (require_both_terms) and it keeps its pose.
struct LocalSearchSettings {
  /// The best hypotheses (by the final cost) of each instance that are searched around (then the winner is
  /// chosen as select_by_local_cost says). 0 turns the stage off (the final cost's best is selected).
  int candidates_per_instance = 3;
  float rotation_step_rad = 0.3f;  ///< the first level's turn, radians (~17 deg)
  int levels = 4;                  ///< the step halves each level (0.3 -> 0.0375 rad, ~2 deg)
  int moves_per_level = 3;         ///< most accepted turns per level (a level ends at no improvement)
  int stride = 4;                  ///< render stride of the candidates (>= 1)
  /// Before the hill climbing, turns by 2 pi k / sweep_turns (k = 1 .. sweep_turns - 1) about each model
  /// axis are tried once: a label seen from the wrong side is more than a few steps away. 0 or 1 = none.
  /// Off by default: large turns can also land on a look-alike side of a label, and the sweep has not
  /// been measured on its own (try `bench_sixdof --sweep 8`).
  int sweep_turns = 0;
  /// A turn is taken only if it lowers the total without raising either term (rendered outliers,
  /// unexplained observed points): counting outliers favours poses that show fewer points, and a turn that
  /// only trades one term for the other is such a trade, not a better fit. So an untextured object keeps
  /// GICP's pose unless a turn explains more with fewer outliers.
  bool require_both_terms = true;
  /// The searched poses get one more GICP pass (second_pass_* settings) at second_pass_stride: it restores
  /// any tilt the turns brought while it cannot undo a turn about a symmetry axis it does not see.
  bool polish = true;
  /// Which cost picks the winner among an instance's searched poses: `cost` above (true) or the final
  /// SixDofSettings::cost at the moved poses (false, default). On bench_sixdof's 20 scenes (ground-truth
  /// masks) the final cost chose better: ADD(-S) AUC 93.9 vs 93.6 and ADD-S < 2 cm 100% vs 99% (a mostly
  /// hidden block, whose candidates the nearest-colour cost ranked differently, ended 37 mm off).
  bool select_by_local_cost = false;
  /// The colour test of the nearest neighbour (ColorRule::Nearest) sees a few millimetres of print
  /// misalignment that AnyNeighbour tolerates by design (see ColorRule).
  CostSettings cost = [] {
    CostSettings c;
    c.delta_m = 0.01f;
    c.color_rule = ColorRule::Nearest;
    return c;
  }();
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
  /// After the first pass every hypothesis is re-rendered at its stride and scored with first_pass_cost (a
  /// cheap ranking); only the best keep_per_instance distinct poses of each instance go on to the second
  /// pass, the re-render at score_stride and the final cost (0 = all; an instance whose first pass ran on a
  /// finer grid, see first_pass_min_points, keeps all its distinct poses). Many proposals converge to the
  /// same pose: two poses are distinct unless their translations differ by less than distinct_translation_m
  /// and their rotations (under the model's symmetries) by less than distinct_rotation_rad.
  int keep_per_instance = 12;
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
  double local = 0;  ///< the local search (its renders and costs are also in render and cost)
  double fit = 0;    ///< the final surface fit (its re-score's render and cost are in render and cost)
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
    for (const auto& m : models_) diameter_.push_back(sixdof_detail::model_diameter_bound(m.mesh));
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
    const typename Backend::Cost cost(observed);
    const Occluders occluders{frame.depth_m, labels};
    result.timings.observed = seconds_since(t);

    // ---- proposals
    t = Clock::now();
    std::vector<Hypothesis> hyps;
    std::vector<std::size_t> points_estimate;  // per instance: rendered points bound for the chunk size
    for (std::size_t k = 0; k < K; ++k) {
      const SixDofInstance& in = instances[k];
      const std::string who = "instances[" + std::to_string(k) + "] mask";
      const auto rotations = rotation_proposals(s.proposals, models_[in.model].symmetries);
      Image<std::uint8_t> trimmed(labels.width, labels.height, 0);  // the mask after trimming
      for (std::size_t i = 0; i < labels.data.size(); ++i) trimmed.data[i] = labels.data[i] == int(k + 1);
      const auto depths = proposal_depths(frame.depth_m, trimmed, models_[in.model].mesh, s.proposals, who);
      Eigen::Vector4i box = in.box_xywh;
      if (box[2] < 0 || box[3] < 0) box = mask_box(in.mask);
      const auto poses = pose_proposals(frame.camera, box_centre_px(box), rotations, depths);
      for (const auto& T : poses) hyps.push_back({in.model, T, std::int32_t(k + 1)});
      result.rotations.push_back(rotations.size());
      result.depths.push_back(depths.size());
      result.hypotheses.push_back(poses.size());
      // The object's image at the nearest depth covers at most its diameter's projection, squared.
      const float px = frame.camera.fx * diameter_[in.model] / std::max(depths.front(), 1e-3f);
      const int stride = std::min({s.render.stride, s.second_pass_stride, s.score_stride});
      points_estimate.push_back(std::size_t(px * px / float(stride * stride)) + 1);
    }
    result.hypotheses_total = hyps.size();
    result.timings.proposals = seconds_since(t);

    // ---- first pass over every proposal (chunks): render, refine, re-render, cheap cost. Each instance at
    // the coarsest stride that still shows it with first_pass_min_points (a mostly hidden object is
    // refined on a finer grid); hypotheses are grouped by instance, so each stride is a contiguous run.
    std::vector<int> first_stride(K);
    for (std::size_t k = 0; k < K; ++k) first_stride[k] = first_pass_stride(result.segment_points[k]);
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
      const auto c = run_chunks(frame, occluders, registration, cost, first, run, points_estimate, result);
      refined.insert(refined.end(), run.begin(), run.end());
      first_costs.insert(first_costs.end(), c.begin(), c.end());
      begin = end;
    }
    hyps = std::move(refined);

    // ---- second pass over the best distinct poses of each instance: tighter refinement, final cost
    std::vector<Hypothesis> kept = keep_best(hyps, first_costs, first_stride, instances);
    result.second_pass_hypotheses = kept.size();
    Pass second;
    second.stride = s.second_pass_stride;
    second.gicp = s.gicp;
    second.gicp.max_correspondence_distance_m = s.second_pass_cap_m;
    second.gicp.max_iterations = s.second_pass_iterations;
    second.gicp.icp_warmup_iterations = 0;
    second.refine = s.second_pass_cap_m > 0;
    second.score_stride = s.score_stride;
    second.cost = &s.cost;
    const std::vector<CostBreakdown> costs =
        run_chunks(frame, occluders, registration, cost, second, kept, points_estimate, result);

    // ---- select: the best acceptable hypotheses of each instance, refined by the local search
    t = Clock::now();
    const std::size_t n_local = s.local.candidates_per_instance > 0 ? s.local.candidates_per_instance : 1;
    std::vector<std::size_t> top = best_per_instance(kept, costs, K, n_local, s.score_stride);
    result.timings.select += seconds_since(t);
    std::vector<Hypothesis> finalists;
    for (const std::size_t h : top) finalists.push_back(kept[h]);
    std::vector<CostBreakdown> final_costs;
    for (const std::size_t h : top) final_costs.push_back(costs[h]);
    if (s.local.candidates_per_instance > 0) {
      t = Clock::now();
      const std::vector<CostBreakdown> local_costs =
          local_search(frame, occluders, cost, finalists, points_estimate, result);
      if (s.local.polish && second.refine) {  // GICP restores what the turns may have tilted (it cannot undo
                                              // a turn it cannot see)
        const CloudBatch rendered = render(finalists, frame.camera, s.second_pass_stride, occluders, result);
        refine(finalists, rendered, registration, second.gicp, result);
      }
      // The winner per instance (acceptable first) by the local cost or by the final cost (re-evaluated
      // at the moved poses; the winner's gives the score either way).
      std::vector<CostBreakdown> moved_costs =
          score(frame, occluders, cost, finalists, s.score_stride, s.cost, points_estimate, result);
      const std::vector<std::size_t> winners =
          s.local.select_by_local_cost ? best_per_instance(finalists, local_costs, K, 1, s.local.stride)
                                       : best_per_instance(finalists, moved_costs, K, 1, s.score_stride);
      std::vector<Hypothesis> chosen;
      final_costs.clear();
      for (const std::size_t h : winners)
        chosen.push_back(finalists[h]), final_costs.push_back(moved_costs[h]);
      finalists = std::move(chosen);
      result.timings.local += seconds_since(t);
    }
    t = Clock::now();
    std::vector<SixDofPose> best(K);
    for (std::size_t k = 0; k < K; ++k) best[k].instance = int(k), best[k].model = instances[k].model;
    std::vector<bool> seen(K, false);
    for (std::size_t h = 0; h < finalists.size(); ++h) {  // in order: an instance's best comes first
      const auto k = std::size_t(finalists[h].label - 1);
      if (seen[k]) continue;
      seen[k] = true;
      best[k].T_cam_obj = finalists[h].T_cam_obj;
      best[k].found = final_costs[h].rendered_points >= s.min_rendered_points;
      best[k].cost = final_costs[h];
    }
    result.timings.select += seconds_since(t);
    if (s.fit.iterations > 0) {
      t = Clock::now();
      fit_poses(frame, labels, occluders, cost, points_estimate, best, result);
      result.timings.fit += seconds_since(t);
    }
    for (auto& p : best) {
      const CostBreakdown& b = p.cost;
      const float n = float(b.rendered_points + b.observed_in_volume);
      p.score = n > 0
                    ? std::clamp(1.f - float(b.rendered_outliers() + b.observed_unexplained()) / n, 0.f, 1.f)
                    : 0.f;
    }
    result.poses = std::move(best);
    result.timings.total = seconds_since(t_start);
    return result;
  }

 private:
  static std::vector<Mesh> meshes_of(const std::vector<SixDofModel>& models) {
    if (models.empty()) throw InvalidInput("6-DoF models", "no models given");
    std::vector<Mesh> out;
    for (const auto& m : models) out.push_back(m.mesh);
    return out;
  }

  void validate(const RgbdFrame& frame, const std::vector<SixDofInstance>& instances) const {
    const SixDofSettings& s = settings_;
    perch2::validate(s.proposals);
    perch2::validate(s.gicp);
    if (s.score_stride < 1) throw InvalidInput("SixDofSettings::score_stride", "must be >= 1");
    if (s.second_pass_stride < 1) throw InvalidInput("SixDofSettings::second_pass_stride", "must be >= 1");
    if (s.render.stride < 1) throw InvalidInput("SixDofSettings::render.stride", "must be >= 1");
    if (s.keep_per_instance < 0) throw InvalidInput("SixDofSettings::keep_per_instance", "must be >= 0");
    if (!(s.distinct_translation_m >= 0) || !(s.distinct_rotation_rad >= 0))
      throw InvalidInput("SixDofSettings::distinct_*", "must be >= 0");
    if (!(s.second_pass_cap_m >= 0)) throw InvalidInput("SixDofSettings::second_pass_cap_m", "must be >= 0");
    if (s.second_pass_iterations < 1)
      throw InvalidInput("SixDofSettings::second_pass_iterations", "must be >= 1");
    if (s.local.candidates_per_instance < 0)
      throw InvalidInput("SixDofSettings::local.candidates_per_instance", "must be >= 0 (0 = off)");
    if (!(std::isfinite(s.local.rotation_step_rad) && s.local.rotation_step_rad > 0))
      throw InvalidInput("SixDofSettings::local.rotation_step_rad", "must be finite and > 0");
    if (s.local.levels < 0 || s.local.moves_per_level < 0)
      throw InvalidInput("SixDofSettings::local.levels/moves_per_level", "must be >= 0");
    if (s.local.stride < 1) throw InvalidInput("SixDofSettings::local.stride", "must be >= 1");
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
  void fit_poses(const RgbdFrame& frame, const LabelImage& labels, const Occluders& occ,
                 const typename Backend::Cost& cost, const std::vector<std::size_t>& points_estimate,
                 std::vector<SixDofPose>& best, SixDofResult& result) const {
    const SixDofSettings& s = settings_;
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
    const std::vector<CostBreakdown> c =
        score(frame, occ, cost, fitted, s.score_stride, s.cost, points_estimate, result);
    for (std::size_t i = 0; i < which.size(); ++i) {
      SixDofPose& p = best[which[i]];
      const float slack = s.fit_cost_slack * float(p.cost.rendered_points + p.cost.observed_in_volume);
      if (c[i].rendered_points < s.min_rendered_points || c[i].total > p.cost.total + slack) continue;
      p.T_cam_obj = r.T_cam_obj[i], p.cost = c[i];
      ++result.fits_kept;
    }
  }

  CloudBatch render(const std::vector<Hypothesis>& h, const Intrinsics& camera, int stride,
                    const Occluders& occ, SixDofResult& result) const {
    const auto t = sixdof_detail::Clock::now();
    RenderSettings rs = settings_.render;
    rs.stride = stride;
    CloudBatch out = renderer_.render(h, camera, rs, &occ);
    result.timings.render += sixdof_detail::seconds_since(t);
    return out;
  }

  /// One GICP pass of every hypothesis against its own segment (only gs's ICP warm-up if warmup_only);
  /// moves the hypotheses.
  void refine(std::vector<Hypothesis>& chunk, const CloudBatch& rendered,
              const typename Backend::Registration& registration, const GicpSettings& gs,
              SixDofResult& result, bool warmup_only = false) const {
    const auto t = sixdof_detail::Clock::now();
    std::vector<std::int32_t> segment(chunk.size());
    for (std::size_t h = 0; h < chunk.size(); ++h) segment[h] = chunk[h].label - 1;
    const RegistrationResult r = warmup_only ? registration.icp(rendered, segment, icp_warmup_settings(gs))
                                             : registration.gicp(rendered, segment, gs);
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
  std::vector<CostBreakdown> run_chunks(const RgbdFrame& frame, const Occluders& occ,
                                        const typename Backend::Registration& registration,
                                        const typename Backend::Cost& cost, const Pass& pass,
                                        std::vector<Hypothesis>& hyps,
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
      const std::size_t points = run_chunk(frame, occ, registration, cost, pass, chunk, costs, result);
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
  std::vector<CostBreakdown> score(const RgbdFrame& frame, const Occluders& occ,
                                   const typename Backend::Cost& cost, const std::vector<Hypothesis>& hyps,
                                   int stride, const CostSettings& cs,
                                   const std::vector<std::size_t>& points_estimate,
                                   SixDofResult& result) const {
    const int finest =
        std::min({settings_.render.stride, settings_.second_pass_stride, settings_.score_stride});
    const double scale = double(finest * finest) / double(stride * stride);
    std::vector<CostBreakdown> costs;
    costs.reserve(hyps.size());
    for (std::size_t begin = 0; begin < hyps.size();) {
      const std::size_t end = chunk_end(hyps, begin, scale, points_estimate);
      const std::vector<Hypothesis> chunk(hyps.begin() + std::ptrdiff_t(begin),
                                          hyps.begin() + std::ptrdiff_t(end));
      const CloudBatch rendered = render(chunk, frame.camera, stride, occ, result);
      result.peak_chunk_bytes =
          std::max(result.peak_chunk_bytes, rendered.size() * settings_.bytes_per_point);
      const auto t = sixdof_detail::Clock::now();
      CostRequest request;
      for (const auto& h : chunk) request.add(h.label - 1);
      const std::vector<CostBreakdown> c = cost.evaluate(rendered, request, cs).hypotheses;
      costs.insert(costs.end(), c.begin(), c.end());
      result.timings.cost += sixdof_detail::seconds_since(t);
      begin = end;
    }
    return costs;
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

  /// The local search (LocalSearchSettings) around each of `hyps`, which it moves; returns their costs
  /// (LocalSearchSettings::cost at its stride) at the poses found.
  std::vector<CostBreakdown> local_search(const RgbdFrame& frame, const Occluders& occ,
                                          const typename Backend::Cost& cost, std::vector<Hypothesis>& hyps,
                                          const std::vector<std::size_t>& points_estimate,
                                          SixDofResult& result) const {
    const LocalSearchSettings& ls = settings_.local;
    TurnSchedule schedule;
    schedule.rotation_step_rad = ls.rotation_step_rad, schedule.levels = ls.levels;
    schedule.moves_per_level = ls.moves_per_level, schedule.sweep_turns = ls.sweep_turns;
    schedule.require_both_terms = ls.require_both_terms;
    auto turn = [](Hypothesis h, int axis, float angle_rad) {  // about the model's own axis
      h.T_cam_obj.linear() =
          h.T_cam_obj.linear() * Eigen::AngleAxisf(angle_rad, Eigen::Vector3f::Unit(axis)).toRotationMatrix();
      return h;
    };
    auto costs = [&](const std::vector<Hypothesis>& h) {
      return score(frame, occ, cost, h, ls.stride, ls.cost, points_estimate, result);
    };
    return climb_turns(hyps, 3, 3, schedule, turn, costs, &result.local_candidates);
  }

  /// Renders, refines, re-renders and scores one chunk (appending its costs). Returns its largest rendered
  /// point count.
  std::size_t run_chunk(const RgbdFrame& frame, const Occluders& occ,
                        const typename Backend::Registration& registration,
                        const typename Backend::Cost& cost, const Pass& pass, std::vector<Hypothesis>& chunk,
                        std::vector<CostBreakdown>& costs, SixDofResult& result) const {
    using namespace sixdof_detail;
    std::size_t points = 0;
    if (pass.refine && pass.dedupe_after_warmup && pass.gicp.icp_warmup_iterations > 0) {
      // ICP warm-up, then GICP only for the distinct poses it reached (re-rendered there).
      const CloudBatch rendered = render(chunk, frame.camera, pass.stride, occ, result);
      points = rendered.size();
      refine(chunk, rendered, registration, pass.gicp, result, /*warmup_only=*/true);
      chunk = distinct_poses(chunk);
      result.first_pass_distinct += chunk.size();
      GicpSettings rest = pass.gicp;
      rest.icp_warmup_iterations = 0;
      const CloudBatch moved = render(chunk, frame.camera, pass.stride, occ, result);
      points = std::max(points, moved.size());
      refine(chunk, moved, registration, rest, result);
    } else if (pass.refine) {
      if (pass.first) result.first_pass_distinct += chunk.size();
      const CloudBatch rendered = render(chunk, frame.camera, pass.stride, occ, result);
      points = rendered.size();
      refine(chunk, rendered, registration, pass.gicp, result);
    }
    const CloudBatch rendered = render(chunk, frame.camera, pass.score_stride, occ, result);
    points = std::max(points, rendered.size());
    const auto t = Clock::now();
    CostRequest request;
    for (const auto& h : chunk) request.add(h.label - 1);
    const std::vector<CostBreakdown> c = cost.evaluate(rendered, request, *pass.cost).hypotheses;
    costs.insert(costs.end(), c.begin(), c.end());
    result.timings.cost += seconds_since(t);
    return points;
  }

  /// The best keep_per_instance distinct hypotheses of each instance by cost (all if 0), in instance then
  /// cost order. A hypothesis showing fewer than min_rendered_points (scaled to the first pass' stride)
  /// ranks after every one that shows enough.
  std::vector<Hypothesis> keep_best(const std::vector<Hypothesis>& hyps,
                                    const std::vector<CostBreakdown>& costs, const std::vector<int>& stride,
                                    const std::vector<SixDofInstance>& instances) const {
    const SixDofSettings& s = settings_;
    const std::size_t K = instances.size();
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

  std::vector<SixDofModel> models_;
  SixDofSettings settings_;
  typename Backend::Renderer renderer_;
  SurfaceFit<Backend> surface_fit_;
  std::vector<float> diameter_;  ///< per model, an upper bound (2 x the largest vertex distance), metres
};

}  // namespace perch2
