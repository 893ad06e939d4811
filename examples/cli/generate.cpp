// perch2 generate: writes a synthetic BOP dataset (see perch2/synth/dataset.hpp).
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <string>
#include <vector>

#include "commands.hpp"
#include "perch2/io/image_io.hpp"
#include "perch2/synth/synth.hpp"

namespace {

[[noreturn]] void generate_usage(const std::string& error) {
  std::cerr
      << "perch2 generate: " << error
      << "\nusage: perch2 generate --mode 3dof|6dof|video [--models DIR] [--model-scale S] --scenes N\n"
         "                       [--images-per-scene M] [--objects N|MIN-MAX] --seed S --out DIR "
         "[--preview]\n"
         "                       [--decoys] [--targets bop19|bop24]\n"
         "  --objects: annotated objects per scene (default 4-7)\n"
         "  --decoys: models/ also holds 3 look-alikes of each model (another print, 0.8x the size, other\n"
         "            colours), never placed: a catalogue for 6D detection\n"
         "  --targets bop24: test_targets_bop24.json (images only: 6D detection) instead of _bop19.json\n"
         "  --preview writes OUT/preview_{rgb,depth,masks}.png for scene 1, image 0\n"
         "  --mode video: 6-DoF scenes whose images are the frames of a hand-held camera circling the table\n"
         "                (1.5 deg per frame, shake, bursts of 4 deg per frame, its aim swinging 12 cm to "
         "the\n"
         "                sides) for perch2 track; in half the scenes an object is pushed 8 cm, in half a\n"
         "                hand-sized occluder crosses in front of an object (24 frames)\n";
  std::exit(2);
}

/// Reads scene 1, image 0 back from the dataset and writes pictures of its depth and visible masks.
void write_preview(const std::string& out) {
  namespace fs = std::filesystem;
  const fs::path scene = fs::path(out) / "test" / "000001";
  const perch2::ColorImage rgb = perch2::io::load_color_image((scene / "rgb" / "000000.png").string());
  const perch2::DepthImage depth = perch2::io::load_depth_png((scene / "depth" / "000000.png").string());
  perch2::LabelImage labels(rgb.width, rgb.height, 0);
  for (int k = 0;; ++k) {
    char name[32];
    std::snprintf(name, sizeof name, "000000_%06d.png", k);
    if (!fs::exists(scene / "mask_visib" / name)) break;
    const perch2::LabelImage m = perch2::io::load_label_png((scene / "mask_visib" / name).string());
    for (std::size_t p = 0; p < m.data.size(); ++p)
      if (m.data[p]) labels.data[p] = k + 1;
  }
  // Colour ramp over the 1st to 90th percentile of the readings (the far walls would flatten the table).
  std::vector<float> valid;
  for (float d : depth.data)
    if (d > 0) valid.push_back(d);
  std::sort(valid.begin(), valid.end());
  const float lo = valid.empty() ? 0.f : valid[valid.size() / 100];
  const float hi = valid.empty() ? 1.f : valid[valid.size() * 9 / 10];
  perch2::io::save_color_image(out + "/preview_rgb.png", rgb);
  perch2::io::save_color_image(out + "/preview_depth.png",
                               perch2::synth::depth_preview(depth, lo, std::max(hi, lo + 0.01f)));
  perch2::io::save_color_image(out + "/preview_masks.png", perch2::synth::label_overlay(rgb, labels));
}

}  // namespace

