// One image of a BOP dataset at a time, in either mode: what `perch2 estimate`, the Python bindings and the
// distributed driver's workers call (library perch2::runner, which links the backends).
//
//   perch2::dataset::BopDataset data(root);
//   perch2::dataset::RunOptions options;             // mode, backend, variant, masks, box, settings
//   options.mode = perch2::dataset::RunMode::SixDof;
//   const perch2::dataset::BopRunner runner(data, options);  // models loaded once, estimator built once
//   for (const auto& [scene, im] : runner.images()) {
//     try {
//       const perch2::dataset::ImageResult r = runner.estimate(scene, im);  // rows, timings, counts
//       use(r.rows);
//     } catch (const perch2::dataset::ImageError& e) {  // this image only: unreadable file, bad entry, ...
//       report(e.scene_id, e.im_id, e.reason);
//     }
//   }
//
// The image can also come from memory: a process that reads the dataset sends the bytes of
// runner.image_files(scene, im) (read_files, perch2/dataset/bop.hpp); one that cannot (the same dataset's
// JSON and models, without its images) calls runner.estimate(scene, im, files).
#pragma once

#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "perch2/core/export.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/results.hpp"
#include "perch2/search/sixdof.hpp"
#include "perch2/search/sixdof_bop.hpp"
#include "perch2/search/tabletop.hpp"

namespace perch2::dataset {

enum class RunMode { Tabletop, SixDof };  ///< "3dof" (x, y, yaw on the table) | "6dof" (full pose)
enum class BackendKind { Cpu, ThrustOmp };

/// "3dof" | "6dof"; InvalidInput naming the value otherwise.
PERCH2_API RunMode parse_mode(const std::string& name);
PERCH2_API const char* mode_name(RunMode m);
/// "cpu" | "thrust_omp"; InvalidInput naming the value otherwise.
PERCH2_API BackendKind parse_backend(const std::string& name);
PERCH2_API const char* backend_name(BackendKind b);
/// The CLI spellings: perch2c | perch2a | perch2b | perch | depth-only | bf-icp; InvalidInput otherwise.
PERCH2_API SearchVariant parse_variant(const std::string& name);
PERCH2_API const char* variant_name(SearchVariant v);
inline constexpr const char* kVariantNames = "perch2c|perch2a|perch2b|perch|depth-only|bf-icp";

/// How a run estimates each image.
struct RunOptions {
  RunMode mode = RunMode::Tabletop;
  BackendKind backend = BackendKind::ThrustOmp;
  /// 3-DoF: the search variant, applied over `tabletop` (tabletop_variant); instances not found are reported
  /// in ImageResult::missing, never thrown (strict_instances is turned off).
  SearchVariant variant = SearchVariant::Perch2C;
  TabletopSettings tabletop;
  /// 6-DoF: where the instances come from: "gt" (the dataset's mask_visib), a detection file (BOP/COCO
  /// JSON with RLE masks, read once when the runner is built), or "none": no masks, the targets' objects
  /// and instance counts are searched for in the whole frame (SixDofEstimator::estimate_scene; instances
  /// not found are counted in ImageResult::missing).
  /// On detection targets (bop24: images only) "none" searches the whole catalogue
  /// (SixDofEstimator::detect with `detect`), and "gt" or a file estimates every instance they give.
  std::string masks = "gt";
  BoxKind box = BoxKind::Full;  ///< 6-DoF with "gt" masks: scene_gt_info's amodal bbox_obj, or bbox_visib
  SixDofSettings sixdof;
  /// Detection targets (bop24): what detect() may report (6-DoF with masks "none"; 3-DoF: its caps only,
  /// its score has another scale and the colour limit is the 6-DoF search's).
  DetectSettings detect;
  /// 6-DoF: an instance with fewer valid depth readings inside its mask (on the observed grid, once later
  /// masks have taken their pixels) is skipped and counted in ImageResult::unusable.
  int min_instance_points = 10;
};

/// What a run with these options reads of each image (rgb and depth; 6-DoF with "gt" masks: mask_visib
/// too), e.g. for BopDataset::read_image_files() in a driver that holds no runner.
PERCH2_API ImageLoadOptions load_options(const RunOptions& options);

/// One image's estimate.
struct ImageResult {
  int scene_id = 0, im_id = 0;
  std::vector<PoseEstimate> rows;  ///< BOP rows (may be empty: nothing found or every instance unusable)
  std::vector<int> row_models;     ///< per row: index into BopRunner::meshes()
  std::vector<bool> row_found;     ///< per row: 6-DoF: the pose showed enough rendered points; 3-DoF: true
  /// Per-stage wall-clock seconds in the estimator's order, "total" last (3-DoF: table, observed,
  /// hypotheses, render, refine, cost, select, yaw (the yaw search; its renders and costs are also in render
  /// and cost); 6-DoF: observed, proposals, render, refine, cost, select).
  std::vector<std::pair<std::string, double>> stages;
  double seconds = 0;  ///< the image's estimate time (the rows' "time" column)
  int requested = 0;   ///< instances the targets ask for
  int missing = 0;     ///< 3-DoF and 6-DoF with masks "none": requested instances not found
  int unusable = 0;    ///< 6-DoF: target instances skipped for too few depth readings in their mask
  int instances = 0;   ///< 6-DoF: instances estimated (masks "none": placed)
  std::optional<TabletopResult> tabletop;  ///< the estimator's full result (3-DoF)
  /// the estimator's full result (6-DoF; masks "none": the scene search's counts and timings, no poses)
  std::optional<SixDofResult> sixdof;
};

/// An image that could not be estimated (an unreadable or truncated image file, a missing mask, a
/// malformed per-image JSON entry, ...): only that image is lost. what() = "scene S image I: REASON", where
/// REASON names the file (or input) and what is wrong.
struct PERCH2_API ImageError : std::runtime_error {
  ImageError(int scene, int im, const std::string& why);
  int scene_id = 0, im_id = 0;
  std::string reason;
};

/// Estimates the target objects of a BOP dataset's images one at a time: the models of every target object
/// are loaded (millimetres -> metres) and the estimator is built once. Holds its own copy of the dataset's
/// index (the BopDataset may go away). Dataset-level problems (a missing model, an unreadable detection
/// file, no target) throw from the constructor; per-image problems throw ImageError from estimate().
class PERCH2_API BopRunner {
 public:
  /// `obj_ids`: the objects to load; empty = every object of the dataset's targets.
  BopRunner(const BopDataset& data, RunOptions options, std::vector<int> obj_ids = {});
  ~BopRunner();
  BopRunner(BopRunner&&) noexcept;
  BopRunner& operator=(BopRunner&&) noexcept;

