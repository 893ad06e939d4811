// Scene composition: objects on a textured table in a room, with distractors, and camera viewpoints.
//
// The world frame is the table frame (BOP's world frame for cam_R_w2c / cam_t_w2c): z up, table top at z = 0.
#pragma once

#include <cstdint>
#include <vector>

#include "perch2/core/export.hpp"
#include "perch2/synth/models.hpp"
#include "perch2/synth/random.hpp"

namespace perch2::synth {

enum class Mode {
  ThreeDof,  ///< objects upright on the table at random (x, y, yaw), not touching
  SixDof,    ///< statically stable resting poses: any face down, leaning on neighbours, stacked
};

struct SceneSettings {
  Mode mode = Mode::ThreeDof;
  int min_objects = 4, max_objects = 7;  ///< annotated instances per scene (fewer if they do not fit)
  float duplicate_probability = 0.15f;   ///< chance that an instance repeats a model already in the scene
  int min_distractors = 1, max_distractors = 3;  ///< unannotated random shapes on the table
  float distractor_min_size_m = 0.02f, distractor_max_size_m = 0.13f;  ///< extent range of distractors
  float placement_radius_m = 0.2f;  ///< objects' origins lie within this disc around the table centre
  float min_gap_m = 0.004f;         ///< 3-DoF: footprints keep at least this distance, metres
  int placement_attempts = 200;     ///< random tries per object before it is left out
  // 6-DoF resting poses.
  float upright_probability = 0.35f;  ///< natural up (+z up); otherwise upside down or on a side
  float upside_down_probability = 0.15f;
  float lean_probability = 0.25f;  ///< tilted by lean_min..lean_max about a horizontal axis
  float lean_min_rad = 0.25f, lean_max_rad = 0.6f;
  float stack_probability = 0.2f;  ///< dropped over an object already placed (lands on top of it)
  float stack_jitter_m = 0.015f;   ///< sigma of the drop point around the object below, metres
  float lean_min_distance_m = 0.02f, lean_max_distance_m = 0.09f;  ///< leaning: drop point from a neighbour
  float max_stack_height_m = 0.25f;  ///< objects would rest higher than this: retried
  float height_cell_m = 0.002f;      ///< 6-DoF drop height map resolution, metres
  float clearance_m = 0.001f;        ///< 6-DoF: gap left above the surface an object is dropped on
  /// 6-DoF: points this close to what lies below support the object; a resting pose is kept only if the
  /// object's centre lies over the hull of its support points (static stability), metres.
  float contact_m = 0.004f;
  // Table and room.
  float table_size_x_m = 1.4f, table_size_y_m = 1.0f, table_thickness_m = 0.03f;
  float room_size_m = 4.f, floor_z_m = -0.75f, wall_height_m = 2.6f;
  // Camera viewpoints.
  float camera_min_distance_m = 0.6f, camera_max_distance_m = 1.2f;  ///< eye to the look-at point
  float camera_min_elevation_rad = 0.5235988f, camera_max_elevation_rad = 1.1344640f;  ///< 30 to 65 deg
  float look_at_jitter_m = 0.04f;  ///< look-at point: table centre + uniform jitter in x, y
  float look_at_height_m = 0.03f;  ///< height of the look-at point above the table top, metres
  float camera_roll_rad = 0.06f;   ///< uniform roll jitter about the optical axis
};

/// An annotated object: model index into the models vector and its pose.
struct SceneObject {
  int model = 0;
  Pose T_world_obj = Pose::Identity();
};

/// Geometry without a model (table, room, distractors).
struct Prop {
  Mesh mesh;
  Material material;
  Pose T_world_obj = Pose::Identity();
};

struct Scene {
  std::vector<SceneObject> objects;
  std::vector<Prop> distractors;  ///< on the table, not annotated
  std::vector<Prop> environment;  ///< table, floor, walls
};

/// A random scene (deterministic for the generator's state). InvalidInput if models is empty or the
/// settings are inconsistent.
PERCH2_API Scene compose_scene(const std::vector<ObjectModel>& models, const SceneSettings& settings,
                               Rng& rng);

/// A random viewpoint T_world_cam (OpenCV camera frame) looking at the table.
PERCH2_API Pose sample_camera_pose(const SceneSettings& settings, Rng& rng);

/// T_world_cam of a camera at `eye` looking at `target` with the image's up roughly along world +z.
PERCH2_API Pose look_at(const Eigen::Vector3f& eye, const Eigen::Vector3f& target);

/// A box with every face textured by planar projection (texture repeats every `texture_period_m`).
PERCH2_API Mesh textured_box(const Eigen::Vector3f& size_m, ColorImage texture, float texture_period_m);

/// Area-weighted surface samples of a mesh, at most `spacing_m` apart along each triangle edge direction.
PERCH2_API std::vector<Eigen::Vector3f> sample_surface(const Mesh& mesh, float spacing_m);

}  // namespace perch2::synth
