#include "perch2/dataset/bop.hpp"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <set>

#include "json_util.hpp"
#include "perch2/io/image_io.hpp"
#include "perch2/io/mesh_io.hpp"

namespace fs = std::filesystem;

namespace perch2::dataset {

using namespace detail;

std::string bop_id(int id) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%06d", id);
  return buf;
}

std::map<std::pair<int, int>, std::vector<Target>> targets_by_image(const std::vector<Target>& targets,
                                                                    int first_scene, int last_scene) {
  std::map<std::pair<int, int>, std::vector<Target>> out;
  for (const auto& t : targets)
    if (t.scene_id >= first_scene && t.scene_id <= last_scene && t.inst_count > 0)
      out[{t.scene_id, t.im_id}].push_back(t);
  return out;
}

namespace {

std::string join(const std::string& a, const std::string& b) {
  return (fs::path(a) / b).string();
}

/// Width and height from a PNG's IHDR chunk (the first 24 bytes); false if the file is not a PNG.
bool png_size(const std::string& path, int& width, int& height) {
  std::ifstream f(path, std::ios::binary);
  unsigned char b[24];
  if (!f.read(reinterpret_cast<char*>(b), 24)) return false;
  static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  for (int k = 0; k < 8; ++k)
    if (b[k] != sig[k]) return false;
  auto be32 = [&](int o) {
    return int(b[o]) << 24 | int(b[o + 1]) << 16 | int(b[o + 2]) << 8 | int(b[o + 3]);
  };
  width = be32(16), height = be32(20);
  return width > 0 && height > 0;
}

/// rgb/IM_ID.png or .jpg; datasets with grey cameras (ITODD) have gray/ instead (read as grey RGB).
std::string rgb_path(const std::string& scene_dir, int im_id) {
  for (const char* folder : {"rgb", "gray"}) {
    const std::string stem = join(join(scene_dir, folder), bop_id(im_id));
    if (fs::exists(stem + ".png")) return stem + ".png";
    if (fs::exists(stem + ".jpg")) return stem + ".jpg";
    if (fs::exists(stem + ".tif")) return stem + ".tif";
  }
  return join(join(scene_dir, "rgb"), bop_id(im_id)) + ".png";  // named in the error
}

std::string mask_path(const std::string& scene_dir, const char* folder, int im_id, int gt_id) {
  return join(join(scene_dir, folder), bop_id(im_id) + "_" + bop_id(gt_id) + ".png");
}

Mask to_mask(const LabelImage& labels) {
  Mask m(labels.width, labels.height, 0);
  for (std::size_t k = 0; k < labels.data.size(); ++k) m.data[k] = labels.data[k] != 0;
  return m;
}

struct CameraDefaults {
  bool present = false;
  Intrinsics K;
  float depth_scale_mm = 1.f;
};

CameraDefaults load_camera_json(const std::string& path) {
  CameraDefaults c;
  if (!fs::exists(path)) return c;
  const json j = read_json(path);
  c.present = true;
  c.K.fx = float(number(member(j, "fx", path, "camera"), path, "fx"));
  c.K.fy = float(number(member(j, "fy", path, "camera"), path, "fy"));
  c.K.cx = float(number(member(j, "cx", path, "camera"), path, "cx"));
  c.K.cy = float(number(member(j, "cy", path, "camera"), path, "cy"));
  c.K.width = integer(member(j, "width", path, "camera"), path, "width");
  c.K.height = integer(member(j, "height", path, "camera"), path, "height");
  if (j.contains("depth_scale")) c.depth_scale_mm = float(number(j["depth_scale"], path, "depth_scale"));
  return c;
}

/// What went wrong with one image's entries, or with a whole scene file: the file and the reason.
struct Problem {
  std::string path, reason;
};

/// The problems found while parsing one scene's JSON files: per image, and those of no known image (a
/// malformed file, a key that is not an image id, an entry for an image scene_camera.json does not list).
struct SceneProblems {
  std::map<int, Problem> images;
  std::vector<Problem> scene;
};

/// e.what() is "PATH: REASON" (FileError); split it again for path.
Problem problem_of(const FileError& e, const std::string& path) {
  const std::string what = e.what();
  if (what.rfind(path + ": ", 0) == 0) return {path, what.substr(path.size() + 2)};
  return {path, what};
}

/// A JSON object keyed by image id; a missing or malformed file is a problem of the whole scene.
std::optional<json> read_scene_file(const std::string& path, SceneProblems& problems) {
  try {
    json j = read_json(path);
    if (!j.is_object()) throw FileError(path, "expected a JSON object keyed by image id");
    return j;
  } catch (const FileError& e) {
    problems.scene.push_back(problem_of(e, path));
    return std::nullopt;
  }
}

/// The image id of a key, or nullopt (a problem of the scene).
std::optional<int> image_key(const std::string& key, const std::string& path, SceneProblems& problems) {
  try {
    return key_id(key, path, "image key");
  } catch (const FileError& e) {
    problems.scene.push_back(problem_of(e, path));
    return std::nullopt;
  }
}

void parse_scene_camera(const std::string& path, int scene_id, const CameraDefaults& defaults,
                        std::map<int, ImageInfo>& images, SceneProblems& problems) {
  const std::optional<json> j = read_scene_file(path, problems);
  if (!j) return;
  for (const auto& [key, cam] : j->items()) {
    const std::optional<int> im_id = image_key(key, path, problems);
    if (!im_id) continue;
    const std::string where = "image " + key;
    try {
      ImageInfo info;
      info.scene_id = scene_id, info.im_id = *im_id;
      const auto K = numbers(member(cam, "cam_K", path, where), 9, path, where + " cam_K");
      info.camera = {float(K[0]), float(K[4]), float(K[2]), float(K[5]), defaults.K.width, defaults.K.height};
      if (K[1] != 0 || K[3] != 0 || K[6] != 0 || K[7] != 0 || K[8] != 1)
        throw FileError(path, where + " cam_K: expected [fx, 0, cx, 0, fy, cy, 0, 0, 1] (no skew)");
      info.depth_scale_mm = defaults.depth_scale_mm;
      if (cam.contains("depth_scale"))
        info.depth_scale_mm = float(number(cam["depth_scale"], path, where + " depth_scale"));
      if (!(info.depth_scale_mm > 0)) throw FileError(path, where + " depth_scale: must be > 0");
      if (cam.contains("cam_R_w2c") || cam.contains("cam_t_w2c"))
        info.T_cam_world = pose_from_bop(member(cam, "cam_R_w2c", path, where),
                                         member(cam, "cam_t_w2c", path, where), path, where + " cam_*_w2c");
      images[*im_id] = std::move(info);
    } catch (const FileError& e) {
      problems.images[*im_id] = problem_of(e, path);
    }
  }
}

/// Calls fn(key, value, image) for every entry of a per-image JSON file of the scene (keys are image ids
/// that scene_camera.json lists). A malformed file costs every image of the scene; a malformed entry (fn
/// throws FileError) costs its image, which leaves `images`.
template <class Fn>
void for_each_image_entry(const std::string& path, std::map<int, ImageInfo>& images, SceneProblems& problems,
                          Fn fn) {
  const std::optional<json> j = read_scene_file(path, problems);
  if (!j) {
    for (const auto& [id, info] : images) problems.images[id] = problems.scene.back();
    images.clear();
    return;
  }
  for (const auto& [key, value] : j->items()) {
    const std::optional<int> im_id = image_key(key, path, problems);
    if (!im_id || problems.images.count(*im_id)) continue;
    const auto it = images.find(*im_id);
    if (it == images.end()) {
      problems.scene.push_back({path, "image " + key + " is not in scene_camera.json"});
      continue;
    }
    try {
      fn(key, value, it->second);
    } catch (const FileError& e) {
      problems.images[*im_id] = problem_of(e, path);
      images.erase(it);
    }
  }
}

void parse_scene_gt(const std::string& path, const std::map<int, ModelInfo>& models,
                    std::map<int, ImageInfo>& images, SceneProblems& problems) {
  for_each_image_entry(
      path, images, problems, [&](const std::string& key, const json& list, ImageInfo& info) {
        if (!list.is_array()) throw FileError(path, "image " + key + ": expected a list of instances");
        for (std::size_t g = 0; g < list.size(); ++g) {
          const std::string where = "image " + key + " instance " + std::to_string(g);
          GtInstance gt;
          gt.obj_id = integer(member(list[g], "obj_id", path, where), path, where + " obj_id");
          if (!models.count(gt.obj_id))
            throw FileError(path,
                            where + ": obj_id " + std::to_string(gt.obj_id) + " is not in models_info.json");
          gt.T_cam_obj = pose_from_bop(member(list[g], "cam_R_m2c", path, where),
                                       member(list[g], "cam_t_m2c", path, where), path, where + " cam_*_m2c");
          info.gt.push_back(gt);
        }
      });
}

Eigen::Vector4i bbox(const json& j, const std::string& path, const std::string& where) {
  const auto b = numbers(j, 4, path, where);
  return {int(b[0]), int(b[1]), int(b[2]), int(b[3])};
}

void parse_scene_gt_info(const std::string& path, std::map<int, ImageInfo>& images, SceneProblems& problems) {
  for_each_image_entry(
      path, images, problems, [&](const std::string& key, const json& list, ImageInfo& info) {
        if (!list.is_array() || list.size() != info.gt.size())
          throw FileError(path, "image " + key + ": expected one entry per scene_gt.json instance (" +
                                    std::to_string(info.gt.size()) + ")");
        for (std::size_t g = 0; g < list.size(); ++g) {
          const std::string where = "image " + key + " instance " + std::to_string(g);
          const json& e = list[g];
          GtInstance& gt = info.gt[g];
          gt.has_info = true;
          gt.visib_fract = float(number(member(e, "visib_fract", path, where), path, where + " visib_fract"));
          if (e.contains("bbox_obj")) gt.bbox_obj = bbox(e["bbox_obj"], path, where + " bbox_obj");
          if (e.contains("bbox_visib")) gt.bbox_visib = bbox(e["bbox_visib"], path, where + " bbox_visib");
          if (e.contains("px_count_all")) gt.px_count_all = integer(e["px_count_all"], path, where);
          if (e.contains("px_count_valid")) gt.px_count_valid = integer(e["px_count_valid"], path, where);
          if (e.contains("px_count_visib")) gt.px_count_visib = integer(e["px_count_visib"], path, where);
        }
      });
}

/// The targets file: its images, and for localization (bop19: obj_id and inst_count per entry) its
/// targets; detection targets (bop24) name images only, and nothing of them is taken from the ground truth.
/// An image its scene could not give (a bad entry, a broken scene file) is kept and listed in `bad` if it
/// is not yet; an image that is nowhere in the split is an error of the targets file. Entries of both kinds
/// in one file are an error.
std::vector<Target> parse_targets(const std::string& path,
                                  const std::map<int, std::map<int, ImageInfo>>& scenes,
                                  const std::map<int, std::vector<Problem>>& scene_problems,
                                  std::map<std::pair<int, int>, BadImage>& bad,
                                  std::vector<std::pair<int, int>>& images, TargetTask& task) {
  const json j = read_json(path);
  if (!j.is_array()) throw FileError(path, "expected a JSON list of targets");
  std::vector<Target> out;
  for (std::size_t k = 0; k < j.size(); ++k) {
    const std::string where = "target " + std::to_string(k);
    Target t;
    t.scene_id = integer(member(j[k], "scene_id", path, where), path, where + " scene_id");
    t.im_id = integer(member(j[k], "im_id", path, where), path, where + " im_id");
    const std::pair<int, int> key{t.scene_id, t.im_id};
    const auto s = scenes.find(t.scene_id);
    const bool good = s != scenes.end() && s->second.count(t.im_id);
    if (!good && !bad.count(key)) {
      const auto p = scene_problems.find(t.scene_id);
      if (p == scene_problems.end())
        throw FileError(path, where + ": scene " + std::to_string(t.scene_id) + " image " +
                                  std::to_string(t.im_id) + " is not in the split");
      std::string reason = "image " + std::to_string(t.im_id) +
                           " (listed in the targets file) is not in the scene's JSON files:";
      for (const Problem& q : p->second) reason += " [" + q.path + ": " + q.reason + "]";
      bad[key] = {t.scene_id, t.im_id, p->second.front().path, reason};
    }
    images.push_back(key);
    const TargetTask kind = j[k].contains("obj_id") ? TargetTask::Localization : TargetTask::Detection;
    if (task != TargetTask::NoTargets && kind != task)
      throw FileError(path, where + ": mixes image-only (bop24) and object (bop19) targets");
    task = kind;
    if (kind == TargetTask::Localization) {  // bop19: one object of the image
      t.obj_id = integer(j[k]["obj_id"], path, where + " obj_id");
      t.inst_count = integer(member(j[k], "inst_count", path, where), path, where + " inst_count");
      if (t.inst_count < 1) throw FileError(path, where + " inst_count: must be >= 1");
      out.push_back(t);
    }
  }
  std::sort(images.begin(), images.end());
  images.erase(std::unique(images.begin(), images.end()), images.end());
  return out;
}

}  // namespace

