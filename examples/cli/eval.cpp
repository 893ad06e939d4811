// perch2 eval: scores a BOP results CSV against a BOP dataset (ADD/ADD-S AUC, BOP VSD/MSSD/MSPD recalls;
// with bop24 targets also the BOP 2024 detection mAP).
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>

#include "cli_common.hpp"
#include "commands.hpp"
#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/results.hpp"
#include "perch2/eval/evaluator.hpp"
#include "perch2/eval/tracking.hpp"

namespace {

constexpr const char* kUsage =
    "usage: perch2 eval --dataset DIR --results FILE.csv [--split test] [--targets FILE] [--models DIR]\n"
    "                   [--json OUT.json] [--plot OUT.png] [--no-vsd] [--vsd-delta-mm D] [--tracking]\n"
    "  DIR is a BOP dataset root (models/, SPLIT/, test_targets_bop19.json or _bop24.json: then the 6D\n"
    "  detection scores of BOP 2024 too, bop24_mAP); FILE.csv holds BOP results\n"
    "  (scene_id,im_id,obj_id,score,R,t,time; t in mm). --models defaults to models_eval/ if present, else\n"
    "  models/. --no-vsd skips VSD (no rendering, no depth reading): AR = mean(AR_MSSD, AR_MSPD).\n"
    "  --vsd-delta-mm: VSD visibility tolerance (BOP: 15 mm; 5 mm for ITODD, chosen when DIR is named "
    "itodd).\n"
    "  --plot: precision-recall curves (detection) or accuracy-threshold curves (ADD(-S)) per object.\n"
    "  --tracking: FILE.csv is `perch2 track`'s (each scene a video, score 0 = lost): also per scene the\n"
    "  object-frames lost, losses, recoveries and frames to recover, and the latency per frame and object.\n";

int usage_error(const std::string& message) {
  return perch2::cli::usage_error("eval", kUsage, message);
}

int eval_command(int argc, char** argv) {
  std::string dataset_dir, results, json_out, plot_out, delta_mm;
  perch2::dataset::DatasetOptions options;
  perch2::eval::EvalSettings settings;
  bool tracking = false;
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    auto value = [&](std::string& out) {
      if (k + 1 >= argc) return false;
      out = argv[++k];
      return true;
    };
    if (a == "-h" || a == "--help") {
      std::cout << kUsage;
      return 0;
    }
    const bool ok = a == "--dataset"        ? value(dataset_dir)
                    : a == "--results"      ? value(results)
                    : a == "--json"         ? value(json_out)
                    : a == "--plot"         ? value(plot_out)
                    : a == "--split"        ? value(options.split)
                    : a == "--targets"      ? value(options.targets_file)
                    : a == "--models"       ? value(options.models_dir)
                    : a == "--vsd-delta-mm" ? value(delta_mm)
                    : a == "--no-vsd"       ? (settings.compute_vsd = false, true)
                    : a == "--tracking"     ? (tracking = true, true)
                                        : (std::cerr << "perch2 eval: unknown argument " << a << "\n", false);
    if (!ok) return usage_error("bad or incomplete argument " + a);
  }
  if (dataset_dir.empty() || results.empty()) return usage_error("--dataset and --results are required");
  std::filesystem::path dir = std::filesystem::path(dataset_dir).lexically_normal();
  if (dir.filename().empty()) dir = dir.parent_path();  // "DIR/"
  if (dir.filename() == "itodd")
    settings.vsd_delta_m = 0.005;  // eval_bop19_pose.py vsd_deltas: 5 mm for ITODD, 15 mm otherwise
  if (!delta_mm.empty()) {
    try {
      settings.vsd_delta_m = std::stod(delta_mm) * 1e-3;
    } catch (const std::exception&) {
      return usage_error("--vsd-delta-mm needs a number, got " + delta_mm);
    }
  }
  if (options.models_dir.empty() && std::filesystem::is_directory(dataset_dir + "/models_eval"))
    options.models_dir = "models_eval";  // bop_toolkit evaluates on the eval models when a dataset has them

  const perch2::dataset::BopDataset data(dataset_dir, options);
  const auto estimates = perch2::dataset::load_results_csv(results);
  if (data.target_task() == perch2::dataset::TargetTask::Detection)
    std::fprintf(stderr, "perch2 eval: %zu estimates, 6D detection on %zu images in %s\n", estimates.size(),
                 data.target_images().size(), data.targets_path().c_str());
  else
    std::fprintf(stderr, "perch2 eval: %zu estimates, %zu targets in %s\n", estimates.size(),
                 data.targets().size(), data.targets_path().c_str());
  const auto progress = [](int done, int total) {
    if (done == total || done % 50 == 0) std::fprintf(stderr, "\r  images %d / %d", done, total);
    if (done == total) std::fprintf(stderr, "\n");
  };
  const auto report = perch2::eval::evaluate(data, estimates, settings, results, progress);
  std::cout << perch2::eval::format_report(report);
  if (tracking)
    std::cout << "tracking:\n" << perch2::eval::format_tracking(perch2::eval::tracking_summary(estimates));
  if (!json_out.empty()) {
    std::ofstream f(json_out);
    f << perch2::eval::report_json(report, settings);
    if (!f) throw perch2::FileError(json_out, "cannot be written");
    std::cout << "wrote " << json_out << "\n";
  }
  if (!plot_out.empty()) {
    perch2::eval::plot_report(report, settings, plot_out);
    std::cout << "wrote " << plot_out << "\n";
  }
  return 0;
}

}  // namespace

int run_eval(int argc, char** argv) {
  try {
    return eval_command(argc, argv);
  } catch (const std::exception& e) {  // bad files and bad input name the file (and line) in the message
    std::cerr << "perch2 eval: " << e.what() << "\n";
    return 1;
  }
}
