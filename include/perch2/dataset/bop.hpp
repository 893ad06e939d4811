// Reading datasets in BOP format
// (https://github.com/thodan/bop_toolkit/blob/master/docs/bop_datasets_format.md).
//
//   ROOT/camera.json                       optional: fx, fy, cx, cy, width, height, depth_scale
//   ROOT/models/obj_OBJ_ID.ply             models in millimetres (models_eval/ is preferred for evaluation)
//   ROOT/models/models_info.json           {"OBJ_ID": {diameter (mm), symmetries_discrete [[16 numbers: 4x4
//                                          row-major, translation in mm]], symmetries_continuous
//                                          [{axis [3], offset [3] (mm)}], ...}}
//   ROOT/test_targets_bop19.json           [{scene_id, im_id, obj_id, inst_count}]: 6D localization (or
//                                          _bop24: [{scene_id, im_id}], 6D detection: any model, any count)
//   ROOT/SPLIT/SCENE_ID/scene_camera.json  {"IM_ID": {cam_K [9, row-major], depth_scale (mm per unit),
//                                          cam_R_w2c [9]?, cam_t_w2c [3] (mm)?}}
//   ROOT/SPLIT/SCENE_ID/scene_gt.json      {"IM_ID": [{obj_id, cam_R_m2c [9], cam_t_m2c [3] (mm)}]}
//   ROOT/SPLIT/SCENE_ID/scene_gt_info.json {"IM_ID": [{bbox_obj, bbox_visib, px_count_*, visib_fract}]}
//   ROOT/SPLIT/SCENE_ID/rgb/IM_ID.{png,jpg}, depth/IM_ID.png (16-bit, value * depth_scale = mm, planar z),
//                      mask/IM_ID_GT_ID.png, mask_visib/IM_ID_GT_ID.png   (ids zero-padded to 6 digits)
//
// Everything is converted to perch2's units on reading: metres, poses T_cam_obj (model -> camera) as Pose.
// Opening a dataset parses the JSON files only; images are read one at a time by load_image().
// Problems with a file raise perch2::FileError naming the file and what is wrong (with the JSON key).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "perch2/core/camera.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"

