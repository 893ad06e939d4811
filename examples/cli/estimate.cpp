// perch2 estimate: 3-DoF or 6-DoF pose estimation over a BOP dataset (perch2::dataset::BopRunner), written
// as a BOP results CSV.
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <string>

#include "cli_common.hpp"
#include "commands.hpp"
#include "perch2/dataset/runner.hpp"
#include "perch2/io/image_io.hpp"

namespace {

using namespace perch2;

constexpr const char* kUsage =
    "usage: perch2 estimate --mode 3dof|6dof --dataset DIR --out RESULTS.csv [--split test] [--scenes A-B]\n"
    "                       [--variant perch2c|perch2a|perch2b|perch|depth-only|bf-icp]\n"
    "                       [--backend cpu|thrust_omp] [--overlays DIR] [--targets FILE]\n"
    "                       [--masks gt|none|DETECTIONS.json] [--box full|visible]   (6dof)\n"
    "                       [--resume] [--strict]\n"
    "  Estimates the target objects (test_targets_bop19.json: inst_count per obj_id and image) of every "
    "image\n"
    "  of a BOP dataset and writes BOP results (score = 1 / (1 + cost), time = seconds per image).\n"
    "  3dof assumes: every model stands with its own +z axis up (lowest vertex on the table); a continuous\n"
    "  symmetry about the model's z axis in models_info.json means one yaw per position; the table frame is\n"
    "  scene_camera.json's cam_R_w2c/cam_t_w2c (BOP world: z up, table top at z = 0) when given, else\n"
    "  estimated from the depth. Ground truth (scene_gt.json) is never used.\n"
    "  --scenes A-B (or A): only scenes A..B.  --overlays DIR: writes DIR/SCENE_IM.png with the estimated\n"
    "  models drawn over each image.  Default variant perch2c, backend thrust_omp.\n"
    "  6dof: every target instance from its mask (--masks gt: mask_visib; or a detection file with COCO RLE\n"
    "  masks) and box (--box full: scene_gt_info's bbox_obj, the default; visible: bbox_visib), by\n"
    "  SixDofEstimator (proposals on the box ray, GICP, RGB-D cost); score in [0, 1].  --masks none: no\n"
    "  detector; the frame is segmented (support plane, depth edges) and the targets' objects and counts\n"
    "  are searched for on every segment and placed one by one (instances not found are reported missing).\n"
    "  With test_targets_bop24.json (images only: BOP 2024's 6D detection) --masks none detects every\n"
    "  instance of every model of models/ (a coarse search ranks the models on each segment; the best get\n"
    "  the full search), up to 100 rows per image, best score first.\n"
    "  Each image's rows are appended to RESULTS.csv (and the image to RESULTS.csv.done) as soon as it is\n"
    "  done. A bad image (unreadable or truncated PNG/JPG, missing mask, malformed entry of its scene's "
    "JSON\n"
    "  files) is reported with the file and reason and skipped; the run goes on.  --strict: stop at the "
    "first.\n"
    "  --resume: keep the images RESULTS.csv already holds in full and estimate the others.  "
    "SIGINT/SIGTERM:\n"
    "  the current image is finished and written, then the run stops (a second signal stops it at once).\n"
    "  Exit status: 0 all images estimated, 3 some skipped, 1 an error (or --strict stopped), 2 bad usage,\n"
    "  130/143 interrupted by SIGINT/SIGTERM.\n";

int usage_error(const std::string& message) {
  return cli::usage_error("estimate", kUsage, message);
}

/// DIR/SCENE_IM.png: the estimated models (poses found) drawn over the image.
void write_overlay(const dataset::BopRunner& runner, const dataset::BopImage& image,
                   const dataset::ImageResult& r, const std::string& dir) {
  std::vector<int> model_of_pose;
  std::vector<Pose> poses;
  for (std::size_t k = 0; k < r.rows.size(); ++k)
    if (r.row_found[k]) model_of_pose.push_back(r.row_models[k]), poses.push_back(r.rows[k].T_cam_obj);
  io::save_color_image(
      dir + "/" + dataset::bop_id(r.scene_id) + "_" + dataset::bop_id(r.im_id) + ".png",
      cli::draw_overlay(image.frame.rgb, image.frame.camera, runner.meshes(), model_of_pose, poses));
}

/// What a run did, for its summary.
struct Tally {
  cli::StageTimes times;
  std::vector<std::string> skipped;  ///< ImageError messages
  int seen = 0, estimated = 0, poses = 0, requested = 0, missing = 0, unusable = 0;
  double seconds = 0, last_s = 0;

