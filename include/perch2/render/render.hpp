// The batch-render stage: (model, T_cam_obj) hypotheses -> one point-cloud batch on the stride grid.
// Backends implement `Renderer` with this interface (see perch2/cpu/render.hpp, perch2/cuda/render.hpp):
//   explicit Renderer(std::vector<Mesh> models);
//   CloudBatch render(const std::vector<Hypothesis>&, const Intrinsics& full_res_camera,
//                     const RenderSettings&, const Occluders* = nullptr) const;
// Cloud h of the result holds hypothesis h's visible surface points, in raster order of the stride grid.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "perch2/core/camera.hpp"
#include "perch2/core/cloud.hpp"
#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"

namespace perch2 {

struct RenderSettings {
  int stride = 4;                    ///< render full-resolution pixels (s*i, s*j) only, i.e. intrinsics K/s
  float near_m = 0.01f;              ///< near clipping plane, metres; nearer surface is not rendered
  bool cull_back_faces = true;       ///< skip triangles facing away (needs consistent outward winding)
  float occlusion_margin_m = 0.01f;  ///< an observed depth nearer by more than this occludes, metres
  /// Working memory of one chunk of hypotheses in the Thrust backend (z-buffers, posed vertices, resolved
  /// samples, outputs), bytes. 0: the backend's default: 64 MiB on CPU systems (there each thread renders
  /// whole hypotheses in its own cache-sized scratch; the chunk holds their outputs, and fewer chunks mean
  /// fewer parallel regions), 256 MiB on CUDA (enough hypotheses per chunk to fill a GPU).
  std::size_t memory_budget_bytes = 0;
};

struct Hypothesis {
  int model = 0;                      ///< index into the renderer's models
  Pose T_cam_obj = Pose::Identity();  ///< object -> camera
  int label =
      -1;  ///< the observed label this hypothesis explains (its own pixels never occlude it); -1: none
};

/// Observed images that hide rendered pixels behind them (the C-PERCH "extraneous occluders").
/// A rendered pixel is dropped when the observed depth there is valid and nearer by more than
/// RenderSettings::occlusion_margin_m and, if labels are given, the pixel is labelled as another
/// object or background (label != Hypothesis::label).
struct Occluders {
  DepthImage depth_m;  ///< full resolution, metres, 0 = no reading
  LabelImage labels;   ///< empty, or full resolution
};

/// Throws InvalidInput for zero hypotheses, unknown models, invalid poses, bad settings or mismatched
/// occluder images. Shared by every backend so all reject the same inputs with the same message.
inline void validate_render_request(const std::vector<Hypothesis>& hypotheses, std::size_t num_models,
                                    const Intrinsics& camera, const RenderSettings& settings,
                                    const Occluders* occluders) {
  if (hypotheses.empty()) throw InvalidInput("hypotheses", "no hypotheses to render");
  camera.validate("render camera");
  if (settings.stride < 1) throw InvalidInput("RenderSettings::stride", "must be >= 1");
  if (camera.grid_width(settings.stride) > 32767 || camera.grid_height(settings.stride) > 32767)
    throw InvalidInput("render camera", "the stride grid must be at most 32767 samples wide and high");
  if (!(settings.near_m > 0)) throw InvalidInput("RenderSettings::near_m", "must be > 0");
  if (!(settings.occlusion_margin_m >= 0))
    throw InvalidInput("RenderSettings::occlusion_margin_m", "must be >= 0");
  for (std::size_t h = 0; h < hypotheses.size(); ++h) {
    const std::string who = "hypothesis " + std::to_string(h);
    if (hypotheses[h].model < 0 || std::size_t(hypotheses[h].model) >= num_models)
      throw InvalidInput(who, "model index " + std::to_string(hypotheses[h].model) + " out of range (" +
                                  std::to_string(num_models) + " models)");
    if (!is_valid_pose(hypotheses[h].T_cam_obj))
      throw InvalidInput(who, "T_cam_obj is not a finite rigid transform");
  }
  if (occluders) {
    check_size(occluders->depth_m, camera.width, camera.height, "occluder depth");
    check_depth_values(occluders->depth_m, "occluder depth");
    if (!occluders->labels.empty())
      check_size(occluders->labels, camera.width, camera.height, "occluder labels");
  }
}

inline void validate_models(const std::vector<Mesh>& models) {
  if (models.empty()) throw InvalidInput("models", "no models given to the renderer");
  for (const auto& m : models) m.validate();
}

}  // namespace perch2
