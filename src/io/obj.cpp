// Wavefront OBJ + MTL through tinyobjloader, with a strict line-by-line check first: tinyobjloader is lenient
// (it reads malformed numbers as 0 and drops faces with bad indices with only a warning), so perch2 checks
// the syntax, counts and index ranges itself and raises FileError naming the line.
#include <tiny_obj_loader.h>

#include <algorithm>
#include <filesystem>
#include <map>
#include <set>

#include "io_detail.hpp"
#include "perch2/io/mesh_io.hpp"

namespace perch2::io {

namespace {

namespace fs = std::filesystem;
using detail::next_token;
using detail::quote;

/// What the strict check learns about the file.
struct ObjSummary {
  std::size_t vertices = 0, colored_vertices = 0, texcoords = 0, normals = 0, faces = 0;
  std::vector<std::pair<std::string, std::size_t>> mtllibs;  ///< file name, line
  std::vector<std::pair<std::string, std::size_t>> usemtls;  ///< material name, first line using it
};

ObjSummary check_obj_text(const std::string& path, const std::string& text) {
  ObjSummary s;
  std::size_t pos = 0, line_no = 0;
  // Largest 1-based positive index per kind and the line that used it (checked against the totals at the end,
  // since some writers reference vertices defined later).
  std::int64_t max_index[3] = {0, 0, 0};
  std::size_t max_line[3] = {0, 0, 0};
  const char* kind_name[3] = {"vertex", "texture coordinate", "normal"};
  std::set<std::string> seen_materials;
  while (pos < text.size()) {
    std::size_t eol = text.find('\n', pos);
    if (eol == std::string::npos) eol = text.size();
    std::string_view line(text.data() + pos, eol - pos);
    pos = eol + 1;
    ++line_no;
    const std::size_t hash = line.find('#');
    if (hash != std::string_view::npos) line = line.substr(0, hash);
    std::size_t p = 0;
    const std::string_view key = next_token(line, p);
    if (key.empty()) continue;
    auto fail = [&](const std::string& reason) {
      return FileError(path, "line " + std::to_string(line_no) + ": " + reason);
    };
    auto numbers = [&](std::size_t min_n, std::size_t max_n, const char* what) {
      std::size_t n = 0;
      for (std::string_view t = next_token(line, p); !t.empty(); t = next_token(line, p), ++n) {
        double value;
        if (!detail::parse_double(t, value))
          throw fail(std::string("non-numeric value ") + quote(t) + " in " + what);
        if (!std::isfinite(value)) throw fail(std::string("non-finite value ") + quote(t) + " in " + what);
      }
      if (n < min_n || n > max_n)
        throw fail(std::string(what) + " has " + std::to_string(n) + " values, expected " +
                   std::to_string(min_n) + (min_n == max_n ? "" : " to " + std::to_string(max_n)) +
                   " (truncated line?)");
      return n;
    };
    if (key == "v") {
      const std::size_t n = numbers(3, 6, "vertex 'v'");
      if (n == 5) throw fail("vertex 'v' has 5 values; expected x y z [w] or x y z r g b (truncated line?)");
      if (n == 6) ++s.colored_vertices;
      ++s.vertices;
    } else if (key == "vt") {
      numbers(1, 3, "texture coordinate 'vt'");
      ++s.texcoords;
    } else if (key == "vn") {
      numbers(3, 3, "normal 'vn'");
      ++s.normals;
    } else if (key == "f") {
      std::size_t corners = 0;
      int layout = -1;  // which of v, vt, vn the corners give, as a bit mask; must agree within a face
      for (std::string_view t = next_token(line, p); !t.empty(); t = next_token(line, p), ++corners) {
        int mask = 0;
        std::size_t start = 0;
        for (int kind = 0; kind < 3 && start <= t.size(); ++kind) {
          std::size_t slash = t.find('/', start);
          if (slash == std::string_view::npos) slash = t.size();
          const std::string_view part = t.substr(start, slash - start);
          const bool last = slash == t.size();
          if (part.empty()) {
            if (kind != 1 || last) throw fail("malformed face corner " + quote(t) + " (truncated line?)");
          } else {
            std::int64_t idx;
            if (!detail::parse_int(part, idx) || idx == 0)
              throw fail("face corner " + quote(t) + " has an invalid index " + quote(part));
            const std::size_t count = kind == 0 ? s.vertices : kind == 1 ? s.texcoords : s.normals;
            if (idx < 0) {
              if (std::int64_t(count) + idx < 0)
                throw fail("face corner " + quote(t) + " refers to " + kind_name[kind] + " " +
                           std::to_string(idx) + " but only " + std::to_string(count) +
                           " are defined before it");
            } else if (idx > max_index[kind]) {
              max_index[kind] = idx, max_line[kind] = line_no;
            }
            mask |= 1 << kind;
          }
          start = slash + 1;
          if (last) break;
          if (kind == 2) throw fail("malformed face corner " + quote(t));
        }
        if (!(mask & 1)) throw fail("face corner " + quote(t) + " has no vertex index");
        if (layout >= 0 && mask != layout)
          throw fail("face corners mix index layouts (" + quote(t) + "); truncated line?");
        layout = mask;
      }
      if (corners < 3)
        throw fail("face has " + std::to_string(corners) +
                   " corners; at least 3 are needed (truncated line?)");
      ++s.faces;
    } else if (key == "mtllib") {
      // The rest of the line names one or more libraries (tinyobjloader splits on spaces too).
      for (std::string_view t = next_token(line, p); !t.empty(); t = next_token(line, p))
        s.mtllibs.emplace_back(std::string(t), line_no);
    } else if (key == "usemtl") {
      const std::string name(next_token(line, p));
      if (!name.empty() && seen_materials.insert(name).second) s.usemtls.emplace_back(name, line_no);
    }
  }
  const std::size_t counts[3] = {s.vertices, s.texcoords, s.normals};
  for (int kind = 0; kind < 3; ++kind)
    if (max_index[kind] > std::int64_t(counts[kind]))
      throw FileError(path, "line " + std::to_string(max_line[kind]) + ": face refers to " + kind_name[kind] +
                                " " + std::to_string(max_index[kind]) + " but the file defines " +
                                std::to_string(counts[kind]) + " (truncated file or out-of-range index)");
  if (s.vertices == 0) throw FileError(path, "empty mesh: no vertices ('v' lines)");
  if (s.faces == 0) throw FileError(path, "empty mesh: no faces ('f' lines)");
  if (s.colored_vertices != 0 && s.colored_vertices != s.vertices)
    throw FileError(path, std::to_string(s.colored_vertices) + " of " + std::to_string(s.vertices) +
                              " vertices have colours; all or none must");
  return s;
}

std::uint8_t to_byte(double value, double full_scale) {
  const double c = std::nearbyint(std::clamp(value / full_scale, 0.0, 1.0) * 255.0);
  return std::uint8_t(c);
}

}  // namespace

Mesh load_obj(const std::string& path, const MeshLoadOptions& options) {
  detail::check_scale(options.scale);
  const std::string text = detail::read_file_bytes(path);
  const ObjSummary summary = check_obj_text(path, text);
  const fs::path folder = fs::path(path).parent_path();
  for (const auto& [lib, line] : summary.mtllibs) {
    std::error_code ec;
    if (!fs::is_regular_file(folder / lib, ec))
      throw FileError(path, "line " + std::to_string(line) + ": material library '" + lib +
                                "' not found (looked for '" + (folder / lib).string() + "')");
  }

  tinyobj::ObjReaderConfig config;
  config.triangulate = true;
  config.vertex_color = false;  // colours only when every 'v' line has them (checked above)
  config.mtl_search_path = folder.empty() ? std::string("./") : folder.string() + "/";
  tinyobj::ObjReader reader;
  if (!reader.ParseFromFile(path, config) || !reader.Valid())
    throw FileError(path, "tinyobjloader could not parse it: " + reader.Error());
  const tinyobj::attrib_t& attrib = reader.GetAttrib();
  const auto& shapes = reader.GetShapes();
  const auto& materials = reader.GetMaterials();
  if (attrib.vertices.size() != 3 * summary.vertices)
    throw FileError(path, "tinyobjloader read " + std::to_string(attrib.vertices.size() / 3) +
                              " vertices, the file has " + std::to_string(summary.vertices));
  for (const auto& usemtl : summary.usemtls) {
    const std::string& name = usemtl.first;  // not a structured binding: C++17 lambdas cannot capture those
    const std::size_t line = usemtl.second;
    const bool found = std::any_of(materials.begin(), materials.end(),
                                   [&](const tinyobj::material_t& m) { return m.name == name; });
    if (!found)
      throw FileError(path, "line " + std::to_string(line) + ": 'usemtl " + name +
                                "' names a material that no material library defines");
  }

  Mesh mesh;
  mesh.name = fs::path(path).stem().string();
  const std::size_t nv = summary.vertices;
  mesh.vertices.resize(nv);
  const double scale = options.scale;
  for (std::size_t i = 0; i < nv; ++i)
    mesh.vertices[i] = (scale * Eigen::Vector3d(attrib.vertices[3 * i], attrib.vertices[3 * i + 1],
                                                attrib.vertices[3 * i + 2]))
                           .cast<float>();
  if (summary.colored_vertices == nv && attrib.colors.size() == 3 * nv) {
    // Colours are floats in [0, 1]; some writers use 0..255 instead, recognised by any value above 1.
    const double max_value = *std::max_element(attrib.colors.begin(), attrib.colors.end());
    const double full_scale = max_value > 1.0 ? 255.0 : 1.0;
    mesh.vertex_colors.resize(nv);
    for (std::size_t i = 0; i < nv; ++i)
      mesh.vertex_colors[i] = {to_byte(attrib.colors[3 * i], full_scale),
                               to_byte(attrib.colors[3 * i + 1], full_scale),
                               to_byte(attrib.colors[3 * i + 2], full_scale)};
  }

  // Triangles, their materials and texture coordinates.
  std::map<int, std::size_t> faces_per_material;
  std::set<std::string> textures;  // distinct diffuse textures used by faces
  std::size_t untextured_faces = 0;
  std::vector<int> corner_texcoord;
  for (const auto& shape : shapes) {
    const auto& m = shape.mesh;
    for (std::size_t f = 0; f < m.num_face_vertices.size(); ++f) {
      if (m.num_face_vertices[f] != 3)
        throw FileError(path, "tinyobjloader returned a face with " +
                                  std::to_string(int(m.num_face_vertices[f])) +
                                  " corners after triangulation");
      Eigen::Vector3i tri;
      for (int c = 0; c < 3; ++c) {
        const tinyobj::index_t& idx = m.indices[3 * f + c];
        if (idx.vertex_index < 0 || std::size_t(idx.vertex_index) >= nv)
          throw FileError(path, "face in shape '" + shape.name + "' references vertex " +
                                    std::to_string(idx.vertex_index + 1) + " of " + std::to_string(nv));
        if (idx.texcoord_index >= 0 && std::size_t(idx.texcoord_index) >= attrib.texcoords.size() / 2)
          throw FileError(path, "face in shape '" + shape.name + "' references texture coordinate " +
                                    std::to_string(idx.texcoord_index + 1) + " of " +
                                    std::to_string(attrib.texcoords.size() / 2));
        tri[c] = idx.vertex_index;
        corner_texcoord.push_back(idx.texcoord_index);
      }
      mesh.triangles.push_back(tri);
      const int material = f < m.material_ids.size() ? m.material_ids[f] : -1;
      ++faces_per_material[material];
      if (material >= 0 && std::size_t(material) < materials.size() &&
          !materials[material].diffuse_texname.empty())
        textures.insert(materials[material].diffuse_texname);
      else
        ++untextured_faces;
    }
  }
  if (mesh.triangles.empty()) throw FileError(path, "empty mesh: no triangles after triangulation");

  // Base colour: Kd of the material used by most faces.
  int main_material = -1;
  std::size_t most = 0;
  for (const auto& [material, count] : faces_per_material)
    if (material >= 0 && std::size_t(material) < materials.size() && count > most)
      main_material = material, most = count;
  if (main_material >= 0) {
    const auto& kd = materials[main_material].diffuse;
    mesh.base_color = {to_byte(kd[0], 1.0), to_byte(kd[1], 1.0), to_byte(kd[2], 1.0)};
  }

  if (textures.size() > 1) {
    std::string names;
    for (const auto& t : textures) names += (names.empty() ? "'" : ", '") + t + "'";
    throw FileError(
        path, "faces use " + std::to_string(textures.size()) + " different textures (" + names +
                  "); meshes with several textures are not supported (bake them into one texture atlas)");
  }
  if (textures.size() == 1) {
    if (untextured_faces > 0)
      throw FileError(
          path, std::to_string(untextured_faces) + " of " + std::to_string(mesh.triangles.size()) +
                    " triangles use a material without a texture while the others use '" + *textures.begin() +
                    "'; mixing textured and untextured materials is not supported");
    const auto missing = std::find(corner_texcoord.begin(), corner_texcoord.end(), -1);
    if (missing != corner_texcoord.end())
      throw FileError(path, "triangle " + std::to_string((missing - corner_texcoord.begin()) / 3) +
                                " has no texture coordinates although its material has the texture '" +
                                *textures.begin() + "'");
    mesh.corner_uvs.resize(corner_texcoord.size());
    for (std::size_t k = 0; k < corner_texcoord.size(); ++k) {
      const std::size_t t = std::size_t(corner_texcoord[k]);
      mesh.corner_uvs[k] =
          Eigen::Vector2d(attrib.texcoords[2 * t], attrib.texcoords[2 * t + 1]).cast<float>();
    }
    mesh.texture = detail::load_texture(path, folder, *textures.begin(), "map_Kd in its material library");
  }
  try {
    mesh.validate();
  } catch (const InvalidInput& e) {
    throw FileError(path, e.what());
  }
  return mesh;
}

Mesh load_mesh(const std::string& path, const MeshLoadOptions& options) {
  const std::string ext = detail::lower_extension(path);
  if (ext == ".obj") return load_obj(path, options);
  if (ext == ".ply") return load_ply(path, options);
  throw FileError(path, "unsupported mesh format '" + ext + "' (supported: .obj, .ply)");
}

}  // namespace perch2::io
