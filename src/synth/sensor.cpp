#include "perch2/synth/sensor.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <opencv2/imgproc.hpp>

#include "noise_field.hpp"
#include "perch2/cpu/render.hpp"
#include "perch2/synth/detections.hpp"

namespace perch2::synth {

namespace {

using Vec3 = Eigen::Vector3f;
constexpr float kPi = 3.14159265358979f;

float srgb_to_linear(float c) {
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}
float linear_to_srgb(float c) {
  return c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.f / 2.4f) - 0.055f;
}

/// What an instance is: scene object k, distractor d, or environment.
enum class Kind { Object, Distractor, Environment };

struct Instance {
  int mesh;  ///< albedo mesh index in the renderer; the normal mesh is mesh + num_meshes
  Pose T_world_obj;
  Material material;
  Kind kind;
  int index;  ///< k or d
};

/// Nearest-surface composite of some clouds of a batch.
struct Composite {
  std::vector<float> z;       ///< 0 = nothing
  std::vector<int> instance;  ///< -1 = nothing
  std::vector<Rgb8> colour;
  Composite(int n) : z(std::size_t(n), 0.f), instance(std::size_t(n), -1), colour(std::size_t(n)) {}
  void add(const CloudBatch& b, std::size_t cloud, int id) {
    for (auto i = b.offsets[cloud]; i < b.offsets[cloud + 1]; ++i) {
      const int p = b.pixel[i];
      if (z[p] == 0.f || b.z[i] < z[p]) z[p] = b.z[i], instance[p] = id, colour[p] = unpack_rgb(b.rgb[i]);
    }
  }
};

Vec3 decode_normal(Rgb8 c) {
  const Vec3 n(c.r / 127.5f - 1.f, c.g / 127.5f - 1.f, c.b / 127.5f - 1.f);
  const float len = n.norm();
  return len > 1e-3f ? Vec3(n / len) : Vec3(0, 0, -1);
}

}  // namespace

void validate(const SensorSettings& s) {
  s.camera.validate("SensorSettings::camera");
  auto need = [](bool ok, const char* field, const char* why) {
    if (!ok) throw InvalidInput(std::string("SensorSettings::") + field, why);
  };
  need(s.depth_noise_a_m >= 0 && s.depth_noise_b_per_m >= 0, "depth_noise_a_m", "noise terms must be >= 0");
  need(s.depth_scale_mm > 0 && s.depth_scale_mm <= 10, "depth_scale_mm", "must be in (0, 10]");
  need(s.min_range_m >= 0 && s.max_range_m > s.min_range_m, "min_range_m", "need 0 <= min < max");
  need(s.max_range_m * 1000.f / s.depth_scale_mm <= 65535.f, "max_range_m",
       "max range does not fit a 16-bit PNG at this depth_scale_mm");
  need(s.edge_band_px >= 0, "edge_band_px", "must be >= 0");
  need(s.grazing_cos_none > s.grazing_cos_full, "grazing_cos_none", "must exceed grazing_cos_full");
  need(s.ambient_min >= 0 && s.ambient_max >= s.ambient_min, "ambient_min", "need 0 <= min <= max");
  need(s.light_min_distance_m > 0 && s.light_max_distance_m >= s.light_min_distance_m, "light_min_distance_m",
       "need 0 < min <= max");
  need(s.shadow_map_size_px >= 16 && s.shadow_map_half_extent_m > 0, "shadow_map_size_px",
       "need >= 16 pixels and a positive extent");
  need(s.exposure_target > 0 && s.exposure_target < 1, "exposure_target", "must be in (0, 1)");
  need(s.blur_sigma_px >= 0 && s.shot_noise >= 0 && s.read_noise >= 0, "blur_sigma_px", "must be >= 0");
}

