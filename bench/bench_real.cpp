// Real RGB-D frames (BOP layout; default ../shared/data/real/lm_cat_dev, 29 Kinect v1 frames of the LINEMOD
// cat): the 6-DoF estimator and OpenCV's PPF + ICP peer on the same masks, scored by perch2::eval (ADD-S AUC,
// ADD AUC, BOP AR with VSD, MSSD, MSPD).
//   gt:  the dataset's mask_visib with the full (amodal) box, as `perch2 estimate --mode 6dof --masks gt`;
//   det: the same masks degraded like a detector's (perch2::synth::degrade_mask: boundary grown or shrunk by
//        up to 3 px and wobbly, moved by up to 2 px, bleeding onto the surroundings or cut, each image from
//        its own seeded stream), boxes from the degraded masks, written to SCRATCH/detections_degraded.json
//        (usable with `perch2 estimate --masks FILE`).
// The peer (when OpenCV's surface_matching module is found at configure time): PPF3DDetector(0.025, 0.05)
// trained once on the model's vertices (area-weighted vertex normals) thinned to 0.025 x the diameter apart
// (see train_ppf); per instance, the mask's readings (mask grown by 3 px) with computeNormalsPC3d normals
// (30 neighbours, oriented to the camera), match(1/5, 0.05), ICP(100, 0.005, 2.5, 8) of the camera-facing
// vertices on the 10 most voted poses, the pose with the largest fitness kept (see run_ppf). Millimetres,
// depth only.
// Usage: bench_real [--dataset DIR] [--dir SCRATCH (/tmp/perch2_bench_real)] [--seed S (1)]
//   [--masks gt|det|both] [--backend cpu|thrust_omp (thrust_omp)] [--peer 0|1 (1)] [--perch2 0|1 (1)]
//   [--fit N (SixDofSettings::fit.iterations; 0 = no final fit)]
//   [--target-stride N (SixDofSettings::first_pass_target_stride)]
#include <omp.h>

#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <vector>

#ifdef PERCH2_HAVE_PPF
#include <opencv2/imgproc.hpp>

#include "ppf_peer.hpp"
#endif

#include "bench_support.hpp"
#include "cli_common.hpp"
#include "perch2/cpu/estimators.hpp"
#include "perch2/cuda/estimators.hpp"
#include "perch2/dataset/runner.hpp"
#include "perch2/eval/evaluator.hpp"
#include "perch2/search/sixdof_bop.hpp"
#include "perch2/synth/detections.hpp"

using namespace perch2;
namespace fs = std::filesystem;

namespace {

struct Options {
  std::string dataset = std::string(PERCH2_SHARED_DATA_DIR) + "/real/lm_cat_dev";
  std::string dir = "/tmp/perch2_bench_real";
  std::uint64_t seed = 1;
  std::vector<std::string> masks{"gt", "det"};
  dataset::BackendKind backend = dataset::BackendKind::ThrustOmp;
  bool peer = true;
  bool perch2 = true;      ///< --perch2 0: the peer alone
  int fit = -1;            ///< >= 0: SixDofSettings::fit.iterations
  int target_stride = -1;  ///< >= 1: SixDofSettings::first_pass_target_stride
};

constexpr const char* kUsage =
    "bench_real [--dataset DIR] [--dir SCRATCH] [--seed S] [--masks gt|det|both] [--backend cpu|thrust_omp] "
    "[--peer 0|1] [--perch2 0|1] [--fit N] [--target-stride N]";

Options parse(int argc, char** argv) {
  Options o;
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    if (k + 1 >= argc) throw InvalidInput(a, std::string("needs a value; usage: ") + kUsage);
    const std::string v = argv[++k];
    if (a == "--dataset") {
      o.dataset = v;
    } else if (a == "--dir") {
      o.dir = v;
    } else if (a == "--seed") {
      o.seed = std::stoull(v);
    } else if (a == "--masks") {
      if (v != "gt" && v != "det" && v != "both") throw InvalidInput("--masks", "must be gt, det or both");
      o.masks = v == "both" ? std::vector<std::string>{"gt", "det"} : std::vector<std::string>{v};
    } else if (a == "--backend") {
      o.backend = dataset::parse_backend(v);
    } else if (a == "--peer") {
      o.peer = v != "0";
    } else if (a == "--perch2") {
      o.perch2 = v != "0";
    } else if (a == "--fit") {
      o.fit = std::stoi(v);
    } else if (a == "--target-stride") {
      o.target_stride = std::stoi(v);
      if (o.target_stride < 1) throw InvalidInput("--target-stride", "must be >= 1");
    } else {
      throw InvalidInput(a, std::string("unknown argument; usage: ") + kUsage);
    }
  }
  return o;
}