  void add(const dataset::ImageResult& r) {
    times.add(r.stages);
    poses += int(r.rows.size()), requested += r.requested, missing += r.missing, unusable += r.unusable;
    seconds += r.seconds, last_s = r.seconds;
    ++estimated;
  }
  double mean_seconds() const { return estimated ? seconds / estimated : 0.0; }

  void print(const dataset::BopRunner& runner, const std::string& out, const std::string& overlays,
             bool strict) const {
    if (requested > 0)
      std::printf("perch2 estimate: %d poses for %d requested instances in %d images -> %s\n", poses,
                  requested, estimated, out.c_str());
    else  // detection (bop24 targets): nothing is requested
      std::printf("perch2 estimate: %d detections in %d images -> %s\n", poses, estimated, out.c_str());
    if (missing > 0) std::printf("  %d instance(s) not found\n", missing);
    if (unusable > 0)
      std::printf("  %d instance(s) skipped: too few valid depth readings inside the mask\n", unusable);
    std::printf("per-stage wall-clock times (%s):\n", runner.describe().c_str());
    times.print(stdout);
    if (!overlays.empty()) std::printf("overlays in %s/\n", overlays.c_str());
    if (skipped.empty()) return;
    std::fprintf(
        stderr,
        "perch2 estimate: %zu image(s) skipped%s (not in %s; fix them and run again with --resume):\n",
        skipped.size(), strict ? ", stopped at the first (--strict)" : "", out.c_str());
    for (const std::string& s : skipped) std::fprintf(stderr, "  %s\n", s.c_str());
  }
};

// The first SIGINT/SIGTERM asks the loop to stop after the current image; a second one kills at once (the
// CSV is still valid: each image is appended with one write).
volatile std::sig_atomic_t g_stop_signal = 0;

extern "C" void on_stop_signal(int sig) {
  g_stop_signal = sig;
  std::signal(sig, SIG_DFL);
}

int estimate_command(int argc, char** argv) {
  std::string mode, dataset_dir, out, variant = "perch2c", backend = "thrust_omp", overlays, scenes;
  std::string masks = "gt", box = "full";
  bool resume = false, strict = false;
  dataset::DatasetOptions options;
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    if (a == "-h" || a == "--help") {
      std::cout << kUsage;
      return 0;
    }
    if (a == "--resume" || a == "--strict") {
      (a == "--resume" ? resume : strict) = true;
      continue;
    }
    if (k + 1 >= argc) return usage_error(a + " needs a value");
    std::string& target = a == "--mode"       ? mode
                          : a == "--dataset"  ? dataset_dir
                          : a == "--out"      ? out
                          : a == "--variant"  ? variant
                          : a == "--backend"  ? backend
                          : a == "--overlays" ? overlays
                          : a == "--scenes"   ? scenes
                          : a == "--split"    ? options.split
                          : a == "--targets"  ? options.targets_file
                          : a == "--masks"    ? masks
                          : a == "--box"      ? box
                                              : mode;
    if (&target == &mode && a != "--mode") return usage_error("unknown argument " + a);
    target = argv[++k];
  }
  if (mode != "3dof" && mode != "6dof") return usage_error("--mode must be 3dof or 6dof");
  if (box != "full" && box != "visible") return usage_error("--box must be full or visible");
  if (dataset_dir.empty() || out.empty()) return usage_error("--dataset and --out are required");
  if (!std::filesystem::is_directory(dataset_dir))
    throw FileError(dataset_dir, "is not a directory (expected a BOP dataset root)");
  dataset::RunOptions run;
  run.mode = dataset::parse_mode(mode);
  run.variant = dataset::parse_variant(variant);
  run.backend = dataset::parse_backend(backend);
  run.masks = masks;
  run.box = box == "full" ? BoxKind::Full : BoxKind::Visible;
  const auto [first, last] =
      scenes.empty() ? std::pair<int, int>{0, 1 << 30} : cli::parse_scene_range(scenes);

