// The paper's Table II on generated scenes: 6-DoF accuracy and time of SixDofEstimator with ground-truth
// masks and with the generator's degraded detections.
//   1. Generates N cluttered 6-DoF scenes (fixed seed; built-in objects, 4-7 per scene, stacked, leaning and
//      lying, 1-3 distractors; one 640x480 image each) into SCRATCH/dataset with perch2::synth, once: later
//      runs with the same --scenes and --seed reuse it (so the table can be run in parts).
//   2. Runs each configuration (masks gt|det x backend) over the requested scenes in its own process (peak
//      memory per configuration; a re-executed child, not a fork: libgomp's pool does not survive fork()),
//      writing one BOP results CSV and one line of stage times per scene under SCRATCH/results/CONFIG/.
//   3. Evaluates every scene found for a configuration with perch2::eval (targets restricted to those
//      scenes): ADD-S AUC, ADD(-S) AUC (0-10 cm) and ADD-S < 2 cm per object and overall; mean wall and
//      process CPU seconds per scene with a per-stage breakdown; peak resident memory and the estimator's
//      largest chunk; the load average while it ran (other jobs share the cores). Per-instance errors go
//      to SCRATCH/results/CONFIG/instances.txt.
// --masks det: detections_synth.json as a detector would give them (boundaries grown/shrunk and wobbly,
// jittered boxes, misses, look-alike confusions, spurious ones); a missed instance counts as a failure.
// --masks none: no masks; the targets' objects and instance counts are searched for in the whole frame
// (SixDofEstimator::estimate_scene); instances not placed count as failures.
// Usage: bench_sixdof [--scenes N (20)] [--seed S (2020)] [--only A-B (all)] [--masks gt|det|none|both
// (both)]
//                     [--backend cpu|thrust_omp|both (cpu)] [--dir SCRATCH (/tmp/perch2_bench_sixdof)]
//                     [--eval-only] [--color-rule any|nearest] [--warmup N] [--iterations N]
//                     [--local N (local search candidates per instance)] [--sweep N (its sweep turns)]
//                     [--final-stride N (its final comparison's render stride)]
//                     [--geometry-tolerance X (its look-alike tolerance)]
//                     [--placed-only 0|1 (--masks none: local search only for the candidate being placed)]
//                     [--dedupe 0|1 (de-duplication after the ICP warm-up)]
//                     [--fit N (Gauss-Newton steps of the final surface fit, 0 = off)]
//                     [--target-stride N (the first pass' GICP target grid, pixels)]
//                     [--screen-in-scene 0|1 (--masks none: the screen before the first pass)]
//                     [--screen-keep X (the screen's keep fraction)]
#include <omp.h>

#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "bench_support.hpp"
#include "cli_common.hpp"
#include "perch2/cpu/estimators.hpp"
#include "perch2/cuda/estimators.hpp"
#include "perch2/dataset/runner.hpp"
#include "perch2/eval/evaluator.hpp"
#include "perch2/search/sixdof_bop.hpp"
#include "perch2/synth/synth.hpp"

using namespace perch2;
namespace fs = std::filesystem;

