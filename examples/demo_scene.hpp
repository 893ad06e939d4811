// The built-in demo scene: a table with a textured can, a vertex-coloured box and a blob, seen from above.
#pragma once

#include <vector>

#include "perch2/core/camera.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"

namespace perch2::demo {

struct Scene {
  Intrinsics camera;              ///< 640x480
  Pose T_cam_table;               ///< table frame: z up, surface at z = 0
  std::vector<Mesh> models;       ///< table, can, box, blob
  std::vector<Pose> T_table_obj;  ///< ground-truth placement of each model on the table
};

Mesh make_cylinder(float radius_m, float height_m, int segments, ColorImage label_texture);
Mesh make_box(float sx, float sy, float sz);
Scene make_scene();

/// T_table_obj for an object standing on the table at (x, y) turned by yaw about the table normal.
Pose on_table(float x_m, float y_m, float yaw_rad, float z_m = 0.f);

}  // namespace perch2::demo
