// Timing harness of the 3-DoF tabletop search (TabletopEstimator): generated 640x480 scenes (perch2::synth,
// fixed seed, 4-6 objects), the estimator's per-stage wall times, the process CPU time (getrusage: all
// threads) of each estimate, the hypothesis counts and the ADD-S error of every ground-truth object.
//
//   bench_search3dof [--scenes N] [--seed S] [--backend cpu|thrust_omp] [--score-stride K] [--render-stride
//   K] [--coarse-stride K (0: off)] [--rescore-yaws N] [--icp-points N (0: all)]
//                    [--icp-iterations K] [--icp-epsilon E] [--depth-only] [--no-eval]
//                    [--dedupe-mm D] [--dedupe-deg A] [--no-exclusive] [--raw-colour] [--kl L] [--tau T]
//                    [--verbose]
//
// CPU time, not wall time, is the figure to compare on a shared machine (wall time grows with other load).
// Measured 2026-11-30 on the shared 2-core machine (load 6-9, so absolute figures are high): 4 scenes, seed
// 8, cpu backend, paired runs of one binary with the old and new libperch2_cpu: 8.7 s -> 5.0 s process CPU
// per scene (cost stage ~2x, ICP ~1.6x less), identical poses (ADD-S < 1 cm 16/20). --render-stride 6: 3.3 s,
// 16/20, mean ADD-S 17.4 vs 16.7 mm.
#include <sys/resource.h>

#include <cstdio>
#include <cstdlib>
#include <limits>
#include <string>
#include <vector>

#include "bench_support.hpp"
#include "perch2/cpu/estimators.hpp"
#include "perch2/cuda/estimators.hpp"
#include "perch2/eval/metrics.hpp"
#include "perch2/search/tabletop.hpp"
#include "perch2/synth/synth.hpp"

using namespace perch2;

namespace {

struct Options {
  int scenes = 1;
  std::uint64_t seed = 8;
  std::string backend = "cpu";
  int score_stride = -1, render_stride = -1, icp_iterations = -1, coarse_stride = -1, rescore_yaws = -1,
      icp_points = -1;
  float icp_epsilon = -1;  ///< translation (m) and rotation (rad) convergence thresholds of the ICP
  bool depth_only = false;
  float dedupe_mm = -1, dedupe_deg = -1;
  float lightness_factor = -1, tau_c = -1;
  bool no_exclusive = false, raw_colour = false;
  bool verbose = false;  ///< per object: the chosen pose's cost and the best scored one near the truth
  bool eval = true;      ///< --no-eval: skip ADD-S (its model kd-trees would pollute a profile of the search)
};

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> const char* {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--scenes")
      o.scenes = std::atoi(next());
    else if (a == "--seed")
      o.seed = std::strtoull(next(), nullptr, 10);
    else if (a == "--backend")
      o.backend = next();
    else if (a == "--score-stride")
      o.score_stride = std::atoi(next());
    else if (a == "--coarse-stride")
      o.coarse_stride = std::atoi(next());
    else if (a == "--icp-points")
      o.icp_points = std::atoi(next());
    else if (a == "--rescore-yaws")
      o.rescore_yaws = std::atoi(next());
    else if (a == "--render-stride")
      o.render_stride = std::atoi(next());
    else if (a == "--icp-iterations")
      o.icp_iterations = std::atoi(next());
    else if (a == "--depth-only")
      o.depth_only = true;
    else if (a == "--icp-epsilon")
      o.icp_epsilon = float(std::atof(next()));
    else if (a == "--dedupe-mm")
      o.dedupe_mm = float(std::atof(next()));
    else if (a == "--dedupe-deg")
      o.dedupe_deg = float(std::atof(next()));
    else if (a == "--kl")
      o.lightness_factor = float(std::atof(next()));
    else if (a == "--tau")
      o.tau_c = float(std::atof(next()));
    else if (a == "--raw-colour")
      o.raw_colour = true;
    else if (a == "--no-exclusive")
      o.no_exclusive = true;
    else if (a == "--verbose")
      o.verbose = true;
    else if (a == "--no-eval")
      o.eval = false;
    else {
      std::fprintf(stderr, "unknown option %s\n", a.c_str());
      std::exit(2);
    }
  }
  return o;
}