namespace {

struct Options {
  int scenes = 20;
  std::uint64_t seed = 2020;
  int first = 1, last = 1 << 30;
  std::vector<std::string> masks{"gt", "det"};
  std::vector<dataset::BackendKind> backends{dataset::BackendKind::Cpu};
  std::string dir = "/tmp/perch2_bench_sixdof";
  bool eval_only = false;
  std::string color_rule;  ///< "" = the default; any|nearest: SixDofSettings::cost.color_rule
  int local_candidates = -1, local_sweep = -1, dedupe = -1, final_stride = -1,
      placed_only = -1;  ///< >= 0: SixDofSettings overrides (local.turns, scene.local_search_placed_only)
  float geometry_tolerance = -1;  ///< >= 0: SixDofSettings::local.turns.geometry_tolerance
  int warmup = -1,
      iterations = -1;       ///< >= 0: the first pass' ICP warm-up / GICP passes (SixDofSettings::gicp)
  int fit = -1;              ///< >= 0: SixDofSettings::fit.iterations
  int target_stride = -1;    ///< >= 1: SixDofSettings::first_pass_target_stride
  int screen_in_scene = -1;  ///< >= 0: SixDofSettings::screen.in_scene
  float screen_keep = -1;    ///< > 0: SixDofSettings::screen.keep_fraction
  std::string child_masks, child_backend;  ///< internal: run one configuration over [first, last] and exit
};

constexpr const char* kUsage =
    "bench_sixdof [--scenes N] [--seed S] [--only A-B] [--masks gt|det|none|both] [--backend "
    "cpu|thrust_omp|both]\n"
    "             [--dir SCRATCH] [--eval-only] [--color-rule any|nearest] [--warmup N] [--iterations N]\n"
    "             [--local N] [--sweep N] [--final-stride N] [--geometry-tolerance X] [--placed-only 0|1]\n"
    "             [--dedupe 0|1] [--fit N] [--target-stride N] [--screen-in-scene 0|1] [--screen-keep X]";

Options parse(int argc, char** argv) {
  Options o;
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    if (a == "--eval-only") {
      o.eval_only = true;
      continue;
    }
    if (k + 1 >= argc) throw InvalidInput(a, std::string("needs a value; usage: ") + kUsage);
    const std::string v = argv[++k];
    if (a == "--scenes") {
      o.scenes = std::stoi(v);
      if (o.scenes < 1) throw InvalidInput("--scenes", "must be >= 1");
    } else if (a == "--seed") {
      o.seed = std::stoull(v);
    } else if (a == "--only") {
      const auto dash = v.find('-');
      o.first = std::stoi(v.substr(0, dash));
      o.last = dash == std::string::npos ? o.first : std::stoi(v.substr(dash + 1));
      if (o.first < 1 || o.last < o.first)
        throw InvalidInput("--only", "'" + v + "' is not A-B with 1 <= A <= B");
    } else if (a == "--masks") {
      if (v != "gt" && v != "det" && v != "none" && v != "both")
        throw InvalidInput("--masks", "must be gt, det, none or both");
      o.masks = v == "both" ? std::vector<std::string>{"gt", "det"} : std::vector<std::string>{v};
    } else if (a == "--backend") {
      o.backends = v == "both" ? std::vector<dataset::BackendKind>{dataset::BackendKind::Cpu,
                                                                   dataset::BackendKind::ThrustOmp}
                               : std::vector<dataset::BackendKind>{dataset::parse_backend(v)};
    } else if (a == "--color-rule") {
      if (v != "any" && v != "nearest") throw InvalidInput("--color-rule", "must be any or nearest");
      o.color_rule = v;
    } else if (a == "--local" || a == "--sweep" || a == "--dedupe" || a == "--final-stride" ||
               a == "--placed-only") {
      (a == "--local"          ? o.local_candidates
       : a == "--sweep"        ? o.local_sweep
       : a == "--dedupe"       ? o.dedupe
       : a == "--final-stride" ? o.final_stride
                               : o.placed_only) = std::stoi(v);
    } else if (a == "--geometry-tolerance") {
      o.geometry_tolerance = std::stof(v);
      if (!(o.geometry_tolerance >= 0)) throw InvalidInput("--geometry-tolerance", "must be >= 0");
    } else if (a == "--warmup" || a == "--iterations" || a == "--fit") {
      (a == "--warmup" ? o.warmup : a == "--fit" ? o.fit : o.iterations) = std::stoi(v);
    } else if (a == "--target-stride") {
      o.target_stride = std::stoi(v);
      if (o.target_stride < 1) throw InvalidInput("--target-stride", "must be >= 1");
    } else if (a == "--screen-in-scene") {
      o.screen_in_scene = std::stoi(v);
    } else if (a == "--screen-keep") {
      o.screen_keep = std::stof(v);
      if (!(o.screen_keep > 0 && o.screen_keep <= 1))
        throw InvalidInput("--screen-keep", "must be in (0, 1]");
    } else if (a == "--dir") {
      o.dir = v;
    } else if (a == "--child" && k + 1 < argc) {
      o.child_masks = v, o.child_backend = argv[++k];
    } else {
      throw InvalidInput(a, std::string("unknown argument; usage: ") + kUsage);
    }
  }
  return o;
}