int run_generate(int argc, char** argv) {
  using namespace perch2::synth;
  DatasetSettings settings;
  std::string mode, models_dir, out;
  UserModelSettings user;
  bool have_seed = false, have_scenes = false, preview = false;
  for (int k = 2; k < argc; ++k) {
    const std::string a = argv[k];
    if (a == "--preview" || a == "--decoys") {
      (a == "--preview" ? preview : settings.decoys) = true;
      continue;
    }
    if (a == "-h" || a == "--help") generate_usage("writes a synthetic BOP dataset");
    if (k + 1 >= argc) generate_usage(a + " needs a value");
    const std::string v = argv[++k];
    try {
      if (a == "--mode")
        mode = v;
      else if (a == "--models")
        models_dir = v;
      else if (a == "--model-scale")
        user.scale = std::stof(v);
      else if (a == "--scenes")
        settings.num_scenes = std::stoi(v), have_scenes = true;
      else if (a == "--images-per-scene")
        settings.images_per_scene = std::stoi(v);
      else if (a == "--objects") {
        const auto dash = v.find('-');
        settings.scene.min_objects = std::stoi(v.substr(0, dash));
        settings.scene.max_objects =
            dash == std::string::npos ? settings.scene.min_objects : std::stoi(v.substr(dash + 1));
      } else if (a == "--seed")
        settings.seed = std::stoull(v), have_seed = true;
      else if (a == "--out")
        out = v;
      else if (a == "--targets") {
        if (v != "bop19" && v != "bop24") generate_usage("--targets must be bop19 or bop24, got " + v);
        settings.detection_targets = v == "bop24";
      } else
        generate_usage("unknown argument " + a);
    } catch (const std::logic_error&) {
      generate_usage("bad number for " + a + ": " + v);
    }
  }
  if (mode != "3dof" && mode != "6dof" && mode != "video")
    generate_usage("--mode must be 3dof, 6dof or video");
  if (!have_scenes || !have_seed || out.empty()) generate_usage("--scenes, --seed and --out are required");
  settings.scene.mode = mode == "3dof" ? Mode::ThreeDof : Mode::SixDof;
  if (mode ==
      "video") {  // the orbit with its events: an object pushed, an occluder, objects leaving the view
    settings.video = VideoSettings{};
    settings.video->look_at_swing_m = 0.12f;
    settings.video->push_probability = 0.5f;
    settings.video->occluder_probability = 0.5f;
    settings.scene.min_distractors = std::max(settings.scene.min_distractors, 1);
  }
  const std::vector<ObjectModel> models =
      models_dir.empty() ? builtin_models() : load_user_models(models_dir, user);

  const int total = settings.num_scenes * settings.images_per_scene;
  const DatasetSummary s = generate_dataset(models, settings, out, [&](int done, int all) {
    if (all >= 4) std::fprintf(stderr, "\r  image %d / %d (%.0f%%)", done, all, 100.0 * done / all);
    if (done == all && all >= 4) std::fprintf(stderr, "\n");
  });
  (void)total;
  if (preview) write_preview(out);
  std::printf("perch2 generate: %s, %d scenes x %d images, seed %llu -> %s (%.1f s)\n", mode.c_str(),
              s.scenes, settings.images_per_scene, static_cast<unsigned long long>(settings.seed),
              out.c_str(), s.seconds);
  int w = 6;  // name column width
  for (const auto& o : s.objects) w = std::max(w, int(o.name.size()));
  std::printf("  %-4s %-*s %9s %8s %9s %11s\n", "id", w, "object", "instances", "targets", "detected",
              "mean visib");
  for (const auto& o : s.objects)
    std::printf("  %-4d %-*s %9d %8d %9d %11.2f\n", o.obj_id, w, o.name.c_str(), o.instances, o.targets,
                o.detected, o.instances ? o.visible_fraction_sum / o.instances : 0.0);
  int detected = 0;
  double visib = 0;
  for (const auto& o : s.objects) detected += o.detected, visib += o.visible_fraction_sum;
  std::printf("  %-*s %9d %8d %9d %11.2f\n", w + 5, "all", s.instances, s.targets, detected,
              s.instances ? visib / s.instances : 0.0);
  std::printf("  %d detections (%d spurious, %d with a look-alike's label) in %s\n", s.detections, s.spurious,
              s.detections - s.spurious - detected, settings.detections_file.c_str());
  return 0;
}
