// 6D detection (BOP 2024) against the catalogue's size: SixDofEstimator::detect on a generated decoy set
// (built-in models placed; models/ also holds three look-alikes of each: another print, 0.8x the size,
// other colours; test_targets_bop24.json lists the images only), once with the whole catalogue and once
// with the placed models alone, image by image in the same run (both see the same machine load), each
// scored by perch2::eval (bop24_mAP). The targets: <= 5 s per image with the catalogue, <= 1.5x the
// placed models' time.
//   1. Generates the set into SCRATCH (fixed seed; later runs with the same --scenes and --seed reuse it).
//   2. Per image: detect() with the catalogue, then with the placed models (DetectSettings defaults, or
//      --jobs-per-object / --viewpoints); wall time of each call.
//   3. Per catalogue: bop24_mAP (MSSD, MSPD), median and mean seconds per image, the retrieval's share;
//      the ratio of the catalogue's mean time to the placed models'.
// Usage: bench_detect [--scenes N (4)] [--seed S (47)] [--dir SCRATCH (/tmp/perch2_bench_detect)]
//                     [--jobs-per-object N] [--viewpoints N]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "perch2/cuda/estimators.hpp"  // SixDofEstimator<thrust_omp::Backend>, the production build
#include "perch2/dataset/bop.hpp"
#include "perch2/eval/evaluator.hpp"
#include "perch2/search/sixdof.hpp"
#include "perch2/search/sixdof_bop.hpp"
#include "perch2/synth/synth.hpp"

using namespace perch2;
namespace fs = std::filesystem;

namespace {

struct Options {
  int scenes = 4;
  std::uint64_t seed = 47;
  std::string dir = "/tmp/perch2_bench_detect";
  int jobs_per_object = -1, viewpoints = -1;  ///< < 0: DetectSettings' defaults
};

Options parse(int argc, char** argv) {
  Options o;
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    if (k + 1 >= argc) throw InvalidInput(a, "needs a value (see the usage in bench/bench_detect.cpp)");
    const std::string v = argv[++k];
    if (a == "--scenes")
      o.scenes = std::stoi(v);
    else if (a == "--seed")
      o.seed = std::stoull(v);
    else if (a == "--dir")
      o.dir = v;
    else if (a == "--jobs-per-object")
      o.jobs_per_object = std::stoi(v);
    else if (a == "--viewpoints")
      o.viewpoints = std::stoi(v);
    else
      throw InvalidInput(a, "unknown option (see the usage in bench/bench_detect.cpp)");
  }
  if (o.scenes < 1) throw InvalidInput("--scenes", "must be >= 1");
  return o;
}

/// Generates the decoy set unless `dir` already holds the one of these settings.
void generate(const Options& o) {
  const std::string stamp = o.dir + "/bench_stamp.txt",
                    want = std::to_string(o.scenes) + " " + std::to_string(o.seed);
  std::string have;
  std::getline(std::ifstream(stamp), have);
  if (have == want && fs::is_directory(o.dir + "/test")) return;
  synth::DatasetSettings s;
  s.num_scenes = o.scenes, s.images_per_scene = 1, s.seed = o.seed;
  s.scene.mode = synth::Mode::SixDof;
  s.decoys = true, s.detection_targets = true;
  fs::remove_all(o.dir);
  const auto summary = synth::generate_dataset(synth::builtin_models(), s, o.dir);
  std::printf("generated %d images, %d instances -> %s\n", summary.scenes, summary.instances, o.dir.c_str());
  std::ofstream(stamp) << want << '\n';
}

/// One catalogue's estimator, its BOP rows and times.
struct Run {
  std::string name;
  std::vector<int> obj_ids;  ///< per model of the estimator
  std::vector<dataset::PoseEstimate> rows;
  std::vector<double> seconds, retrieve_s;
};

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n == 0 ? 0 : n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

double mean(const std::vector<double>& v) {
  double s = 0;
  for (const double x : v) s += x;
  return v.empty() ? 0 : s / double(v.size());
}

}  // namespace

int main(int argc, char** argv) try {
  const Options o = parse(argc, argv);
  generate(o);
  const dataset::BopDataset data(o.dir);
  const int placed = int(synth::builtin_models().size());  // obj_ids 1..placed; decoys after them
  Run runs[2] = {{"catalogue", {}, {}, {}, {}}, {"placed models", {}, {}, {}, {}}};
  std::vector<SixDofModel> catalogue, placed_models;
  for (const auto& [id, info] : data.models_info()) {
    catalogue.push_back(sixdof_model(data.load_model(id), info)), runs[0].obj_ids.push_back(id);
    if (id <= placed) placed_models.push_back(catalogue.back()), runs[1].obj_ids.push_back(id);
  }
  using Estimator = SixDofEstimator<thrust_omp::Backend>;
  const Estimator whole(std::move(catalogue)), only_placed(std::move(placed_models));
  const Estimator* estimators[2] = {&whole, &only_placed};
  DetectSettings settings;
  if (o.jobs_per_object >= 0) settings.retrieval_jobs_per_object = o.jobs_per_object;
  if (o.viewpoints >= 0) settings.retrieval_viewpoints = o.viewpoints;
  std::printf("6D detection, %zu images, catalogue of %zu models (%d placed), backend thrust_omp\n",
              data.target_images().size(), runs[0].obj_ids.size(), placed);
  for (const auto& [scene_id, im_id] : data.target_images()) {
    const dataset::BopImage image = data.load_image(scene_id, im_id);
    for (int r = 0; r < 2; ++r) {
      const auto t = std::chrono::steady_clock::now();
      const SixDofSceneResult found = estimators[r]->detect(image.frame, settings);
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
      for (const SixDofPose& p : found.poses) {
        dataset::PoseEstimate e;
        e.scene_id = scene_id, e.im_id = im_id, e.obj_id = runs[r].obj_ids[std::size_t(p.model)];
        e.score = p.score, e.T_cam_obj = p.T_cam_obj, e.time_s = s;
        runs[r].rows.push_back(e);
      }
      runs[r].seconds.push_back(s), runs[r].retrieve_s.push_back(found.search.timings.retrieve);
      std::printf("  image %d/%d %-13s %5.1f s, %2zu detections, %3zu jobs (%zu retrieved out)\n", scene_id,
                  im_id, runs[r].name.c_str(), s, found.poses.size(), found.jobs, found.retrieved_out);
      std::fflush(stdout);
    }
  }
  eval::EvalSettings es;
  es.compute_vsd = false;
  std::printf(
      "\n| catalogue | models | bop24_mAP | MSSD | MSPD | median s / image | mean s / image | retrieval |\n"
      "|---|---|---|---|---|---|---|---|\n");
  for (const Run& r : runs) {
    const eval::EvalReport report = eval::evaluate(data, r.rows, es, r.name);
    const eval::DetectionScores& d = report.detection.overall;
    std::printf("| %s | %zu | %.3f | %.3f | %.3f | %.2f | %.2f | %.0f %% |\n", r.name.c_str(),
                r.obj_ids.size(), d.ap, d.ap_mssd, d.ap_mspd, median(r.seconds), mean(r.seconds),
                100 * mean(r.retrieve_s) / std::max(mean(r.seconds), 1e-9));
  }
  std::printf("\ncatalogue / placed models, mean time: %.2fx (same run, image by image)\n",
              mean(runs[0].seconds) / std::max(mean(runs[1].seconds), 1e-9));
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_detect: %s\n", e.what());
  return 1;
}