std::map<int, ModelInfo> load_models_info(const std::string& path) {
  const json j = read_json(path);
  if (!j.is_object()) throw FileError(path, "expected a JSON object keyed by object id");
  std::map<int, ModelInfo> out;
  for (const auto& [key, m] : j.items()) {
    const std::string where = "object " + key;
    ModelInfo info;
    info.obj_id = key_id(key, path, "object key");
    info.diameter_m = float(number(member(m, "diameter", path, where), path, where + " diameter") * 1e-3);
    if (!(info.diameter_m > 0)) throw FileError(path, where + " diameter: must be > 0");
    if (m.contains("symmetries_discrete")) {
      const json& list = m["symmetries_discrete"];
      if (!list.is_array()) throw FileError(path, where + " symmetries_discrete: expected a list");
      for (std::size_t s = 0; s < list.size(); ++s) {
        const std::string w = where + " symmetries_discrete[" + std::to_string(s) + "]";
        const auto v = numbers(list[s], 16, path, w);
        if (v[12] != 0 || v[13] != 0 || v[14] != 0 || v[15] != 1)
          throw FileError(path, w + ": the last row must be [0, 0, 0, 1]");
        info.symmetries_discrete.push_back(pose_from_bop(
            json{v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]}, json{v[3], v[7], v[11]}, path, w));
      }
    }
    if (m.contains("symmetries_continuous")) {
      const json& list = m["symmetries_continuous"];
      if (!list.is_array()) throw FileError(path, where + " symmetries_continuous: expected a list");
      for (std::size_t s = 0; s < list.size(); ++s) {
        const std::string w = where + " symmetries_continuous[" + std::to_string(s) + "]";
        const auto a = numbers(member(list[s], "axis", path, w), 3, path, w + " axis");
        const auto o = numbers(member(list[s], "offset", path, w), 3, path, w + " offset");
        ContinuousSymmetry c;
        c.axis = Eigen::Vector3d(a[0], a[1], a[2]).cast<float>();
        if (!(c.axis.norm() > 0)) throw FileError(path, w + " axis: must not be zero");
        c.axis.normalize();
        c.offset_m = Eigen::Vector3d(o[0] * 1e-3, o[1] * 1e-3, o[2] * 1e-3).cast<float>();
        info.symmetries_continuous.push_back(c);
      }
    }
    out[info.obj_id] = std::move(info);
  }
  return out;
}

