// A hand-held orbit: azimuth advancing at a speed that bursts now and then, the eye and the look-at point
// shaken by smooth (first-order autoregressive) noise, the elevation swinging slowly.
#include "perch2/synth/video.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

#include "perch2/core/error.hpp"

namespace perch2::synth {

namespace {

constexpr float kPi = 3.14159265358979f;

/// Smooth noise: each call moves the state a step towards a fresh random value (correlation ~5 frames).
struct Shake {
  Eigen::Vector3f x = Eigen::Vector3f::Zero();
  Eigen::Vector3f next(Rng& rng, float sigma) {
    const float a = 0.8f;  // x_k = a x_{k-1} + sqrt(1 - a^2) sigma n_k: stationary sigma
    for (int i = 0; i < 3; ++i) x[i] = a * x[i] + std::sqrt(1.f - a * a) * sigma * rng.normal();
    return x;
  }
};

void check(const VideoSettings& v) {
  if (v.frames < 1) throw InvalidInput("VideoSettings::frames", "must be >= 1");
  auto finite_non_negative = [](float x) { return std::isfinite(x) && x >= 0.f; };
  if (!finite_non_negative(v.degrees_per_frame))
    throw InvalidInput("VideoSettings::degrees_per_frame", "must be finite and >= 0");
  if (!finite_non_negative(v.burst_degrees_per_frame))
    throw InvalidInput("VideoSettings::burst_degrees_per_frame", "must be finite and >= 0");
  if (!(v.burst_probability >= 0.f && v.burst_probability <= 1.f))
    throw InvalidInput("VideoSettings::burst_probability", "must be in [0, 1]");
  if (v.burst_frames < 0) throw InvalidInput("VideoSettings::burst_frames", "must be >= 0");
  if (!finite_non_negative(v.shake_m))
    throw InvalidInput("VideoSettings::shake_m", "must be finite and >= 0");
  if (!finite_non_negative(v.shake_rad))
    throw InvalidInput("VideoSettings::shake_rad", "must be finite and >= 0");
  if (!finite_non_negative(v.elevation_swing_rad))
    throw InvalidInput("VideoSettings::elevation_swing_rad", "must be finite and >= 0");
  if (!finite_non_negative(v.look_at_swing_m))
    throw InvalidInput("VideoSettings::look_at_swing_m", "must be finite and >= 0");
  if (!(v.push_probability >= 0.f && v.push_probability <= 1.f))
    throw InvalidInput("VideoSettings::push_probability", "must be in [0, 1]");
  if (!finite_non_negative(v.push_m)) throw InvalidInput("VideoSettings::push_m", "must be finite and >= 0");
  if (v.push_frames < 1) throw InvalidInput("VideoSettings::push_frames", "must be >= 1");
  if (!(v.occluder_probability >= 0.f && v.occluder_probability <= 1.f))
    throw InvalidInput("VideoSettings::occluder_probability", "must be in [0, 1]");
  if (v.occluder_frames < 1) throw InvalidInput("VideoSettings::occluder_frames", "must be >= 1");
  if (!(v.occluder_fraction > 0.f && v.occluder_fraction < 1.f))
    throw InvalidInput("VideoSettings::occluder_fraction", "must be in (0, 1)");
}

/// 0 before `start`, 1 after start + frames, a smooth step in between.
float progress(int f, int start, int frames) {
  const float t = std::clamp(float(f - start) / float(frames), 0.f, 1.f);
  return t * t * (3.f - 2.f * t);
}

/// A hand-sized box (8 wide, 18 high, 3 cm thick in the camera frame), skin-coloured, faintly textured.
const Mesh& occluder_mesh() {
  static const Mesh mesh = [] {
    ColorImage tex(8, 8);
    for (int v = 0; v < 8; ++v)
      for (int u = 0; u < 8; ++u) {
        const auto d = std::uint8_t(((u + v) % 3) * 6);
        tex(u, v) = Rgb8{std::uint8_t(214 - d), std::uint8_t(170 - d), std::uint8_t(140 - d)};
      }
    return textured_box({0.08f, 0.18f, 0.03f}, tex, 0.05f);
  }();
  return mesh;
}

}  // namespace

std::vector<Pose> camera_path(const SceneSettings& s, const VideoSettings& v, Rng& rng) {
  check(v);
  const float distance = rng.uniform(s.camera_min_distance_m, s.camera_max_distance_m);
  const float elevation = rng.uniform(s.camera_min_elevation_rad, s.camera_max_elevation_rad);
  float azimuth = rng.uniform(0.f, 2 * kPi);
  const float direction = rng.uniform() < 0.5 ? 1.f : -1.f;
  const float swing_phase = rng.uniform(0.f, 2 * kPi);
  const Eigen::Vector3f target(rng.uniform(-s.look_at_jitter_m, s.look_at_jitter_m),
                               rng.uniform(-s.look_at_jitter_m, s.look_at_jitter_m), s.look_at_height_m);
  Shake eye_shake, look_shake;
  int burst_left = 0;
  float speed = v.degrees_per_frame;
  std::vector<Pose> out;
  for (int f = 0; f < v.frames; ++f) {
    if (f > 0) {
      if (burst_left == 0 && rng.uniform() < v.burst_probability) burst_left = v.burst_frames;
      const float goal = burst_left > 0 ? v.burst_degrees_per_frame : v.degrees_per_frame;
      const float ramp = std::abs(v.burst_degrees_per_frame - v.degrees_per_frame) / 3.f;
      speed += std::clamp(goal - speed, -ramp, ramp);
      burst_left = std::max(0, burst_left - 1);
      azimuth += direction * speed * kPi / 180.f;
    }
    const float el =
        std::clamp(elevation + v.elevation_swing_rad * std::sin(0.05f * float(f) + swing_phase), 0.05f, 1.5f);
    const Eigen::Vector3f eye = target +
                                distance * Eigen::Vector3f(std::cos(el) * std::cos(azimuth),
                                                           std::cos(el) * std::sin(azimuth), std::sin(el)) +
                                eye_shake.next(rng, v.shake_m);
    const Eigen::Vector3f swing(-std::sin(azimuth), std::cos(azimuth), 0.f);  // sideways, seen from the eye
    const Eigen::Vector3f look = target + distance * look_shake.next(rng, v.shake_rad) +
                                 v.look_at_swing_m * std::sin(2 * kPi * float(f) / 120.f) * swing;
    out.push_back(look_at(eye, look));
  }
  return out;
}

VideoEvents draw_events(const Scene& scene, const VideoSettings& v, Rng& rng) {
  check(v);
  VideoEvents e;
  const int n = int(scene.objects.size());
  if (n == 0) return e;
  if (rng.uniform() < v.push_probability) {
    e.pushed = std::min(n - 1, int(rng.uniform() * float(n)));
    e.push_start = int(rng.uniform(0.2f, 0.6f) * float(v.frames));
    Eigen::Vector3f out = scene.objects[std::size_t(e.pushed)].T_world_obj.translation();
    out.z() = 0.f;
    if (out.norm() < 1e-3f) out = Eigen::Vector3f::UnitX();
    e.push_m = v.push_m * out.normalized();
  }
  if (rng.uniform() < v.occluder_probability) {
    e.occluded = std::min(n - 1, int(rng.uniform() * float(n)));
    e.occluder_start = int(rng.uniform(0.1f, 0.7f) * float(v.frames));
  }
  return e;
}

Scene scene_at(const Scene& scene, const VideoEvents& e, const VideoSettings& v, int f,
               const Pose& T_world_cam) {
  Scene out = scene;
  if (e.pushed >= 0)
    out.objects[std::size_t(e.pushed)].T_world_obj.translation() +=
        progress(f, e.push_start, v.push_frames) * e.push_m;
  if (e.occluded >= 0 && f >= e.occluder_start && f < e.occluder_start + v.occluder_frames) {
    // On the line of sight to the object (occluder_fraction of the way), crossing it sideways (camera x)
    // from 12 cm left to 12 cm right, upright in the camera's view.
    const Eigen::Vector3f eye = T_world_cam.translation();
    const Eigen::Vector3f to = out.objects[std::size_t(e.occluded)].T_world_obj.translation() - eye;
    const float t = (float(f - e.occluder_start) + 0.5f) / float(v.occluder_frames);
    Prop hand;
    hand.mesh = occluder_mesh();
    hand.T_world_obj = T_world_cam;  // box axes along the camera's: its 18 cm along the image's vertical
    hand.T_world_obj.translation() =
        eye + v.occluder_fraction * to + (0.24f * t - 0.12f) * T_world_cam.linear().col(0);
    out.distractors.push_back(std::move(hand));
  }
  return out;
}

}  // namespace perch2::synth