/// Generates the dataset unless SCRATCH/dataset already holds the one of these settings; returns whether it
/// did (earlier results are then stale).
bool generate(const std::string& dir, int scenes, std::uint64_t seed) {
  const std::string stamp = dir + "/bench_stamp.txt",
                    want = std::to_string(scenes) + " " + std::to_string(seed);
  std::string have;
  std::getline(std::ifstream(stamp), have);
  if (have == want && fs::is_directory(dir + "/test")) return false;
  synth::DatasetSettings s;
  s.num_scenes = scenes, s.images_per_scene = 1, s.seed = seed;
  s.scene.mode = synth::Mode::SixDof;
  fs::remove_all(dir);
  const auto summary = synth::generate_dataset(synth::builtin_models(), s, dir);
  std::printf("generated %d scenes, %d instances (%d targets), %d detections in %.1f s -> %s\n",
              summary.scenes, summary.instances, summary.targets, summary.detections, summary.seconds,
              dir.c_str());
  std::ofstream(stamp) << want << '\n';
  return true;
}

/// Process CPU time (all threads), seconds: glibc's clock() reads CLOCK_PROCESS_CPUTIME_ID.
double cpu_seconds_now() {
  return double(std::clock()) / CLOCKS_PER_SEC;
}

/// The setting overrides a child needs on its command line.
std::string child_overrides(const Options& o) {
  std::string out;
  const std::pair<const char*, int> all[] = {{"--warmup", o.warmup},
                                             {"--iterations", o.iterations},
                                             {"--local", o.local_candidates},
                                             {"--sweep", o.local_sweep},
                                             {"--dedupe", o.dedupe},
                                             {"--final-stride", o.final_stride},
                                             {"--placed-only", o.placed_only},
                                             {"--fit", o.fit},
                                             {"--target-stride", o.target_stride},
                                             {"--screen-in-scene", o.screen_in_scene}};
  for (const auto& [flag, v] : all)
    if (v >= 0) out += std::string(" ") + flag + " " + std::to_string(v);
  if (o.geometry_tolerance >= 0) out += " --geometry-tolerance " + std::to_string(o.geometry_tolerance);
  if (o.screen_keep > 0) out += " --screen-keep " + std::to_string(o.screen_keep);
  return out;
}

std::string config_dir(const Options& o, const std::string& masks, dataset::BackendKind b) {
  return o.dir + "/results/" + masks + "_" + dataset::backend_name(b);
}

