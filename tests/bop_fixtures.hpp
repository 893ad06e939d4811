// Writes tiny BOP datasets for the dataset and evaluation tests: meshes, JSON, depth rendered from the ground
// truth with the CPU renderer, visible masks and visible fractions.
#pragma once

#include <cstdio>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "perch2/cpu/render.hpp"
#include "perch2/dataset/bop.hpp"
#include "perch2/io/io.hpp"

namespace perch2::test {

/// Closed cylinder about the object z axis, centred at the origin, outward winding.
inline Mesh make_cylinder_mesh(float radius, float height, int segments) {
  Mesh m;
  m.name = "cylinder";
  const float pi = 3.14159265358979f;
  for (int k = 0; k < segments; ++k) {
    const float a = 2 * pi * k / segments;
    m.vertices.emplace_back(radius * std::cos(a), radius * std::sin(a), -0.5f * height);
    m.vertices.emplace_back(radius * std::cos(a), radius * std::sin(a), 0.5f * height);
  }
  const int bottom = int(m.vertices.size()), top = bottom + 1;
  m.vertices.emplace_back(0, 0, -0.5f * height);
  m.vertices.emplace_back(0, 0, 0.5f * height);
  for (int k = 0; k < segments; ++k) {
    const int b0 = 2 * k, t0 = 2 * k + 1, b1 = 2 * ((k + 1) % segments), t1 = b1 + 1;
    m.triangles.emplace_back(b0, b1, t1);
    m.triangles.emplace_back(b0, t1, t0);
    m.triangles.emplace_back(bottom, b1, b0);
    m.triangles.emplace_back(top, t0, t1);
  }
  return m;
}

struct FixtureObject {
  int obj_id = 1;
  Mesh mesh_m;  ///< metres (written in millimetres)
  float diameter_m = 0.1f;
  nlohmann::json symmetries;  ///< extra models_info keys (symmetries_discrete / _continuous, in mm)
};

struct FixtureInstance {
  int obj_id = 1;
  Pose T_cam_obj = Pose::Identity();
};

struct FixtureImage {
  int scene_id = 1, im_id = 0;
  std::vector<FixtureInstance> gt;
};

inline nlohmann::json bop_R(const Pose& T) {
  nlohmann::json r = nlohmann::json::array();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r.push_back(double(T.linear()(i, j)));
  return r;
}
inline nlohmann::json bop_t_mm(const Pose& T) {
  const Eigen::Vector3d t = T.translation().cast<double>() * 1e3;
  return {t.x(), t.y(), t.z()};
}

inline void write_text(const std::string& path, const std::string& text) {
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) throw FileError(path, "cannot write");
  std::fwrite(text.data(), 1, text.size(), f);
  std::fclose(f);
}

