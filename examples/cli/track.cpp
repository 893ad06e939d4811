// perch2 track: the objects of each scene of a BOP dataset followed frame after frame (a scene whose image
// ids are consecutive frames is a video, as YCB-Video's test scenes), started by perch2's own search or from
// the ground truth, one BOP CSV row per tracked object per frame.
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <iostream>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "cli_common.hpp"
#include "commands.hpp"
#include "perch2/core/error.hpp"
#include "perch2/cpu/backend.hpp"
#include "perch2/cpu/estimators.hpp"
#include "perch2/cuda/backend.hpp"
#include "perch2/cuda/estimators.hpp"
#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/detections.hpp"
#include "perch2/dataset/results.hpp"
#include "perch2/eval/tracking.hpp"
#include "perch2/io/image_io.hpp"
#include "perch2/search/sixdof.hpp"
#include "perch2/search/sixdof_bop.hpp"
#include "perch2/track/tracker.hpp"

#if PERCH2_CLI_HAVE_VIDEOIO
#include <opencv2/core.hpp>
#include <opencv2/videoio.hpp>
#endif

using namespace perch2;

namespace {

const char* kUsage =
    "usage: perch2 track --dataset DIR --out RESULTS.csv [--scenes A-B] [--init search|gt]\n"
    "                    [--masks none|gt|DETECTIONS.json]\n"
    "                    [--backend thrust_omp|cpu] [--split test] [--targets FILE] [--overlays DIR]\n"
    "                    [--fps F] [--video OUT.mp4] [--recovery background|update]\n"
    "\n"
    "  Tracks the objects of each scene (its images in id order are the frames of one video) with\n"
    "  perch2::Tracker. The start: --init search (default) runs the 6-DoF search on the scene's first\n"
    "  frame: without masks (--masks none, default) with the objects and counts of its targets\n"
    "  (test_targets_bop19.json), or on the instances of its ground-truth visible masks (--masks gt) or of "
    "a\n"
    "  detection file (BOP COCO-style JSON);\n"
    "  --init gt starts from the first frame's scene_gt.json (read only then). Writes one BOP CSV row per\n"
    "  tracked object per frame (score 0 while lost; time = that frame's update, the start's search on the\n"
    "  first frame), prints per scene the frames lost, losses, recoveries and the update's median and 95th\n"
    "  percentile, with --overlays a PNG per frame and with --video a video of them (one per scene:\n"
    "  OUT_SCENE.mp4 when there are several; OpenCV's VideoWriter, MPEG-4). Frames are fed at --fps\n"
    "  (default 30, as a camera gives them: a background recovery search spans the frames it would live;\n"
    "  0: as fast as the tracker goes). --recovery update runs a lost object's search inside the update\n"
    "  (reproducible; the update then takes as long as the search). Exit status: 0 done, 1 an error, 2 bad\n"
    "  usage.\n";

int usage_error(const std::string& message) {
  return cli::usage_error("track", kUsage, message);
}

/// What one scene's tracking gave.
struct SceneTally {
  int frames = 0, lost_frames = 0, losses = 0, recoveries = 0, searches = 0;
  double start_s = 0;
  std::vector<double> update_s;
};

struct Run {
  const dataset::BopDataset& data;
  std::string init, masks, overlays, video;
  double fps = 30;
  bool background_search = true;  ///< RecoverySettings::background
  std::map<int, int> model_of;    ///< obj_id -> model index
  std::vector<int> obj_id_of;     ///< model index -> obj_id
  std::vector<SixDofModel> models;
  std::vector<Mesh> meshes;
  std::vector<dataset::Detection> detections;  ///< --masks FILE
  std::map<std::pair<int, int>, std::vector<std::size_t>> detections_by_image;
  std::vector<std::size_t> detections_of(const dataset::BopImage& image) const {
    const auto it = detections_by_image.find({image.info.scene_id, image.info.im_id});
    return it == detections_by_image.end() ? std::vector<std::size_t>{} : it->second;
  }
};

/// A video of the overlays (--video), one file per scene when the run has several; nothing without a path.
class VideoOut {
 public:
  VideoOut(const std::string& path, int scene, bool per_scene, double fps) : fps_(fps) {
    if (path.empty()) return;
    path_ = path;
    if (per_scene) {
      const auto dot = path.rfind('.');
      path_ = path.substr(0, dot) + "_" + dataset::bop_id(scene) +
              (dot == std::string::npos ? "" : path.substr(dot));
    }
  }
  void add(const ColorImage& rgb) {
    if (path_.empty()) return;
#if PERCH2_CLI_HAVE_VIDEOIO
    if (!writer_.isOpened()) {
      writer_.open(path_, cv::VideoWriter::fourcc('m', 'p', '4', 'v'), fps_, cv::Size(rgb.width, rgb.height));
      if (!writer_.isOpened())
        throw FileError(
            path_,
            "cannot be written (OpenCV's VideoWriter has no MPEG-4 encoder, or the folder is missing)");
    }
    cv::Mat bgr(rgb.height, rgb.width, CV_8UC3);
    for (int v = 0; v < rgb.height; ++v)
      for (int u = 0; u < rgb.width; ++u) {
        const Rgb8 c = rgb(u, v);
        bgr.at<cv::Vec3b>(v, u) = cv::Vec3b(c.b, c.g, c.r);
      }
    writer_.write(bgr);
#else
    (void)rgb;
    throw FileError(path_, "cannot be written: this perch2 was built without OpenCV's videoio");
#endif
  }

