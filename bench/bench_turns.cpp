// Which rule puts a printed object's turn right? For every ground-truth instance of a textured model without
// symmetries in models_info.json (a print breaks the shape's symmetry) of a BOP dataset (visible fraction
// >= 0.1), the turns about the model's z axis (or all three) by every `step` degrees from
// the ground truth (or from a results CSV's estimate), rendered at `stride`. A turn is a look-alike when its
// depth-only cost (J_r + J_o as fractions, delta 1 cm) is at most 0.02 worse than the start's (what
// search_turns does); among the look-alikes each rule picks its best, and the table counts how often that
// turn lies within `within` degrees of the ground truth:
//   weighted    appearance correlation weighted by the look-alikes' print variation (the library's rule,
//               perch2/cost/appearance.hpp)
//   unweighted  the same correlation, every pair weighing 1
//   nearest     fewest nearest-colour CIEDE2000 failures (ColorRule::Nearest, the previous local search's)
// --recolour 1|2 first passes the frame's colours through another camera pipeline (1: a strong white balance,
// a filmic tone curve and 35 % desaturation; 2: gamma 0.7 and a green cast), as an outside renderer or camera
// would.
// Without --dataset it generates bench_sixdof's 20 cluttered 6-DoF scenes (seed 2020) into
// /tmp/perch2_bench_turns.
// Usage: bench_turns [--dataset DIR] [--step DEG (2)] [--stride S (2)] [--within DEG (5)] [--axes 1|3 (1)]
//                    [--recolour 0|1|2 (0)] [--from RESULTS.csv] [--verbose 1]
#include <omp.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "bench_support.hpp"
#include "perch2/core/observed.hpp"
#include "perch2/cost/appearance.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/cuda/backend.hpp"
#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/results.hpp"
#include "perch2/synth/synth.hpp"

using namespace perch2;
using Backend = thrust_omp::Backend;

namespace {

struct Options {
  std::string dataset, from;
  int step_deg = 2, stride = 2, within_deg = 5, axes = 1, recolour = 0;
  bool verbose = false;
};

Options parse(int argc, char** argv) {
  Options o;
  for (int k = 1; k + 1 < argc; k += 2) {
    const std::string a = argv[k], v = argv[k + 1];
    if (a == "--dataset")
      o.dataset = v;
    else if (a == "--from")
      o.from = v;
    else if (a == "--step")
      o.step_deg = std::stoi(v);
    else if (a == "--stride")
      o.stride = std::stoi(v);
    else if (a == "--within")
      o.within_deg = std::stoi(v);
    else if (a == "--axes")
      o.axes = std::stoi(v);
    else if (a == "--recolour")
      o.recolour = std::stoi(v);
    else if (a == "--verbose")
      o.verbose = v == "1";
    else
      throw InvalidInput(a, "unknown argument (see the file comment)");
  }
  if (o.step_deg < 1 || o.stride < 1 || (o.axes != 1 && o.axes != 3) || o.recolour < 0 || o.recolour > 2)
    throw InvalidInput("bench_turns", "needs --step >= 1, --stride >= 1, --axes 1 or 3, --recolour 0..2");
  return o;
}

/// Another camera's colour pipeline, in linear light (see the file comment).
void recolour(Image<Rgb8>& rgb, int kind) {
  auto encode = [](double x) {
    x = std::clamp(x, 0.0, 1.0);
    return std::uint8_t(
        std::lround(255 * (x <= 0.0031308 ? 12.92 * x : 1.055 * std::pow(x, 1 / 2.4) - 0.055)));
  };
  for (Rgb8& c : rgb.data) {
    double r = color_math::srgb_to_linear<double>(c.r), g = color_math::srgb_to_linear<double>(c.g),
           b = color_math::srgb_to_linear<double>(c.b);
    if (kind == 1) {
      auto tone = [](double x) { return 1.3 * x / (x + 0.3); };
      r = tone(1.25 * r), g = tone(g), b = tone(0.8 * b);
      const double y = 0.2126 * r + 0.7152 * g + 0.0722 * b;
      r = 0.65 * r + 0.35 * y, g = 0.65 * g + 0.35 * y, b = 0.65 * b + 0.35 * y;
    } else {
      r = std::pow(r, 0.7), g = 1.15 * std::pow(g, 0.7), b = std::pow(b, 0.7);
    }
    c = Rgb8{encode(r), encode(g), encode(b)};
  }
}

bool textured(const Mesh& m) {
  if (m.has_texture()) return true;
  return m.has_vertex_colors() &&
         std::any_of(m.vertex_colors.begin(), m.vertex_colors.end(),
                     [&](const Rgb8& c) { return pack_rgb(c) != pack_rgb(m.vertex_colors.front()); });
}

float rotation_deg(const Pose& a, const Pose& b) {
  const Eigen::Matrix3f d = a.linear().transpose() * b.linear();
  return std::acos(std::clamp((d.trace() - 1.f) / 2.f, -1.f, 1.f)) * 57.29578f;
}

}  // namespace