using Images = std::map<std::pair<int, int>, std::vector<dataset::Target>>;

/// Every target instance's visible mask degraded like a detector's, one seeded stream per image.
std::vector<dataset::Detection> degraded_detections(const dataset::BopDataset& data, const Images& images,
                                                    std::uint64_t seed) {
  std::vector<dataset::Detection> out;
  dataset::ImageLoadOptions load;
  load.rgb = false, load.depth = false, load.masks_visib = true;
  for (const auto& [key, targets] : images) {
    const dataset::BopImage image = data.load_image(key.first, key.second, load);
    synth::Rng rng = synth::Rng::stream(seed, std::uint64_t(key.first), std::uint64_t(key.second));
    for (std::size_t g = 0; g < image.info.gt.size(); ++g) {
      const bool target = std::any_of(targets.begin(), targets.end(), [&](const dataset::Target& t) {
        return t.obj_id == image.info.gt[g].obj_id;
      });
      if (!target) continue;
      const Image<std::uint8_t> mask =
          synth::degrade_mask(image.masks_visib[g], synth::MaskDegradation{}, rng);
      const auto box = mask_bbox(mask);
      if (box[0] < 0) continue;  // nothing left: a miss
      dataset::Detection d;
      d.scene_id = key.first, d.image_id = key.second, d.category_id = image.info.gt[g].obj_id;
      d.score = 1.f;
      d.bbox = {float(box[0]), float(box[1]), float(box[2]), float(box[3])};
      d.segmentation = dataset::rle_encode(mask);
      out.push_back(std::move(d));
    }
  }
  return out;
}

/// The instances of one image: ground-truth masks or the detections, targets only, usable ones.
BopInstances instances_of(const dataset::BopImage& image, const std::vector<dataset::Target>& targets,
                          const std::string& masks, const std::vector<dataset::Detection>& detections,
                          const std::vector<std::size_t>& detection_indices,
                          const std::map<int, int>& model_of, const ObservedCloudSettings& observed) {
  const BopInstances all =
      masks == "gt" ? bop_instances_from_gt(image, model_of, BoxKind::Full)
                    : bop_instances_from_detections(image, detections, detection_indices, model_of);
  return usable_instances(only_targets(all, targets), image.frame, observed);
}

template <class Backend>
std::vector<dataset::PoseEstimate> run_perch2(const Options& o, const dataset::BopDataset& data,
                                              const Images& images, const std::string& masks,
                                              const std::vector<dataset::Detection>& detections,
                                              double& cpu_s) {
  std::map<int, int> model_of;
  std::vector<SixDofModel> models;
  for (const auto& [id, info] : data.models_info())
    model_of[id] = int(models.size()), models.push_back(sixdof_model(data.load_model(id), info));
  SixDofSettings settings;
  if (o.fit >= 0) settings.fit.iterations = o.fit;
  if (o.target_stride >= 1) settings.first_pass_target_stride = o.target_stride;
  const SixDofEstimator<Backend> estimator(std::move(models), settings);
  auto by_image = dataset::detections_by_image(detections);
  dataset::ImageLoadOptions load;
  load.masks_visib = masks == "gt";
  std::vector<dataset::PoseEstimate> rows;
  int done = 0;
  double wall = 0;
  for (const auto& [key, targets] : images) {
    const dataset::BopImage image = data.load_image(key.first, key.second, load);
    const BopInstances in = instances_of(image, targets, masks, detections, by_image[key], model_of,
                                         estimator.settings().observed);
    const std::clock_t c0 = std::clock();
    SixDofResult r;
    const auto image_rows = estimate_bop_image(estimator, image, in, &r);
    cpu_s += double(std::clock() - c0) / CLOCKS_PER_SEC;
    rows.insert(rows.end(), image_rows.begin(), image_rows.end());
    wall += r.timings.total;
    ++done;
    cli::print_progress(stderr, done, int(images.size()), wall / done, r.timings.total);
  }
  std::fprintf(stderr, "\n");
  return rows;
}

#ifdef PERCH2_HAVE_PPF
using bench::ppf_peer::kPpfUnit;
using bench::ppf_peer::PpfModels;