Mesh normal_mesh(const Mesh& mesh, float crease_rad) {
  mesh.validate();
  const std::size_t nt = mesh.triangles.size();
  std::vector<Vec3> face_n(nt);  // area-weighted
  for (std::size_t t = 0; t < nt; ++t) {
    const auto& f = mesh.triangles[t];
    face_n[t] = (mesh.vertices[f[1]] - mesh.vertices[f[0]]).cross(mesh.vertices[f[2]] - mesh.vertices[f[0]]);
  }
  // Corners grouped by position (texture seams duplicate vertices at one place).
  std::map<std::array<std::int64_t, 3>, std::vector<std::size_t>> groups;
  auto key = [&](const Vec3& v) {
    return std::array<std::int64_t, 3>{std::llround(v.x() * 1e6), std::llround(v.y() * 1e6),
                                       std::llround(v.z() * 1e6)};
  };
  for (std::size_t t = 0; t < nt; ++t)
    for (int c = 0; c < 3; ++c) groups[key(mesh.vertices[mesh.triangles[t][c]])].push_back(t);
  const float cos_crease = std::cos(crease_rad);
  Mesh out;
  out.name = mesh.name + "_normals";
  for (std::size_t t = 0; t < nt; ++t) {
    const Vec3 own = face_n[t].normalized();
    for (int c = 0; c < 3; ++c) {
      const Vec3& v = mesh.vertices[mesh.triangles[t][c]];
      Vec3 n = Vec3::Zero();
      for (std::size_t u : groups[key(v)])
        if (face_n[u].normalized().dot(own) >= cos_crease) n += face_n[u];
      n = n.norm() > 0 ? Vec3(n.normalized()) : own;
      out.vertices.push_back(v);
      auto enc = [](float x) { return std::uint8_t(std::clamp(std::lround((x + 1.f) * 127.5f), 0L, 255L)); };
      out.vertex_colors.push_back({enc(n.x()), enc(n.y()), enc(n.z())});
    }
    out.triangles.emplace_back(int(3 * t), int(3 * t + 1), int(3 * t + 2));
  }
  return out;
}

/// The nearest surface at every pixel: which instance, its camera-frame point and shading normal.
struct Surfaces {
  Composite nearest;
  std::vector<Vec3> point, normal;
  explicit Surfaces(int n)
      : nearest(n), point(std::size_t(n), Vec3::Zero()), normal(std::size_t(n), Vec3(0, 0, -1)) {}
};

/// Linear-light image before the camera, and the specular part of it (for depth dropouts).
struct Radiance {
  cv::Mat linear;  ///< CV_32FC3
  std::vector<float> highlight;
};

struct SceneRenderer::Impl {
  std::unique_ptr<cpu::Renderer> renderer;
  std::vector<Instance> instances;
  std::vector<Eigen::AlignedBox3f> object_boxes;  ///< per scene object, object frame
  int num_meshes = 0, num_objects = 0;

  /// Renders instances `ids` (albedo or normal meshes) from camera T_world_cam with intrinsics K.
  CloudBatch render(const std::vector<int>& ids, bool normals, const Pose& T_world_cam,
                    const Intrinsics& K) const {
    const Pose T_cam_world = T_world_cam.inverse();
    std::vector<Hypothesis> hyps;
    for (int i : ids)
      hyps.push_back(
          {instances[i].mesh + (normals ? num_meshes : 0), T_cam_world * instances[i].T_world_obj});
    RenderSettings rs;
    rs.stride = 1;
    return renderer->render(hyps, K, rs);
  }

