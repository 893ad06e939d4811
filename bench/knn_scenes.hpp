// The kNN benchmark problems (bench_knn, bench_launch_shapes): 2,400 query clouds x 300 points against one
// target segment, at the sizes:
//   6dof: the LINEMOD cat under pose perturbations up to 15 deg / 3 cm against one 5,000-point segment;
//   3dof: the cat on a 3-DoF grid of table positions and yaws against one ~20,000-point observed scene.
// Without the shared data the model is a synthetic box surface.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "perch2/core/cloud.hpp"
#include "perch2/core/device.hpp"
#include "perch2/io/mesh_io.hpp"

namespace perch2::bench {

/// The vertices of a PLY model in millimetres (LINEMOD, BOP), as metres (perch2's PLY reader).
inline std::vector<Vec3f> ply_vertices_mm(const std::string& path) {
  std::vector<Vec3f> v;
  for (const auto& p : perch2::io::load_ply(path, {0.001f}).vertices) v.push_back(Vec3f{p.x(), p.y(), p.z()});
  return v;
}

/// Fallback model without the shared data: a 6 cm x 4 cm x 8 cm box surface.
inline std::vector<Vec3f> box_model(std::mt19937& rng, int n) {
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  std::uniform_int_distribution<int> face(0, 5);
  const float h[3] = {0.03f, 0.02f, 0.04f};
  std::vector<Vec3f> p;
  for (int i = 0; i < n; ++i) {
    float c[3] = {h[0] * u(rng), h[1] * u(rng), h[2] * u(rng)};
    const int f = face(rng);
    c[f / 2] = f % 2 ? h[f / 2] : -h[f / 2];
    p.push_back({c[0], c[1], c[2]});
  }
  return p;
}

inline Rigid3f rotation(Vec3f axis, float angle, Vec3f t) {
  const float n = std::sqrt(squared_norm(axis));
  const Vec3f a = (1.f / n) * axis;
  const float c = std::cos(angle), s = std::sin(angle), C = 1 - c;
  return {{{c + a.x * a.x * C, a.x * a.y * C - a.z * s, a.x * a.z * C + a.y * s, a.y * a.x * C + a.z * s,
            c + a.y * a.y * C, a.y * a.z * C - a.x * s, a.z * a.x * C - a.y * s, a.z * a.y * C + a.x * s,
            c + a.z * a.z * C}},
          t};
}

inline void append(CloudBatch& b, const std::vector<Vec3f>& pts) {
  for (const Vec3f& p : pts) {
    b.x.push_back(p.x), b.y.push_back(p.y), b.z.push_back(p.z);
    b.rgb.push_back(0), b.pixel.push_back(-1), b.cloud.push_back(std::int32_t(b.num_clouds()));
  }
  b.offsets.push_back(std::int64_t(b.x.size()));
}

inline std::vector<Vec3f> sample(std::mt19937& rng, const std::vector<Vec3f>& pts, std::size_t n) {
  std::uniform_int_distribution<std::size_t> pick(0, pts.size() - 1);
  std::vector<Vec3f> out(n);
  for (auto& p : out) p = pts[pick(rng)];
  return out;
}

inline std::vector<Vec3f> transformed(const std::vector<Vec3f>& pts, const Rigid3f& T, std::mt19937& rng,
                                      float noise_m) {
  std::normal_distribution<float> g(0.f, noise_m);
  std::vector<Vec3f> out;
  for (const Vec3f& p : pts) out.push_back(T * p + Vec3f{g(rng), g(rng), g(rng)});
  return out;
}

struct Scene {
  std::string name;
  CloudBatch targets, queries;
  std::vector<std::int32_t> segment;
};

struct KnnScenes {
  std::string model_name;
  std::size_t model_vertices = 0;
  std::vector<Scene> scenes;  ///< 6dof, then 3dof
};

/// Builds both scenes (deterministic: one seeded generator) from the cat model under data_dir.
inline KnnScenes knn_scenes(const std::string& data_dir) {
  std::mt19937 rng(42);
  std::vector<Vec3f> model = ply_vertices_mm(data_dir + "/models/linemod_obj_06/obj_06.ply");
  const bool real = !model.empty();
  if (!real) model = box_model(rng, 15000);
  // Centre the model at its bounding-box centre.
  Vec3f lo = model[0], hi = model[0];
  for (const Vec3f& p : model)
    lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)},
    hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
  const Vec3f centre = 0.5f * (lo + hi);
  for (Vec3f& p : model) p = p - centre;

  KnnScenes out;
  out.model_name = real ? "LINEMOD obj_06 (cat)" : "synthetic box (no shared data)";
  out.model_vertices = model.size();
  std::vector<Scene>& scenes = out.scenes;
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  const Rigid3f T_cam_obj = rotation({1, 0.3f, 0.1f}, 2.2f, {0.02f, -0.05f, 0.75f});
  {  // 6-DoF: one object segment of 5,000 points, hypotheses perturbed around the true pose.
    Scene s;
    s.name = "6dof: 2400 x 300 queries -> 1 segment of 5000";
    append(s.targets, transformed(sample(rng, model, 5000), T_cam_obj, rng, 0.001f));
    for (int h = 0; h < 2400; ++h) {
      const Vec3f axis{u(rng), u(rng), u(rng)};  // drawn in sequence: argument order is unspecified
      const float angle = 0.26f * u(rng);
      const Rigid3f dT = rotation(axis, angle, {0.03f * u(rng), 0.03f * u(rng), 0.03f * u(rng)});
      Rigid3f T = T_cam_obj;
      std::vector<Vec3f> pts = transformed(sample(rng, model, 300), T, rng, 0.f);
      for (Vec3f& p : pts) p = dT * (p - T_cam_obj.t) + T_cam_obj.t;
      append(s.queries, pts);
      s.segment.push_back(0);
    }
    scenes.push_back(std::move(s));
  }
  {  // 3-DoF: table plane (1 m x 0.8 m, ~17,000 points) + the object (3,000), hypotheses on a table grid.
    Scene s;
    s.name = "3dof: 2400 x 300 queries -> 1 scene of 20000";
    const Rigid3f T_cam_table = rotation({1, 0, 0}, -2.2f, {0.f, 0.1f, 0.9f});  // table z up, seen from above
    std::vector<Vec3f> scene;
    std::uniform_real_distribution<float> tx(-0.5f, 0.5f), ty(-0.4f, 0.4f);
    for (int i = 0; i < 17000; ++i) scene.push_back(T_cam_table * Vec3f{tx(rng), ty(rng), 0.f});
    const float half_h = 0.5f * (hi.z - lo.z);
    const Rigid3f T_table_obj = rotation({0, 0, 1}, 0.7f, {0.1f, -0.05f, half_h});
    for (const Vec3f& p : sample(rng, model, 3000)) scene.push_back(T_cam_table * (T_table_obj * p));
    append(s.targets, transformed(scene, rotation({0, 0, 1}, 0.f, {0, 0, 0}), rng, 0.001f));
    // 3-DoF grid: x, y every 8 cm over the table (13 x 10), yaw in 22.5 deg steps (16) -> 2,080; pad to
    // 2,400.
    std::vector<Rigid3f> hyps;
    for (int i = 0; i < 13; ++i)
      for (int j = 0; j < 10; ++j)
        for (int y = 0; y < 16; ++y)
          hyps.push_back(rotation({0, 0, 1}, 0.3927f * float(y),
                                  {-0.48f + 0.08f * float(i), -0.36f + 0.08f * float(j), half_h}));
    while (hyps.size() < 2400) hyps.push_back(hyps[hyps.size() % 2080]);
    for (const Rigid3f& T : hyps) {
      std::vector<Vec3f> pts = sample(rng, model, 300);
      for (Vec3f& p : pts) p = T_cam_table * (T * p);
      append(s.queries, pts);
      s.segment.push_back(0);
    }
    scenes.push_back(std::move(s));
  }
  return out;
}

}  // namespace perch2::bench
