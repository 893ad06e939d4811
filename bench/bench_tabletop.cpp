// The paper's Table I on synthetic scenes: 3-DoF accuracy and time of every search variant.
//   1. Generates N scenes (fixed seed 2020, 4-6 built-in objects each, one image per scene, origins within
//      0.4 m of the table centre: objects over ~1 m x 1 m) into a scratch folder with perch2::synth.
//   2. Runs each variant (the default variant on every requested backend) over them in its own process (so
//      peak memory is per configuration), writing BOP results CSVs. The process is this program re-run
//      (`--child VARIANT BACKEND`), not a fork: libgomp's thread pool does not survive fork().
//   3. Evaluates each with perch2::eval: ADD-S AUC (0-10 cm) and ADD-S < 1 cm, ADD AUC and ADD(-S) AUC (ADD
//      for models without symmetries in models_info.json, ADD-S for the others) per object and overall,
//      mean time per scene with a per-stage breakdown, peak resident memory.
// Usage: bench_tabletop [--scenes N (30)] [--variants perch2c,perch2a,...|all (all)]
//                       [--backend cpu|thrust_omp|both (both)] [--dir SCRATCH (/tmp/perch2_bench_tabletop)]
//                       [--dataset BOP_DIR (instead of generating: e.g. `perch2 generate --seed 77`'s)]
//                       [--yaw-search 0|1 (1; TabletopSettings::yaw_search.enabled of the RGB-D variants)]
//                       [--yaw-sweep N] [--yaw-fine N] [--yaw-step RAD] [--yaw-levels N] [--yaw-tolerance X]
//                       [--yaw-starts N] [--yaw-sweep-stride S] [--yaw-fine-stride S]
//                       [--yaw-final-stride S] [--yaw-moves N]
//                       (yaw_search.turns.sweep_turns, .fine_turns, .climb_step_rad, .levels,
//                       .geometry_tolerance, .starts, .sweep_stride, .fine_stride, .final_stride,
//                       .moves_per_level; default: the library's)
#include <omp.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "bench_support.hpp"
#include "cli_common.hpp"
#include "perch2/dataset/runner.hpp"
#include "perch2/eval/evaluator.hpp"
#include "perch2/synth/synth.hpp"

using namespace perch2;
namespace fs = std::filesystem;

