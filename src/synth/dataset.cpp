#include "perch2/synth/dataset.hpp"

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>

#include "bop_json.hpp"
#include "perch2/io/image_io.hpp"

namespace perch2::synth {

namespace {

namespace fs = std::filesystem;
using json = nlohmann::ordered_json;

std::string id6(int id) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "%06d", id);
  return buf;
}

void write_json(const fs::path& path, const json& j) {
  detail::write_bop_json(path.string(), j);
}

/// Row-major rotation and translation in millimetres.
void put_pose(json& j, const char* R_key, const char* t_key, const Pose& T) {
  std::vector<double> R, t;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) R.push_back(T.linear()(r, c));
  for (int r = 0; r < 3; ++r) t.push_back(1000.0 * T.translation()(r));
  j[R_key] = R, j[t_key] = t;
}

void save_mask(const fs::path& path, const MaskImage& mask) {
  LabelImage l(mask.width, mask.height, 0);
  for (std::size_t p = 0; p < mask.data.size(); ++p) l.data[p] = mask.data[p];
  io::save_label_png(path.string(), l);
}

void check(const DatasetSettings& s, const std::vector<ObjectModel>& models) {
  if (models.empty()) throw InvalidInput("models", "no object models to generate scenes with");
  if (s.num_scenes < 1) throw InvalidInput("DatasetSettings::num_scenes", "must be >= 1");
  if (s.first_scene < 1) throw InvalidInput("DatasetSettings::first_scene", "must be >= 1");
  if (s.images_per_scene < 1) throw InvalidInput("DatasetSettings::images_per_scene", "must be >= 1");
  if (s.split.empty() || s.detections_file.empty())
    throw InvalidInput("DatasetSettings::split", "names must not be empty");
  std::map<int, int> seen;
  for (const auto& m : models)
    if (m.obj_id < 1 || seen[m.obj_id]++)
      throw InvalidInput("model '" + m.name + "'",
                         "obj_id must be >= 1 and unique, got " + std::to_string(m.obj_id));
  validate(s.sensor);
}

}  // namespace

