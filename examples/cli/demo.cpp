// perch2 demo: a built-in 3-DoF scene (three cans of one shape with different labels and a bottle on a
// table, from a fixed seed), estimated by the default variant, compared with the ground truth; or with
// --mode 6dof a cluttered pile (stacked, leaning, lying objects) generated in memory, estimated in full 6-DoF
// from its ground-truth visible masks.
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <map>
#include <string>

#include "cli_common.hpp"
#include "commands.hpp"
#include "perch2/cpu/estimators.hpp"
#include "perch2/cuda/estimators.hpp"
#include "perch2/dataset/runner.hpp"
#include "perch2/eval/metrics.hpp"
#include "perch2/io/image_io.hpp"
#include "perch2/search/sixdof.hpp"
#include "perch2/synth/synth.hpp"

namespace {

using namespace perch2;

constexpr const char* kUsage =
    "usage: perch2 demo [--mode 3dof|6dof] [--out DIR] [--backend cpu|thrust_omp] [--seed S] [--masks "
    "gt|none]\n"
    "  generates a table scene with built-in models (cans cola/cherry/aqua: one shape, different labels, and "
    "a\n"
    "  a lime bottle) into DIR/dataset (BOP format), estimates their 3-DoF poses with PERCH 2.0-C and "
    "writes\n"
    "  DIR/scene_rgb.png and DIR/overlay.png (estimated models tinted and outlined over the image).\n"
    "  --mode 6dof: six built-in objects piled on a table (stacked, leaning, lying) with distractors, "
    "generated\n"
    "  in memory; every instance's full pose from its ground-truth visible mask and full box\n"
    "  (SixDofEstimator, default settings); prints each pose's ADD-S and ADD(-S) error, score and the\n"
    "  per-stage times; writes DIR/overlay_6dof.png (the image | the estimated models over it).\n"
    "  --mode 6dof --masks none: no masks; each of the six objects is searched for in the whole frame\n"
    "  (SixDofEstimator::estimate_scene) and placed one by one; objects it cannot find are reported.\n";

/// The demo's dataset: one image of four built-in models (obj_id 1-4), each once.
dataset::BopDataset make_dataset(const std::string& dir, std::uint64_t seed,
                                 std::map<int, std::string>& names) {
  std::vector<synth::ObjectModel> models;
  for (auto& m : synth::builtin_models())
    if (m.obj_id <= 4) names[m.obj_id] = m.name, models.push_back(std::move(m));
  synth::DatasetSettings s;
  s.num_scenes = 1, s.images_per_scene = 1, s.seed = seed;
  s.scene.mode = synth::Mode::ThreeDof;
  s.scene.min_objects = s.scene.max_objects = 4;
  s.scene.duplicate_probability = 0.f;
  s.scene.min_distractors = s.scene.max_distractors = 1;
  synth::generate_dataset(models, s, dir);
  return dataset::BopDataset(dir);
}

// ---- 6-DoF ---------------------------------------------------------------------------------------------

/// The 6-DoF demo's frame, generated in memory: the models, the frame, one instance per annotated object
/// visible enough to be detected, and its ground truth.
struct Demo6 {
  std::vector<synth::ObjectModel> models;
  synth::Frame frame;
  std::vector<SixDofInstance> instances;  ///< ground-truth visible mask + full (amodal) box
  std::vector<Pose> gt;                   ///< T_cam_obj per instance
  int hidden = 0;                         ///< annotated objects left out: fewer than kMinVisiblePx visible
};

constexpr int kMinVisiblePx = 300;
constexpr std::uint64_t kSeed6dof =
    3;  ///< the 6-DoF demo's default scene  ///< a detector would not report less of an object (~17x17 px)

/// Six built-in objects (cola and aqua cans, the lime bottle, the printed box, the bowl, the block) dropped
/// on a table in 6-DoF resting poses (stacked, leaning, lying), two distractors, one 640x480 view.
Demo6 make_scene_6dof(std::uint64_t seed) {
  Demo6 d;
  for (auto& m : synth::builtin_models())
    if (m.obj_id == 1 || m.obj_id == 3 || m.obj_id == 4 || m.obj_id >= 6) d.models.push_back(std::move(m));
  synth::SceneSettings ss;
  ss.mode = synth::Mode::SixDof;
  ss.min_objects = ss.max_objects = int(d.models.size());
  ss.duplicate_probability = 0.f;
  ss.min_distractors = ss.max_distractors = 2;
  ss.placement_radius_m = 0.15f;  // a pile, not a spread: neighbours occlude and touch
  ss.camera_min_distance_m = 0.7f, ss.camera_max_distance_m = 0.9f;
  synth::Rng rng(seed);
  const synth::Scene scene = synth::compose_scene(d.models, ss, rng);
  const Pose T_world_cam = synth::sample_camera_pose(ss, rng);
  d.frame = synth::SceneRenderer(d.models, scene).render(T_world_cam, synth::SensorSettings{}, rng);
  for (std::size_t k = 0; k < scene.objects.size(); ++k) {
    SixDofInstance in{scene.objects[k].model,
                      Image<std::uint8_t>(d.frame.camera.width, d.frame.camera.height, 0),
                      {-1, -1, -1, -1}};
    int visible = 0;
    for (std::size_t i = 0; i < in.mask.data.size(); ++i)
      if (d.frame.visible.data[i] == int(k) + 1) in.mask.data[i] = 1, ++visible;
    if (visible < kMinVisiblePx) {
      ++d.hidden;
      continue;
    }
    const auto& b = d.frame.bbox_obj[k];
    in.box_xywh = {b[0], b[1], b[2], b[3]};
    d.instances.push_back(std::move(in));
    d.gt.push_back(T_world_cam.inverse() * scene.objects[k].T_world_obj);
  }
  return d;
}

/// The image on the left, the estimated models tinted and outlined over it on the right.
ColorImage side_by_side(const ColorImage& a, const ColorImage& b) {
  ColorImage out(a.width + b.width, std::max(a.height, b.height), Rgb8{0, 0, 0});
  for (int v = 0; v < a.height; ++v)
    for (int u = 0; u < a.width; ++u) out(u, v) = a(u, v);
  for (int v = 0; v < b.height; ++v)
    for (int u = 0; u < b.width; ++u) out(a.width + u, v) = b(u, v);
  return out;
}

/// --masks none: every model once, searched for in the whole frame.
template <class Backend>
int demo_6dof_scene(const Demo6& d, const SixDofEstimator<Backend>& estimator, const RgbdFrame& frame,
                    const std::vector<Mesh>& meshes, const std::string& out) {
  std::vector<SixDofObject> objects;
  for (std::size_t m = 0; m < d.models.size(); ++m) objects.push_back({int(m), 1});
  const SixDofSceneResult r = estimator.estimate_scene(frame, objects);
  std::printf("  %zu segments (support plane %s), %zu (model, segment) searches, %zu candidates\n",
              r.segments.size(), r.plane ? "found" : "none", r.jobs, r.candidates);
  std::printf("\n  %-11s %-8s %7s %7s %7s %8s %10s %6s\n", "object", "overlay", "x m", "y m", "z m",
              "ADD-S mm", "ADD(-S) mm", "score");
  int adds_1cm = 0, add_s_2cm = 0;
  std::vector<int> model_of_pose;
  std::vector<Pose> poses;
  for (std::size_t k = 0; k < r.poses.size(); ++k) {
    const SixDofPose& p = r.poses[k];
    const synth::ObjectModel& m = d.models[std::size_t(p.model)];
    const eval::ModelPoints points(m.mesh.vertices);
    double adds = INFINITY, add_s = INFINITY;  // against the ground truth of the same model
    for (std::size_t g = 0; g < d.instances.size(); ++g)
      if (d.instances[g].model == p.model) {
        adds = eval::adds_error(p.T_cam_obj, d.gt[g], points);
        add_s = m.symmetries.empty() ? eval::add_error(p.T_cam_obj, d.gt[g], m.mesh.vertices) : adds;
      }
    adds_1cm += adds < 0.01, add_s_2cm += add_s < 0.02;
    const Eigen::Vector3f t = p.T_cam_obj.translation();
    std::printf("  %-11s %-8s %7.3f %7.3f %7.3f %8.1f %10.1f %6.3f\n", m.name.c_str(),
                cli::overlay_color_name(int(k)), t.x(), t.y(), t.z(), 1000 * adds, 1000 * add_s, p.score);
    model_of_pose.push_back(p.model), poses.push_back(p.T_cam_obj);
  }
  for (std::size_t i = 0; i < objects.size(); ++i)
    if (r.missing[i] > 0) std::printf("  %-11s not found\n", d.models[i].name.c_str());
  std::printf("  %d / %zu visible instances within 1 cm ADD-S, %d within 2 cm ADD(-S)\n\n", adds_1cm,
              d.instances.size(), add_s_2cm);
  const SixDofTimings& t = r.search.timings;
  std::printf("per-stage wall-clock seconds (%zu hypotheses):\n", r.search.hypotheses_total);
  std::printf(
      "  segment %.3f  observed %.3f  proposals %.3f  render %.3f  refine %.3f  cost %.3f  explain %.3f  "
      "total %.3f\n",
      t.segment, t.observed, t.proposals, t.render, t.refine, t.cost, t.explain, t.total);
  std::filesystem::create_directories(out);
  const ColorImage overlay = cli::draw_overlay(frame.rgb, frame.camera, meshes, model_of_pose, poses);
  io::save_color_image(out + "/overlay_6dof.png", side_by_side(frame.rgb, overlay));
  std::printf("wrote %s/overlay_6dof.png (left: the image; right: the estimated models over it)\n",
              out.c_str());
  return 0;
}

template <class Backend>
int demo_6dof(const std::string& out, dataset::BackendKind backend, std::uint64_t seed, bool no_masks) {
  const Demo6 d = make_scene_6dof(seed);
  if (d.instances.empty()) throw InvalidInput("--seed", "this seed's scene shows no object well enough");
  std::vector<SixDofModel> models;
  std::vector<Mesh> meshes;
  for (const auto& m : d.models) {
    models.push_back({m.mesh, ModelSymmetries::from(m.symmetries.discrete, m.symmetries.continuous)});
    meshes.push_back(m.mesh);
  }
  const SixDofEstimator<Backend> estimator(std::move(models));
  RgbdFrame frame;
  frame.camera = d.frame.camera, frame.depth_m = d.frame.depth_m, frame.rgb = d.frame.rgb;
  if (no_masks) {
    std::printf(
        "perch2 demo --mode 6dof --masks none: %zu objects piled on a table, %dx%d RGB-D, no masks, "
        "%s (seed %llu)\n",
        d.models.size(), frame.camera.width, frame.camera.height, dataset::backend_name(backend),
        static_cast<unsigned long long>(seed));
    return demo_6dof_scene(d, estimator, frame, meshes, out);
  }
  std::printf(
      "perch2 demo --mode 6dof: %zu objects piled on a table (%d hidden), %dx%d RGB-D, ground-truth "
      "visible masks and full boxes, %s (seed %llu)\n",
      d.instances.size(), d.hidden, frame.camera.width, frame.camera.height, dataset::backend_name(backend),
      static_cast<unsigned long long>(seed));
  const double cpu0 = (double(std::clock()) / CLOCKS_PER_SEC);
  const SixDofResult r = estimator.estimate(frame, d.instances);
  const double cpu = (double(std::clock()) / CLOCKS_PER_SEC) - cpu0;

  std::printf("\n  %-11s %-8s %7s %7s %7s %8s %10s %6s %5s %7s\n", "object", "overlay", "x m", "y m", "z m",
              "ADD-S mm", "ADD(-S) mm", "score", "hyp", "segment");
  int adds_1cm = 0, add_s_2cm = 0;
  std::vector<int> model_of_pose;
  std::vector<Pose> poses;
  for (std::size_t k = 0; k < r.poses.size(); ++k) {
    const SixDofPose& p = r.poses[k];
    const synth::ObjectModel& m = d.models[std::size_t(p.model)];
    const eval::ModelPoints points(m.mesh.vertices);
    const double adds = eval::adds_error(p.T_cam_obj, d.gt[k], points);
    // ADD(-S): ADD for a model without symmetries (its texture decides its turn), ADD-S otherwise.
    const double add_s = m.symmetries.empty() ? eval::add_error(p.T_cam_obj, d.gt[k], m.mesh.vertices) : adds;
    adds_1cm += adds < 0.01, add_s_2cm += add_s < 0.02;
    const Eigen::Vector3f t = p.T_cam_obj.translation();
    std::printf("  %-11s %-8s %7.3f %7.3f %7.3f %8.1f %10.1f %6.3f %5zu %7zu%s\n", m.name.c_str(),
                cli::overlay_color_name(int(k)), t.x(), t.y(), t.z(), 1000 * adds, 1000 * add_s, p.score,
                r.hypotheses[k], r.segment_points[k], p.found ? "" : "  (no acceptable hypothesis)");
    model_of_pose.push_back(p.model), poses.push_back(p.T_cam_obj);
  }
  std::printf(
      "  (x, y, z: the object's centre in the camera frame; score: fraction of rendered and observed points "
      "the\n"
      "   pose explains; hyp: pose hypotheses; segment: the instance's observed points after trimming)\n");
  std::printf("  %d / %zu instances within 1 cm ADD-S, %d / %zu within 2 cm ADD(-S)\n\n", adds_1cm,
              r.poses.size(), add_s_2cm, r.poses.size());
  const SixDofTimings& t = r.timings;
  std::printf("per-stage wall-clock seconds (%zu hypotheses in %zu chunks):\n", r.hypotheses_total, r.chunks);
  std::printf(
      "  observed %.3f  proposals %.3f  render %.3f  refine %.3f  cost %.3f  select %.3f  total %.3f\n",
      t.observed, t.proposals, t.render, t.refine, t.cost, t.select, t.total);
  std::printf("  process CPU time %.2f s (%.1f cores busy on average)\n", cpu, cpu / std::max(t.total, 1e-9));

  std::filesystem::create_directories(out);
  const ColorImage overlay = cli::draw_overlay(frame.rgb, frame.camera, meshes, model_of_pose, poses);
  io::save_color_image(out + "/overlay_6dof.png", side_by_side(frame.rgb, overlay));
  std::printf("wrote %s/overlay_6dof.png (left: the image; right: the estimated models over it)\n",
              out.c_str());
  return 0;
}

// ---- 3-DoF ---------------------------------------------------------------------------------------------

int demo_3dof(const std::string& out, dataset::BackendKind b, std::uint64_t seed) {
  std::filesystem::create_directories(out);
  std::map<int, std::string> names;
  const dataset::BopDataset data = make_dataset(out + "/dataset", seed, names);
  dataset::RunOptions options;  // PERCH 2.0-C
  options.backend = b;
  const dataset::BopRunner runner(data, options);
  const auto images = runner.images();
  if (images.size() != 1) throw InvalidInput("demo dataset", "expected one image with targets");
  const auto [scene_id, im_id] = images.front();
  const std::vector<int>& ids = runner.obj_ids();

  const dataset::BopImage image = runner.load_image(scene_id, im_id);
  std::printf("perch2 demo: %zu objects on a table, %dx%d RGB-D, PERCH 2.0-C on %s (seed %llu)\n", ids.size(),
              image.frame.camera.width, image.frame.camera.height, dataset::backend_name(b),
              static_cast<unsigned long long>(seed));
  const dataset::ImageResult e = runner.estimate(image);
  const TabletopResult& r = *e.tabletop;
  std::printf("  table frame %s; %zu grid hypotheses, %zu with observed support, %zu scored; %.2f s\n",
              r.table_estimated ? "estimated from the depth" : "from scene_camera.json", r.hypotheses_grid,
              r.hypotheses_kept, r.hypotheses_scored, e.seconds);

  std::printf("\n  %-12s %-8s %8s %8s %8s %9s %8s %7s %7s %7s %6s %6s\n", "object", "overlay", "x m", "y m",
              "yaw deg", "ADD-S cm", "cost", "J_r", "J_o", "render", "in", "vol");
  std::vector<int> model_of_pose;
  std::vector<Pose> poses;
  int within_1cm = 0;
  for (std::size_t i = 0; i < r.poses.size(); ++i) {
    const TabletopPose& p = r.poses[i];
    const int obj_id = e.rows[i].obj_id;
    const eval::ModelPoints points(runner.meshes()[std::size_t(p.model)].vertices);
    double adds = INFINITY;  // the nearest ground-truth instance of the same object
    for (const auto& g : image.info.gt)
      if (g.obj_id == obj_id) adds = std::min(adds, eval::adds_error(p.T_cam_obj, g.T_cam_obj, points));
    within_1cm += adds < 0.01;
    std::printf("  %-12s %-8s %8.3f %8.3f %8.1f %9.2f %8.3f %7.3f %7.3f %7d %6d %6d\n", names[obj_id].c_str(),
                cli::overlay_color_name(int(i)), p.x_m, p.y_m, p.yaw_rad * 180.0 / 3.14159265358979,
                100 * adds, p.cost.total, p.cost.J_r, p.cost.J_o, p.cost.rendered_points,
                p.cost.rendered_inliers, p.cost.observed_in_volume);
    model_of_pose.push_back(p.model), poses.push_back(p.T_cam_obj);
  }
  for (const auto& m : r.missing)
    std::printf("  obj_id %d: %d instance(s) not found\n", runner.obj_ids()[std::size_t(m.model)], m.count);
  std::printf(
      "  (cost = J_r + J_o of the RGB-D explanation cost; render = rendered points, in = explained, vol =\n"
      "   observed points in the object's volume)\n");
  std::printf("  %d / %zu objects within 1 cm ADD-S of the ground truth\n\n", within_1cm, ids.size());
  std::printf("per-stage wall-clock times:\n");
  cli::StageTimes times;
  times.add(e.stages);
  times.print(stdout);

  io::save_color_image(out + "/scene_rgb.png", image.frame.rgb);
  io::save_color_image(out + "/overlay.png", cli::draw_overlay(image.frame.rgb, image.frame.camera,
                                                               runner.meshes(), model_of_pose, poses));
  std::printf("wrote %s/scene_rgb.png, %s/overlay.png; the scene as a BOP dataset in %s/dataset\n",
              out.c_str(), out.c_str(), out.c_str());
  return 0;
}

int demo_command(int argc, char** argv) {
  std::string out = "demo_out", backend = "thrust_omp", mode = "3dof", seed_text, masks = "gt";
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    if (a == "-h" || a == "--help") return std::cout << kUsage, 0;
    if (k + 1 >= argc ||
        (a != "--out" && a != "--backend" && a != "--seed" && a != "--mode" && a != "--masks")) {
      std::cerr << "perch2 demo: bad argument " << a << "\n\n" << kUsage;
      return 2;
    }
    const std::string v = argv[++k];
    (a == "--out"       ? out
     : a == "--backend" ? backend
     : a == "--mode"    ? mode
     : a == "--masks"   ? masks
                        : seed_text) = v;
  }
  if (mode != "3dof" && mode != "6dof") throw InvalidInput("--mode", "'" + mode + "' is not 3dof or 6dof");
  if (masks != "gt" && masks != "none") throw InvalidInput("--masks", "'" + masks + "' is not gt or none");
  if (masks == "none" && mode != "6dof") throw InvalidInput("--masks", "none needs --mode 6dof");
  std::uint64_t seed = mode == "3dof" ? 7 : kSeed6dof;
  if (!seed_text.empty()) {
    try {
      seed = std::stoull(seed_text);
    } catch (const std::logic_error&) {
      throw InvalidInput("--seed", "'" + seed_text + "' is not a number");
    }
  }
  const dataset::BackendKind b = dataset::parse_backend(backend);
  if (mode == "3dof") return demo_3dof(out, b, seed);
  return b == dataset::BackendKind::Cpu ? demo_6dof<cpu::Backend>(out, b, seed, masks == "none")
                                        : demo_6dof<thrust_omp::Backend>(out, b, seed, masks == "none");
}

}  // namespace

int run_demo(int argc, char** argv) {
  try {
    return demo_command(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "perch2 demo: " << e.what() << "\n";
    return 1;
  }
}
