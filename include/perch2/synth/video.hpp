// Synthetic RGB-D sequences for tracking: a hand-held camera circling a table (a smooth orbit with
// shake, now and then a faster burst), rendered frame by frame by SceneRenderer.
#pragma once

#include <vector>

#include "perch2/core/export.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/synth/random.hpp"
#include "perch2/synth/scene.hpp"

namespace perch2::synth {

struct VideoSettings {
  int frames = 120;                     ///< frames of the sequence, >= 1
  float degrees_per_frame = 1.5f;       ///< the orbit's speed about the table's vertical axis, degrees
  float burst_degrees_per_frame = 4.f;  ///< its speed during a burst, degrees
  float burst_probability = 0.02f;      ///< chance per frame that a burst starts, in [0, 1]
  int burst_frames = 10;                ///< frames a burst lasts (speed ramps over 3 frames each way)
  float shake_m = 0.002f;               ///< hand-held shake: smooth random offsets of the eye, metres (sigma)
  float shake_rad = 0.004f;             ///< ... and of the viewing direction, radians (sigma)
  float elevation_swing_rad = 0.08f;    ///< a slow up-and-down of the elevation, radians (amplitude)
};

/// Camera poses T_world_cam, one per frame, circling the table of `scene` settings' camera ranges: the
/// distance, elevation and start azimuth drawn as sample_camera_pose() draws them, then the orbit at
/// VideoSettings' speed with shake and bursts. InvalidInput on bad settings.
PERCH2_API std::vector<Pose> camera_path(const SceneSettings& scene, const VideoSettings& video, Rng& rng);

}  // namespace perch2::synth