LabelImage BopImage::visible_labels() const {
  LabelImage out(frame.camera.width, frame.camera.height, 0);
  for (std::size_t g = 0; g < masks_visib.size(); ++g) {
    check_size(masks_visib[g], out.width, out.height, "mask_visib " + std::to_string(g));
    for (std::size_t k = 0; k < out.data.size(); ++k)
      if (masks_visib[g].data[k]) out.data[k] = std::int32_t(g + 1);
  }
  return out;
}

BopDataset::BopDataset(std::string root, DatasetOptions options) : root_(std::move(root)) {
  if (!fs::is_directory(root_)) throw FileError(root_, "dataset root is not a folder");
  split_path_ = join(root_, options.split);
  if (!fs::is_directory(split_path_)) throw FileError(split_path_, "split folder not found");
  models_path_ = join(root_, options.models_dir.empty() ? "models" : options.models_dir);
  const std::string info_path = join(models_path_, "models_info.json");
  models_info_ = load_models_info(info_path);
  const CameraDefaults defaults = load_camera_json(join(root_, "camera.json"));

  std::map<int, std::vector<Problem>> scene_problems;
  int scene_folders = 0;
  for (const auto& entry : fs::directory_iterator(split_path_)) {
    if (!entry.is_directory()) continue;
    const std::string name = entry.path().filename().string();
    int scene_id = -1;
    try {
      std::size_t end = 0;
      scene_id = std::stoi(name, &end);
      if (end != name.size()) continue;
    } catch (const std::exception&) {
      continue;  // not a scene folder
    }
    ++scene_folders;
    const std::string dir = entry.path().string();
    auto& images = scenes_[scene_id];
    SceneProblems problems;
    parse_scene_camera(join(dir, "scene_camera.json"), scene_id, defaults, images, problems);
    if (options.ground_truth && fs::exists(join(dir, "scene_gt.json")))
      parse_scene_gt(join(dir, "scene_gt.json"), models_info_, images, problems);
    if (options.ground_truth && fs::exists(join(dir, "scene_gt_info.json")))
      parse_scene_gt_info(join(dir, "scene_gt_info.json"), images, problems);
    if (!defaults.present && !images.empty()) {  // image size from the first image of the scene
      const int im = images.begin()->first;
      int w = 0, h = 0;
      if (png_size(join(join(dir, "depth"), bop_id(im) + ".png"), w, h) || png_size(rgb_path(dir, im), w, h))
        for (auto& [id, info] : images) info.camera.width = w, info.camera.height = h;
    }
    for (const auto& [im, p] : problems.images)
      bad_images_[{scene_id, im}] = {scene_id, im, p.path, p.reason};
    for (const Problem& p : problems.scene) warnings_.push_back(p.path + ": " + p.reason);
    if (!problems.scene.empty()) scene_problems[scene_id] = problems.scene;
  }
  if (scene_folders == 0) throw FileError(split_path_, "no scene folders (000000, 000001, ...) found");

  if (!options.targets_file.empty()) {
    targets_path_ = join(root_, options.targets_file);
    if (!fs::exists(targets_path_)) throw FileError(targets_path_, "targets file not found");
  } else if (fs::exists(join(root_, "test_targets_bop19.json"))) {
    targets_path_ = join(root_, "test_targets_bop19.json");
  } else if (fs::exists(join(root_, "test_targets_bop24.json"))) {
    targets_path_ = join(root_, "test_targets_bop24.json");
  }
  if (!targets_path_.empty())
    targets_ =
        parse_targets(targets_path_, scenes_, scene_problems, bad_images_, target_images_, target_task_);
}

