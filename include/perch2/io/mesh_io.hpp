// Reading and writing triangle meshes: Wavefront OBJ (+ MTL + diffuse texture) and Stanford PLY.
//
// Every loader returns a Mesh in metres (after MeshLoadOptions::scale) that has passed Mesh::validate().
// Any problem with a file -- missing, unreadable, malformed, truncated, indices out of range, a texture named
// by the file that cannot be found -- raises perch2::FileError whose message starts with the file's path and
// says what is wrong (with the line or element where that helps). Bad arguments raise perch2::InvalidInput.
#pragma once

#include <string>

#include "perch2/core/mesh.hpp"

namespace perch2::io {

struct MeshLoadOptions {
  /// Multiplies every vertex coordinate (unitless; file units -> metres). Default 1 (the file is in metres).
  /// BOP / LINEMOD PLY models are in millimetres: use 0.001. Must be finite and > 0.
  float scale = 1.f;
};

/// Loads a mesh, choosing the reader by the file extension (case-insensitive): ".obj" -> load_obj,
/// ".ply" -> load_ply. Any other extension raises FileError.
Mesh load_mesh(const std::string& path, const MeshLoadOptions& options = {});

/// Wavefront OBJ through tinyobjloader (polygons triangulated). Reads
/// - vertex positions, optional vertex colours "v x y z r g b" (floats in [0, 1]; if any exceeds 1 the whole
///   file is taken as 0..255) -> Mesh::vertex_colors,
/// - per-corner texture coordinates "vt" -> Mesh::corner_uvs (OBJ convention, v = 0 at the image bottom),
/// - the MTL library: Kd of the material used by most faces -> Mesh::base_color; map_Kd -> Mesh::texture
///   (loaded relative to the MTL's folder; 8-bit RGB, alpha dropped).
/// Texture coordinates are kept only when a texture is present. A mesh whose faces use several different
/// textures, or that mixes textured and untextured faces, is not supported (FileError saying so).
/// Mesh::name is the file stem. Syntax, value counts per line, index ranges and materials are checked
/// strictly. An OBJ declares no element counts, so a file cut exactly at a line end after a complete face
/// cannot be told from a complete smaller mesh; cuts inside a line, or before faces' vertices/UVs are
/// defined, are detected.
Mesh load_obj(const std::string& path, const MeshLoadOptions& options = {});

/// Stanford PLY: ascii, binary_little_endian and binary_big_endian, any scalar property type
/// (char/uchar/short/ushort/int/uint/float/double and the int8/uint8/.../float32/float64 aliases). Reads
/// - element "vertex": x, y, z; optional red, green, blue (alpha ignored) as 8-bit integers or floats in
///   [0, 1] -> Mesh::vertex_colors; optional per-vertex texture coordinates (texture_u/texture_v, s/t or
///   u/v),
/// - element "face": list "vertex_indices" or "vertex_index" (polygons fan-triangulated); optional list
///   "texcoord" (2 floats per corner) -> Mesh::corner_uvs (takes precedence over per-vertex coordinates),
/// - header line "comment TextureFile <name>" -> Mesh::texture, loaded relative to the PLY's folder.
/// Other elements and properties (normals, lists, ...) are skipped. Mesh::name is the file stem.
Mesh load_ply(const std::string& path, const MeshLoadOptions& options = {});

/// Writes a mesh as PLY (binary little-endian, or ascii): vertex x, y, z as float, red/green/blue as uchar
/// when the mesh has vertex colours, face list "vertex_indices". A textured mesh also gets a face list
/// "texcoord" and its texture is written beside it as "<stem>.png", named by "comment TextureFile".
/// Coordinates are written as they are (metres). Raises InvalidInput if the mesh fails Mesh::validate(),
/// FileError if the file cannot be written.
void save_ply(const std::string& path, const Mesh& mesh, bool binary = true);

}  // namespace perch2::io
