// BopRunner: per-image BOP estimation in both modes over a backend chosen at run time.
#include "perch2/dataset/runner.hpp"

#include <algorithm>
#include <filesystem>
#include <map>
#include <set>
#include <variant>

#include "perch2/cpu/estimators.hpp"
#include "perch2/cuda/estimators.hpp"
#include "perch2/dataset/detections.hpp"
#include "perch2/search/tabletop_bop.hpp"

namespace perch2::dataset {

namespace {

constexpr std::pair<const char*, SearchVariant> kVariants[] = {
    {"perch2c", SearchVariant::Perch2C},       {"perch2a", SearchVariant::Perch2A},
    {"perch2b", SearchVariant::Perch2B},       {"perch", SearchVariant::Perch},
    {"depth-only", SearchVariant::DepthOnlyC}, {"bf-icp", SearchVariant::BfIcp},
};

}  // namespace

RunMode parse_mode(const std::string& name) {
  if (name == "3dof") return RunMode::Tabletop;
  if (name == "6dof") return RunMode::SixDof;
  throw InvalidInput("--mode", "'" + name + "' is not 3dof or 6dof");
}

const char* mode_name(RunMode m) {
  return m == RunMode::Tabletop ? "3dof" : "6dof";
}

BackendKind parse_backend(const std::string& name) {
  if (name == "cpu") return BackendKind::Cpu;
  if (name == "thrust_omp") return BackendKind::ThrustOmp;
  throw InvalidInput("--backend", "unknown backend '" + name + "' (cpu|thrust_omp)");
}

const char* backend_name(BackendKind b) {
  return b == BackendKind::Cpu ? "cpu" : "thrust_omp";
}

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

ImageError::ImageError(int scene, int im, const std::string& why)
    : std::runtime_error("scene " + std::to_string(scene) + " image " + std::to_string(im) + ": " + why),
      scene_id(scene),
      im_id(im),
      reason(why) {}

namespace {

template <class Backend>
using Tabletop = std::unique_ptr<TabletopEstimator<Backend>>;
template <class Backend>
using SixDof = std::unique_ptr<SixDofEstimator<Backend>>;
using Estimator = std::variant<Tabletop<cpu::Backend>, Tabletop<thrust_omp::Backend>, SixDof<cpu::Backend>,
                               SixDof<thrust_omp::Backend>>;

template <class Backend>
Estimator make_estimator(const BopDataset& data, const RunOptions& o, const std::vector<int>& obj_ids,
                         std::vector<Mesh>& meshes) {
  for (const int id : obj_ids) meshes.push_back(data.load_model(id));  // millimetres -> metres
  if (o.mode == RunMode::Tabletop) {
    std::vector<TabletopModel> models;
    for (std::size_t k = 0; k < obj_ids.size(); ++k)
      models.push_back(tabletop_model(meshes[k], data.model_info(obj_ids[k])));
    TabletopSettings settings = tabletop_variant(o.variant, o.tabletop);
    settings.strict_instances = false;  // one hard image must not lose the other poses of a batch run
    return std::make_unique<TabletopEstimator<Backend>>(std::move(models), settings);
  }
  std::vector<SixDofModel> models;
  for (std::size_t k = 0; k < obj_ids.size(); ++k)
    models.push_back(sixdof_model(meshes[k], data.model_info(obj_ids[k])));
  return std::make_unique<SixDofEstimator<Backend>>(std::move(models), o.sixdof);
}

using Stages = std::vector<std::pair<std::string, double>>;

Stages stages_of(const TabletopTimings& t) {
  return {{"table", t.table},   {"observed", t.observed}, {"hypotheses", t.hypotheses},
          {"render", t.render}, {"refine", t.refine},     {"cost", t.cost},
          {"select", t.select}, {"yaw", t.yaw},           {"total", t.total}};
}

Stages stages_of(const SixDofTimings& t) {
  return {{"observed", t.observed}, {"proposals", t.proposals}, {"render", t.render}, {"refine", t.refine},
          {"cost", t.cost},         {"select", t.select},       {"total", t.total}};
}

/// --masks none: also the segmentation, detection's retrieval and the scene explanation, before "total".
Stages scene_stages_of(const SixDofTimings& t) {
  Stages out{{"segment", t.segment}, {"retrieve", t.retrieve}};
  for (const auto& st : stages_of(t))
    if (st.first != "total") out.push_back(st);
  out.push_back({"explain", t.explain});
  out.push_back({"total", t.total});
  return out;
}

}  // namespace

struct BopRunner::Impl {
  BopDataset data;
  RunOptions options;
  std::vector<int> obj_ids;
  std::map<int, int> model_of;  // obj_id -> model index
  std::vector<Mesh> meshes;
  std::map<std::pair<int, int>, std::vector<Target>> targets;
  bool detection = false;  // detection targets (bop24): no objects or counts given
  std::vector<Detection> detections;
  std::map<std::pair<int, int>, std::vector<std::size_t>> detections_of;
  Estimator estimator;