int main(int argc, char** argv) try {
  Options o = parse(argc, argv);
  if (o.dataset.empty()) {  // bench_sixdof's scenes
    o.dataset = "/tmp/perch2_bench_turns";
    if (!std::filesystem::is_directory(o.dataset + "/test")) {
      synth::DatasetSettings s;
      s.num_scenes = 20, s.images_per_scene = 1, s.seed = 2020;
      s.scene.mode = synth::Mode::SixDof;
      synth::generate_dataset(synth::builtin_models(), s, o.dataset);
    }
  }
  const dataset::BopDataset data(o.dataset);
  std::map<int, int> model_of;
  std::vector<Mesh> meshes;
  for (const auto& [id, info] : data.models_info())
    model_of[id] = int(meshes.size()), meshes.push_back(data.load_model(id));
  const std::vector<dataset::PoseEstimate> estimates =
      o.from.empty() ? std::vector<dataset::PoseEstimate>{} : dataset::load_results_csv(o.from);
  const Backend::Renderer renderer(meshes);
  RenderSettings rs;
  rs.stride = o.stride;
  CostSettings nearest;
  nearest.delta_m = 0.01f, nearest.color_rule = ColorRule::Nearest;
  CostSettings depth_only = nearest;
  depth_only.use_color = false, depth_only.normalization = Normalization::Fractions;
  constexpr float kTolerance = 0.02f;  // TurnSearchSettings::geometry_tolerance
  const char* names[] = {"weighted", "unweighted", "nearest"};
  int right[3] = {0, 0, 0}, total = 0;
  std::set<std::pair<int, int>> images;
  for (const auto& t : data.targets()) images.insert({t.scene_id, t.im_id});
  std::printf("bench_turns: %s, stride %d, turns every %d deg about %s, recolour %d, from %s\n",
              o.dataset.c_str(), o.stride, o.step_deg, o.axes == 1 ? "z" : "x, y, z", o.recolour,
              o.from.empty() ? "the ground truth" : o.from.c_str());
  for (const auto& [scene, im] : images) {
    dataset::BopImage image = data.load_image(scene, im);
    if (o.recolour) recolour(image.frame.rgb, o.recolour);
    const LabelImage labels = image.visible_labels();
    std::vector<std::int32_t> segment_labels;
    for (std::size_t g = 0; g < image.info.gt.size(); ++g) segment_labels.push_back(std::int32_t(g + 1));
    const CloudBatch observed =
        observed_segments(image.frame, labels, segment_labels, ObservedCloudSettings{2});
    const Backend::Cost cost(observed);
    const Occluders occ{image.frame.depth_m, labels};
    for (std::size_t g = 0; g < image.info.gt.size(); ++g) {
      const dataset::GtInstance& gt = image.info.gt[g];
      const int model = model_of.at(gt.obj_id);
      if (!textured(meshes[std::size_t(model)]) || data.model_info(gt.obj_id).is_symmetric() ||
          gt.visib_fract < 0.1f || observed.cloud_size(g) < 30)
        continue;
      Pose start = gt.T_cam_obj;
      if (!estimates.empty()) {  // this object's estimate nearest the ground truth (within 2 cm)
        float best = 0.02f;
        bool found = false;
        for (const auto& e : estimates)
          if (e.scene_id == scene && e.im_id == im && e.obj_id == gt.obj_id)
            if (const float d = (e.T_cam_obj.translation() - gt.T_cam_obj.translation()).norm(); d < best)
              best = d, start = e.T_cam_obj, found = true;
        if (!found) continue;
      }
      for (int axis = 2; axis >= 3 - o.axes; --axis) {
        std::vector<Hypothesis> turns;
        for (int a = 0; a < 360; a += o.step_deg) {
          Hypothesis h{model, start, std::int32_t(g + 1)};
          h.T_cam_obj.linear() *=
              Eigen::AngleAxisf(float(a) * 3.1415927f / 180.f, Eigen::Vector3f::Unit(axis))
                  .toRotationMatrix();
          turns.push_back(h);
        }
        const CloudBatch rendered = renderer.render(turns, image.frame.camera, rs, &occ);
        CostRequest request;
        for (std::size_t h = 0; h < turns.size(); ++h) request.add(std::int32_t(g));
        const auto geometry = cost.evaluate(rendered, request, depth_only).hypotheses;
        const auto colour = cost.evaluate(rendered, request, nearest).hypotheses;
        const auto pairs = appearance_samples(rendered, image.frame, nearest.delta_m);
        std::vector<std::size_t> alike;
        PrintVariation variation(image.frame.camera.width, o.stride);
        for (std::size_t h = 0; h < turns.size(); ++h)
          if (geometry[h].total <= geometry[0].total + kTolerance)
            alike.push_back(h), variation.add(pairs[h]);
        std::size_t best[3] = {0, 0, 0};
        float top[3] = {-2.f, -2.f, 0.f};
        for (const std::size_t h : alike) {
          const float w = appearance_score(pairs[h], &variation).ncc, u = appearance_score(pairs[h]).ncc,
                      c = -colour[h].total;
          if (w > top[0]) top[0] = w, best[0] = h;
          if (u > top[1]) top[1] = u, best[1] = h;
          if (h == alike.front() || c > top[2]) top[2] = c, best[2] = h;
        }
        ++total;
        if (o.verbose)
          std::printf("scene %d gt %zu obj %d axis %d visib %.2f:", scene, g, gt.obj_id, axis,
                      gt.visib_fract);
        for (int r = 0; r < 3; ++r) {
          const float err = rotation_deg(turns[best[r]].T_cam_obj, gt.T_cam_obj);
          right[r] += err <= float(o.within_deg);
          if (o.verbose) std::printf(" %s %.0f deg%s", names[r], err, err <= float(o.within_deg) ? "" : "*");
        }
        if (o.verbose) std::printf("\n");
      }
    }
  }
  std::printf("best look-alike turn within %d deg of the ground truth, of %d:", o.within_deg, total);
  for (int r = 0; r < 3; ++r) std::printf(" %s %d", names[r], right[r]);
  std::printf("\n");
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_turns: %s\n", e.what());
  return 1;
}
