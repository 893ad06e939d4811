// Estimates the 3-DoF poses (x, y, yaw on the table) of known objects in one RGB-D frame with
// perch2::TabletopEstimator. The frame is synthesised here (perch2::synth: two cans of one shape with
// different labels and a bottle on a table); with a real camera, fill an RgbdFrame from your images instead.
// Exits 1 if an object is more than 2 cm from where it was placed (the example doubles as a test).
#include <algorithm>
#include <cstdio>
#include <string>

#include "perch2/cpu/estimators.hpp"
#include "perch2/search/tabletop.hpp"
#include "perch2/synth/synth.hpp"

int main(int argc, char** argv) try {
  using namespace perch2;
  // A scene with built-in models (obj_id 1, 3, 4), one of each, seen from a random viewpoint (seed 3).
  const std::vector<synth::ObjectModel> builtin = synth::builtin_models();
  const std::vector<synth::ObjectModel> cans{builtin[0], builtin[2], builtin[3]};  // cola, aqua, lime bottle
  synth::SceneSettings scene_settings;
  scene_settings.min_objects = scene_settings.max_objects = 3;
  scene_settings.duplicate_probability = 0.f;
  scene_settings.min_distractors = scene_settings.max_distractors = 0;
  synth::Rng rng(argc > 1 ? std::stoull(argv[1]) : 3);
  const synth::Scene scene = synth::compose_scene(cans, scene_settings, rng);
  const Pose T_world_cam = synth::sample_camera_pose(scene_settings, rng);
  const synth::Frame sensor = synth::SceneRenderer(cans, scene).render(T_world_cam, {}, rng);

  // --- the library use: models, one frame, the objects it shows, optionally the table frame ---
  std::vector<TabletopModel> models;
  for (const auto& c : cans) models.push_back({c.mesh, /*yaw_symmetric=*/false, std::nullopt});
  TabletopEstimator<cpu::Backend> estimator(models);  // PERCH 2.0-C, then polish and yaw search
  const RgbdFrame frame{sensor.camera, sensor.depth_m, sensor.rgb};
  const std::vector<ObjectCount> objects{{0, 1}, {1, 1}, {2, 1}};  // model index, instances
  const Pose T_cam_world = T_world_cam.inverse();  // omit to estimate the table plane from the depth
  const TabletopResult result = estimator.estimate(frame, objects, T_cam_world);
  for (const TabletopPose& p : result.poses)
    std::printf("%-10s x %.3f m  y %.3f m  yaw %6.1f deg  cost %.3f\n", cans[p.model].name.c_str(), p.x_m,
                p.y_m, p.yaw_rad * 57.2958f, p.cost.total);
  std::printf("%.2f s\n", result.timings.total);
  // ---

  int misplaced = 0;
  for (const TabletopPose& p : result.poses)
    for (const auto& o : scene.objects)
      if (o.model == p.model) {
        const float error_m = (p.T_world_obj.translation() - o.T_world_obj.translation()).norm();
        const long visible = std::count(sensor.visible.data.begin(), sensor.visible.data.end(), p.model + 1);
        std::printf("%-10s placed %.1f cm from the truth (%ld pixels visible)\n", cans[p.model].name.c_str(),
                    100 * error_m, visible);
        misplaced += error_m > 0.02f;
      }
  return misplaced == 0 && result.poses.size() == objects.size() ? 0 : 1;
} catch (const std::exception& e) {
  std::fprintf(stderr, "estimate_tabletop: %s\n", e.what());
  return 1;
}