std::vector<std::pair<int, int>> run_images(const BopDataset& data, int first_scene, int last_scene) {
  std::set<std::pair<int, int>> with_targets;
  for (const auto& t : data.targets())
    if (t.inst_count > 0) with_targets.insert({t.scene_id, t.im_id});
  std::vector<std::pair<int, int>> out;
  const bool detection = data.target_task() == TargetTask::Detection;
  for (const auto& key : data.target_images())
    if (key.first >= first_scene && key.first <= last_scene &&
        (detection || with_targets.count(key) || data.bad_image(key.first, key.second)))
      out.push_back(key);
  return out;
}

const ModelInfo& BopDataset::model_info(int obj_id) const {
  const auto it = models_info_.find(obj_id);
  if (it == models_info_.end())
    throw InvalidInput("obj_id " + std::to_string(obj_id),
                       "not in " + join(models_path_, "models_info.json"));
  return it->second;
}

std::string BopDataset::model_path(int obj_id) const {
  return join(models_path_, "obj_" + bop_id(obj_id) + ".ply");
}

Mesh BopDataset::load_model(int obj_id) const {
  model_info(obj_id);
  io::MeshLoadOptions o;
  o.scale = 0.001f;  // BOP models are in millimetres
  return io::load_mesh(model_path(obj_id), o);
}

