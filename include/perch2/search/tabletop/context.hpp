// What the tabletop search's passes share (perch2/search/tabletop.hpp): the estimator's Context (models,
// settings, the renderer, each model's footprint and reach) and a frame's Frame (the table, the observed
// clouds, the cost and registration built on them, the occluders), the Candidate a pass hands to the next
// (a model at (x, y, yaw) on the table), and the few helpers every pass uses: the placement of a candidate,
// its render and the TabletopPose it becomes. Every pass is a function template over Backend taking the
// Context and the Frame; the estimator owns the one and builds the other per call.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
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
#include "perch2/render/render.hpp"
#include "perch2/search/tabletop/result.hpp"
#include "perch2/search/tabletop/settings.hpp"

namespace perch2::tabletop_detail {

using Clock = std::chrono::steady_clock;
inline double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

inline constexpr float kTwoPi = 6.28318531f;

inline Pose placement(float x, float y, float yaw) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisf(yaw, Eigen::Vector3f::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3f(x, y, 0.f);
  return T;
}

inline Pose default_rest_pose(const Mesh& m) {
  Pose T = Pose::Identity();
  T.translation().z() = -m.bounds().min().z();
  return T;
}

struct Candidate {
  int model;
  float x, y, yaw;
};

/// Whether a turn of the model can change what the colour test sees: it has a texture, or vertex colours
/// that differ, and is not declared symmetric about the table normal without a texture (e.g. an untextured
/// bowl). A single-coloured model's yaw is decided by its geometry (ICP) alone.
inline bool yaw_visible_in_colour(const TabletopModel& m) {
  if (m.mesh.has_texture()) return true;
  if (m.yaw_symmetric || m.mesh.vertex_colors.empty()) return false;
  const Rgb8 c0 = m.mesh.vertex_colors.front();
  return std::any_of(m.mesh.vertex_colors.begin(), m.mesh.vertex_colors.end(),
                     [&](const Rgb8& c) { return c.r != c0.r || c.g != c0.g || c.b != c0.b; });
}

/// Whether the yaw search (TabletopSettings::yaw_search) runs after selection.
inline bool yaw_search_runs(const TabletopSettings& s) {
  return s.yaw_search.enabled && s.mode != SearchMode::BruteForceIcp;
}

/// Keeps the points of a batch for which keep(global index) is true (offsets recomputed).
template <class Keep>
CloudBatch filter_points(const CloudBatch& in, Keep&& keep) {
  CloudBatch out;
  out.offsets = {0};
  for (std::size_t c = 0; c < in.num_clouds(); ++c) {
    for (auto i = std::size_t(in.offsets[c]); i < std::size_t(in.offsets[c + 1]); ++i)
      if (keep(i)) {
        out.x.push_back(in.x[i]), out.y.push_back(in.y[i]), out.z.push_back(in.z[i]);
        out.rgb.push_back(in.rgb[i]), out.pixel.push_back(in.pixel[i]), out.cloud.push_back(in.cloud[i]);
      }
    out.offsets.push_back(std::int64_t(out.size()));
  }
  return out;
}

/// The estimator's state: the models (rest poses filled in), the settings, the renderer holding the
/// models, and per model what the passes derive from it once.
template <class Backend>
struct Context {
  /// Validates the models and uploads them to the backend's renderer. Throws InvalidInput on no models,
  /// a bad mesh or a bad rest pose.
  Context(std::vector<TabletopModel> models_in, TabletopSettings settings_in)
      : models(std::move(models_in)), settings(std::move(settings_in)), renderer(meshes_of(models)) {
    for (auto& m : models) {
      if (!m.T_place_obj) m.T_place_obj = default_rest_pose(m.mesh);
      if (!is_valid_pose(*m.T_place_obj))
        throw InvalidInput("model '" + m.mesh.name + "'", "T_place_obj is not a finite rigid transform");
      footprints.push_back(table_footprint(m.mesh, *m.T_place_obj, 0.f));  // floor set per call
      float r2 = 0;
      for (const auto& p : footprints.back().polygon_xy_m) r2 = std::max(r2, p.squaredNorm());
      circumradius.push_back(std::sqrt(r2));
      yaw_symmetric.push_back(m.yaw_symmetric);
      yaw_searched.push_back(yaw_visible_in_colour(m));
    }
  }

  static std::vector<Mesh> meshes_of(const std::vector<TabletopModel>& models) {
    if (models.empty()) throw InvalidInput("tabletop models", "no models given");
    std::vector<Mesh> out;
    for (const auto& m : models) out.push_back(m.mesh);
    return out;
  }

  std::vector<TabletopModel> models;
  TabletopSettings settings;
  typename Backend::Renderer renderer;
  std::vector<Footprint> footprints;  ///< per model, placement frame (floor: min_height_m, per call)
  std::vector<float> circumradius;    ///< per model, of the footprint about the placement origin, metres
  std::vector<bool> yaw_symmetric;    ///< per model (TabletopModel::yaw_symmetric)
  std::vector<bool> yaw_searched;     ///< per model: the yaw search turns it (yaw_visible_in_colour)
};

/// Per-frame state.
template <class Backend>
struct Frame {
  explicit Frame(const RgbdFrame& f) : rgbd(f) {}
  const RgbdFrame& rgbd;
  Pose T_cam_world = Pose::Identity();
  CloudBatch observed;                     ///< scored against (whole frame at settings.observed)
  CloudBatch objects;                      ///< observed readings above the table (ICP target)
  std::vector<Eigen::Vector2f> object_xy;  ///< their table coordinates
  Eigen::AlignedBox2f workspace;
  std::optional<typename Backend::Cost> cost;
  std::optional<typename Backend::Registration> registration;
  /// The observed depth as occluders (occluder marking): with missing_depth_hides, a pixel without a
  /// reading holds the smallest positive depth, which hides every rendered point.
  Occluders occluders;
};

template <class Backend>
Pose T_world_obj(const Context<Backend>& ctx, const Candidate& c) {
  return placement(c.x, c.y, c.yaw) * *ctx.models[c.model].T_place_obj;
}

template <class Backend>
std::vector<Hypothesis> to_hypotheses(const Context<Backend>& ctx, const Frame<Backend>& f,
                                      const std::vector<Candidate>& cands) {
  std::vector<Hypothesis> h;
  for (const auto& c : cands) h.push_back({c.model, f.T_cam_world * T_world_obj(ctx, c), -1});
  return h;
}

template <class Backend>
CloudBatch render(const Context<Backend>& ctx, const Frame<Backend>& f, const std::vector<Candidate>& cands,
                  int stride, const Occluders* occ, TabletopTimings& timings) {
  const auto t = Clock::now();
  RenderSettings rs = ctx.settings.render;
  rs.stride = stride;
  CloudBatch out = ctx.renderer.render(to_hypotheses(ctx, f, cands), f.rgbd.camera, rs, occ);
  timings.render += seconds_since(t);
  return out;
}

template <class Backend>
TabletopPose make_pose(const Context<Backend>& ctx, const Frame<Backend>& f, const Candidate& c, int instance,
                       float score, const CostBreakdown& b) {
  TabletopPose p;
  p.model = c.model, p.instance = instance;
  p.T_world_obj = T_world_obj(ctx, c);
  p.T_cam_obj = f.T_cam_world * p.T_world_obj;
  p.x_m = c.x, p.y_m = c.y, p.yaw_rad = c.yaw, p.score = score, p.cost = b;
  return p;
}

}  // namespace perch2::tabletop_detail