void print_breakdown(const char* what, const TabletopPose& p, double adds) {
  const CostBreakdown& b = p.cost;
  std::printf(
      "    %-9s total %7.1f ADD-S %.4f rendered %4d (depth out %3d colour out %3d) volume %4d (depth out %3d "
      "colour out %3d)\n",
      what, b.total, adds, b.rendered_points, b.rendered_depth_outliers, b.rendered_color_outliers,
      b.observed_in_volume, b.observed_depth_outliers, b.observed_color_outliers);
}

/// --verbose: the chosen pose(s) of a ground-truth object's model and the best-scored hypothesis of that
/// model within 1 cm ADD-S of the truth (what the cost would have needed to prefer).
void print_costs(const TabletopResult& r, int model, const Pose& T_world_true, const eval::ModelPoints& pts) {
  for (const auto& p : r.poses)
    if (p.model == model) print_breakdown("chosen", p, eval::adds_error(p.T_world_obj, T_world_true, pts));
  const TabletopPose* near = nullptr;
  for (const auto& p : r.scored)
    if (p.model == model && (p.T_world_obj.translation() - T_world_true.translation()).norm() < 0.02f &&
        eval::adds_error(p.T_world_obj, T_world_true, pts) < 0.01 && (!near || p.score < near->score))
      near = &p;
  if (near)
    print_breakdown("near-true", *near, eval::adds_error(near->T_world_obj, T_world_true, pts));
  else
    std::printf("    no scored hypothesis within 1 cm of the truth\n");
}