/// Child: one configuration over scenes [first, last]; per scene SSSSSS.csv and SSSSSS.times (observed
/// proposals render refine cost select total cpu hypotheses chunk_peak_mib rss_peak_mib load instances local
/// explain fit; local and explain are parts of the other stages' wall time, fit of render + cost's).
template <class Backend>
void run(const Options& o, const std::string& masks, const std::string& out_dir) {
  const dataset::BopDataset data(o.dir + "/dataset");
  const auto images = dataset::targets_by_image(data.targets(), o.first, o.last);
  std::map<int, int> model_of;
  std::vector<SixDofModel> models;
  for (const auto& [id, info] : data.models_info())
    model_of[id] = int(models.size()), models.push_back(sixdof_model(data.load_model(id), info));
  SixDofSettings settings;
  if (!o.color_rule.empty())
    settings.cost.color_rule = o.color_rule == "any" ? ColorRule::AnyNeighbour : ColorRule::Nearest;
  if (o.warmup >= 0) settings.gicp.icp_warmup_iterations = o.warmup;
  if (o.local_candidates >= 0) settings.local.candidates_per_instance = o.local_candidates;
  if (o.local_sweep >= 0) settings.local.turns.sweep_turns = o.local_sweep;
  if (o.final_stride >= 0) settings.local.turns.final_stride = o.final_stride;
  if (o.geometry_tolerance >= 0) settings.local.turns.geometry_tolerance = o.geometry_tolerance;
  if (o.placed_only >= 0) settings.scene.local_search_placed_only = o.placed_only != 0;
  if (o.dedupe >= 0) settings.dedupe_after_warmup = o.dedupe != 0;
  if (o.iterations >= 0) settings.gicp.max_iterations = o.iterations;
  if (o.fit >= 0) settings.fit.iterations = o.fit;
  if (o.target_stride >= 1) settings.first_pass_target_stride = o.target_stride;
  if (o.screen_in_scene >= 0) settings.screen.in_scene = o.screen_in_scene != 0;
  if (o.screen_keep > 0) settings.screen.keep_fraction = o.screen_keep;
  const SixDofEstimator<Backend> estimator(std::move(models), settings);
  std::vector<dataset::Detection> detections;
  std::map<std::pair<int, int>, std::vector<std::size_t>> detections_of;
  if (masks == "det") {
    detections = dataset::load_detections(data.root() + "/detections_synth.json");
    detections_of = dataset::detections_by_image(detections);
  }
  fs::create_directories(out_dir);
  dataset::ImageLoadOptions load;
  load.masks_visib = masks == "gt";
  int done = 0;
  double wall = 0;
  for (const auto& [key, targets] : images) {
    const dataset::BopImage image = data.load_image(key.first, key.second, load);
    const double load_before = bench::load_average(), cpu0 = cpu_seconds_now();
    SixDofResult r;
    std::vector<dataset::PoseEstimate> rows;
    std::size_t instances = 0;
    if (masks == "none") {  // no masks: the targets' objects and counts in the whole frame
      std::map<int, int> count;
      for (const auto& t : targets) count[model_of.at(t.obj_id)] += t.inst_count;
      std::vector<SixDofObject> objects;
      for (const auto& [m, n] : count) objects.push_back({m, n});
      SixDofSceneResult sr = estimator.estimate_scene(image.frame, objects);
      for (const auto& p : sr.poses) {
        dataset::PoseEstimate e;
        e.scene_id = key.first, e.im_id = key.second, e.score = p.score, e.T_cam_obj = p.T_cam_obj;
        for (const auto& [id, m] : model_of)
          if (m == p.model) e.obj_id = id;
        e.time_s = sr.search.timings.total;
        rows.push_back(e);
      }
      instances = sr.poses.size();
      r = std::move(sr.search);
    } else {
      const BopInstances all =
          masks == "gt" ? bop_instances_from_gt(image, model_of, BoxKind::Full)
                        : bop_instances_from_detections(image, detections, detections_of[key], model_of);
      const BopInstances in =
          usable_instances(only_targets(all, targets), image.frame, estimator.settings().observed);
      rows = estimate_bop_image(estimator, image, in, &r);
      instances = in.instances.size();
    }
    const double cpu = cpu_seconds_now() - cpu0;
    const std::string base = out_dir + "/" + dataset::bop_id(key.first);
    dataset::save_results_csv(base + ".csv", rows);
    const SixDofTimings& t = r.timings;
    std::ofstream(base + ".times") << t.observed << ' ' << t.proposals << ' ' << t.render << ' ' << t.refine
                                   << ' ' << t.cost << ' ' << t.select << ' ' << t.total << ' ' << cpu << ' '
                                   << r.hypotheses_total << ' ' << double(r.peak_chunk_bytes) / 1048576.0
                                   << ' ' << double(bench::status_kb("VmHWM")) / 1024.0 << ' '
                                   << 0.5 * (load_before + bench::load_average()) << ' ' << instances << ' '
                                   << t.local << ' ' << t.explain << ' ' << t.fit << ' ' << t.first_pass
                                   << ' ' << t.second_pass << ' ' << t.screen << ' '
                                   << r.proposals_screened_out << '\n';
    wall += t.total;
    ++done;  // before the call: its arguments' evaluation order is unspecified
    cli::print_progress(stderr, done, int(images.size()), wall / done, t.total);
  }
}

struct Totals {
  int scenes = 0;
  double observed = 0, proposals = 0, render = 0, refine = 0, cost = 0, select = 0, total = 0, cpu = 0;
  double hypotheses = 0, chunk_mib = 0, rss_mib = 0, load = 0, instances = 0, local = 0, explain = 0, fit = 0;
  double first_pass = 0, second_pass = 0, screen = 0, screened_out = 0;
};

