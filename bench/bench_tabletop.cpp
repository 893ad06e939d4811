// The paper's Table I on synthetic scenes: 3-DoF accuracy and time of every search variant.
//   1. Generates N scenes (fixed seed 2020, 4-6 built-in objects each, one image per scene, origins within
//      0.4 m of the table centre: objects over ~1 m x 1 m) into a scratch folder with perch2::synth.
//   2. Runs each variant (the default variant on every requested backend) over them in its own process (so
//      peak memory is per configuration), writing BOP results CSVs. The process is this program re-run
//      (`--child VARIANT BACKEND`), not a fork: libgomp's thread pool does not survive fork().
//   3. Evaluates each with perch2::eval: ADD-S AUC (0-10 cm) and ADD-S < 1 cm per object and overall, mean
//      time per scene with a per-stage breakdown, peak resident memory.
// Usage: bench_tabletop [--scenes N (30)] [--variants perch2c,perch2a,...|all (all)]
//                       [--backend cpu|thrust_omp|both (both)] [--dir SCRATCH (/tmp/perch2_bench_tabletop)]
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
    } else if (a != "--variants" && a != "--backend") {
      throw InvalidInput(a, "unknown argument (--scenes N, --variants LIST|all, --backend B|both, --dir D)");
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
    sum.refine += t.refine, sum.cost += t.cost, sum.select += t.select, sum.total += t.total;
    ++images;
  }
};

/// Runs one configuration over every target image; writes CSV and the stage times and peak memory (one line
/// of 10 numbers).
void run(const dataset::BopDataset& data, SearchVariant v, dataset::BackendKind b, const std::string& csv,
         const std::string& times_file) {
  dataset::RunOptions options;
  options.variant = v, options.backend = b;
  const dataset::BopRunner runner(data, options);
  const auto images = runner.images();
  StageSums times;
  std::vector<dataset::PoseEstimate> rows;
  int done = 0;
  for (const auto& [scene_id, im_id] : images) {
    const dataset::ImageResult e = runner.estimate(scene_id, im_id);
    rows.insert(rows.end(), e.rows.begin(), e.rows.end());
    times.add(e.tabletop->timings);
    ++done;  // before the call: its arguments' evaluation order is unspecified
    cli::print_progress(stderr, done, int(images.size()), times.sum.total / done, e.tabletop->timings.total);
  }
  dataset::save_results_csv(csv, rows);
  const TabletopTimings& t = times.sum;
  std::ofstream(times_file) << t.table << ' ' << t.observed << ' ' << t.hypotheses << ' ' << t.render << ' '
                            << t.refine << ' ' << t.cost << ' ' << t.select << ' ' << t.total << ' '
                            << times.images << ' ' << double(bench::status_kb("VmHWM")) / 1024.0 << '\n';
}

}  // namespace

int main(int argc, char** argv) try {
  const Options o = parse(argc, argv);
  const std::string data_dir = o.dir + "/dataset";
  const auto csv_of = [&](SearchVariant v, dataset::BackendKind b) {
    return o.dir + "/" + dataset::variant_name(v) + "_" + dataset::backend_name(b) + ".csv";
  };
  if (!o.child_variant.empty()) {
    const SearchVariant v = dataset::parse_variant(o.child_variant);
    const dataset::BackendKind b = dataset::parse_backend(o.child_backend);
    run(dataset::BopDataset(data_dir), v, b, csv_of(v, b), csv_of(v, b) + ".times");
    return 0;
  }
  std::printf("bench_tabletop: %s, %d OpenMP threads\n", bench::cpu_model().c_str(), omp_get_max_threads());
  generate(data_dir, o.scenes);
  const dataset::BopDataset data(data_dir);
  eval::EvalSettings es;
  es.compute_vsd = false;

  struct Row {
    std::string name;
    eval::EvalReport report;
    StageSums times;
    double peak_mib = 0;
  };
  std::vector<Row> rows;
  for (const SearchVariant v : o.variants)
    for (const dataset::BackendKind b : o.backends) {
      if (v != SearchVariant::Perch2C && b != o.backends.front()) continue;  // backends: default variant only
      const std::string name = std::string(dataset::variant_name(v)) + "/" + dataset::backend_name(b);
      const std::string csv = csv_of(v, b), times_file = csv + ".times";
      std::fprintf(stderr, "%s\n", name.c_str());
      fs::remove(times_file);
      const std::string command = "'" + fs::canonical("/proc/self/exe").string() + "' --dir '" + o.dir +
                                  "' --child " + dataset::variant_name(v) + " " + dataset::backend_name(b);
      if (std::system(command.c_str()) != 0) throw InvalidInput(name, "the run failed: " + command);
      Row row{name, eval::evaluate(data, dataset::load_results_csv(csv), es, csv), {}, 0};
      std::ifstream f(times_file);
      TabletopTimings& t = row.times.sum;
      f >> t.table >> t.observed >> t.hypotheses >> t.render >> t.refine >> t.cost >> t.select >> t.total >>
          row.times.images >> row.peak_mib;
      if (!f) throw FileError(times_file, "missing or truncated (did the run fail?)");
      rows.push_back(std::move(row));
    }

  std::printf("\nADD-S AUC (0-10 cm) / ADD-S < 1 cm, percent, per object (%d scenes):\n", o.scenes);
  std::printf("%-22s", "variant/backend");
  for (const auto& [obj, s] : rows.front().report.per_object)
    std::printf(" %13s", ("obj " + std::to_string(obj)).c_str());
  std::printf(" %13s\n", "all");
  for (const Row& r : rows) {
    std::printf("%-22s", r.name.c_str());
    for (const auto& [obj, s] : r.report.per_object)
      std::printf(" %6.1f/%6.1f", 100 * s.auc_adds, 100 * s.adds_below_1cm);
    std::printf(" %6.1f/%6.1f\n", 100 * r.report.overall.auc_adds, 100 * r.report.overall.adds_below_1cm);
  }
  std::printf("\nmean seconds per scene by stage, peak resident memory:\n");
  std::printf("%-22s %7s %7s %7s %7s %7s %7s %7s %8s %9s\n", "variant/backend", "table", "observ", "hypoth",
              "render", "refine", "cost", "select", "total", "peak MiB");
  for (const Row& r : rows) {
    const TabletopTimings& t = r.times.sum;
    const double n = std::max(r.times.images, 1);
    std::printf("%-22s %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %8.3f %9.0f\n", r.name.c_str(), t.table / n,
                t.observed / n, t.hypotheses / n, t.render / n, t.refine / n, t.cost / n, t.select / n,
                t.total / n, r.peak_mib);
  }
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_tabletop: %s\n", e.what());
  return 1;
}