template <class Backend>
int run(const Options& o) {
  const std::vector<synth::ObjectModel> models = synth::builtin_models();
  std::vector<TabletopModel> tm;
  std::vector<eval::ModelPoints> points;
  for (const auto& m : models) {
    TabletopModel t;
    t.mesh = m.mesh;
    for (const auto& c : m.symmetries.continuous)
      t.yaw_symmetric |= c.axis.cross(Eigen::Vector3f::UnitZ()).norm() < 1e-6f;
    tm.push_back(t);
    if (o.eval) points.emplace_back(synth::sample_surface(m.mesh, 0.005f));
  }
  synth::SceneSettings ss;
  ss.mode = synth::Mode::ThreeDof;
  ss.min_objects = 4, ss.max_objects = 6;
  const synth::SensorSettings sensor;
  double cpu_total = 0, wall_total = 0;
  TabletopTimings sum;
  int objects = 0, below_1cm = 0;
  double adds_sum = 0;
  for (int k = 0; k < o.scenes; ++k) {
    synth::Rng rng = synth::Rng::stream(o.seed, std::uint64_t(k));
    const synth::Scene scene = synth::compose_scene(models, ss, rng);
    // The rest pose of each model as it stands in this scene (the estimator's T_place_obj).
    std::vector<ObjectCount> counts;
    for (const auto& obj : scene.objects) {
      tm[std::size_t(obj.model)].T_place_obj = rest_pose_from(obj.T_world_obj);
      bool listed = false;
      for (auto& c : counts) listed |= c.model == obj.model && ++c.count > 0;
      if (!listed) counts.push_back({obj.model, 1});
    }
    const Pose T_world_cam = synth::sample_camera_pose(ss, rng);
    const synth::SceneRenderer renderer(models, scene);
    const synth::Frame fr = renderer.render(T_world_cam, sensor, rng);
    RgbdFrame frame{fr.camera, fr.depth_m, fr.rgb};

    TabletopSettings s;
    s.strict_instances = false;
    if (o.score_stride > 0) s.score_stride = o.score_stride;
    if (o.coarse_stride >= 0) s.coarse_score_stride = o.coarse_stride;
    if (o.rescore_yaws > 0) s.rescore_yaws = o.rescore_yaws;
    if (o.icp_points >= 0) s.icp_max_points = o.icp_points;
    if (o.render_stride > 0) s.render.stride = o.render_stride;
    if (o.icp_iterations > 0) s.icp.max_iterations = o.icp_iterations;
    if (o.depth_only) s.cost.use_color = false;
    if (o.dedupe_mm >= 0) s.dedupe_xy_m = 1e-3f * o.dedupe_mm;
    if (o.dedupe_deg >= 0) s.dedupe_yaw_rad = o.dedupe_deg * 3.14159265f / 180.f;
    s.exclusive_placements = !o.no_exclusive;
    s.cost.shading_invariant = !o.raw_colour;
    if (o.lightness_factor > 0) s.cost.lightness_factor = o.lightness_factor;
    if (o.tau_c > 0) s.cost.tau_c = o.tau_c;
    s.keep_scored = o.verbose;
    if (o.icp_epsilon > 0) s.icp.translation_epsilon_m = s.icp.rotation_epsilon_rad = o.icp_epsilon;
    TabletopEstimator<Backend> est(tm, s);
    const double c0 = bench::cpu_seconds();
    const TabletopResult r = est.estimate(frame, counts, T_world_cam.inverse());
    const double cpu = bench::cpu_seconds() - c0;
    cpu_total += cpu, wall_total += r.timings.total;
    const TabletopTimings& t = r.timings;
    sum.render += t.render, sum.refine += t.refine, sum.cost += t.cost, sum.observed += t.observed;
    sum.hypotheses += t.hypotheses, sum.select += t.select;
    std::printf(
        "scene %d: %zu objects, hypotheses grid %zu kept %zu coarse %zu scored %zu | cpu %.2f s "
        "wall %.2f s "
        "(observed %.3f grid %.3f render %.3f refine %.3f cost %.3f select %.3f)\n",
        k, scene.objects.size(), r.hypotheses_grid, r.hypotheses_kept, r.hypotheses_coarse,
        r.hypotheses_scored, cpu, t.total, t.observed, t.hypotheses, t.render, t.refine, t.cost, t.select);
    if (!o.eval) continue;
    // ADD-S of each ground-truth object: the best of the estimated poses of its model (misses: infinite).
    for (const auto& obj : scene.objects) {
      double best = std::numeric_limits<double>::infinity();
      for (const auto& p : r.poses)
        if (p.model == obj.model)
          best = std::min(best,
                          eval::adds_error(p.T_world_obj, obj.T_world_obj, points[std::size_t(obj.model)]));
      ++objects, below_1cm += best < 0.01, adds_sum += std::min(best, 0.1);
      std::printf("  %-14s ADD-S %.4f m\n", models[std::size_t(obj.model)].name.c_str(), best);
      if (o.verbose) print_costs(r, obj.model, obj.T_world_obj, points[std::size_t(obj.model)]);
    }
  }
  const double n = o.scenes;
  std::printf(
      "backend %s, %d scene(s), seed %llu: mean cpu %.2f s, wall %.2f s (render %.3f refine %.3f cost "
      "%.3f); ADD-S < 1 cm %d/%d, mean ADD-S (capped 0.1) %.4f m\n",
      o.backend.c_str(), o.scenes, (unsigned long long)o.seed, cpu_total / n, wall_total / n, sum.render / n,
      sum.refine / n, sum.cost / n, below_1cm, objects, adds_sum / objects);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const Options o = parse(argc, argv);
  if (o.backend == "cpu") return run<cpu::Backend>(o);
  if (o.backend == "thrust_omp") return run<thrust_omp::Backend>(o);
  std::fprintf(stderr, "unknown backend %s\n", o.backend.c_str());
  return 2;
}