  /// Every instance rendered twice (albedo, normals) and composited by nearest depth; fills the frame's
  /// true depth, visible labels and whole-object masks.
  Surfaces surfaces(Frame& f) const {
    const Intrinsics& K = f.camera;
    const int W = K.width, N = K.num_pixels(), num_inst = int(instances.size());
    const Pose T_cam_world = f.T_world_cam.inverse();
    std::vector<int> all(num_inst);
    for (int i = 0; i < num_inst; ++i) all[i] = i;
    const CloudBatch albedo = render(all, false, f.T_world_cam, K);
    const CloudBatch normals = render(all, true, f.T_world_cam, K);
    Surfaces out(N);
    Composite shading(N);
    f.masks.assign(num_objects, MaskImage(W, K.height, 0));
    for (int i = 0; i < num_inst; ++i) {
      out.nearest.add(albedo, i, i), shading.add(normals, i, i);
      if (instances[i].kind == Kind::Object)
        for (auto p = albedo.offsets[i]; p < albedo.offsets[i + 1]; ++p)
          f.masks[i].data[albedo.pixel[p]] = 255;
    }
    f.true_depth_m = DepthImage(W, K.height, 0.f);
    f.visible = LabelImage(W, K.height, 0);
    for (int p = 0; p < N; ++p) {
      const int i = out.nearest.instance[p];
      if (i < 0) continue;
      f.true_depth_m.data[p] = out.nearest.z[p];
      const Instance& in = instances[i];
      f.visible.data[p] = in.kind == Kind::Object       ? in.index + 1
                          : in.kind == Kind::Distractor ? -(in.index + 1)
                                                        : 0;
      const Vec3f q = K.backproject(float(p % W), float(p / W), out.nearest.z[p]);
      out.point[p] = Vec3(q.x, q.y, q.z);
      const int j = shading.instance[p] >= 0 ? shading.instance[p] : i;
      const Eigen::Matrix3f R_cam_obj = T_cam_world.linear() * instances[j].T_world_obj.linear();
      Vec3 n = R_cam_obj * decode_normal(shading.colour[p]);
      if (n.dot(out.point[p]) > 0) n = -n;  // face the camera
      out.normal[p] = n;
    }
    return out;
  }

  /// px_count_all and bbox_obj: from the mask when the object lies inside the image, else from a render on a
  /// canvas three times the image (BOP counts the truncated part too).
  void silhouettes(Frame& f) const {
    const Intrinsics& K = f.camera;
    const int W = K.width, H = K.height;
    const Pose T_cam_world = f.T_world_cam.inverse();
    f.px_count_all.assign(num_objects, 0);
    f.bbox_obj.assign(num_objects, {-1, -1, -1, -1});
    std::vector<int> truncated;
    for (int k = 0; k < num_objects; ++k) {
      const Pose T = T_cam_world * instances[k].T_world_obj;
      bool inside = true;
      for (int c = 0; c < 8; ++c) {
        const Vec3 v = T * object_boxes[k].corner(Eigen::AlignedBox3f::CornerType(c));
        const float u = K.fx * v.x() / v.z() + K.cx, w = K.fy * v.y() / v.z() + K.cy;
        inside = inside && v.z() > 0 && u >= 0 && w >= 0 && u <= W - 1 && w <= H - 1;
      }
      if (!inside) {
        truncated.push_back(k);
        continue;
      }
      for (const std::uint8_t m : f.masks[k].data) f.px_count_all[k] += m != 0;
      f.bbox_obj[k] = mask_bbox(f.masks[k]);
    }
    if (truncated.empty()) return;
    const Intrinsics big{K.fx, K.fy, K.cx + W, K.cy + H, 3 * W, 3 * H};
    const CloudBatch c = render(truncated, false, f.T_world_cam, big);
    for (std::size_t t = 0; t < truncated.size(); ++t) {
      const int k = truncated[t];
      int x0 = 1 << 30, y0 = 1 << 30, x1 = -(1 << 30), y1 = -(1 << 30);
      f.px_count_all[k] = int(c.cloud_size(t));
      for (auto i = c.offsets[t]; i < c.offsets[t + 1]; ++i) {
        const int u = c.pixel[i] % big.width - W, v = c.pixel[i] / big.width - H;
        x0 = std::min(x0, u), x1 = std::max(x1, u), y0 = std::min(y0, v), y1 = std::max(y1, v);
      }
      if (f.px_count_all[k] > 0) f.bbox_obj[k] = {x0, y0, x1 - x0, y1 - y0};
    }
  }