namespace {

struct Options {
  int scenes = 30;
  std::vector<SearchVariant> variants{SearchVariant::Perch2C,    SearchVariant::Perch2A,
                                      SearchVariant::Perch2B,    SearchVariant::Perch,
                                      SearchVariant::DepthOnlyC, SearchVariant::BfIcp};
  std::vector<dataset::BackendKind> backends{dataset::BackendKind::ThrustOmp, dataset::BackendKind::Cpu};
  std::string dir = "/tmp/perch2_bench_tabletop";
  std::string dataset;  ///< an existing BOP dataset; empty: generate one in dir
  bool yaw_search = true;
  YawSearchSettings yaw;                     ///< yaw_search overrides (enabled: yaw_search)
  std::string yaw_args;                      ///< the overrides as given, passed on to the child runs
  std::string child_variant, child_backend;  ///< internal: run one configuration and exit
};

Options parse(int argc, char** argv) {
  Options o;
  for (int k = 1; k + 1 < argc; k += 2) {
    const std::string a = argv[k], v = argv[k + 1];
    if (a == "--child" && k + 2 < argc) {
      o.child_variant = v, o.child_backend = argv[k + 2];
      return o;
    }
    if (a == "--scenes") {
      o.scenes = std::stoi(v);
      if (o.scenes < 1) throw InvalidInput("--scenes", "must be >= 1");
    } else if (a == "--variants" && v != "all") {
      o.variants.clear();
      std::stringstream ss(v);
      for (std::string name; std::getline(ss, name, ',');) o.variants.push_back(dataset::parse_variant(name));
    } else if (a == "--backend" && v != "both") {
      o.backends = {dataset::parse_backend(v)};
    } else if (a == "--dir") {
      o.dir = v;
    } else if (a == "--dataset") {
      o.dataset = v;
    } else if (a == "--yaw-search") {
      if (v != "0" && v != "1") throw InvalidInput("--yaw-search", "must be 0 or 1, not '" + v + "'");
      o.yaw_search = v == "1";
    } else if (a == "--yaw-sweep" || a == "--yaw-step" || a == "--yaw-levels" || a == "--yaw-tolerance" ||
               a == "--yaw-starts" || a == "--yaw-sweep-stride" || a == "--yaw-fine-stride" ||
               a == "--yaw-final-stride" || a == "--yaw-moves" || a == "--yaw-fine") {
      TurnSearchSettings& t = o.yaw.turns;
      if (a == "--yaw-sweep") t.sweep_turns = std::stoi(v);
      if (a == "--yaw-fine") t.fine_turns = std::stoi(v);
      if (a == "--yaw-step") t.climb_step_rad = std::stof(v);
      if (a == "--yaw-levels") t.levels = std::stoi(v);
      if (a == "--yaw-tolerance") t.geometry_tolerance = std::stof(v);
      if (a == "--yaw-starts") t.starts = std::stoi(v);
      if (a == "--yaw-sweep-stride") t.sweep_stride = std::stoi(v);
      if (a == "--yaw-fine-stride") t.fine_stride = std::stoi(v);
      if (a == "--yaw-final-stride") t.final_stride = std::stoi(v);
      if (a == "--yaw-moves") t.moves_per_level = std::stoi(v);
      o.yaw_args += " " + a + " " + v;
    } else if (a != "--variants" && a != "--backend") {
      throw InvalidInput(a,
                         "unknown argument (--scenes N, --variants LIST|all, --backend B|both, --dir D, "
                         "--dataset D, --yaw-search 0|1)");
    }
  }
  if (argc % 2 == 0) throw InvalidInput(argv[argc - 1], "needs a value");
  return o;
}

void generate(const std::string& dir, int scenes) {
  synth::DatasetSettings s;
  s.num_scenes = scenes, s.images_per_scene = 1, s.seed = 2020;
  s.scene.mode = synth::Mode::ThreeDof;
  s.scene.min_objects = 4, s.scene.max_objects = 6;
  s.scene.placement_radius_m = 0.4f;  // origins in a 0.8 m disc: objects span ~1 m x 1 m
  fs::remove_all(dir);
  const auto summary = synth::generate_dataset(synth::builtin_models(), s, dir);
  std::printf("generated %d scenes, %d instances (%d targets) in %.1f s -> %s\n", summary.scenes,
              summary.instances, summary.targets, summary.seconds, dir.c_str());
}

/// Per-stage wall-clock seconds summed over images.
struct StageSums {
  TabletopTimings sum;
  int images = 0;
  void add(const TabletopTimings& t) {
    sum.table += t.table, sum.observed += t.observed, sum.hypotheses += t.hypotheses, sum.render += t.render;
    sum.refine += t.refine, sum.cost += t.cost, sum.select += t.select, sum.yaw += t.yaw,
        sum.total += t.total;
    ++images;
  }
};

/// Runs one configuration over every target image; writes CSV and the stage times and peak memory (one line
/// of 12 numbers: the stages' seconds, images, peak MiB and process CPU seconds).
void run(const dataset::BopDataset& data, SearchVariant v, dataset::BackendKind b,
         const YawSearchSettings& yaw, const std::string& csv, const std::string& times_file) {
  dataset::RunOptions options;
  options.variant = v, options.backend = b;
  options.tabletop.yaw_search = yaw;  // tabletop_variant() keeps it off for the depth-only variants
  const dataset::BopRunner runner(data, options);
  const auto images = runner.images();
  StageSums times;
  std::vector<dataset::PoseEstimate> rows;
  int done = 0;
  for (const auto& [scene_id, im_id] : images) {
    dataset::ImageResult e;
    try {
      e = runner.estimate(scene_id, im_id);
    } catch (const dataset::ImageError& err) {  // e.g. no table plane found: its targets count as misses
      std::fprintf(stderr, "\n  skipped: %s\n", err.what());
      continue;
    }
    rows.insert(rows.end(), e.rows.begin(), e.rows.end());
    times.add(e.tabletop->timings);
    ++done;  // before the call: its arguments' evaluation order is unspecified
    cli::print_progress(stderr, done, int(images.size()), times.sum.total / done, e.tabletop->timings.total);
  }
  dataset::save_results_csv(csv, rows);
  const TabletopTimings& t = times.sum;
  std::ofstream(times_file) << t.table << ' ' << t.observed << ' ' << t.hypotheses << ' ' << t.render << ' '
                            << t.refine << ' ' << t.cost << ' ' << t.select << ' ' << t.yaw << ' ' << t.total
                            << ' ' << times.images << ' ' << double(bench::status_kb("VmHWM")) / 1024.0 << ' '
                            << bench::cpu_seconds() << '\n';
}

}  // namespace