/// Writes ROOT/{camera.json, models/, test/SCENE/..., test_targets_bop19.json}. Depth is the ground truth
/// rendered at stride 1 (1 mm units, depth_scale 1); targets are every annotated object with its count.
inline void write_bop_dataset(const std::string& root, const std::vector<FixtureObject>& objects,
                              const std::vector<FixtureImage>& images, const Intrinsics& K) {
  namespace fs = std::filesystem;
  fs::remove_all(root);
  fs::create_directories(root + "/models");
  nlohmann::json info = nlohmann::json::object();
  std::vector<Mesh> meshes;
  std::map<int, int> model_index;
  for (const auto& o : objects) {
    Mesh mm = o.mesh_m;
    for (auto& v : mm.vertices) v *= 1000.f;
    io::save_ply(root + "/models/obj_" + dataset::bop_id(o.obj_id) + ".ply", mm, false);
    nlohmann::json e = {{"diameter", o.diameter_m * 1000.0}};
    if (o.symmetries.is_object()) e.update(o.symmetries);
    info[std::to_string(o.obj_id)] = e;
    model_index[o.obj_id] = int(meshes.size());
    meshes.push_back(o.mesh_m);
  }
  write_text(root + "/models/models_info.json", info.dump());
  write_text(root + "/camera.json", nlohmann::json{{"fx", K.fx},
                                                   {"fy", K.fy},
                                                   {"cx", K.cx},
                                                   {"cy", K.cy},
                                                   {"width", K.width},
                                                   {"height", K.height},
                                                   {"depth_scale", 1.0}}
                                        .dump());
  const cpu::Renderer renderer(meshes);
  RenderSettings rs;
  rs.stride = 1;
  std::map<int, nlohmann::json> cams, gts, infos;
  nlohmann::json targets = nlohmann::json::array();
  for (const auto& im : images) {
    const std::string dir = root + "/test/" + dataset::bop_id(im.scene_id);
    for (const char* sub : {"rgb", "depth", "mask_visib", "mask"}) fs::create_directories(dir + "/" + sub);
    std::vector<Hypothesis> hyps;
    for (const auto& g : im.gt) hyps.push_back({model_index.at(g.obj_id), g.T_cam_obj});
    DepthImage depth(K.width, K.height, 0.f);
    LabelImage owner(K.width, K.height, 0);
    std::vector<int> all_pixels(im.gt.size(), 0);
    if (!hyps.empty()) {
      const CloudBatch b = renderer.render(hyps, K, rs);
      for (std::size_t h = 0; h < hyps.size(); ++h)
        for (auto i = b.offsets[h]; i < b.offsets[h + 1]; ++i) {
          const auto p = std::size_t(b.pixel[std::size_t(i)]);
          ++all_pixels[h];
          if (depth.data[p] == 0 || b.z[std::size_t(i)] < depth.data[p])
            depth.data[p] = b.z[std::size_t(i)], owner.data[p] = int(h) + 1;
        }
    }
    const std::string id = dataset::bop_id(im.im_id);
    io::save_depth_png(dir + "/depth/" + id + ".png", depth, 0.001f);
    ColorImage rgb(K.width, K.height, Rgb8{90, 90, 90});
    io::save_color_image(dir + "/rgb/" + id + ".png", rgb);
    nlohmann::json gt_list = nlohmann::json::array(), info_list = nlohmann::json::array();
    std::map<int, int> counts;
    for (std::size_t h = 0; h < im.gt.size(); ++h) {
      LabelImage mask(K.width, K.height, 0);
      int visible = 0;
      for (std::size_t p = 0; p < mask.data.size(); ++p)
        if (owner.data[p] == int(h) + 1) mask.data[p] = 255, ++visible;
      io::save_label_png(dir + "/mask_visib/" + id + "_" + dataset::bop_id(int(h)) + ".png", mask);
      gt_list.push_back({{"obj_id", im.gt[h].obj_id},
                         {"cam_R_m2c", bop_R(im.gt[h].T_cam_obj)},
                         {"cam_t_m2c", bop_t_mm(im.gt[h].T_cam_obj)}});
      info_list.push_back({{"visib_fract", all_pixels[h] ? double(visible) / all_pixels[h] : 0.0},
                           {"px_count_all", all_pixels[h]},
                           {"px_count_visib", visible}});
      ++counts[im.gt[h].obj_id];
    }
    cams[im.scene_id][std::to_string(im.im_id)] = {{"cam_K", {K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1}},
                                                   {"depth_scale", 1.0}};
    gts[im.scene_id][std::to_string(im.im_id)] = gt_list;
    infos[im.scene_id][std::to_string(im.im_id)] = info_list;
    for (const auto& [obj, n] : counts)
      targets.push_back({{"scene_id", im.scene_id}, {"im_id", im.im_id}, {"obj_id", obj}, {"inst_count", n}});
  }
  for (const auto& [scene, j] : cams) {
    const std::string dir = root + "/test/" + dataset::bop_id(scene);
    write_text(dir + "/scene_camera.json", j.dump());
    write_text(dir + "/scene_gt.json", gts[scene].dump());
    write_text(dir + "/scene_gt_info.json", infos[scene].dump());
  }
  write_text(root + "/test_targets_bop19.json", targets.dump());
}

}  // namespace perch2::test
