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
    const Eigen::Vector3f look = target + distance * look_shake.next(rng, v.shake_rad);
    out.push_back(look_at(eye, look));
  }
  return out;
}

}  // namespace perch2::synth