struct Row {
  std::string name;
  eval::EvalReport report;
  Totals t;
};

/// Evaluates every scene found under `dir` against the targets of those scenes.
Row evaluate(const Options& o, const std::string& name, const std::string& dir) {
  Row row{name, {}, {}};
  std::vector<dataset::PoseEstimate> estimates;
  std::set<int> scenes;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() != ".times") continue;
    const fs::path csv = fs::path(e.path()).replace_extension(".csv");
    if (!fs::exists(csv)) continue;
    std::ifstream f(e.path());
    Totals& t = row.t;
    double v[13];
    for (double& x : v) f >> x;
    if (!f) throw FileError(e.path().string(), "truncated (did the run fail?)");
    t.observed += v[0], t.proposals += v[1], t.render += v[2], t.refine += v[3], t.cost += v[4];
    t.select += v[5], t.total += v[6], t.cpu += v[7], t.hypotheses += v[8];
    t.chunk_mib = std::max(t.chunk_mib, v[9]), t.rss_mib = std::max(t.rss_mib, v[10]);
    t.load += v[11], t.instances += v[12], ++t.scenes;
    // local, explain, fit, first and second pass, screen, screened out (absent in older files)
    double parts[7] = {0, 0, 0, 0, 0, 0, 0};
    for (double& x : parts) f >> x;
    t.local += parts[0], t.explain += parts[1], t.fit += parts[2], t.first_pass += parts[3];
    t.second_pass += parts[4], t.screen += parts[5], t.screened_out += parts[6];
    const auto rows = dataset::load_results_csv(csv.string());
    estimates.insert(estimates.end(), rows.begin(), rows.end());
    scenes.insert(std::stoi(e.path().stem().string()));
  }
  if (scenes.empty()) throw FileError(dir, "holds no results (run without --eval-only first)");
  // The targets of the scenes run, in a file of their own (a partial run is evaluated over its scenes).
  const std::string root = o.dir + "/dataset",
                    targets_name = "bench_targets_" + fs::path(dir).filename().string() + ".json";
  nlohmann::json targets = nlohmann::json::array();
  const dataset::BopDataset all(root);  // named: targets() refers into it
  for (const auto& t : all.targets())
    if (scenes.count(t.scene_id))
      targets.push_back(
          {{"im_id", t.im_id}, {"inst_count", t.inst_count}, {"obj_id", t.obj_id}, {"scene_id", t.scene_id}});
  std::ofstream(root + "/" + targets_name) << targets.dump() << '\n';
  dataset::DatasetOptions options;
  options.targets_file = targets_name;
  eval::EvalSettings es;
  es.compute_vsd = false;
  row.report = eval::evaluate(dataset::BopDataset(root, options), estimates, es, dir);
  // Per-instance errors (scene im obj gt visib ADD-S ADD(-S), mm) for looking at the failures.
  std::ofstream per(dir + "/instances.txt");
  for (const auto& i : row.report.instances)
    per << i.scene_id << ' ' << i.im_id << ' ' << i.obj_id << ' ' << i.gt_index << ' ' << i.visib_fract << ' '
        << 1000 * i.adds_m << ' ' << 1000 * i.add_or_adds_m << '\n';
  return row;
}

