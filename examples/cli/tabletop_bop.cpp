#include "tabletop_bop.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <variant>

#include "perch2/cpu/backend.hpp"
#include "perch2/cuda/backend.hpp"

namespace perch2::cli {

BackendKind parse_backend(const std::string& name) {
  if (name == "cpu") return BackendKind::Cpu;
  if (name == "thrust_omp") return BackendKind::ThrustOmp;
  throw InvalidInput("--backend", "unknown backend '" + name + "' (cpu|thrust_omp)");
}

const char* backend_name(BackendKind b) {
  return b == BackendKind::Cpu ? "cpu" : "thrust_omp";
}

namespace {
constexpr std::pair<const char*, SearchVariant> kVariants[] = {
    {"perch2c", SearchVariant::Perch2C},       {"perch2a", SearchVariant::Perch2A},
    {"perch2b", SearchVariant::Perch2B},       {"perch", SearchVariant::Perch},
    {"depth-only", SearchVariant::DepthOnlyC}, {"bf-icp", SearchVariant::BfIcp},
};
}  // namespace

SearchVariant parse_variant(const std::string& name) {
  for (const auto& [n, v] : kVariants)
    if (name == n) return v;
  throw InvalidInput("--variant", "unknown variant '" + name + "' (" + kVariantNames + ")");
}

const char* variant_name(SearchVariant v) {
  for (const auto& [n, w] : kVariants)
    if (v == w) return n;
  return "?";
}

void StageTimes::add(const TabletopTimings& t) {
  sum.table += t.table, sum.observed += t.observed, sum.hypotheses += t.hypotheses, sum.render += t.render;
  sum.refine += t.refine, sum.cost += t.cost, sum.select += t.select, sum.yaw += t.yaw, sum.total += t.total;
  ++images;
}

void StageTimes::print(std::FILE* out, const char* indent) const {
  const std::pair<const char*, double> stages[] = {
      {"table", sum.table},   {"observed", sum.observed}, {"hypotheses", sum.hypotheses},
      {"render", sum.render}, {"refine", sum.refine},     {"cost", sum.cost},
      {"select", sum.select}, {"yaw", sum.yaw},           {"total", sum.total}};
  const double n = std::max(images, 1);
  std::fprintf(out, "%s%-11s %10s %12s %7s\n", indent, "stage", "total s", "s / image", "share");
  for (const auto& [name, s] : stages)
    std::fprintf(out, "%s%-11s %10.3f %12.3f %6.1f%%\n", indent, name, s, s / n,
                 sum.total > 0 ? 100 * s / sum.total : 0.0);
}

std::map<std::pair<int, int>, std::vector<dataset::Target>> targets_by_image(const dataset::BopDataset& data,
                                                                             int first_scene,
                                                                             int last_scene) {
  std::map<std::pair<int, int>, std::vector<dataset::Target>> out;
  for (const auto& t : data.targets())
    if (t.scene_id >= first_scene && t.scene_id <= last_scene && t.inst_count > 0)
      out[{t.scene_id, t.im_id}].push_back(t);
  return out;
}

namespace {

/// A continuous symmetry about the model's z axis through its origin: the model looks the same at every yaw.
bool symmetric_about_z(const dataset::ModelInfo& info) {
  for (const auto& s : info.symmetries_continuous) {
    const Eigen::Vector3f a = s.axis.normalized();
    if (std::abs(std::abs(a.z()) - 1.f) < 1e-3f && s.offset_m.head<2>().norm() < 1e-3f) return true;
  }
  return false;
}

template <class Backend>
using EstimatorPtr = std::unique_ptr<TabletopEstimator<Backend>>;

}  // namespace

struct BopTabletop::Impl {
  std::variant<EstimatorPtr<cpu::Backend>, EstimatorPtr<thrust_omp::Backend>> estimator;
};

BopTabletop::BopTabletop(const dataset::BopDataset& data, const std::vector<int>& obj_ids,
                         SearchVariant variant, BackendKind backend, TabletopSettings base)
    : obj_ids_(obj_ids), impl_(std::make_unique<Impl>()) {
  if (obj_ids_.empty()) throw InvalidInput("dataset " + data.root(), "no target objects to estimate");
  std::vector<TabletopModel> models;
  for (int id : obj_ids_) {
    Mesh mesh = data.load_model(id);  // millimetres -> metres
    const bool sym = symmetric_about_z(data.model_info(id));
    meshes_.push_back(mesh);
    yaw_symmetric_.push_back(sym);
    models.push_back({std::move(mesh), sym, std::nullopt});  // default rest pose: model z up
  }
  TabletopSettings settings = tabletop_variant(variant, base);
  settings.strict_instances = false;  // one hard image must not lose the other poses of a batch run
  if (backend == BackendKind::Cpu)
    impl_->estimator = std::make_unique<TabletopEstimator<cpu::Backend>>(std::move(models), settings);
  else
    impl_->estimator = std::make_unique<TabletopEstimator<thrust_omp::Backend>>(std::move(models), settings);
}

BopTabletop::~BopTabletop() = default;

int BopTabletop::model_index(int obj_id) const {
  const auto it = std::find(obj_ids_.begin(), obj_ids_.end(), obj_id);
  if (it == obj_ids_.end()) throw InvalidInput("obj_id " + std::to_string(obj_id), "not a loaded model");
  return int(it - obj_ids_.begin());
}

bool BopTabletop::yaw_symmetric(int obj_id) const {
  return yaw_symmetric_[std::size_t(model_index(obj_id))];
}

ImageEstimate BopTabletop::estimate(const dataset::BopImage& image,
                                    const std::vector<dataset::Target>& targets) const {
  ImageEstimate out;
  out.scene_id = image.info.scene_id, out.im_id = image.info.im_id;
  std::vector<ObjectCount> request;
  for (const auto& t : targets) {
    if (t.scene_id != out.scene_id || t.im_id != out.im_id)
      throw InvalidInput("targets", "mix images (" + std::to_string(t.scene_id) + ", " +
                                        std::to_string(t.im_id) + ") and (" + std::to_string(out.scene_id) +
                                        ", " + std::to_string(out.im_id) + ")");
    request.push_back({model_index(t.obj_id), t.inst_count});
  }
  const auto t0 = std::chrono::steady_clock::now();
  out.result =
      std::visit([&](const auto& e) { return e->estimate(image.frame, request, image.info.T_cam_world); },
                 impl_->estimator);
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  for (const auto& p : out.result.poses) {
    const int obj_id = obj_ids_[std::size_t(p.model)];
    out.pose_obj_ids.push_back(obj_id);
    dataset::PoseEstimate e;
    e.scene_id = out.scene_id, e.im_id = out.im_id, e.obj_id = obj_id;
    e.score = 1.0 / (1.0 + std::max(0.0, double(p.score)));  // BOP: higher is better; cost is >= 0
    e.T_cam_obj = p.T_cam_obj;
    e.time_s = out.seconds;
    out.rows.push_back(e);
  }
  for (const auto& m : out.result.missing) out.missing.push_back({obj_ids_[std::size_t(m.model)], m.count});
  return out;
}

Rgb8 overlay_color(int i) {
  static const Rgb8 colors[] = {{255, 40, 40}, {40, 230, 40}, {60, 110, 255}, {255, 220, 0},
                                {255, 0, 255}, {0, 230, 230}, {255, 140, 0},  {255, 255, 255}};
  return colors[i % 8];
}

const char* overlay_color_name(int i) {
  static const char* names[] = {"red", "green", "blue", "yellow", "magenta", "cyan", "orange", "white"};
  return names[i % 8];
}

ColorImage draw_overlay(const ColorImage& rgb, const Intrinsics& camera, const std::vector<Mesh>& meshes,
                        const std::vector<int>& model_of_pose, const std::vector<Pose>& T_cam_obj) {
  if (rgb.empty()) throw InvalidInput("overlay", "no colour image to draw on");
  ColorImage out = rgb;
  if (T_cam_obj.empty()) return out;
  std::vector<Hypothesis> hyps;
  for (std::size_t i = 0; i < T_cam_obj.size(); ++i) hyps.push_back({model_of_pose[i], T_cam_obj[i]});
  RenderSettings full;
  full.stride = 1;
  const CloudBatch c = cpu::Renderer(meshes).render(hyps, camera, full);
  // Nearest pose per pixel, then tint it and outline where the label changes.
  const int w = camera.width, h = camera.height;
  std::vector<float> z(std::size_t(w) * h, INFINITY);
  std::vector<int> label(std::size_t(w) * h, -1);
  for (std::size_t i = 0; i < c.size(); ++i)
    if (c.z[i] < z[c.pixel[i]]) z[c.pixel[i]] = c.z[i], label[c.pixel[i]] = int(c.cloud[i]);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const int l = label[std::size_t(v) * w + u];
      bool edge = false;
      for (int dv = -1; dv <= 1 && !edge; ++dv)
        for (int du = -1; du <= 1 && !edge; ++du) {
          const int uu = std::clamp(u + du, 0, w - 1), vv = std::clamp(v + dv, 0, h - 1);
          edge = label[std::size_t(vv) * w + uu] != l && (l >= 0 || label[std::size_t(vv) * w + uu] >= 0);
        }
      const int owner = l >= 0 ? l : -1;
      if (edge) {
        int k = owner;
        for (int dv = -1; dv <= 1 && k < 0; ++dv)
          for (int du = -1; du <= 1 && k < 0; ++du)
            k = label[std::size_t(std::clamp(v + dv, 0, h - 1)) * w + std::clamp(u + du, 0, w - 1)];
        out(u, v) = overlay_color(k);
      } else if (owner >= 0) {
        const Rgb8 a = rgb(u, v), b = overlay_color(owner);
        out(u, v) = {std::uint8_t((a.r * 3 + b.r * 2) / 5), std::uint8_t((a.g * 3 + b.g * 2) / 5),
                     std::uint8_t((a.b * 3 + b.b * 2) / 5)};
      }
    }
  return out;
}

void print_progress(std::FILE* out, int done, int total, double mean_s, double last_s) {
  const int width = 30, filled = total > 0 ? width * done / total : width;
  std::fprintf(out, "\r  [%s%s] %d/%d images  %.2f s/image (last %.2f s)", std::string(filled, '#').c_str(),
               std::string(width - filled, '.').c_str(), done, total, mean_s, last_s);
  if (done == total) std::fprintf(out, "\n");
  std::fflush(out);
}

}  // namespace perch2::cli