  /// run_images(dataset, first_scene, last_scene): the images with targets, (scene_id, im_id) ascending;
  /// images the targets file lists whose JSON entries are broken are included (estimate() reports them).
  std::vector<std::pair<int, int>> images(int first_scene = 0, int last_scene = 1 << 30) const;
  /// The image's targets (empty if it has none).
  const std::vector<Target>& targets(int scene_id, int im_id) const;

  /// What estimate() needs of an image: load_options(options()).
  ImageLoadOptions load_options() const;

  /// Reads one image of the dataset as estimate() needs it; ImageError if any of its files is bad.
  BopImage load_image(int scene_id, int im_id) const;
  /// load_image() + estimate(image). ImageError if anything about this image is bad.
  ImageResult estimate(int scene_id, int im_id) const;
  /// The files estimate() reads for the image (paths; bytes empty: read_files() fills them). ImageError if
  /// the image is bad (its JSON entry).
  ImageFiles image_files(int scene_id, int im_id) const;
  /// Decodes the image from its files' bytes (decode_image with the dataset's ImageInfo) and estimates it;
  /// ImageError naming the file for bad bytes, as estimate(scene_id, im_id).
  ImageResult estimate(int scene_id, int im_id, const ImageFiles& files) const;
  /// Estimates an image already in memory (e.g. from decode_image) with its targets from the dataset.
  ImageResult estimate(const BopImage& image) const;

  const RunOptions& options() const;
  const std::vector<int>& obj_ids() const;  ///< the loaded objects, ascending; model index = position
  const std::vector<Mesh>& meshes() const;  ///< per model, metres
  int model_index(int obj_id) const;        ///< InvalidInput if obj_id is not loaded
  /// A one-line description: "3dof, variant perch2c, backend thrust_omp" / "6dof, masks gt, full boxes, ...".
  std::string describe() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace perch2::dataset