  options.ground_truth = run.mode == dataset::RunMode::SixDof && masks == "gt";  // never read otherwise
  const dataset::BopDataset data(dataset_dir, options);
  if (data.targets_path().empty())
    throw FileError(dataset_dir, "has no targets file (test_targets_bop19.json or _bop24.json)");
  for (const std::string& w : data.warnings())
    std::fprintf(stderr, "perch2 estimate: warning: %s\n", w.c_str());
  const auto images = dataset::run_images(data, first, last);
  if (images.empty())
    throw InvalidInput(data.targets_path(),
                       "lists no targets" + (scenes.empty() ? std::string() : " in scenes " + scenes));
  // Before the models load: an unwritable output or another run writing it fails at once.
  dataset::ResultsWriter writer(out, {resume, false});
  for (const std::string& note : writer.resume_notes())
    std::fprintf(stderr, "perch2 estimate: %s\n", note.c_str());
  const dataset::BopRunner runner(data, run);
  if (!overlays.empty()) std::filesystem::create_directories(overlays);
  std::vector<std::pair<int, int>> todo;
  for (const auto& key : images)
    if (!writer.is_done(key.first, key.second)) todo.push_back(key);

  std::fprintf(stderr, "perch2 estimate: %zu images", todo.size());
  if (todo.size() != images.size()) std::fprintf(stderr, " (%zu done already)", images.size() - todo.size());
  std::fprintf(stderr, ", %zu objects, %s\n", runner.obj_ids().size(), runner.describe().c_str());
  std::signal(SIGINT, on_stop_signal);
  std::signal(SIGTERM, on_stop_signal);
  Tally tally;
  for (const auto& [scene_id, im_id] : todo) {
    if (g_stop_signal) break;
    try {
      const dataset::BopImage image = runner.load_image(scene_id, im_id);
      const dataset::ImageResult r = runner.estimate(image);
      writer.write_image(scene_id, im_id, r.rows);  // appended and flushed now
      if (!overlays.empty()) write_overlay(runner, image, r, overlays);
      tally.add(r);
    } catch (const dataset::ImageError& e) {  // this image only
      tally.skipped.push_back(e.what());
      std::fprintf(stderr, "\nperch2 estimate: skipped %s\n", e.what());
      if (strict) break;
    }
    ++tally.seen;
    cli::print_progress(stderr, tally.seen, int(todo.size()), tally.mean_seconds(), tally.last_s);
  }
  tally.print(runner, out, overlays, strict);
  if (g_stop_signal && tally.seen < int(todo.size())) {
    std::fprintf(stderr,
                 "perch2 estimate: interrupted by %s after %d of %zu images; %s holds every finished image "
                 "(%zu); run again with --resume to finish\n",
                 g_stop_signal == SIGINT ? "SIGINT" : "SIGTERM", tally.seen, todo.size(), out.c_str(),
                 writer.done().size());
    return 128 + g_stop_signal;
  }
  if (!tally.skipped.empty()) return strict ? 1 : 3;
  return 0;
}

}  // namespace

int run_estimate(int argc, char** argv) {
  try {
    return estimate_command(argc, argv);
  } catch (const std::exception& e) {  // bad files and bad input name the file and the reason
    std::cerr << "perch2 estimate: " << e.what() << "\n";
    return 1;
  }
}
