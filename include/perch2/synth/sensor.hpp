// Rendering a composed scene as an RGB-D sensor would see it: perch2's renderer (one hypothesis per
// object, composited by nearest depth) for geometry, albedo and normals; Blinn-Phong shading from a random
// key light with shadows plus ambient light; camera exposure, white balance, vignetting, blur and noise;
// Kinect-like depth noise, quantisation and missing readings at depth edges, grazing angles, projector
// shadows and specular highlights.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "perch2/core/camera.hpp"
#include "perch2/core/export.hpp"
#include "perch2/core/image.hpp"
#include "perch2/synth/scene.hpp"

namespace perch2::synth {

using MaskImage = Image<std::uint8_t>;  ///< 0 or 255

struct SensorSettings {
  Intrinsics camera{615.f, 615.f, 319.5f, 239.5f, 640, 480};
  // Depth (Nguyen, Izadi, Lovell 2012): sigma(z) = a + b (z - z0)^2.
  float depth_noise_a_m = 0.0012f;      ///< axial noise at z0, metres
  float depth_noise_b_per_m = 0.0019f;  ///< growth, metres per metre^2
  float depth_noise_z0_m = 0.4f;        ///< metres
  float depth_scale_mm = 1.f;           ///< BOP depth_scale: one PNG unit in millimetres (quantisation step)
  float min_range_m = 0.35f, max_range_m = 4.f;  ///< no reading outside, metres
  float edge_jump_m = 0.02f;            ///< a neighbour farther by more than this makes a depth edge, metres
  float edge_dropout = 0.7f;            ///< chance a pixel next to a depth edge has no reading
  int edge_band_px = 2;                 ///< edge band half-width, pixels (widened at random by up to 1)
  float grazing_cos_full = 0.12f;       ///< |cos(view, normal)| below this: no reading
  float grazing_cos_none = 0.35f;       ///< above this: no grazing dropout (linear ramp in between)
  float projector_baseline_m = 0.075f;  ///< IR projector offset along +x: its shadows have no reading
  float specular_dropout = 0.5f;        ///< chance of no reading where the specular highlight saturates
  float specular_saturation = 0.8f;     ///< exposed highlight (linear) above which it counts as saturated
  float random_dropout = 0.003f;        ///< isolated missing pixels, fraction
  // Colour.
  float ambient_min = 0.25f, ambient_max = 0.45f;  ///< ambient light relative to the key light
  float light_min_elevation_rad = 0.6f, light_max_elevation_rad = 1.4f;
  float light_min_distance_m = 1.2f, light_max_distance_m = 2.5f;
  float shadow_bias_m = 0.004f;           ///< shadow-map depth bias, metres
  float shadow_slope_bias_m = 0.01f;      ///< extra bias where the light grazes (times 1 - cos), metres
  int shadow_map_size_px = 768;           ///< square shadow map rendered from the key light
  float shadow_map_half_extent_m = 0.6f;  ///< it covers +- this around the table centre, metres
  float light_colour_jitter = 0.1f;       ///< warm/cool tint: red and blue gains change by up to this
  float ambient_sky_fraction = 0.3f;      ///< part of the ambient light that comes from above (n . up)
  float exposure_target = 0.2f;           ///< auto exposure: mean linear luminance of the image
  float exposure_jitter = 0.25f;          ///< relative, uniform +-
  float white_balance_jitter = 0.08f;     ///< relative per-channel gain, uniform +-
  float vignetting = 0.25f;               ///< brightness loss at the image corners, fraction
  float blur_sigma_px = 0.6f;             ///< optics + demosaicing, pixels
  float shot_noise = 0.02f;               ///< sigma of sqrt(signal) noise (linear intensity in 0..1)
  float read_noise = 0.006f;              ///< sigma of additive noise (linear intensity)
};

/// One rendered frame with its ground truth.
struct Frame {
  Intrinsics camera;
  Pose T_world_cam = Pose::Identity();
  ColorImage rgb;                ///< the sensor's colour image
  DepthImage depth_m;            ///< the sensor's depth (noisy, quantised to depth_scale_mm, 0 = no reading)
  DepthImage true_depth_m;       ///< noiseless z-buffer of everything (0 = nothing)
  LabelImage visible;            ///< k + 1 where scene object k is the nearest surface; -(d + 1) distractor d
  std::vector<MaskImage> masks;  ///< per scene object: its whole silhouette in the image (mask/)
  std::vector<int> px_count_all;             ///< silhouette pixels, including the part outside the image
  std::vector<std::array<int, 4>> bbox_obj;  ///< x, y, w, h of the whole silhouette (may leave the image)
};

/// Renders one scene from many viewpoints (the meshes are uploaded once).
class PERCH2_API SceneRenderer {
 public:
  SceneRenderer(const std::vector<ObjectModel>& models, const Scene& scene);
  ~SceneRenderer();
  SceneRenderer(SceneRenderer&&) noexcept;

  /// A frame seen from T_world_cam; `rng` draws the light, camera response and sensor noise.
  Frame render(const Pose& T_world_cam, const SensorSettings& settings, Rng& rng) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Sensor settings check: InvalidInput naming the field.
PERCH2_API void validate(const SensorSettings& settings);

/// Per-corner shading normals as vertex colours: every triangle corner gets its own vertex whose colour
/// encodes (n + 1) / 2 of the area-weighted normal of the faces around it that bend by less than
/// `crease_rad` (so rims stay sharp and cylinders look round).
PERCH2_API Mesh normal_mesh(const Mesh& mesh, float crease_rad = 0.6f);

}  // namespace perch2::synth