// Per instance (see ppf_peer.hpp for the model side: train_ppf on every vertex). The scene is the mask's
// readings, the mask grown by 3 px as a detector's crop would be (a degraded mask cut short of the
// silhouette loses the edge readings that fix the pose), with with_normals' normals. match() quantises the
// scene to 20 cells per side of its box (260-480 samples on the cat) and takes every 5th as a reference
// point (52-96; the sample's 1/40 leaves ~8); each gives one pose, most votes first. The default clustering
// is kept: in millimetres it merges nothing, and a coarser position threshold merges unrelated rotations
// (matchPose compares the rotations' angles, not the rotation between them). ICP refines the 10 most voted
// (refine_icp), and the pose with the largest fitness (fraction of the model's sampled points within 0.03 x
// the diameter of a scene reading, see fitness) is kept: the votes of a partial view favour flips.
constexpr int kPpfMaskGrowPx = 3;
constexpr double kPpfSceneSampleStep = 1.0 / 5.0, kPpfSceneDistance = 0.05;
constexpr std::size_t kPpfRefined = 10;

/// OpenCV PPF + ICP (see the comment above) on every target instance's mask.
std::vector<dataset::PoseEstimate> run_ppf(const dataset::BopDataset& data, const Images& images,
                                           const std::string& masks,
                                           const std::vector<dataset::Detection>& detections,
                                           PpfModels& models, double& cpu_s) {
  namespace ppf = cv::ppf_match_3d;
  const std::map<int, int>& model_of = models.model_of;
  auto by_image = dataset::detections_by_image(detections);
  dataset::ImageLoadOptions load;
  load.masks_visib = masks == "gt";
  const cv::Mat grow =
      cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * kPpfMaskGrowPx + 1, 2 * kPpfMaskGrowPx + 1));
  std::vector<dataset::PoseEstimate> rows;
  int done = 0;
  for (const auto& [key, targets] : images) {
    const dataset::BopImage image = data.load_image(key.first, key.second, load);
    ObservedCloudSettings every_pixel;
    const BopInstances in =
        instances_of(image, targets, masks, detections, by_image[key], model_of, every_pixel);
    const auto t0 = std::chrono::steady_clock::now();
    const std::clock_t c0 = std::clock();
    std::vector<dataset::PoseEstimate> image_rows;
    for (std::size_t k = 0; k < in.instances.size(); ++k) {
      const int obj = in.obj_ids[k];
      const RgbdFrame& f = image.frame;
      Image<std::uint8_t> mask = in.instances[k].mask;
      const cv::Mat mask_cv(mask.height, mask.width, CV_8U, mask.data.data());
      cv::dilate(mask_cv, mask_cv, grow);
      std::vector<cv::Vec3f> pts;
      for (int v = 0; v < f.camera.height; ++v)
        for (int u = 0; u < f.camera.width; ++u)
          if (mask(u, v) && f.depth_m(u, v) > 0) {
            const Vec3f p = f.depth_m(u, v) * f.camera.ray(float(u), float(v));
            pts.push_back({kPpfUnit * p.x, kPpfUnit * p.y, kPpfUnit * p.z});
          }
      if (pts.size() < 10) continue;
      const cv::Mat scene(int(pts.size()), 3, CV_32F, pts.data());
      const cv::Mat scene_n = bench::ppf_peer::with_normals(scene);
      std::vector<ppf::Pose3DPtr> results;
      models.detector[obj]->match(scene_n, results, kPpfSceneSampleStep, kPpfSceneDistance);
      if (results.empty()) continue;
      results.resize(std::min(results.size(), kPpfRefined));
      bench::ppf_peer::SceneIndex scene_index(scene, cvflann::KDTreeSingleIndexParams(8));
      const float fit_d = float(bench::ppf_peer::kPpfFitnessDistance * kPpfUnit * models.diameter_m[obj]);
      ppf::Pose3DPtr best;
      double best_fitness = -1;
      for (const ppf::Pose3DPtr& pose : results) {
        bench::ppf_peer::refine_icp(models.cloud[obj], pose, scene_n);
        const double fitness = bench::ppf_peer::fitness(ppf::transformPCPose(models.sampled[obj], pose->pose),
                                                        scene_index, fit_d);
        if (fitness > best_fitness) best_fitness = fitness, best = pose;
      }
      dataset::PoseEstimate e;
      e.scene_id = key.first, e.im_id = key.second, e.obj_id = obj;
      e.score = float(best_fitness);
      e.T_cam_obj = bench::ppf_peer::to_pose(best->pose);
      image_rows.push_back(e);
    }
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    cpu_s += double(std::clock() - c0) / CLOCKS_PER_SEC;
    for (auto& e : image_rows) e.time_s = wall;
    rows.insert(rows.end(), image_rows.begin(), image_rows.end());
    ++done;
    cli::print_progress(stderr, done, int(images.size()), 0.0, wall);
  }
  std::fprintf(stderr, "\n");
  return rows;
}
#endif

}  // namespace

