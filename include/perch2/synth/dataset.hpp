// Writing a complete synthetic BOP dataset (bop_toolkit docs/bop_datasets_format.md):
//   OUT/camera.json, OUT/test_targets_bop19.json, OUT/models/{obj_XXXXXX.ply, models_info.json},
//   OUT/test/SSSSSS/{scene_camera.json, scene_gt.json, scene_gt_info.json, rgb/, depth/, mask/, mask_visib/},
//   OUT/detections_synth.json (BOP/COCO detection list with degraded masks, see detections.hpp).
// Units as BOP: millimetres for models and translations, depth PNG value * depth_scale = mm, cam_K and all
// rotations row-major; the world frame (cam_R_w2c, cam_t_w2c) is the table frame, z up, table top z = 0.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "perch2/core/export.hpp"
#include "perch2/synth/detections.hpp"
#include "perch2/synth/scene.hpp"
#include "perch2/synth/sensor.hpp"
#include "perch2/synth/video.hpp"

namespace perch2::synth {

struct DatasetSettings {
  int num_scenes = 1;  ///< scenes first_scene ... (each a different arrangement), >= 1
  /// The first scene's id (>= 1). Scene s depends only on (seed, s), so scene 18 of a seed can be had
  /// without generating scenes 1 to 17.
  int first_scene = 1;
  int images_per_scene = 4;  ///< viewpoints per scene (image ids 0 ...), >= 1
  std::uint64_t seed = 0;    ///< everything is a function of the seed; scene s depends only on (seed, s)
  std::string split = "test";
  std::string detections_file = "detections_synth.json";
  float target_min_visible_fraction = 0.1f;  ///< BOP'19 targets: instances at least this visible
  /// models/ also holds make_decoys() of the models (obj_ids after the largest), which are never placed:
  /// a catalogue of look-alikes for 6D detection.
  bool decoys = false;
  /// Write BOP 2024's test_targets_bop24.json (the images only: 6D detection, nothing said about what is
  /// in them) instead of test_targets_bop19.json.
  bool detection_targets = false;
  SceneSettings scene;
  SensorSettings sensor;
  DetectionSettings detection;
  /// Set: each scene is a video, its images the frames of a hand-held camera's path around the table
  /// (camera_path; VideoSettings::frames is images_per_scene) instead of independent viewpoints.
  std::optional<VideoSettings> video;
};

/// Per-object counts over the dataset (for the summary table).
struct ObjectSummary {
  int obj_id = 0;
  std::string name;
  int instances = 0, targets = 0, detected = 0;
  double visible_fraction_sum = 0;  ///< over all instances
};

struct DatasetSummary {
  int scenes = 0, images = 0, instances = 0, targets = 0, detections = 0, spurious = 0;
  std::vector<ObjectSummary> objects;
  double seconds = 0;
};

/// Writes the dataset into `out_dir` (created; existing files are overwritten). `progress(done, total)`
/// is called after each image. InvalidInput for bad settings or no models; FileError if writing fails.
PERCH2_API DatasetSummary generate_dataset(const std::vector<ObjectModel>& models,
                                           const DatasetSettings& settings, const std::string& out_dir,
                                           const std::function<void(int, int)>& progress = {});

}  // namespace perch2::synth