std::vector<int> BopDataset::scene_ids() const {
  std::vector<int> out;
  for (const auto& s : scenes_) out.push_back(s.first);
  return out;
}

std::vector<std::pair<int, int>> BopDataset::image_ids() const {
  std::vector<std::pair<int, int>> out;
  for (const auto& [s, images] : scenes_)
    for (const auto& im : images) out.emplace_back(s, im.first);
  return out;
}

bool BopDataset::has_image(int scene_id, int im_id) const {
  const auto s = scenes_.find(scene_id);
  return s != scenes_.end() && s->second.count(im_id);
}

const BadImage* BopDataset::bad_image(int scene_id, int im_id) const {
  const auto it = bad_images_.find({scene_id, im_id});
  return it == bad_images_.end() ? nullptr : &it->second;
}

const ImageInfo& BopDataset::info(int scene_id, int im_id) const {
  if (const BadImage* bad = bad_image(scene_id, im_id)) throw FileError(bad->path, bad->reason);
  if (!has_image(scene_id, im_id))
    throw InvalidInput("scene " + std::to_string(scene_id) + " image " + std::to_string(im_id),
                       "not in " + split_path_);
  return scenes_.at(scene_id).at(im_id);
}

ImageFiles BopDataset::image_files(int scene_id, int im_id, const ImageLoadOptions& options) const {
  const ImageInfo& image = info(scene_id, im_id);
  const std::string dir = join(split_path_, bop_id(scene_id));
  ImageFiles out;
  if (options.depth) out.depth = FileBytes{join(join(dir, "depth"), bop_id(im_id) + ".png"), {}};
  if (options.rgb) out.rgb = FileBytes{rgb_path(dir, im_id), {}};
  for (std::size_t g = 0; g < image.gt.size(); ++g) {
    if (options.masks_visib) out.masks_visib.push_back({mask_path(dir, "mask_visib", im_id, int(g)), {}});
    if (options.masks) out.masks.push_back({mask_path(dir, "mask", im_id, int(g)), {}});
  }
  return out;
}