int main(int argc, char** argv) try {
  const Options o = parse(argc, argv);
  if (!fs::is_directory(o.dataset)) {
    std::printf("bench_real: no dataset at %s (the shared real frames are not here); nothing to do\n",
                o.dataset.c_str());
    return 0;
  }
  fs::create_directories(o.dir);
  std::printf("bench_real: %s, %s, %d OpenMP threads, load average %.2f at start\n", o.dataset.c_str(),
              bench::cpu_model().c_str(), omp_get_max_threads(), bench::load_average());
  const dataset::BopDataset data(o.dataset);
  const Images images = dataset::targets_by_image(data.targets(), 1, 1 << 30);
  const std::vector<dataset::Detection> detections = degraded_detections(data, images, o.seed);
  const std::string det_file = o.dir + "/detections_degraded.json";
  dataset::save_detections(det_file, detections);
  std::printf("degraded detections (seed %llu): %zu -> %s\n", (unsigned long long)o.seed, detections.size(),
              det_file.c_str());

  struct Row {
    std::string name;
    eval::EvalReport report;
    double cpu_s;
  };
  std::vector<Row> rows;
  auto add = [&](const std::string& name, const std::vector<dataset::PoseEstimate>& estimates, double cpu_s) {
    const std::string csv = o.dir + "/" + name + ".csv";
    dataset::save_results_csv(csv, estimates);
    rows.push_back({name, eval::evaluate(data, estimates, eval::EvalSettings{}, csv), cpu_s});
    std::ofstream(o.dir + "/" + name + ".json")
        << eval::report_json(rows.back().report, eval::EvalSettings{});
  };
#ifdef PERCH2_HAVE_PPF
  std::unique_ptr<PpfModels>
      ppf_models;  // trained on first use (seconds, see train_ppf), kept for every mask set
#endif
  for (const std::string& masks : o.masks) {
    if (o.perch2) {
      double cpu = 0;
      const auto estimates = o.backend == dataset::BackendKind::Cpu
                                 ? run_perch2<cpu::Backend>(o, data, images, masks, detections, cpu)
                                 : run_perch2<thrust_omp::Backend>(o, data, images, masks, detections, cpu);
      add("perch2_" + masks, estimates, cpu);
    }
#ifdef PERCH2_HAVE_PPF
    if (o.peer) {
      double ppf_cpu = 0;
      if (!ppf_models)
        ppf_models = std::make_unique<PpfModels>(bench::ppf_peer::train_ppf(
            data, [](const Mesh& mesh, double) { return bench::ppf_peer::vertices_with_normals(mesh); }));
      const auto ppf = run_ppf(data, images, masks, detections, *ppf_models, ppf_cpu);
      add("ppf_icp_" + masks, ppf, ppf_cpu);
    }
#else
    if (o.peer) std::printf("PPF + ICP peer: not built (OpenCV's surface_matching module was not found)\n");
#endif
  }
  std::printf("\n%-14s %7s %7s %7s %7s %7s %7s %7s %8s %8s\n", "method/masks", "targets", "ADD-S", "ADD",
              "AR", "VSD", "MSSD", "MSPD", "wall s", "CPU s");
  for (const Row& r : rows) {
    const eval::Scores& s = r.report.overall;
    const double n = std::max(r.report.num_images_timed, 1);
    std::printf("%-14s %7d %7.1f %7.1f %7.3f %7.3f %7.3f %7.3f %8.3f %8.3f\n", r.name.c_str(), s.num_targets,
                100 * s.auc_adds, 100 * s.auc_add, s.ar, s.ar_vsd, s.ar_mssd, s.ar_mspd,
                r.report.mean_time_per_image_s, r.cpu_s / n);
  }
  std::printf(
      "(ADD-S / ADD: AUC over 0-10 cm, percent; AR = mean of the VSD, MSSD, MSPD recalls; per image)\n");
#ifdef PERCH2_HAVE_PPF
  if (ppf_models)
    std::printf("PPF training (once, not in the rows): %.1f CPU s\n", ppf_models->total_train_cpu_s);
#endif
  std::printf("load average %.2f at the end\n", bench::load_average());
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_real: %s\n", e.what());
  return 1;
}