 private:
  std::string path_;
  double fps_;
#if PERCH2_CLI_HAVE_VIDEOIO
  cv::VideoWriter writer_;
#endif
};

/// The first frame's starts: the search's poses for the targets' objects, or the ground truth.
template <class Backend>
std::vector<TrackStart> starts_for(const Run& run, const dataset::BopImage& image,
                                   const std::vector<dataset::Target>& targets, double& seconds) {
  std::vector<TrackStart> out;
  if (run.init == "gt") {
    for (const dataset::GtInstance& g : image.info.gt)
      if (run.model_of.count(g.obj_id)) out.push_back({run.model_of.at(g.obj_id), g.T_cam_obj});
    return out;
  }
  static std::unique_ptr<SixDofEstimator<Backend>> estimator;
  if (!estimator) estimator = std::make_unique<SixDofEstimator<Backend>>(run.models);
  const auto t0 = track_detail::Clock::now();
  if (run.masks == "none") {
    std::vector<SixDofObject> objects;
    for (const dataset::Target& t : targets)
      if (run.model_of.count(t.obj_id)) objects.push_back({run.model_of.at(t.obj_id), t.inst_count});
    out = track_starts(estimator->estimate_scene(image.frame, objects));
  } else {
    const BopInstances in =
        run.masks == "gt"
            ? bop_instances_from_gt(image, run.model_of)
            : bop_instances_from_detections(image, run.detections, run.detections_of(image), run.model_of);
    if (!in.instances.empty()) out = track_starts(estimator->estimate(image.frame, in.instances));
  }
  seconds = track_detail::seconds_since(t0);
  return out;
}

template <class Backend>
SceneTally track_scene(const Run& run, Tracker<Backend>& tracker, int scene,
                       const std::vector<std::pair<int, int>>& images,
                       const std::map<std::pair<int, int>, std::vector<dataset::Target>>& targets,
                       dataset::ResultsWriter& writer, bool many_scenes) {
  SceneTally tally;
  std::vector<bool> lost;
  VideoOut video(run.video, scene, many_scenes, run.fps > 0 ? run.fps : 30);
  auto due = std::chrono::steady_clock::now();
  for (std::size_t f = 0; f < images.size(); ++f) {
    const int im = images[f].second;
    if (const dataset::BadImage* bad = run.data.bad_image(scene, im)) {  // a gap in the stream
      std::fprintf(stderr, "perch2 track: scene %d image %d skipped: %s\n", scene, im,
                   (bad->path + ": " + bad->reason).c_str());
      continue;
    }
    dataset::ImageLoadOptions load;
    load.masks_visib = tally.frames == 0 && run.init == "search" && run.masks == "gt";
    const dataset::BopImage image = run.data.load_image(scene, im, load);
    TrackResult r;
    double seconds = 0;
    if (tally.frames == 0) {
      const auto it = targets.find({scene, im});
      const std::vector<TrackStart> starts = starts_for<Backend>(
          run, image, it == targets.end() ? std::vector<dataset::Target>{} : it->second, tally.start_s);
      if (starts.empty())
        throw InvalidInput("scene " + std::to_string(scene) + " image " + std::to_string(im),
                           run.init == "gt" ? "has no ground-truth instance of a known model to start from"
                                            : "the start's search found none of the target objects");
      r = tracker.start(image.frame, starts);
      due = std::chrono::steady_clock::now();
      seconds = tally.start_s + r.timings.total;
      lost.assign(r.objects.size(), false);
    } else {
      if (run.fps > 0) {  // the next frame arrives 1 / fps after the last one, or now if the tracker is late
        std::this_thread::sleep_until(due);
        due = std::max(due, std::chrono::steady_clock::now() - std::chrono::milliseconds(1)) +
              std::chrono::microseconds(std::int64_t(1e6 / run.fps));
      }
      r = tracker.update(image.frame);
      seconds = r.timings.total;
      tally.update_s.push_back(seconds);
    }
    std::vector<dataset::PoseEstimate> rows;
    std::vector<int> model_of_pose;
    std::vector<Pose> poses;
    for (const TrackedObject& o : r.objects) {
      const bool is_lost = o.state == TrackState::Lost;
      rows.push_back({scene, im, run.obj_id_of[std::size_t(o.model)], is_lost ? 0.0 : double(o.score),
                      o.T_cam_obj, seconds, 0});
      tally.lost_frames += is_lost;
      tally.losses += is_lost && !lost[std::size_t(o.object)];
      tally.recoveries += o.state == TrackState::Recovered;
      lost[std::size_t(o.object)] = is_lost;
      if (!is_lost) model_of_pose.push_back(o.model), poses.push_back(o.T_cam_obj);
    }
    tally.searches += int(r.searched.size());
    writer.write_image(scene, im, rows);
    if ((!run.overlays.empty() || !run.video.empty()) && !image.frame.rgb.empty()) {
      const ColorImage overlay =
          cli::draw_overlay(image.frame.rgb, image.frame.camera, run.meshes, model_of_pose, poses);
      if (!run.overlays.empty())
        io::save_color_image(run.overlays + "/" + dataset::bop_id(scene) + "_" + dataset::bop_id(im) + ".png",
                             overlay);
      video.add(overlay);
    }
    ++tally.frames;
  }
  return tally;
}

template <class Backend>
int track_all(const Run& run, const std::vector<std::pair<int, int>>& images,
              dataset::ResultsWriter& writer) {
  const auto targets = dataset::targets_by_image(run.data.targets());
  std::map<int, std::vector<std::pair<int, int>>> by_scene;
  for (const auto& key : images) by_scene[key.first].push_back(key);
  std::vector<double> all_updates;
  int frames = 0;
  for (auto& [scene, frames_of_scene] : by_scene) {
    std::sort(frames_of_scene.begin(), frames_of_scene.end());
    TrackSettings settings;
    settings.recovery.background = run.background_search;
    Tracker<Backend> tracker(run.models, settings);
    const SceneTally t =
        track_scene(run, tracker, scene, frames_of_scene, targets, writer, by_scene.size() > 1);
    std::printf(
        "scene %d: %d frames, %zu objects; start %.2f s; lost %d object-frames, %d losses, %d recoveries, "
        "%d searches; update median %.1f ms, p95 %.1f ms\n",
        scene, t.frames, tracker.objects().size(), t.start_s, t.lost_frames, t.losses, t.recoveries,
        t.searches, eval::quantile(t.update_s, 0.5) * 1e3, eval::quantile(t.update_s, 0.95) * 1e3);
    std::fflush(stdout);
    all_updates.insert(all_updates.end(), t.update_s.begin(), t.update_s.end());
    frames += t.frames;
  }
  std::printf("perch2 track: %zu scenes, %d frames -> %s (%s; update median %.1f ms, p95 %.1f ms)\n",
              by_scene.size(), frames, writer.path().c_str(), Backend::name,
              eval::quantile(all_updates, 0.5) * 1e3, eval::quantile(all_updates, 0.95) * 1e3);
  return 0;
}

}  // namespace

