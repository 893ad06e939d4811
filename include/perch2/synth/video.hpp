// Synthetic RGB-D sequences for tracking: a hand-held camera circling a table (a smooth orbit with
// shake, now and then a faster burst, its aim swinging so that objects leave the view and come back),
// and what happens on the table meanwhile (an object pushed along it, a hand-sized occluder passing in
// front of an object), rendered frame by frame by SceneRenderer.
#pragma once

#include <Eigen/Core>
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
  /// A slow sideways swing of the look-at point (objects near the edge leave the view and come back),
  /// metres (amplitude; period 120 frames).
  float look_at_swing_m = 0.f;
  // ---- events (video_scenes)
  float push_probability = 0.f;      ///< chance that one object is pushed along the table, in [0, 1]
  float push_m = 0.08f;              ///< how far, metres (outwards from the table's centre)
  int push_frames = 20;              ///< over how many frames (smooth start and stop), >= 1
  float occluder_probability = 0.f;  ///< chance that an occluder passes in front of one object, in [0, 1]
  int occluder_frames = 24;          ///< frames it takes to cross, >= 1
  /// Where it passes: this fraction of the way from the camera to the object, in (0, 1) (0.6: 36 cm at a
  /// camera 60 cm away, beyond a Kinect's 35 cm minimum range).
  float occluder_fraction = 0.6f;
};

/// Turns VideoSettings' probabilities into what happens: each event's frames and object (-1: none).
struct VideoEvents {
  int pushed = -1, push_start = 0;
  Eigen::Vector3f push_m = Eigen::Vector3f::Zero();  ///< world-frame displacement at the end of the push
  int occluded = -1, occluder_start = 0;
};
PERCH2_API VideoEvents draw_events(const Scene& scene, const VideoSettings& video, Rng& rng);

/// The scene at frame f of a video: the pushed object moved as far as the push has gone, the occluder (a
/// hand-sized skin-coloured box, a distractor) between the camera `T_world_cam` and the occluded object,
/// crossing the line of sight from side to side over its frames.
PERCH2_API Scene scene_at(const Scene& scene, const VideoEvents& events, const VideoSettings& video, int f,
                          const Pose& T_world_cam);

/// Camera poses T_world_cam, one per frame, circling the table of `scene` settings' camera ranges: the
/// distance, elevation and start azimuth drawn as sample_camera_pose() draws them, then the orbit at
/// VideoSettings' speed with shake and bursts. InvalidInput on bad settings.
PERCH2_API std::vector<Pose> camera_path(const SceneSettings& scene, const VideoSettings& video, Rng& rng);

}  // namespace perch2::synth