void print_tables(const std::vector<Row>& rows) {
  std::map<int, std::string> names;
  for (const auto& m : synth::builtin_models()) names[m.obj_id] = m.name;
  std::printf(
      "\nper object, percent: ADD-S AUC / ADD(-S) AUC / ADD-S < 2 cm (0-10 cm AUC, YCB-Video style)\n");
  std::printf("%-14s %7s", "object", "targets");
  for (const Row& r : rows) std::printf("  %-22s", r.name.c_str());
  std::printf("\n");
  std::set<int> objects;
  for (const Row& r : rows)
    for (const auto& [obj, s] : r.report.per_object) objects.insert(obj);
  auto line = [&](const std::string& label, auto scores_of) {
    const eval::Scores* first = scores_of(rows.front());
    std::printf("%-14s %7d", label.c_str(), first ? first->num_targets : 0);
    for (const Row& r : rows) {
      const eval::Scores* s = scores_of(r);
      if (s)
        std::printf("  %6.1f / %6.1f / %6.1f", 100 * s->auc_adds, 100 * s->auc_add_or_adds,
                    100 * s->adds_below_2cm);
      else
        std::printf("  %-22s", "-");
    }
    std::printf("\n");
  };
  for (const int obj : objects)
    line(std::to_string(obj) + " " + names[obj], [&](const Row& r) -> const eval::Scores* {
      const auto it = r.report.per_object.find(obj);
      return it == r.report.per_object.end() ? nullptr : &it->second;
    });
  line("all", [](const Row& r) { return &r.report.overall; });

  std::printf(
      "\nmean per scene: stage wall seconds, then what the passes took of them (pass1, pass2 with the "
      "polish, local search, surface fit, scene explanation, the screen), process CPU seconds, hypotheses "
      "(and \n"
      "those the screen kept from the first pass); peak memory\n");
  std::printf("%-16s %6s %5s %7s %7s %7s %7s %7s %7s %7s %7s %7s %7s %7s %7s %7s %7s %6s %6s %8s %8s %6s\n",
              "config", "scenes", "inst", "observ", "propos", "render", "refine", "cost", "select", "total",
              "screen", "pass1", "pass2", "local", "fit", "explain", "CPU s", "hyp", "out", "RSS MiB",
              "chunk MiB", "load");
  for (const Row& r : rows) {
    const Totals& t = r.t;
    const double n = std::max(t.scenes, 1);
    std::printf(
        "%-16s %6d %5.1f %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %7.2f "
        "%6.0f %6.0f %8.0f %8.1f %6.2f\n",
        r.name.c_str(), t.scenes, t.instances / n, t.observed / n, t.proposals / n, t.render / n,
        t.refine / n, t.cost / n, t.select / n, t.total / n, t.screen / n, t.first_pass / n,
        t.second_pass / n, t.local / n, t.fit / n, t.explain / n, t.cpu / n, t.hypotheses / n,
        t.screened_out / n, t.rss_mib, t.chunk_mib, t.load / n);
  }
}

}  // namespace

int main(int argc, char** argv) try {
  const Options o = parse(argc, argv);
  if (!o.child_masks.empty()) {
    const dataset::BackendKind b = dataset::parse_backend(o.child_backend);
    const std::string out = config_dir(o, o.child_masks, b);
    if (b == dataset::BackendKind::Cpu)
      run<cpu::Backend>(o, o.child_masks, out);
    else
      run<thrust_omp::Backend>(o, o.child_masks, out);
    return 0;
  }
  std::printf("bench_sixdof: %s, %d OpenMP threads, load average %.2f at start\n", bench::cpu_model().c_str(),
              omp_get_max_threads(), bench::load_average());
  if (generate(o.dir + "/dataset", o.scenes, o.seed)) fs::remove_all(o.dir + "/results");
  std::vector<Row> rows;
  for (const std::string& masks : o.masks)
    for (const dataset::BackendKind b : o.backends) {
      const std::string name = masks + "/" + dataset::backend_name(b), dir = config_dir(o, masks, b);
      if (!o.eval_only) {
        std::fprintf(stderr, "%s\n", name.c_str());
        const std::string command =
            "'" + fs::canonical("/proc/self/exe").string() + "' --dir '" + o.dir + "' --only " +
            std::to_string(o.first) + "-" + std::to_string(std::min(o.last, o.scenes)) + " --child " + masks +
            " " + dataset::backend_name(b) + (o.color_rule.empty() ? "" : " --color-rule " + o.color_rule) +
            child_overrides(o);
        if (std::system(command.c_str()) != 0) throw InvalidInput(name, "the run failed: " + command);
      }
      rows.push_back(evaluate(o, name, dir));
    }
  print_tables(rows);
  std::printf("load average %.2f at the end\n", bench::load_average());
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_sixdof: %s\n", e.what());
  return 1;
}