  /// Blinn-Phong shading from a random key light (shadow-mapped over objects and distractors) plus ambient.
  Radiance shade(const Surfaces& sf, const Pose& T_world_cam, const SensorSettings& s, Rng& rng) const {
    const int W = s.camera.width, H = s.camera.height, N = W * H;
    const Pose T_cam_world = T_world_cam.inverse();
    const float az = rng.uniform(0.f, 2 * kPi);
    const float el = rng.uniform(s.light_min_elevation_rad, s.light_max_elevation_rad);
    const float dist = rng.uniform(s.light_min_distance_m, s.light_max_distance_m);
    const Vec3 light_world =
        dist * Vec3(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
    const float warmth = rng.uniform(-1.f, 1.f);
    const Vec3 light_colour(1.f + s.light_colour_jitter * warmth, 1.f, 1.f - s.light_colour_jitter * warmth);
    const float ambient = rng.uniform(s.ambient_min, s.ambient_max);
    const Pose T_world_light = look_at(light_world, Vec3(0, 0, 0.05f));
    const Pose T_light_cam = T_world_light.inverse() * T_world_cam;
    const float half = 0.5f * float(s.shadow_map_size_px);
    const float light_f = half * dist / s.shadow_map_half_extent_m;
    const Intrinsics light_K{
        light_f, light_f, half - 0.5f, half - 0.5f, s.shadow_map_size_px, s.shadow_map_size_px};
    std::vector<int> casters;
    for (int i = 0; i < int(instances.size()); ++i)
      if (instances[i].kind != Kind::Environment) casters.push_back(i);
    Composite shadow_map(light_K.num_pixels());
    if (!casters.empty()) {
      const CloudBatch c = render(casters, false, T_world_light, light_K);
      for (std::size_t t = 0; t < casters.size(); ++t) shadow_map.add(c, t, int(t));
    }
    auto lit_fraction = [&](const Vec3& p_cam, float bias) {
      const Vec3 q = T_light_cam * p_cam;
      if (q.z() <= 0) return 1.f;
      const int u = int(std::lround(light_K.fx * q.x() / q.z() + light_K.cx));
      const int v = int(std::lround(light_K.fy * q.y() / q.z() + light_K.cy));
      // Percentage-closer filtering over 5 x 5 texels: soft shadow edges of a light a few centimetres wide.
      int lit = 0, total = 0;
      for (int dv = -2; dv <= 2; ++dv)
        for (int du = -2; du <= 2; ++du, ++total) {
          const int x = u + du, y = v + dv;
          if (x < 0 || y < 0 || x >= light_K.width || y >= light_K.height) {
            ++lit;
            continue;
          }
          const float zs = shadow_map.z[std::size_t(y) * light_K.width + x];
          lit += !(zs > 0 && zs < q.z() - bias);
        }
      return float(lit) / total;
    };
    const Vec3 light_cam = T_cam_world * light_world;
    const Vec3 up_cam = T_cam_world.linear() * Vec3::UnitZ();
    Radiance out{cv::Mat(H, W, CV_32FC3, cv::Scalar(0.015, 0.015, 0.018)), std::vector<float>(N, 0.f)};
    float lut[256];
    for (int c = 0; c < 256; ++c) lut[c] = srgb_to_linear(c / 255.f);
    for (int p = 0; p < N; ++p) {
      const int i = sf.nearest.instance[p];
      if (i < 0) continue;
      const Vec3 &P = sf.point[p], &n = sf.normal[p];
      const Vec3 L = (light_cam - P).normalized(), V = -P.normalized();
      const float ndl = std::max(0.f, n.dot(L));
      const float vis =
          ndl > 0 ? lit_fraction(P, s.shadow_bias_m + s.shadow_slope_bias_m * (1.f - ndl)) : 0.f;
      const Material& mat = instances[i].material;
      const float spec =
          ndl > 0 ? mat.specular * std::pow(std::max(0.f, n.dot((L + V).normalized())), mat.shininess) : 0.f;
      const float amb =
          ambient * (1.f - s.ambient_sky_fraction + s.ambient_sky_fraction * std::max(0.f, n.dot(up_cam)));
      const Rgb8 a = sf.nearest.colour[p];
      const Vec3 albedo_lin(lut[a.r], lut[a.g], lut[a.b]);
      const Vec3 c =
          albedo_lin * amb + (albedo_lin * ndl + Vec3::Constant(spec)).cwiseProduct(light_colour) * vis;
      out.highlight[p] = spec * vis;
      out.linear.at<cv::Vec3f>(p / W, p % W) = {c.x(), c.y(), c.z()};
    }
    return out;
  }
};

namespace {

/// The camera: auto exposure with jitter, white balance, blur, vignetting, shot and read noise, sRGB.
/// Returns the image; `gain` is the exposure applied (linear).
ColorImage expose(cv::Mat linear, const SensorSettings& s, Rng& rng, float& gain) {
  const int W = s.camera.width, H = s.camera.height;
  const cv::Scalar mean = cv::mean(linear);
  const float luminance = float(0.2126 * mean[0] + 0.7152 * mean[1] + 0.0722 * mean[2]);
  gain = s.exposure_target / std::max(luminance, 1e-4f) *
         (1.f + rng.uniform(-s.exposure_jitter, s.exposure_jitter));
  const Vec3 wb(1.f + rng.uniform(-s.white_balance_jitter, s.white_balance_jitter), 1.f,
                1.f + rng.uniform(-s.white_balance_jitter, s.white_balance_jitter));
  if (s.blur_sigma_px > 0) cv::GaussianBlur(linear, linear, {0, 0}, s.blur_sigma_px);
  ColorImage rgb(W, H);
  const float r_max2 = float(W * W + H * H) / 4.f;
  for (int p = 0; p < W * H; ++p) {
    const int u = p % W, v = p / W;
    const float r2 = (float(u - W / 2) * (u - W / 2) + float(v - H / 2) * (v - H / 2)) / r_max2;
    const cv::Vec3f c = linear.at<cv::Vec3f>(v, u);
    std::uint8_t out[3];
    for (int ch = 0; ch < 3; ++ch) {
      float x = c[ch] * gain * wb[ch] * (1.f - s.vignetting * r2);
      x += std::sqrt(s.shot_noise * s.shot_noise * std::max(x, 0.f) + s.read_noise * s.read_noise) *
           rng.normal();
      out[ch] = std::uint8_t(std::lround(255.f * linear_to_srgb(std::clamp(x, 0.f, 1.f))));
    }
    rgb.data[p] = {out[0], out[1], out[2]};
  }
  return rgb;
}

/// Pixels next to a depth jump (or to no surface), widened to a band of `band` pixels.
cv::Mat depth_edges(const std::vector<float>& z, int W, int H, float jump_m, int band) {
  cv::Mat edge(H, W, CV_8U, cv::Scalar(0));
  for (int v = 0; v < H; ++v)
    for (int u = 0; u < W; ++u) {
      const float a = z[v * W + u];
      auto jump = [&](int x, int y) {
        if (x < 0 || y < 0 || x >= W || y >= H) return false;
        const float b = z[y * W + x];
        return (a > 0) != (b > 0) || std::abs(a - b) > jump_m;
      };
      if (jump(u + 1, v) || jump(u, v + 1)) edge.at<uchar>(v, u) = 255;
    }
  if (band > 0)
    cv::dilate(edge, edge, cv::getStructuringElement(cv::MORPH_ELLIPSE, {2 * band + 1, 2 * band + 1}));
  return edge;
}

/// Points the IR projector (offset by `shift` = fx * baseline along +x) cannot light: scanning each row from
/// the right, a point whose projector column is not left of every point seen so far is hidden from it.
std::vector<char> projector_shadows(const std::vector<float>& z, int W, int H, float shift) {
  std::vector<char> shadowed(z.size(), 0);
  for (int v = 0; v < H; ++v) {
    float running_min = 1e30f;
    for (int u = W - 1; u >= 0; --u) {
      const float d = z[v * W + u];
      if (d <= 0) continue;
      const float up = float(u) - shift / d;  // the column the projector lights this point from
      if (up >= running_min) shadowed[v * W + u] = 1;
      running_min = std::min(running_min, up);
    }
  }
  return shadowed;
}

/// The depth sensor: missing readings (edges, grazing angles, projector shadows, saturated highlights,
/// range, random), axial noise sigma(z), quantisation to depth_scale_mm.
DepthImage sense_depth(const Surfaces& sf, const Radiance& r, float gain, const SensorSettings& s, Rng& rng) {
  const int W = s.camera.width, H = s.camera.height;
  const std::vector<float>& z = sf.nearest.z;
  const cv::Mat edge = depth_edges(z, W, H, s.edge_jump_m, s.edge_band_px + rng.integer(0, 1));
  const cv::Mat blotches = detail::smooth_noise(W, H, 6, rng);
  const std::vector<char> shadowed = projector_shadows(z, W, H, s.camera.fx * s.projector_baseline_m);
  DepthImage depth(W, H, 0.f);
  const float unit_m = 0.001f * s.depth_scale_mm;
  for (int p = 0; p < W * H; ++p) {
    const float d = z[p];
    const float r_drop = float(rng.uniform()),
                r_noise = rng.normal();  // drawn for every pixel: stable streams
    if (d <= 0 || d < s.min_range_m || d > s.max_range_m || shadowed[p]) continue;
    if (edge.data[p] && blotches.at<float>(p / W, p % W) < s.edge_dropout) continue;
    const float cos_view = std::abs(sf.normal[p].dot(sf.point[p].normalized()));
    const float grazing =
        std::clamp((s.grazing_cos_none - cos_view) / (s.grazing_cos_none - s.grazing_cos_full), 0.f, 1.f);
    if (r_drop < grazing) continue;
    if (r.highlight[p] * gain > s.specular_saturation && r_drop < s.specular_dropout) continue;
    if (r_drop > 1.f - s.random_dropout) continue;
    const float sigma =
        s.depth_noise_a_m + s.depth_noise_b_per_m * (d - s.depth_noise_z0_m) * (d - s.depth_noise_z0_m);
    depth.data[p] = std::max(0.f, std::round((d + sigma * r_noise) / unit_m)) * unit_m;
  }
  return depth;
}

}  // namespace

SceneRenderer::SceneRenderer(const std::vector<ObjectModel>& models, const Scene& scene)
    : impl_(std::make_unique<Impl>()) {
  std::vector<Mesh> meshes;
  std::vector<Material> materials;
  for (const auto& m : models) meshes.push_back(m.mesh), materials.push_back(m.material);
  for (std::size_t k = 0; k < scene.objects.size(); ++k) {
    const int m = scene.objects[k].model;
    if (m < 0 || std::size_t(m) >= models.size())
      throw InvalidInput("scene object " + std::to_string(k), "model index out of range");
    impl_->instances.push_back({m, scene.objects[k].T_world_obj, models[m].material, Kind::Object, int(k)});
    impl_->object_boxes.push_back(models[m].mesh.bounds());
  }
  auto add_props = [&](const std::vector<Prop>& props, Kind kind) {
    for (std::size_t d = 0; d < props.size(); ++d) {
      impl_->instances.push_back({int(meshes.size()), props[d].T_world_obj, props[d].material, kind, int(d)});
      meshes.push_back(props[d].mesh);
    }
  };
  add_props(scene.distractors, Kind::Distractor);
  add_props(scene.environment, Kind::Environment);
  impl_->num_meshes = int(meshes.size());
  impl_->num_objects = int(scene.objects.size());
  for (int i = 0, n = impl_->num_meshes; i < n; ++i) meshes.push_back(normal_mesh(meshes[i]));
  impl_->renderer = std::make_unique<cpu::Renderer>(std::move(meshes));
}

SceneRenderer::~SceneRenderer() = default;
SceneRenderer::SceneRenderer(SceneRenderer&&) noexcept = default;

Frame SceneRenderer::render(const Pose& T_world_cam, const SensorSettings& s, Rng& rng) const {
  validate(s);
  if (!is_valid_pose(T_world_cam)) throw InvalidInput("T_world_cam", "is not a finite rigid transform");
  Frame f;
  f.camera = s.camera, f.T_world_cam = T_world_cam;
  const Surfaces sf = impl_->surfaces(f);
  impl_->silhouettes(f);
  const Radiance r = impl_->shade(sf, T_world_cam, s, rng);
  float gain = 1.f;
  f.rgb = expose(r.linear.clone(), s, rng, gain);
  f.depth_m = sense_depth(sf, r, gain, s, rng);
  return f;
}

}  // namespace perch2::synth