  template <class Backend>
  ImageResult run(const TabletopEstimator<Backend>& e, const BopImage& image,
                  const std::vector<Target>& targets) const {
    ImageResult out;
    TabletopResult r;
    if (detection) {  // bop24 targets: every model, as many as placed (RunOptions::detect's caps)
      TabletopDetectSettings d;
      d.max_per_model = options.detect.max_per_model, d.max_per_frame = options.detect.max_per_frame;
      out.rows = detect_bop_image(e, image, obj_ids, d, &r);
    } else {
      out.rows = estimate_bop_image(e, image, targets, model_of, &r);
    }
    for (const auto& p : r.poses) out.row_models.push_back(p.model), out.row_found.push_back(true);
    for (const auto& t : targets) out.requested += t.inst_count;
    for (const auto& m : r.missing) out.missing += m.count;
    out.stages = stages_of(r.timings);
    out.seconds = out.rows.empty() ? r.timings.total : out.rows.front().time_s;
    out.tabletop = std::move(r);
    return out;
  }

  /// --masks none: the targets' objects and counts searched for in the whole frame (estimate_scene); on
  /// detection targets every loaded model, any number of times (detect).
  template <class Backend>
  ImageResult run_scene(const SixDofEstimator<Backend>& e, const BopImage& image,
                        const std::vector<Target>& targets) const {
    std::map<int, int> count;  // model -> instances asked for
    for (const auto& t : targets) {
      const auto it = model_of.find(t.obj_id);
      if (it == model_of.end())
        throw InvalidInput("target obj_id " + std::to_string(t.obj_id), "has no loaded model");
      count[it->second] += t.inst_count;
    }
    std::vector<SixDofObject> objects;
    for (const auto& [model, n] : count) objects.push_back({model, n});
    ImageResult out;
    SixDofSceneResult r =
        detection ? e.detect(image.frame, options.detect) : e.estimate_scene(image.frame, objects);
    for (const auto& p : r.poses) {
      PoseEstimate row;
      row.scene_id = image.info.scene_id, row.im_id = image.info.im_id;
      row.obj_id = obj_ids[std::size_t(p.model)];
      row.score = p.score, row.T_cam_obj = p.T_cam_obj, row.time_s = r.search.timings.total;
      out.rows.push_back(row), out.row_models.push_back(p.model), out.row_found.push_back(p.found);
    }
    for (const auto& t : targets) out.requested += t.inst_count;
    for (const int m : r.missing) out.missing += m;
    out.instances = int(r.poses.size());
    out.stages = scene_stages_of(r.search.timings);
    out.seconds = r.search.timings.total;
    out.sixdof = std::move(r.search);
    return out;
  }