namespace perch2::dataset {

using Mask = Image<std::uint8_t>;  ///< binary mask, 1 = inside, 0 = outside

/// Continuous rotational symmetry about the line through offset_m along axis (object frame).
struct ContinuousSymmetry {
  Eigen::Vector3f axis = Eigen::Vector3f::UnitZ();  ///< unit vector
  Eigen::Vector3f offset_m = Eigen::Vector3f::Zero();
};

/// One entry of models_info.json, in metres.
struct ModelInfo {
  int obj_id = 0;
  float diameter_m = 0;  ///< largest distance between two model vertices
  /// Discrete symmetries T_obj_obj' (the identity is not listed), translation in metres.
  std::vector<Pose> symmetries_discrete;
  std::vector<ContinuousSymmetry> symmetries_continuous;
  bool is_symmetric() const { return !symmetries_discrete.empty() || !symmetries_continuous.empty(); }
};

/// One ground-truth instance from scene_gt.json (+ scene_gt_info.json when present).
struct GtInstance {
  int obj_id = 0;
  Pose T_cam_obj = Pose::Identity();  ///< model -> camera, metres
  bool has_info = false;              ///< scene_gt_info.json had an entry for it
  float visib_fract = 1.f;            ///< visible fraction of the silhouette (1 without scene_gt_info)
  Eigen::Vector4i bbox_obj{-1, -1, -1, -1}, bbox_visib{-1, -1, -1, -1};  ///< x, y, width, height, pixels
  int px_count_all = 0, px_count_valid = 0, px_count_visib = 0;
};

/// Everything known about one image without reading its pixels.
struct ImageInfo {
  int scene_id = 0, im_id = 0;
  Intrinsics camera;                ///< cam_K; width/height from camera.json or the first image of the scene
  float depth_scale_mm = 1.f;       ///< millimetres per depth-PNG unit
  std::optional<Pose> T_cam_world;  ///< from cam_R_w2c / cam_t_w2c when given (metres)
  std::vector<GtInstance> gt;       ///< empty when the scene has no scene_gt.json
};

/// One target of the BOP challenge: inst_count instances of obj_id in an image.
struct Target {
  int scene_id = 0, im_id = 0, obj_id = 0, inst_count = 0;
};

/// The task a targets file sets. Localization (test_targets_bop19.json): each image's objects and their
/// instance counts are given. Detection (test_targets_bop24.json, BOP 2024): only the images; any model of
/// the dataset may be in an image any number of times, or not at all.
enum class TargetTask { NoTargets, Localization, Detection };

/// Which parts of an image load_image() reads.
struct ImageLoadOptions {
  bool rgb = true;          ///< rgb/IM_ID.png or .jpg (missing file: FileError)
  bool depth = true;        ///< depth/IM_ID.png -> metres
  bool masks_visib = true;  ///< mask_visib/IM_ID_GT_ID.png for every GT instance
  bool masks = false;       ///< mask/IM_ID_GT_ID.png (full silhouettes) for every GT instance
};

/// One image's pixels. frame.camera has the image size; frame.depth_m is planar z in metres (0 = none).
struct BopImage {
  ImageInfo info;
  RgbdFrame frame;                ///< rgb may be empty (not requested); depth_m empty if not requested
  std::vector<Mask> masks_visib;  ///< one per info.gt entry (if requested)
  std::vector<Mask> masks;        ///< one per info.gt entry (if requested)
  /// mask_visib as one label image: GT index + 1 where visible, 0 elsewhere (later instances win overlaps).
  LabelImage visible_labels() const;
};

/// An image the split lists (or the targets file asks for) that the dataset cannot give: one of its scene's
/// JSON entries is malformed (or the whole file is). Costs only this image: opening the dataset goes on.
struct BadImage {
  int scene_id = 0, im_id = 0;
  std::string path;    ///< the JSON file
  std::string reason;  ///< what is wrong with the image's entry (with the key)
};

/// One file's bytes and the path they came from (named in every error about them).
struct FileBytes {
  std::string path;
  std::string bytes;
};

/// The encoded files of one image, as BopDataset::read_image_files() reads them (or a process that can
/// read the dataset sends them to one that cannot). Absent or empty: not requested.
struct ImageFiles {
  std::optional<FileBytes> rgb;        ///< rgb/IM_ID.png or .jpg (or gray/)
  std::optional<FileBytes> depth;      ///< depth/IM_ID.png
  std::vector<FileBytes> masks_visib;  ///< mask_visib/IM_ID_GT_ID.png, one per info.gt entry
  std::vector<FileBytes> masks;        ///< mask/IM_ID_GT_ID.png, one per info.gt entry
};

/// Reads the bytes of every file named in `files` (from BopDataset::image_files); FileError names a missing
/// or unreadable one.
ImageFiles read_files(ImageFiles files);

/// Decodes an image's files (load_image() is read_image_files() + this): depth to metres with
/// info.depth_scale_mm, masks to 0/1. FileError naming the file for bytes that are not a complete image of
/// the right kind, or whose size disagrees with the camera or the other files; InvalidInput if masks are
/// given but not one per ground-truth instance.
BopImage decode_image(const ImageInfo& info, const ImageFiles& files);

struct DatasetOptions {
  std::string split = "test";  ///< folder of scenes under the root
  /// Targets file under the root; "" = test_targets_bop19.json, else test_targets_bop24.json, else none.
  std::string targets_file;
  /// Folder of the models under the root; "" = "models".
  std::string models_dir;
  /// false: scene_gt.json and scene_gt_info.json are not read (an estimator's view of a test set, whose
  /// ground truth BOP withholds); ImageInfo::gt stays empty, so images have no masks to load.
  bool ground_truth = true;
};

class BopDataset {
 public:
  /// Parses models_info.json, camera.json, the targets file and every scene's JSON files of the split.
  /// A malformed entry of a scene's JSON files (or a malformed scene file) costs only the images it
  /// describes: they are listed in bad_images() and info()/load_image() throw its FileError. A missing or
  /// malformed models_info.json, camera.json or targets file, a missing split folder, a split without
  /// scene folders, or a target in no scene at all still throw FileError here.
  explicit BopDataset(std::string root, DatasetOptions options = {});