ImageFiles read_files(ImageFiles files) {
  auto read = [](FileBytes& f) { f.bytes = io::read_file(f.path); };
  if (files.depth) read(*files.depth);
  if (files.rgb) read(*files.rgb);
  for (FileBytes& f : files.masks_visib) read(f);
  for (FileBytes& f : files.masks) read(f);
  return files;
}

ImageFiles BopDataset::read_image_files(int scene_id, int im_id, const ImageLoadOptions& options) const {
  return read_files(image_files(scene_id, im_id, options));
}

BopImage BopDataset::load_image(int scene_id, int im_id, const ImageLoadOptions& options) const {
  return decode_image(info(scene_id, im_id), read_image_files(scene_id, im_id, options));
}

BopImage decode_image(const ImageInfo& info, const ImageFiles& files) {
  BopImage out;
  out.info = info;
  out.frame.camera = info.camera;
  auto take_size = [&](int w, int h, const std::string& path) {
    if (out.frame.camera.width == 0 && out.frame.camera.height == 0)
      out.frame.camera.width = w, out.frame.camera.height = h;
    else if (out.frame.camera.width != w || out.frame.camera.height != h)
      throw FileError(path, "image is " + std::to_string(w) + "x" + std::to_string(h) + ", the camera says " +
                                std::to_string(out.frame.camera.width) + "x" +
                                std::to_string(out.frame.camera.height));
  };
  if (files.depth) {
    out.frame.depth_m =
        io::decode_depth_png(files.depth->bytes, files.depth->path, info.depth_scale_mm * 0.001f);
    take_size(out.frame.depth_m.width, out.frame.depth_m.height, files.depth->path);
  }
  if (files.rgb) {
    out.frame.rgb = io::decode_color_image(files.rgb->bytes, files.rgb->path);
    take_size(out.frame.rgb.width, out.frame.rgb.height, files.rgb->path);
  }
  auto decode_masks = [&](const std::vector<FileBytes>& in, const char* what, std::vector<Mask>& masks) {
    if (!in.empty() && in.size() != info.gt.size())
      throw InvalidInput(std::string(what) + " of scene " + std::to_string(info.scene_id) + " image " +
                             std::to_string(info.im_id),
                         std::to_string(in.size()) + " masks for " + std::to_string(info.gt.size()) +
                             " ground-truth instances");
    for (const FileBytes& f : in) {
      masks.push_back(to_mask(io::decode_label_png(f.bytes, f.path)));
      take_size(masks.back().width, masks.back().height, f.path);
    }
  };
  decode_masks(files.masks_visib, "mask_visib", out.masks_visib);
  decode_masks(files.masks, "mask", out.masks);
  out.info.camera = out.frame.camera;
  return out;
}

}  // namespace perch2::dataset