int main(int argc, char** argv) try {
  const Options o = parse(argc, argv);
  const std::string data_dir = o.dataset.empty() ? o.dir + "/dataset" : o.dataset;
  const auto csv_of = [&](SearchVariant v, dataset::BackendKind b) {
    std::string tag = o.yaw_search ? o.yaw_args : "_noyaw";
    for (char& c : tag) c = c == ' ' ? '_' : c;
    return o.dir + "/" + dataset::variant_name(v) + "_" + dataset::backend_name(b) + tag + ".csv";
  };
  if (!o.child_variant.empty()) {
    const SearchVariant v = dataset::parse_variant(o.child_variant);
    const dataset::BackendKind b = dataset::parse_backend(o.child_backend);
    YawSearchSettings yaw = o.yaw;
    yaw.enabled = o.yaw_search;
    run(dataset::BopDataset(data_dir), v, b, yaw, csv_of(v, b), csv_of(v, b) + ".times");
    return 0;
  }
  std::printf("bench_tabletop: %s, %d OpenMP threads\n", bench::cpu_model().c_str(), omp_get_max_threads());
  if (o.dataset.empty())
    generate(data_dir, o.scenes);
  else
    fs::create_directories(o.dir), std::printf("dataset %s\n", data_dir.c_str());
  const dataset::BopDataset data(data_dir);
  eval::EvalSettings es;
  es.compute_vsd = false;

  struct Row {
    std::string name;
    eval::EvalReport report;
    StageSums times;
    double peak_mib = 0;
    double cpu_s = 0;  ///< the run's process CPU seconds (all threads)
  };
  std::vector<Row> rows;
  for (const SearchVariant v : o.variants)
    for (const dataset::BackendKind b : o.backends) {
      if (v != SearchVariant::Perch2C && b != o.backends.front()) continue;  // backends: default variant only
      const std::string name = std::string(dataset::variant_name(v)) + "/" + dataset::backend_name(b) +
                               (o.yaw_search ? o.yaw_args : " noyaw");
      const std::string csv = csv_of(v, b), times_file = csv + ".times";
      std::fprintf(stderr, "%s\n", name.c_str());
      fs::remove(times_file);
      const std::string command = "'" + fs::canonical("/proc/self/exe").string() + "' --dir '" + o.dir +
                                  "' --dataset '" + data_dir + "' --yaw-search " +
                                  (o.yaw_search ? "1" : "0") + o.yaw_args + " --child " +
                                  dataset::variant_name(v) + " " + dataset::backend_name(b);
      if (std::system(command.c_str()) != 0) throw InvalidInput(name, "the run failed: " + command);
      Row row{name, eval::evaluate(data, dataset::load_results_csv(csv), es, csv), {}, 0, 0};
      std::ifstream f(times_file);
      TabletopTimings& t = row.times.sum;
      f >> t.table >> t.observed >> t.hypotheses >> t.render >> t.refine >> t.cost >> t.select >> t.yaw >>
          t.total >> row.times.images >> row.peak_mib >> row.cpu_s;
      if (!f) throw FileError(times_file, "missing or truncated (did the run fail?)");
      rows.push_back(std::move(row));
    }

  const std::string images = o.dataset.empty() ? std::to_string(o.scenes) + " scenes" : o.dataset;
  // Two numbers per object and overall, percent.
  auto table = [&](const char* title, double eval::Scores::*a, double eval::Scores::*b) {
    std::printf("\n%s, percent, per object (%s):\n", title, images.c_str());
    std::printf("%-22s", "variant/backend");
    for (const auto& [obj, s] : rows.front().report.per_object)
      std::printf(" %13s", ("obj " + std::to_string(obj)).c_str());
    std::printf(" %13s\n", "all");
    for (const Row& r : rows) {
      std::printf("%-22s", r.name.c_str());
      for (const auto& [obj, s] : r.report.per_object) std::printf(" %6.1f/%6.1f", 100 * s.*a, 100 * s.*b);
      std::printf(" %6.1f/%6.1f\n", 100 * r.report.overall.*a, 100 * r.report.overall.*b);
    }
  };
  table("ADD-S AUC (0-10 cm) / ADD-S < 1 cm", &eval::Scores::auc_adds, &eval::Scores::adds_below_1cm);
  table("ADD AUC / ADD(-S) AUC (0-10 cm)", &eval::Scores::auc_add, &eval::Scores::auc_add_or_adds);
  std::printf(
      "\nmean seconds per scene by stage (yaw: the yaw search, its renders and costs also in render and "
      "cost), process CPU seconds per scene, peak resident memory:\n");
  std::printf("%-22s %7s %7s %7s %7s %7s %7s %7s %7s %8s %7s %9s\n", "variant/backend", "table", "observ",
              "hypoth", "render", "refine", "cost", "select", "yaw", "total", "CPU s", "peak MiB");
  for (const Row& r : rows) {
    const TabletopTimings& t = r.times.sum;
    const double n = std::max(r.times.images, 1);
    std::printf("%-22s %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %8.3f %7.3f %9.0f\n", r.name.c_str(),
                t.table / n, t.observed / n, t.hypotheses / n, t.render / n, t.refine / n, t.cost / n,
                t.select / n, t.yaw / n, t.total / n, r.cpu_s / n, r.peak_mib);
  }
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_tabletop: %s\n", e.what());
  return 1;
}