  const std::string& root() const { return root_; }
  const std::string& split_path() const { return split_path_; }
  const std::string& models_path() const { return models_path_; }

  const std::map<int, ModelInfo>& models_info() const { return models_info_; }
  /// models_info of obj_id; InvalidInput if the dataset has no such object.
  const ModelInfo& model_info(int obj_id) const;
  /// Path of obj_OBJ_ID.ply in the models folder (whether or not it exists).
  std::string model_path(int obj_id) const;
  /// Loads obj_OBJ_ID.ply, millimetres -> metres.
  Mesh load_model(int obj_id) const;

  /// Scene ids of the split, ascending.
  std::vector<int> scene_ids() const;
  /// Every usable (scene, image) of the split, in scene then image order (bad images are not listed).
  std::vector<std::pair<int, int>> image_ids() const;
  /// FileError naming the JSON file and the entry if it is a bad image; InvalidInput if the split has no
  /// such image.
  const ImageInfo& info(int scene_id, int im_id) const;
  bool has_image(int scene_id, int im_id) const;  ///< a usable image (not a bad one)

  /// The images whose JSON entries are malformed, and problems of the scene files that cost no listed
  /// image ("PATH: reason": a key that is not an image id, an entry for an image scene_camera.json does not
  /// list), e.g. to print when a run starts.
  const std::map<std::pair<int, int>, BadImage>& bad_images() const { return bad_images_; }
  const BadImage* bad_image(int scene_id, int im_id) const;  ///< nullptr if the image is not bad
  const std::vector<std::string>& warnings() const { return warnings_; }

  /// Path of the targets file read ("" if none), the task it sets, and its targets (Localization: as
  /// listed; Detection: none, only target_images()).
  const std::string& targets_path() const { return targets_path_; }
  TargetTask target_task() const { return target_task_; }
  const std::vector<Target>& targets() const { return targets_; }
  /// Every image the targets file lists, ascending, bad images included.
  const std::vector<std::pair<int, int>>& target_images() const { return target_images_; }

  /// Reads the requested images of one (scene, image). FileError names a missing or broken file.
  BopImage load_image(int scene_id, int im_id, const ImageLoadOptions& options = {}) const;
  /// Which files load_image() reads for these options: their paths, bytes empty (e.g. for a process that
  /// reads them and sends their bytes to one that cannot). FileError/InvalidInput as info().
  ImageFiles image_files(int scene_id, int im_id, const ImageLoadOptions& options = {}) const;
  /// image_files() with their bytes read, undecoded (see decode_image). FileError names a missing or
  /// unreadable file.
  ImageFiles read_image_files(int scene_id, int im_id, const ImageLoadOptions& options = {}) const;

 private:
  std::string root_, split_path_, models_path_, targets_path_;
  std::map<int, ModelInfo> models_info_;
  std::map<int, std::map<int, ImageInfo>> scenes_;  // usable images only
  std::map<std::pair<int, int>, BadImage> bad_images_;
  std::vector<std::string> warnings_;
  TargetTask target_task_ = TargetTask::NoTargets;
  std::vector<Target> targets_;
  std::vector<std::pair<int, int>> target_images_;
};

/// Targets grouped by image, (scene_id, im_id) ascending; targets with inst_count 0 and scenes outside
/// [first_scene, last_scene] are dropped.
std::map<std::pair<int, int>, std::vector<Target>> targets_by_image(const std::vector<Target>& targets,
                                                                    int first_scene = 0,
                                                                    int last_scene = 1 << 30);

/// The images a run over scenes [first_scene, last_scene] estimates, (scene_id, im_id) ascending: those the
/// targets file lists with at least one instance (Detection: every image it lists), and the bad images it
/// lists (a run reports them).
/// BopRunner::images() is this; a driver that holds no models can list them too.
std::vector<std::pair<int, int>> run_images(const BopDataset& data, int first_scene = 0,
                                            int last_scene = 1 << 30);

/// Zero-padded 6-digit id, as BOP names folders and files ("000042").
std::string bop_id(int id);

/// Parses models_info.json (mm -> m). FileError naming the file and key on any problem.
std::map<int, ModelInfo> load_models_info(const std::string& path);

}  // namespace perch2::dataset