DatasetSummary generate_dataset(const std::vector<ObjectModel>& models, const DatasetSettings& s,
                                const std::string& out_dir, const std::function<void(int, int)>& progress) {
  check(s, models);
  const auto t0 = std::chrono::steady_clock::now();
  const fs::path root(out_dir);
  detail::make_folder(root.string());
  std::vector<ObjectModel> catalogue = models;
  if (s.decoys) {
    int last_id = 0;
    for (const auto& m : models) last_id = std::max(last_id, m.obj_id);
    for (auto& d : make_decoys(models, last_id + 1)) catalogue.push_back(std::move(d));
  }
  write_bop_models((root / "models").string(), catalogue);
  const Intrinsics& K = s.sensor.camera;
  write_json(root / "camera.json", json{{"cx", K.cx},
                                        {"cy", K.cy},
                                        {"depth_scale", s.sensor.depth_scale_mm},
                                        {"fx", K.fx},
                                        {"fy", K.fy},
                                        {"height", K.height},
                                        {"width", K.width}});

  DatasetSummary summary;
  for (const auto& m : models) summary.objects.push_back({m.obj_id, m.name});
  auto object_summary = [&](int obj_id) -> ObjectSummary& {
    for (auto& o : summary.objects)
      if (o.obj_id == obj_id) return o;
    throw InvalidInput("obj_id", std::to_string(obj_id) + " unknown");
  };
  json targets = json::array(), detections = json::array();
  const int total = s.num_scenes * s.images_per_scene;
  for (int scene_id = s.first_scene; scene_id < s.first_scene + s.num_scenes; ++scene_id) {
    Rng scene_rng = Rng::stream(s.seed, std::uint64_t(scene_id));
    const Scene scene = compose_scene(models, s.scene, scene_rng);
    const SceneRenderer renderer(models, scene);
    const fs::path dir = root / s.split / id6(scene_id);
    for (const char* sub : {"rgb", "depth", "mask", "mask_visib"}) detail::make_folder((dir / sub).string());
    std::vector<int> obj_ids;
    for (const auto& o : scene.objects) obj_ids.push_back(models[o.model].obj_id);
    json scene_camera = json::object(), scene_gt = json::object(), scene_gt_info = json::object();
    // A video: the camera's path and what happens on the table (a stream of its own: not the scene's, not
    // a frame's).
    std::vector<Pose> path;
    VideoEvents events;
    VideoSettings video;
    if (s.video) {
      video = *s.video;
      video.frames = s.images_per_scene;
      Rng path_rng = Rng::stream(s.seed, std::uint64_t(scene_id), 0xFFFFFFFFull);
      path = camera_path(s.scene, video, path_rng);
      events = draw_events(scene, video, path_rng);
    }
    const bool still = events.pushed < 0 && events.occluded < 0;
    for (int im_id = 0; im_id < s.images_per_scene; ++im_id) {
      Rng rng = Rng::stream(s.seed, std::uint64_t(scene_id), std::uint64_t(im_id) + 1);
      const Pose T_world_cam = s.video ? path[std::size_t(im_id)] : sample_camera_pose(s.scene, rng);
      const Scene now = still ? scene : scene_at(scene, events, video, im_id, T_world_cam);
      const Frame f = still ? renderer.render(T_world_cam, s.sensor, rng)
                            : SceneRenderer(models, now).render(T_world_cam, s.sensor, rng);
      const std::string key = std::to_string(im_id), name = id6(im_id);
      io::save_color_image((dir / "rgb" / (name + ".png")).string(), f.rgb);
      io::save_depth_png((dir / "depth" / (name + ".png")).string(), f.depth_m,
                         0.001f * s.sensor.depth_scale_mm);

      json cam{{"cam_K", {K.fx, 0.0, K.cx, 0.0, K.fy, K.cy, 0.0, 0.0, 1.0}},
               {"depth_scale", s.sensor.depth_scale_mm}};
      put_pose(cam, "cam_R_w2c", "cam_t_w2c", T_world_cam.inverse());
      scene_camera[key] = cam;
      json gts = json::array(), infos = json::array();
      std::map<int, int> inst_count;
      for (std::size_t k = 0; k < scene.objects.size(); ++k) {
        json gt;
        put_pose(gt, "cam_R_m2c", "cam_t_m2c", T_world_cam.inverse() * now.objects[k].T_world_obj);
        gt["obj_id"] = obj_ids[k];
        gts.push_back(gt);
        // Visible part: where this object is the nearest surface (exact, from the noiseless z-buffer).
        MaskImage visib(K.width, K.height, 0);
        int px_visib = 0, px_valid = 0;
        for (std::size_t p = 0; p < visib.data.size(); ++p) {
          if (f.visible.data[p] == int(k) + 1) visib.data[p] = 255, ++px_visib;
          if (f.masks[k].data[p] && f.depth_m.data[p] > 0) ++px_valid;
        }
        const std::string mask_name = name + "_" + id6(int(k)) + ".png";
        save_mask(dir / "mask" / mask_name, f.masks[k]);
        save_mask(dir / "mask_visib" / mask_name, visib);
        const double fraction = f.px_count_all[k] > 0 ? double(px_visib) / f.px_count_all[k] : 0.0;
        const std::array<int, 4> none{-1, -1, -1, -1};
        infos.push_back({{"bbox_obj", px_visib > 0 ? f.bbox_obj[k] : none},
                         {"bbox_visib", px_visib > 0 ? mask_bbox(visib) : none},
                         {"px_count_all", f.px_count_all[k]},
                         {"px_count_valid", px_valid},
                         {"px_count_visib", px_visib},
                         {"visib_fract", fraction}});
        ObjectSummary& os = object_summary(obj_ids[k]);
        ++os.instances, os.visible_fraction_sum += fraction, ++summary.instances;
        if (fraction >= s.target_min_visible_fraction)
          ++inst_count[obj_ids[k]], ++os.targets, ++summary.targets;
      }
      scene_gt[key] = gts, scene_gt_info[key] = infos;
      if (s.detection_targets)
        targets.push_back({{"im_id", im_id}, {"scene_id", scene_id}});
      else
        for (const auto& [obj_id, n] : inst_count)
          targets.push_back(
              {{"im_id", im_id}, {"inst_count", n}, {"obj_id", obj_id}, {"scene_id", scene_id}});

      for (const Detection& d : simulate_detections(f, obj_ids, models, s.detection, rng)) {
        detections.push_back(
            {{"scene_id", scene_id},
             {"image_id", im_id},
             {"category_id", d.category_id},
             {"score", d.score},
             {"bbox", d.bbox},
             {"segmentation", {{"size", {K.height, K.width}}, {"counts", coco_rle_string(d.mask)}}},
             {"time", d.time_s}});
        ++summary.detections;
        if (d.gt_index < 0)
          ++summary.spurious;
        else if (d.category_id == obj_ids[d.gt_index])
          ++object_summary(d.category_id).detected;
      }
      ++summary.images;
      if (progress) progress(summary.images, total);
    }
    write_json(dir / "scene_camera.json", scene_camera);
    write_json(dir / "scene_gt.json", scene_gt);
    write_json(dir / "scene_gt_info.json", scene_gt_info);
    ++summary.scenes;
  }
  write_json(root / (s.detection_targets ? "test_targets_bop24.json" : "test_targets_bop19.json"), targets);
  write_json(root / s.detections_file, detections);
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return summary;
}

}  // namespace perch2::synth
