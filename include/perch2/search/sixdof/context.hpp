// What the 6-DoF passes share. Shared: per estimator, built once from the models (the models, the
// settings, per-model sizes and colours, the renderer, the surface fit); the estimator owns it. Job: one
// search (a model's proposals around a box, refined against one observed segment). Context: per frame,
// what the passes over it read (the frame, its occluders, the GICP targets, the cost's observed clouds and
// which of them belongs to each job). Also the small helpers several passes use (the clock, mask boxes,
// model colours).
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <optional>
#include <utility>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/observed.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/registration/surface_fit.hpp"
#include "perch2/render/render.hpp"
#include "perch2/render/simplify.hpp"
#include "perch2/search/proposals.hpp"
#include "perch2/search/sixdof/result.hpp"
#include "perch2/search/sixdof/settings.hpp"

namespace perch2 {
namespace sixdof_detail {

using Clock = std::chrono::steady_clock;
inline double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

/// Bounding box (x, y, w = x_max - x_min, h) of a mask's non-zero pixels; w = -1 if none.
inline Eigen::Vector4i mask_box(const Image<std::uint8_t>& mask) {
  const std::array<int, 4> b = mask_bbox(mask);
  return {b[0], b[1], b[2], b[3]};
}

/// A model's colours (packed sRGB), one per bin of 6 bits per channel: its vertex colours, its texture's
/// texels (at most ~65k of them, evenly spread) or its base colour.
inline std::vector<std::uint32_t> model_colours(const Mesh& m) {
  std::vector<std::uint8_t> seen(std::size_t(1) << 18, 0);
  std::vector<std::uint32_t> out;
  auto add = [&](Rgb8 c) {
    const std::size_t bin = std::size_t(c.r >> 2) << 12 | std::size_t(c.g >> 2) << 6 | std::size_t(c.b >> 2);
    if (!seen[bin]) seen[bin] = 1, out.push_back(pack_rgb(c));
  };
  if (m.has_vertex_colors()) {
    for (const Rgb8 c : m.vertex_colors) add(c);
  } else if (m.has_texture()) {
    const int w = m.texture.width, h = m.texture.height;
    const int step = std::max(1, int(std::ceil(std::sqrt(double(w) * double(h) / 65536.0))));
    for (int v = 0; v < h; v += step)
      for (int u = 0; u < w; u += step) add(m.texture(u, v));
  } else {
    add(m.base_color);
  }
  return out;
}

inline float model_diameter_bound(const Mesh& m) {
  float r = 0;
  for (const auto& p : m.vertices) r = std::max(r, p.norm());
  return 2.f * r;  // >= the diameter; exact for a model symmetric about its centre
}

inline std::vector<Mesh> meshes_of(const std::vector<SixDofModel>& models) {
  if (models.empty()) throw InvalidInput("6-DoF models", "no models given");
  std::vector<Mesh> out;
  for (const auto& m : models) out.push_back(m.mesh);
  return out;
}

/// The meshes of the coarse renders (CoarseMeshSettings): each model's simplified copy if it has at least
/// min_triangles; none if no model has (the full meshes are then rendered at every stride).
inline std::vector<Mesh> coarse_meshes_of(const std::vector<SixDofModel>& models,
                                          const CoarseMeshSettings& s) {
  if (s.min_stride < 0)
    throw InvalidInput("SixDofSettings::coarse_mesh.min_stride", "must be >= 0 (0 = never)");
  if (!(std::isfinite(s.cell_fraction) && s.cell_fraction > 0.f))
    throw InvalidInput("SixDofSettings::coarse_mesh.cell_fraction", "must be finite and > 0");
  if (s.texture_factor < 1) throw InvalidInput("SixDofSettings::coarse_mesh.texture_factor", "must be >= 1");
  if (s.min_stride == 0 || std::none_of(models.begin(), models.end(), [&](const SixDofModel& m) {
        return m.mesh.triangles.size() >= s.min_triangles;
      }))
    return {};
  std::vector<Mesh> out;
  for (const auto& m : models)
    out.push_back(m.mesh.triangles.size() >= s.min_triangles
                      ? simplified(m.mesh, s.cell_fraction * model_diameter_bound(m.mesh), s.texture_factor)
                      : m.mesh);
  return out;
}

/// What every pass of one estimator shares: the models and settings, what the passes need to know of each
/// model, the renderer and the surface fit (the models uploaded to the backend once). Validates the models
/// (InvalidInput on no models or a bad mesh).
template <class Backend>
struct Shared {
  Shared(std::vector<SixDofModel> models_in, SixDofSettings settings_in)
      : models(std::move(models_in)),
        settings(std::move(settings_in)),
        renderer(meshes_of(models)),
        surface_fit(meshes_of(models), settings.fit_sample_spacing_m) {
    if (std::vector<Mesh> coarse = coarse_meshes_of(models, settings.coarse_mesh); !coarse.empty())
      coarse_renderer.emplace(std::move(coarse));
    for (const auto& m : models) {
      diameter.push_back(model_diameter_bound(m.mesh));
      Eigen::Vector3f e = m.mesh.bounds().sizes();
      std::sort(e.data(), e.data() + 3);
      size_m.push_back(e.norm());
      face_m2.emplace_back(e[0] * e[1], e[1] * e[2]);
      colours.push_back(model_colours(m.mesh));
      surface_moments.push_back(surface_second_moments(m.mesh));
    }
  }