namespace {
int track_command(int argc, char** argv) {
  std::string dataset_dir, out, init = "search", masks = "none", backend = "thrust_omp", overlays, scenes,
                                fps = "30", video, recovery = "background";
  dataset::DatasetOptions options;
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    if (a == "-h" || a == "--help") {
      std::cout << kUsage;
      return 0;
    }
    if (k + 1 >= argc) return usage_error(a + " needs a value");
    std::string* target = a == "--dataset"    ? &dataset_dir
                          : a == "--out"      ? &out
                          : a == "--init"     ? &init
                          : a == "--masks"    ? &masks
                          : a == "--backend"  ? &backend
                          : a == "--overlays" ? &overlays
                          : a == "--scenes"   ? &scenes
                          : a == "--fps"      ? &fps
                          : a == "--video"    ? &video
                          : a == "--recovery" ? &recovery
                          : a == "--split"    ? &options.split
                          : a == "--targets"  ? &options.targets_file
                                              : nullptr;
    if (!target) return usage_error("unknown argument " + a);
    *target = argv[++k];
  }
  if (dataset_dir.empty() || out.empty()) return usage_error("--dataset and --out are required");
  if (init != "search" && init != "gt") return usage_error("--init must be search or gt");
  if (backend != "thrust_omp" && backend != "cpu") return usage_error("--backend must be thrust_omp or cpu");
  if (recovery != "background" && recovery != "update")
    return usage_error("--recovery must be background or update");
  if (!std::filesystem::is_directory(dataset_dir))
    throw FileError(dataset_dir, "is not a directory (expected a BOP dataset root)");
  const auto [first, last] =
      scenes.empty() ? std::pair<int, int>{0, 1 << 30} : cli::parse_scene_range(scenes);
  options.ground_truth = init == "gt" || (init == "search" && masks == "gt");  // never read otherwise
  const dataset::BopDataset data(dataset_dir, options);
  if (data.targets_path().empty())
    throw FileError(dataset_dir, "has no targets file (test_targets_bop19.json or _bop24.json)");
  for (const std::string& w : data.warnings()) std::fprintf(stderr, "perch2 track: warning: %s\n", w.c_str());
  const auto images = dataset::run_images(data, first, last);
  if (images.empty())
    throw InvalidInput(data.targets_path(),
                       "lists no targets" + (scenes.empty() ? std::string() : " in scenes " + scenes));
  Run run{data, init, masks, overlays, video, 30, recovery == "background", {}, {}, {}, {}, {}, {}};
  if (init == "search" && masks != "none" && masks != "gt") {
    run.detections = dataset::load_detections(masks);
    run.detections_by_image = dataset::detections_by_image(run.detections);
  }
  try {
    run.fps = std::stod(fps);
  } catch (const std::logic_error&) {
    return usage_error("--fps needs a number, got " + fps);
  }
  if (!(run.fps >= 0)) return usage_error("--fps must be >= 0");
  for (const auto& [id, info] : data.models_info()) {
    run.model_of[id] = int(run.models.size()), run.obj_id_of.push_back(id);
    run.models.push_back(sixdof_model(data.load_model(id), info));
    run.meshes.push_back(run.models.back().mesh);
  }
  if (!overlays.empty()) std::filesystem::create_directories(overlays);
  dataset::ResultsWriter writer(out, {false, false});
  return backend == "cpu" ? track_all<cpu::Backend>(run, images, writer)
                          : track_all<thrust_omp::Backend>(run, images, writer);
}
}  // namespace

int run_track(int argc, char** argv) {
  try {
    return track_command(argc, argv);
  } catch (const std::exception& e) {  // bad files and bad input name the file and the reason
    std::cerr << "perch2 track: " << e.what() << "\n";
    return 1;
  }
}