  template <class Backend>
  ImageResult run(const SixDofEstimator<Backend>& e, const BopImage& image,
                  const std::vector<Target>& targets) const {
    if (options.masks == "none") return run_scene(e, image, targets);
    const std::pair<int, int> key{image.info.scene_id, image.info.im_id};
    const auto det = detections_of.find(key);
    static const std::vector<std::size_t> none;
    const BopInstances all =
        options.masks == "gt"
            ? bop_instances_from_gt(image, model_of, options.box)
            : bop_instances_from_detections(image, detections,
                                            det == detections_of.end() ? none : det->second, model_of);
    const BopInstances in = usable_instances(detection ? all : only_targets(all, targets), image.frame,
                                             e.settings().observed, options.min_instance_points);
    ImageResult out;
    SixDofResult r;
    out.rows = estimate_bop_image(e, image, in, &r);
    for (std::size_t k = 0; k < r.poses.size(); ++k)
      out.row_models.push_back(in.instances[k].model), out.row_found.push_back(r.poses[k].found);
    for (const auto& t : targets) out.requested += t.inst_count;
    out.unusable = int(in.skipped.size() - all.skipped.size());
    out.instances = int(in.instances.size());
    out.stages = stages_of(r.timings);
    out.seconds = r.timings.total;
    out.sixdof = std::move(r);
    return out;
  }
};

BopRunner::BopRunner(const BopDataset& data, RunOptions options, std::vector<int> obj_ids)
    : impl_(std::make_unique<Impl>(
          Impl{data, std::move(options), std::move(obj_ids), {}, {}, {}, {}, {}, {}, {}})) {
  Impl& m = *impl_;
  m.targets = targets_by_image(data.targets());
  m.detection = data.target_task() == TargetTask::Detection;
  if (m.detection && m.obj_ids.empty())  // the whole catalogue
    for (const auto& [id, info] : data.models_info()) m.obj_ids.push_back(id);
  if (m.obj_ids.empty()) {
    std::set<int> ids;
    for (const auto& [key, targets] : m.targets)
      for (const auto& t : targets) ids.insert(t.obj_id);
    m.obj_ids.assign(ids.begin(), ids.end());
  }
  std::sort(m.obj_ids.begin(), m.obj_ids.end());
  m.obj_ids.erase(std::unique(m.obj_ids.begin(), m.obj_ids.end()), m.obj_ids.end());
  if (m.obj_ids.empty()) throw InvalidInput("dataset " + data.root(), "no target objects to estimate");
  for (const int id : m.obj_ids) m.model_of[id] = int(m.model_of.size());
  if (m.options.mode == RunMode::SixDof && m.options.masks != "gt" && m.options.masks != "none") {
    if (!std::filesystem::is_regular_file(m.options.masks))
      throw FileError(m.options.masks, "is not a detection file (masks: gt|none|FILE)");
    m.detections = load_detections(m.options.masks);
    m.detections_of = detections_by_image(m.detections);
  }
  m.estimator = m.options.backend == BackendKind::Cpu
                    ? make_estimator<cpu::Backend>(data, m.options, m.obj_ids, m.meshes)
                    : make_estimator<thrust_omp::Backend>(data, m.options, m.obj_ids, m.meshes);
}

BopRunner::~BopRunner() = default;
BopRunner::BopRunner(BopRunner&&) noexcept = default;
BopRunner& BopRunner::operator=(BopRunner&&) noexcept = default;

std::vector<std::pair<int, int>> BopRunner::images(int first_scene, int last_scene) const {
  return run_images(impl_->data, first_scene, last_scene);
}

const std::vector<Target>& BopRunner::targets(int scene_id, int im_id) const {
  static const std::vector<Target> none;
  const auto it = impl_->targets.find({scene_id, im_id});
  return it == impl_->targets.end() ? none : it->second;
}

ImageLoadOptions load_options(const RunOptions& options) {
  ImageLoadOptions load;
  load.masks_visib = options.mode == RunMode::SixDof && options.masks == "gt";
  return load;
}

ImageLoadOptions BopRunner::load_options() const {
  return dataset::load_options(impl_->options);
}

namespace {
/// fn() with perch2's input errors turned into the image's ImageError.
template <class Fn>
auto for_image(int scene_id, int im_id, Fn fn) {
  try {
    return fn();
  } catch (const FileError& e) {
    throw ImageError(scene_id, im_id, e.what());
  } catch (const InvalidInput& e) {
    throw ImageError(scene_id, im_id, e.what());
  }
}
}  // namespace

BopImage BopRunner::load_image(int scene_id, int im_id) const {
  return for_image(scene_id, im_id, [&] { return impl_->data.load_image(scene_id, im_id, load_options()); });
}

ImageFiles BopRunner::image_files(int scene_id, int im_id) const {
  return for_image(scene_id, im_id, [&] { return impl_->data.image_files(scene_id, im_id, load_options()); });
}

ImageResult BopRunner::estimate(int scene_id, int im_id) const {
  return estimate(load_image(scene_id, im_id));
}

ImageResult BopRunner::estimate(int scene_id, int im_id, const ImageFiles& files) const {
  return estimate(
      for_image(scene_id, im_id, [&] { return decode_image(impl_->data.info(scene_id, im_id), files); }));
}

ImageResult BopRunner::estimate(const BopImage& image) const {
  const int scene_id = image.info.scene_id, im_id = image.info.im_id;
  return for_image(scene_id, im_id, [&] {
    ImageResult out = std::visit(
        [&](const auto& e) { return impl_->run(*e, image, targets(scene_id, im_id)); }, impl_->estimator);
    out.scene_id = scene_id, out.im_id = im_id;
    return out;
  });
}

const RunOptions& BopRunner::options() const {
  return impl_->options;
}

const std::vector<int>& BopRunner::obj_ids() const {
  return impl_->obj_ids;
}

const std::vector<Mesh>& BopRunner::meshes() const {
  return impl_->meshes;
}

int BopRunner::model_index(int obj_id) const {
  const auto it = impl_->model_of.find(obj_id);
  if (it == impl_->model_of.end())
    throw InvalidInput("obj_id " + std::to_string(obj_id), "not a loaded model");
  return it->second;
}

std::string BopRunner::describe() const {
  const RunOptions& o = impl_->options;
  if (o.mode == RunMode::Tabletop)
    return std::string("3dof, variant ") + variant_name(o.variant) + ", backend " + backend_name(o.backend);
  return std::string("6dof, masks ") + o.masks + ", " + (o.box == BoxKind::Full ? "full" : "visible") +
         " boxes, backend " + backend_name(o.backend);
}

}  // namespace perch2::dataset