  std::vector<SixDofModel> models;
  SixDofSettings settings;
  typename Backend::Renderer renderer;
  /// The simplified meshes' renderer for strides >= settings.coarse_mesh.min_stride (none: renderer).
  std::optional<typename Backend::Renderer> coarse_renderer;
  SurfaceFit<Backend> surface_fit;
  const typename Backend::Renderer& renderer_at(int stride) const {
    const int min = settings.coarse_mesh.min_stride;
    return coarse_renderer && min > 0 && stride >= min ? *coarse_renderer : renderer;
  }
  std::vector<float> diameter;  ///< per model, an upper bound (2 x the largest vertex distance), metres
  std::vector<float> size_m;    ///< per model, its bounding box's diagonal, metres
  /// per model, its bounding box's smallest and largest face, m^2 (the scene search's size rules)
  std::vector<std::pair<float, float>> face_m2;
  std::vector<std::vector<std::uint32_t>> colours;  ///< per model, model_colours()
  std::vector<Eigen::Matrix3f> surface_moments;  ///< per model, surface_second_moments() (aligned proposals)
};

/// One search of the pipeline: a model's proposals (rotations x depths on the ray through the box centre)
/// refined against one observed segment. estimate(): one per instance; estimate_scene(): one per
/// (model, segment or piece of one).
struct Job {
  int model = 0;
  std::int32_t segment = 0;  ///< observed cloud of the cost (J_o's points; in estimate() GICP's too)
  std::int32_t target = 0;   ///< observed cloud of GICP's targets
  std::int32_t label = 0;    ///< the label of its own pixels in the occluders (they never hide it)
  std::vector<std::int32_t> piece_pixels;  ///< estimate_scene, a piece of a segment: its pixels (targets)
  Eigen::Vector4i box_xywh{0, 0, 0, 0};
  std::vector<float> depths;  ///< proposal depths, metres
  float colour_fraction = 1;  ///< estimate_scene: its readings' fraction of colours the model shows
  /// If finite: the long axis of its pixels in the image, radians (principal_angle()), from which its
  /// proposals' in-plane angles start (aligned_rotation_proposals; detect()'s retrieval).
  float image_axis_rad = NAN;
  float retrieval_score = 0;  ///< detect(): how well the model fits its segment, higher first (retrieval.hpp)
  float retrieval_depth_m = 0;       ///< detect(): planar depth of the coarse search's best pose, metres
  bool retrieval_acceptable = true;  ///< detect(): whether that pose may be placed (acceptable())
  /// detect(): a half of a segment its model's size rule took whole (add_half_jobs)
  bool half = false;
};

/// A job's selected hypothesis (label = job + 1) and its final cost; with the local search deferred
/// (search()'s defer_local), also the job's best hypotheses it would have searched around, best first.
struct Finalist {
  Hypothesis hypothesis;
  CostBreakdown cost;
  std::vector<Hypothesis> local_starts;
};

/// What the passes over one frame share: the estimator's Shared, the frame, its occluders, the observed
/// segments (GICP targets, J_o's points) and the segment each job's hypotheses explain
/// (Hypothesis::label = job + 1).
template <class Backend>
struct Context {
  const Shared<Backend>& shared;
  const RgbdFrame& frame;
  const Occluders& occ;
  const typename Backend::Registration* registration;  ///< null where nothing is refined
  /// The first pass' targets (SixDofSettings::first_pass_target_stride); may be `registration`.
  const typename Backend::Registration* first_pass_registration;
  const typename Backend::Cost& cost;
  const std::vector<std::int32_t>& job_cloud;   ///< per job: its cost's observed cloud (J_o)
  const std::vector<std::int32_t>& job_label;   ///< per job: the label of its own pixels (never hide it)
  const std::vector<std::int32_t>& job_target;  ///< per job: its registration cloud (GICP targets)
  std::int32_t segment_of(const Hypothesis& h) const { return job_cloud[std::size_t(h.label - 1)]; }
  std::int32_t target_of(const Hypothesis& h) const { return job_target[std::size_t(h.label - 1)]; }
  std::int32_t label_of(const Hypothesis& h) const { return job_label[std::size_t(h.label - 1)]; }
  CostRequest request(const std::vector<Hypothesis>& hyps) const {
    CostRequest r;
    for (const auto& h : hyps) r.add(segment_of(h));
    return r;
  }
};

/// Proposals, both passes, the local search and the selection of every job (defined in
/// perch2/search/sixdof.hpp, where it reads as the pipeline; estimate_scene's passes call it too).
template <class Backend>
std::vector<Finalist> search(const Context<Backend>& ctx, const std::vector<Job>& jobs,
                             const std::vector<std::size_t>& segment_points,
                             std::vector<std::size_t>& points_estimate, SixDofResult& result,
                             bool defer_local, bool screen_proposals);

}  // namespace sixdof_detail
}  // namespace perch2
