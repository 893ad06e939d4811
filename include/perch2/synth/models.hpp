// Object models for synthetic scenes: the built-in set (runs with no data folder), user models from a folder,
// and writing them as a BOP models/ folder (PLY in millimetres + models_info.json with symmetries).
//
// Model frames follow BOP: z up when the object stands naturally, origin at the centre of the bounding box.
#pragma once

#include <string>
#include <vector>

#include "perch2/core/export.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"

namespace perch2::synth {

/// Rotation about `axis` (object frame) through `offset_m` by any angle maps the model onto itself.
struct ContinuousSymmetry {
  Eigen::Vector3f axis = Eigen::Vector3f::UnitZ();
  Eigen::Vector3f offset_m = Eigen::Vector3f::Zero();
};

/// BOP's symmetries: the non-identity discrete transforms and the continuous axes.
struct Symmetries {
  std::vector<Pose> discrete;  ///< T_obj_obj' mapping the model onto itself (identity not listed)
  std::vector<ContinuousSymmetry> continuous;
  bool empty() const { return discrete.empty() && continuous.empty(); }
};

/// How the surface reflects light (the shading model in sensor.hpp).
struct Material {
  float specular = 0.05f;  ///< specular reflectance (0 = matte), unitless
  float shininess = 10.f;  ///< Blinn-Phong exponent, unitless
};

struct ObjectModel {
  int obj_id = 0;    ///< BOP object id (>= 1)
  std::string name;  ///< e.g. "can_cola"
  Mesh mesh;         ///< metres, BOP model frame
  Symmetries symmetries;
  Material material;
};

/// The built-in models (obj_id 1..8): three cans of one shape with different labels (1 cola red, 2 cherry
/// red, 3 aqua blue), two bottles of one shape (4 lime green, 5 malt amber), a printed box (6), an
/// untextured bowl (7, continuous symmetry about z) and an untextured block with three distinct edge
/// lengths (8, 180-degree turns about x, y and z).
PERCH2_API std::vector<ObjectModel> builtin_models();

/// Look-alikes of `models` for detection over a catalogue: models a detector must not report when only the
/// originals are in the scene. Three per model, obj_ids first_obj_id, first_obj_id + 1, ...:
///  - NAME_reprint: the same shape with another print (texture mirrored left-right and its hues turned by
///    150 deg; an untextured model's colours turned the same way);
///  - NAME_small: the same print at 0.8x the size (a smaller pack of the same product);
///  - NAME_recolour: the same shape and print in other colours (hues turned by 90 deg, lightness kept).
/// Colours of little saturation get some (0.5) before their hue is turned, so a grey model's decoys differ
/// from it too. Symmetries and materials are kept (scaled with the model).
PERCH2_API std::vector<ObjectModel> make_decoys(const std::vector<ObjectModel>& models, int first_obj_id);

/// A surface of revolution about z: `profile` is (radius, z) in metres from one pole to the other (first
/// and last radius 0 give a closed surface). Texture coordinates: u = angle / 2 pi, v = arc length along the
/// profile / total length (v = 0 at the first point). Winding is made outward.
PERCH2_API Mesh make_lathe(const std::vector<Eigen::Vector2f>& profile, int segments);

/// An axis-aligned box of size (sx, sy, sz) metres centred at the origin: 8 vertices, 12 triangles.
PERCH2_API Mesh make_box(const Eigen::Vector3f& size_m);

/// Moves the model so that the origin is at the centre of its bounding box (BOP convention).
PERCH2_API void centre_on_bounding_box(Mesh& mesh);

struct UserModelSettings {
  /// Scale from file units to metres; 0 = guess per file: millimetres if the bounding box diagonal exceeds
  /// `mm_guess_threshold` file units, else metres.
  float scale = 0.f;
  float mm_guess_threshold = 5.f;  ///< file units (a 5 m object is unlikely on a table)
};

/// Loads every .ply/.obj under `dir`, subfolders included (sorted by relative path; obj_id 1, 2, ...; name =
/// relative path without extension, '/' -> '_'), re-centred on the bounding box. Symmetries are unknown
/// (none). FileError if the folder is missing or holds no model.
PERCH2_API std::vector<ObjectModel> load_user_models(const std::string& dir, const UserModelSettings& = {});

/// Largest distance between two vertices, metres: exact over all pairs for up to 4000 vertices; larger meshes
/// use the vertices extreme along 4000 random directions (a lower bound; equal to the exact value on the
/// scanned LINEMOD cat and YCB banana and scissors).
PERCH2_API float model_diameter(const Mesh& mesh);

/// Writes `dir`/obj_{id:06d}.ply (millimetres; textures as obj_{id:06d}.png) and `dir`/models_info.json.
PERCH2_API void write_bop_models(const std::string& dir, const std::vector<ObjectModel>& models);

}  // namespace perch2::synth
