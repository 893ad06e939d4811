// Evaluation and BOP reading speed:
//  1. ADD-S of 1,000 estimates against 3,000-point models (kd-tree), with the O(n^2) definition as the peer
//     (timed on a subset and scaled), and the whole evaluate() (ADD, ADD-S, MSSD, MSPD, matching; no VSD) on
//     a JSON-only BOP dataset with 1,000 targets.
//  2. Reading one 640x480 BOP image: rgb PNG + 16-bit depth PNG + 5 mask_visib PNGs.
// Usage: bench_eval [SCRATCH_DIR]   (default /tmp/perch2_bench_eval; files are written there)
#include <omp.h>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>

#include <random>

#include "../tests/render_fixtures.hpp"  // make_blob: the same test shapes
#include "bench_support.hpp"
#include "perch2/dataset/bop.hpp"
#include "perch2/eval/evaluator.hpp"
#include "perch2/eval/metrics.hpp"
#include "perch2/io/io.hpp"

using namespace perch2;
namespace fs = std::filesystem;

namespace {

Pose random_pose(std::mt19937& rng) {
  std::normal_distribution<float> g(0.f, 1.f);
  std::uniform_real_distribution<float> u(-0.15f, 0.15f), z(0.5f, 1.0f);
  Pose T = Pose::Identity();
  T.linear() = Eigen::Quaternionf(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
  T.translation() = Eigen::Vector3f(u(rng), u(rng), z(rng));
  return T;
}

Pose perturb(std::mt19937& rng, const Pose& T, float sigma_m, float sigma_rad) {
  std::normal_distribution<float> g(0.f, 1.f);
  const Eigen::Vector3f axis = Eigen::Vector3f{g(rng), g(rng), g(rng)}.normalized();
  const float angle = sigma_rad * g(rng);
  const Eigen::Vector3f dt{sigma_m * g(rng), sigma_m * g(rng), sigma_m * g(rng)};
  return Eigen::Translation3f(dt) * T * Eigen::AngleAxisf(angle, axis);
}

void write(const std::string& path, const std::string& text) {
  std::ofstream(path) << text;
}

std::string row_major(const Pose& T) {
  char buf[256];
  const Eigen::Matrix3f R = T.linear();
  const Eigen::Vector3f t = T.translation() * 1000.f;
  std::snprintf(
      buf, sizeof buf,
      "\"cam_R_m2c\": [%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g], \"cam_t_m2c\": [%.7g,%.7g,%.7g]",
      R(0, 0), R(0, 1), R(0, 2), R(1, 0), R(1, 1), R(1, 2), R(2, 0), R(2, 1), R(2, 2), t.x(), t.y(), t.z());
  return buf;
}

/// JSON-only BOP dataset: 4 asymmetric 3,000-vertex models, 250 images x 4 instances, camera.json.
std::vector<dataset::PoseEstimate> write_json_dataset(const std::string& root, std::mt19937& rng) {
  fs::remove_all(root);
  fs::create_directories(root + "/models");
  fs::create_directories(root + "/test/000001");
  std::string info = "{";
  for (int obj = 1; obj <= 4; ++obj) {
    Mesh m = test::make_blob(rng, 0.05f, 55, 55);
    for (auto& v : m.vertices) v *= 1000.f;
    io::save_ply(root + "/models/obj_" + dataset::bop_id(obj) + ".ply", m);
    info += std::string(obj > 1 ? "," : "") + "\"" + std::to_string(obj) + "\": {\"diameter\": 100}";
  }
  write(root + "/models/models_info.json", info + "}");
  write(root + "/camera.json",
        R"({"fx": 600, "fy": 600, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480})");
  std::string cams = "{", gts = "{", targets = "[";
  std::vector<dataset::PoseEstimate> ests;
  for (int im = 0; im < 250; ++im) {
    const std::string k = "\"" + std::to_string(im) + "\"";
    cams += (im ? "," : "") + k + R"(: {"cam_K": [600, 0, 319.5, 0, 600, 239.5, 0, 0, 1], "depth_scale": 1})";
    gts += (im ? "," : "") + k + ": [";
    for (int obj = 1; obj <= 4; ++obj) {
      const Pose T = random_pose(rng);
      gts +=
          std::string(obj > 1 ? "," : "") + "{\"obj_id\": " + std::to_string(obj) + ", " + row_major(T) + "}";
      targets += std::string(im || obj > 1 ? "," : "") +
                 "{\"scene_id\": 1, \"im_id\": " + std::to_string(im) +
                 ", \"obj_id\": " + std::to_string(obj) + ", \"inst_count\": 1}";
      dataset::PoseEstimate e;
      e.scene_id = 1, e.im_id = im, e.obj_id = obj, e.time_s = 1.0;
      e.T_cam_obj = perturb(rng, T, 0.005f, 0.05f);
      ests.push_back(e);
    }
    gts += "]";
  }
  write(root + "/test/000001/scene_camera.json", cams + "}");
  write(root + "/test/000001/scene_gt.json", gts + "}");
  write(root + "/test_targets_bop19.json", targets + "]");
  return ests;
}

/// One 640x480 image with rgb, depth and 5 visible masks.
void write_image(const std::string& root, std::mt19937& rng) {
  const std::string dir = root + "/test/000001";
  for (const char* sub : {"rgb", "depth", "mask_visib"}) fs::create_directories(dir + "/" + sub);
  std::uniform_int_distribution<int> c(0, 255);
  ColorImage rgb(640, 480);
  for (auto& p : rgb.data) p = {std::uint8_t(c(rng)), std::uint8_t(c(rng)), std::uint8_t(c(rng))};
  DepthImage depth(640, 480);
  for (int v = 0; v < 480; ++v)
    for (int u = 0; u < 640; ++u) depth(u, v) = 0.6f + 0.0004f * u + 0.0001f * float(c(rng));
  io::save_color_image(dir + "/rgb/000000.png", rgb);
  io::save_depth_png(dir + "/depth/000000.png", depth);
  for (int g = 0; g < 5; ++g) {
    LabelImage mask(640, 480, 0);
    for (int v = 100; v < 220; ++v)
      for (int u = 100 * g; u < 100 * g + 90; ++u) mask(u, v) = 255;
    io::save_label_png(dir + "/mask_visib/000000_" + dataset::bop_id(g) + ".png", mask);
  }
  // Five GT instances in image 0 so that load_image reads five masks.
  std::string gts = "{\"0\": [";
  for (int g = 0; g < 5; ++g)
    gts += std::string(g ? "," : "") + "{\"obj_id\": 1, " + row_major(random_pose(rng)) + "}";
  write(dir + "/scene_gt.json", gts + "]}");
}

}  // namespace

int main(int argc, char** argv) {
  const std::string root = argc > 1 ? argv[1] : "/tmp/perch2_bench_eval";
  std::mt19937 rng(1);
  std::printf("bench_eval on %s (%d OpenMP threads available)\n", bench::cpu_model().c_str(),
              omp_get_max_threads());

  // 1a. ADD-S kernel: 1,000 estimates of one 3,000-point model.
  const Mesh model = test::make_blob(rng, 0.05f, 55, 55);
  const eval::ModelPoints points(model.vertices);
  std::vector<Pose> gt(1000), est(1000);
  for (int k = 0; k < 1000; ++k) gt[k] = random_pose(rng), est[k] = perturb(rng, gt[k], 0.005f, 0.05f);
  std::vector<double> adds(1000);
  const auto adds_all = [&] {
#pragma omp parallel for schedule(dynamic, 8)
    for (int k = 0; k < 1000; ++k) adds[k] = eval::adds_error(est[k], gt[k], points);
  };
  const double t_tree = bench::median_seconds(5, adds_all);
  // CPU seconds of one run (all threads): wall time on a loaded machine says little, this says the work.
  const std::clock_t c0 = std::clock();
  adds_all();
  const double cpu_tree = double(std::clock() - c0) / CLOCKS_PER_SEC;
  // Peer: the O(n^2) definition on 20 estimates, scaled to 1,000.
  double brute_check = 0;
  const double t_brute20 = bench::median_seconds(1, [&] {
    for (int k = 0; k < 20; ++k) {
      double sum = 0;
      for (const auto& x : model.vertices) {
        float best = 1e30f;
        const Eigen::Vector3f p = gt[k] * x;
        for (const auto& y : model.vertices) best = std::min(best, (p - est[k] * y).squaredNorm());
        sum += std::sqrt(double(best));
      }
      brute_check = std::max(brute_check, std::abs(sum / model.vertices.size() - adds[k]));
    }
  });
  std::printf(
      "ADD-S, 1000 estimates x %zu model points: ModelPoints (candidate grid + kd-tree) %.1f ms wall (median "
      "of 5), %.0f ms CPU (one run, all "
      "threads); O(n^2) %.0f ms wall (20 timed, x50); max |difference| %.2g m\n",
      model.vertices.size(), 1e3 * t_tree, 1e3 * cpu_tree, 1e3 * t_brute20 * 50, brute_check);

  // 1b. The whole evaluator without VSD on 1,000 targets.
  auto ests = write_json_dataset(root + "/json_only", rng);
  eval::EvalSettings settings;
  settings.compute_vsd = false;
  eval::EvalReport report;
  const double t_eval = bench::median_seconds(3, [&] {
    const dataset::BopDataset data(root + "/json_only");
    report = eval::evaluate(data, ests, settings, "bench");
  });
  std::printf(
      "evaluate() without VSD, %d targets x 3,000-point models (reading JSON and PLY, ADD, ADD-S, MSSD, "
      "MSPD, matching): %.0f ms (median of 3); AUC ADD-S %.1f, AR_MSSD %.1f\n",
      report.overall.num_targets, 1e3 * t_eval, 100 * report.overall.auc_adds, 100 * report.overall.ar_mssd);

  // 2. One BOP image.
  write_image(root + "/json_only", rng);
  const dataset::BopDataset data(root + "/json_only");
  std::size_t bytes = 0;
  const double t_read = bench::median_seconds(20, [&] {
    const auto im = data.load_image(1, 0);
    bytes = im.frame.depth_m.data.size() + im.masks_visib.size();
  });
  std::printf("load_image 640x480 (rgb PNG + 16-bit depth PNG + 5 mask_visib PNGs): %.1f ms (median of 20)\n",
              1e3 * t_read);
  return bytes > 0 ? 0 : 1;
}
