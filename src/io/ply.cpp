// Stanford PLY reader and writer (ascii, binary little- and big-endian), written for perch2: no maintained
// Debian package exists. The reader parses the header, then streams every element row by row, keeping the
// properties a Mesh needs and skipping all others (scalars and lists) by their declared types.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <sstream>

#include "io_detail.hpp"
#include "perch2/io/image_io.hpp"
#include "perch2/io/mesh_io.hpp"

namespace perch2::io {

namespace {

namespace fs = std::filesystem;
using detail::next_token;
using detail::quote;

enum class Type { I8, U8, I16, U16, I32, U32, F32, F64 };

bool parse_type(std::string_view s, Type& t) {
  static const std::pair<const char*, Type> names[] = {
      {"char", Type::I8},   {"int8", Type::I8},     {"uchar", Type::U8},   {"uint8", Type::U8},
      {"short", Type::I16}, {"int16", Type::I16},   {"ushort", Type::U16}, {"uint16", Type::U16},
      {"int", Type::I32},   {"int32", Type::I32},   {"uint", Type::U32},   {"uint32", Type::U32},
      {"float", Type::F32}, {"float32", Type::F32}, {"double", Type::F64}, {"float64", Type::F64}};
  for (const auto& [name, type] : names)
    if (s == name) {
      t = type;
      return true;
    }
  return false;
}

std::size_t type_size(Type t) {
  switch (t) {
    case Type::I8:
    case Type::U8:
      return 1;
    case Type::I16:
    case Type::U16:
      return 2;
    case Type::I32:
    case Type::U32:
    case Type::F32:
      return 4;
    case Type::F64:
      return 8;
  }
  return 0;
}

const char* type_name(Type t) {
  static const char* names[] = {"char", "uchar", "short", "ushort", "int", "uint", "float", "double"};
  return names[int(t)];
}

bool is_integer(Type t) {
  return t != Type::F32 && t != Type::F64;
}

/// Range of an integer type.
void type_range(Type t, double& lo, double& hi) {
  switch (t) {
    case Type::I8:
      lo = -128, hi = 127;
      return;
    case Type::U8:
      lo = 0, hi = 255;
      return;
    case Type::I16:
      lo = -32768, hi = 32767;
      return;
    case Type::U16:
      lo = 0, hi = 65535;
      return;
    case Type::I32:
      lo = -2147483648.0, hi = 2147483647.0;
      return;
    case Type::U32:
      lo = 0, hi = 4294967295.0;
      return;
    default:
      lo = -std::numeric_limits<double>::infinity(), hi = std::numeric_limits<double>::infinity();
  }
}

/// What a property is used for.
enum class Role { Skip, X, Y, Z, Red, Green, Blue, U, V, FaceIndices, FaceTexcoords };

struct Property {
  std::string name;
  bool is_list = false;
  Type count_type = Type::U8;  ///< lists only
  Type type = Type::F32;       ///< the scalar type, or the list's item type
  Role role = Role::Skip;
};

struct Element {
  std::string name;
  std::size_t count = 0;
  std::vector<Property> properties;
};

enum class Format { Ascii, BinaryLittle, BinaryBig };

/// Names what is being read, for error messages: item -2 = the scalar property, -1 = a list's length,
/// k >= 0 = item k of a list.
std::string describe_value(const Property& p, long item) {
  if (item == -2) return "property '" + p.name + "'";
  if (item == -1) return "the length of list '" + p.name + "'";
  return "item " + std::to_string(item) + " of list '" + p.name + "'";
}

struct Header {
  Format format = Format::Ascii;
  std::vector<Element> elements;
  std::string texture_file;     ///< from "comment TextureFile <name>"
  std::size_t data_offset = 0;  ///< first byte after the end_header line
  std::size_t data_line = 0;    ///< 1-based line number of the first data line (ascii)
};

Header parse_header(const std::string& path, const std::string& bytes) {
  Header h;
  std::size_t pos = 0, line_no = 0;
  bool have_format = false, ended = false;
  auto fail = [&](const std::string& reason) -> FileError {
    return FileError(path, "malformed PLY header, line " + std::to_string(line_no) + ": " + reason);
  };
  while (pos < bytes.size()) {
    std::size_t eol = bytes.find('\n', pos);
    if (eol == std::string::npos) eol = bytes.size();
    std::string_view line(bytes.data() + pos, eol - pos);
    pos = std::min(eol + 1, bytes.size());
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    std::size_t p = 0;
    const std::string_view keyword = next_token(line, p);
    if (line_no == 1) {
      if (keyword != "ply" || !next_token(line, p).empty())
        throw FileError(path, "not a PLY file (it does not start with the line 'ply')");
      continue;
    }
    if (keyword.empty()) continue;
    if (keyword == "end_header") {
      ended = true;
      break;
    }
    if (keyword == "comment") {
      std::size_t q = p;
      if (next_token(line, q) == "TextureFile") {
        std::string name(line.substr(q));
        const auto first = name.find_first_not_of(" \t");
        const auto last = name.find_last_not_of(" \t\r");
        if (first != std::string::npos) h.texture_file = name.substr(first, last - first + 1);
      }
    } else if (keyword == "obj_info") {
    } else if (keyword == "format") {
      const std::string_view f = next_token(line, p), version = next_token(line, p);
      if (f == "ascii")
        h.format = Format::Ascii;
      else if (f == "binary_little_endian")
        h.format = Format::BinaryLittle;
      else if (f == "binary_big_endian")
        h.format = Format::BinaryBig;
      else
        throw fail("unknown format " + quote(f) +
                   " (expected ascii, binary_little_endian or binary_big_endian)");
      if (version.empty()) throw fail("the format line has no version");
      have_format = true;
    } else if (keyword == "element") {
      Element e;
      e.name = std::string(next_token(line, p));
      std::int64_t count = -1;
      const std::string_view count_token = next_token(line, p);
      if (e.name.empty() || !detail::parse_int(count_token, count) || count < 0)
        throw fail("expected 'element <name> <count>', got " + quote(line));
      e.count = std::size_t(count);
      h.elements.push_back(std::move(e));
    } else if (keyword == "property") {
      if (h.elements.empty()) throw fail("property before any element");
      Property prop;
      std::string_view t = next_token(line, p);
      if (t == "list") {
        prop.is_list = true;
        const std::string_view ct = next_token(line, p);
        t = next_token(line, p);
        if (!parse_type(ct, prop.count_type) || !parse_type(t, prop.type))
          throw fail("unknown type in " + quote(line));
        if (!is_integer(prop.count_type))
          throw fail("list count type must be an integer type in " + quote(line));
      } else if (!parse_type(t, prop.type)) {
        throw fail("unknown property type " + quote(t));
      }
      prop.name = std::string(next_token(line, p));
      if (prop.name.empty()) throw fail("property without a name");
      h.elements.back().properties.push_back(std::move(prop));
    } else {
      throw fail("unknown keyword " + quote(keyword));
    }
  }
  if (line_no == 0) throw FileError(path, "not a PLY file (it is empty)");
  if (!ended) throw FileError(path, "malformed PLY header: no 'end_header' line (truncated header?)");
  if (!have_format) throw FileError(path, "malformed PLY header: no 'format' line");
  h.data_offset = pos;
  h.data_line = line_no + 1;
  return h;
}

/// Row-by-row reader of ascii data: one element instance per line.
class AsciiCursor {
 public:
  AsciiCursor(const std::string& path, const std::string& bytes, std::size_t offset, std::size_t line_no)
      : path_(path), bytes_(bytes), pos_(offset), line_no_(line_no - 1) {}

  /// Moves to the next non-empty line for row `row` of `e`; FileError if the data ends first.
  void begin_row(const Element& e, std::size_t row) {
    while (pos_ < bytes_.size()) {
      std::size_t eol = bytes_.find('\n', pos_);
      if (eol == std::string::npos) eol = bytes_.size();
      line_ = std::string_view(bytes_.data() + pos_, eol - pos_);
      pos_ = std::min(eol + 1, bytes_.size());
      ++line_no_;
      col_ = 0;
      std::size_t probe = 0;
      if (!next_token(line_, probe).empty()) {
        element_ = &e;
        row_ = row;
        return;
      }
    }
    throw FileError(path_, "truncated: the data ends after " + std::to_string(row) + " of " +
                               std::to_string(e.count) + " '" + e.name + "' rows");
  }

  FileError error(const std::string& reason) const { return FileError(path_, where() + reason); }

  void end_row() {
    const std::string_view extra = next_token(line_, col_);
    if (!extra.empty())
      throw FileError(path_, where() + "more values than the header declares (" + quote(extra) + ")");
  }

  double scalar(Type t, const Property& p, long item) {
    const std::string_view token = next_token(line_, col_);
    if (token.empty()) {
      if (pos_ >= bytes_.size())  // the last line of the file: it was cut
        throw FileError(path_, "truncated: the data ends inside line " + std::to_string(line_no_) + ", '" +
                                   element_->name + "' row " + std::to_string(row_) + " of " +
                                   std::to_string(element_->count));
      throw FileError(path_, where() + "too few values (missing " + describe_value(p, item) + ")");
    }
    double value = 0;
    if (!detail::parse_double(token, value))
      throw FileError(path_,
                      where() + "non-numeric value " + quote(token) + " for " + describe_value(p, item));
    if (is_integer(t)) {
      double lo, hi;
      type_range(t, lo, hi);
      if (value != std::floor(value) || value < lo || value > hi)
        throw FileError(path_, where() + "value " + quote(token) + " for " + describe_value(p, item) +
                                   " is not a valid " + type_name(t));
    }
    return value;
  }

 private:
  std::string where() const {
    return "line " + std::to_string(line_no_) + " ('" + element_->name + "' row " + std::to_string(row_) +
           "): ";
  }
  const std::string& path_;
  const std::string& bytes_;
  std::size_t pos_, line_no_;
  std::string_view line_;
  std::size_t col_ = 0;
  const Element* element_ = nullptr;
  std::size_t row_ = 0;
};

/// Row-by-row reader of binary data in either byte order.
class BinaryCursor {
 public:
  BinaryCursor(const std::string& path, const std::string& bytes, std::size_t offset, bool big_endian)
      : path_(path), bytes_(bytes), pos_(offset) {
    const std::uint16_t one = 1;
    unsigned char first;
    std::memcpy(&first, &one, 1);
    swap_ = big_endian == (first == 1);
  }
  void begin_row(const Element& e, std::size_t row) { element_ = &e, row_ = row; }
  void end_row() {}
  FileError error(const std::string& reason) const {
    return FileError(path_, "'" + element_->name + "' row " + std::to_string(row_) + ": " + reason);
  }

  double scalar(Type t, const Property& p, long item) {
    const std::size_t n = type_size(t);
    if (bytes_.size() - pos_ < n)
      throw FileError(path_, "truncated: the binary data ends inside '" + element_->name + "' row " +
                                 std::to_string(row_) + " of " + std::to_string(element_->count) +
                                 " (reading " + describe_value(p, item) + ")");
    unsigned char b[8];
    std::memcpy(b, bytes_.data() + pos_, n);
    pos_ += n;
    if (swap_) std::reverse(b, b + n);
    switch (t) {
      case Type::I8:
        return double(std::int8_t(b[0]));
      case Type::U8:
        return double(b[0]);
      case Type::I16:
        return load<std::int16_t>(b);
      case Type::U16:
        return load<std::uint16_t>(b);
      case Type::I32:
        return load<std::int32_t>(b);
      case Type::U32:
        return load<std::uint32_t>(b);
      case Type::F32:
        return load<float>(b);
      case Type::F64:
        return load<double>(b);
    }
    return 0;
  }

 private:
  template <class T>
  static double load(const unsigned char* b) {
    T v;
    std::memcpy(&v, b, sizeof(T));
    return double(v);
  }
  const std::string& path_;
  const std::string& bytes_;
  std::size_t pos_;
  bool swap_ = false;
  const Element* element_ = nullptr;
  std::size_t row_ = 0;
};

/// Everything read from the data, before it becomes a Mesh.
struct RawMesh {
  std::vector<double> xyz;               // 3 per vertex
  std::vector<std::uint8_t> rgb;         // 3 per vertex, if colours
  std::vector<float> vertex_uv;          // 2 per vertex, if per-vertex texture coordinates
  std::vector<std::int64_t> face_index;  // flattened face lists
  std::vector<std::uint32_t> face_size;  // corners per face
  std::vector<float> face_uv;            // flattened texcoord lists (2 per corner)
  std::vector<std::uint32_t> face_uv_size;
};

std::uint8_t to_color(double value, Type t) {
  double c;
  if (t == Type::F32 || t == Type::F64)
    c = value * 255.0;  // floats in [0, 1]
  else if (t == Type::U16 || t == Type::I16)
    c = value / 257.0;  // 16-bit channel
  else
    c = value;
  if (!(c >= 0)) c = 0;  // also NaN
  return std::uint8_t(std::min(255.0, std::nearbyint(c)));
}

template <class Cursor>
void read_body(Cursor& cur, const std::vector<Element>& elements, RawMesh& raw) {
  for (const Element& e : elements) {
    const bool is_vertex = e.name == "vertex", is_face = e.name == "face";
    for (std::size_t row = 0; row < e.count; ++row) {
      cur.begin_row(e, row);
      for (const Property& p : e.properties) {
        if (!p.is_list) {
          const double value = cur.scalar(p.type, p, -2);
          if (!is_vertex) continue;
          switch (p.role) {
            case Role::X:
              raw.xyz[3 * row + 0] = value;
              break;
            case Role::Y:
              raw.xyz[3 * row + 1] = value;
              break;
            case Role::Z:
              raw.xyz[3 * row + 2] = value;
              break;
            case Role::Red:
              raw.rgb[3 * row + 0] = to_color(value, p.type);
              break;
            case Role::Green:
              raw.rgb[3 * row + 1] = to_color(value, p.type);
              break;
            case Role::Blue:
              raw.rgb[3 * row + 2] = to_color(value, p.type);
              break;
            case Role::U:
              raw.vertex_uv[2 * row + 0] = float(value);
              break;
            case Role::V:
              raw.vertex_uv[2 * row + 1] = float(value);
              break;
            default:
              break;
          }
          continue;
        }
        const double count_value = cur.scalar(p.count_type, p, -1);
        if (count_value < 0) throw cur.error("negative length for list '" + p.name + "'");
        const std::size_t count = std::size_t(count_value);
        const Role role = is_face ? p.role : Role::Skip;
        if (role == Role::FaceIndices) raw.face_size.push_back(std::uint32_t(count));
        if (role == Role::FaceTexcoords) raw.face_uv_size.push_back(std::uint32_t(count));
        for (std::size_t k = 0; k < count; ++k) {
          const double value = cur.scalar(p.type, p, long(k));
          if (role == Role::FaceIndices)
            raw.face_index.push_back(std::int64_t(value));
          else if (role == Role::FaceTexcoords)
            raw.face_uv.push_back(float(value));
        }
      }
      cur.end_row();
    }
  }
}

Role vertex_role(const std::string& n) {
  if (n == "x") return Role::X;
  if (n == "y") return Role::Y;
  if (n == "z") return Role::Z;
  if (n == "red" || n == "diffuse_red" || n == "r") return Role::Red;
  if (n == "green" || n == "diffuse_green" || n == "g") return Role::Green;
  if (n == "blue" || n == "diffuse_blue" || n == "b") return Role::Blue;
  if (n == "texture_u" || n == "s" || n == "u" || n == "texture_s") return Role::U;
  if (n == "texture_v" || n == "t" || n == "v" || n == "texture_t") return Role::V;
  return Role::Skip;
}

}  // namespace

Mesh load_ply(const std::string& path, const MeshLoadOptions& options) {
  detail::check_scale(options.scale);
  const std::string bytes = detail::read_file_bytes(path);
  Header h = parse_header(path, bytes);

  // Assign roles and check the elements a mesh needs.
  Element* vertex = nullptr;
  Element* face = nullptr;
  for (Element& e : h.elements) {
    if (e.name == "vertex" && !vertex) vertex = &e;
    if (e.name == "face" && !face) face = &e;
  }
  if (!vertex) throw FileError(path, "PLY has no 'vertex' element");
  if (!face)
    throw FileError(path, "PLY has no 'face' element (point clouds and triangle strips are not meshes)");
  if (vertex->count == 0) throw FileError(path, "empty mesh: the PLY declares 0 vertices");
  if (face->count == 0) throw FileError(path, "empty mesh: the PLY declares 0 faces");
  std::array<int, int(Role::FaceTexcoords) + 1> seen{};
  for (Property& p : vertex->properties) {
    p.role = vertex_role(p.name);
    if (p.role != Role::Skip && p.is_list)
      throw FileError(path, "vertex property '" + p.name + "' is a list; a scalar is expected");
    if (p.role != Role::Skip && seen[int(p.role)]++)
      throw FileError(path, "vertex property '" + p.name + "' is declared twice (or with an alias)");
  }
  for (Property& p : face->properties) {
    if (p.name == "vertex_indices" || p.name == "vertex_index")
      p.role = Role::FaceIndices;
    else if (p.name == "texcoord")
      p.role = Role::FaceTexcoords;
    if (p.role != Role::Skip && !p.is_list)
      throw FileError(path, "face property '" + p.name + "' must be a list");
    if (p.role == Role::FaceIndices && !is_integer(p.type))
      throw FileError(path, "face property '" + p.name + "' must list integers, not " + type_name(p.type));
    if (p.role != Role::Skip && seen[int(p.role)]++)
      throw FileError(path, "face property '" + p.name + "' is declared twice (or with an alias)");
  }
  if (!seen[int(Role::X)] || !seen[int(Role::Y)] || !seen[int(Role::Z)])
    throw FileError(path, "the 'vertex' element lacks x, y or z");
  if (!seen[int(Role::FaceIndices)])
    throw FileError(path, "the 'face' element has no list 'vertex_indices' (or 'vertex_index')");
  const bool colours = seen[int(Role::Red)] && seen[int(Role::Green)] && seen[int(Role::Blue)];
  if (!colours)
    for (Property& p : vertex->properties)
      if (p.role == Role::Red || p.role == Role::Green || p.role == Role::Blue) p.role = Role::Skip;
  const bool vertex_uvs = seen[int(Role::U)] && seen[int(Role::V)];
  if (!vertex_uvs)
    for (Property& p : vertex->properties)
      if (p.role == Role::U || p.role == Role::V) p.role = Role::Skip;

  // Allocate no more than the file could hold (a corrupt count must not exhaust memory).
  const std::size_t max_rows = bytes.size() - std::min(bytes.size(), h.data_offset) + 1;
  if (vertex->count > max_rows || face->count > max_rows)
    throw FileError(path, "truncated file or corrupt header: the header declares " +
                              std::to_string(vertex->count) + " vertices and " + std::to_string(face->count) +
                              " faces, more than the " + std::to_string(max_rows - 1) +
                              " data bytes can hold");
  RawMesh raw;
  raw.xyz.assign(3 * vertex->count, 0.0);
  if (colours) raw.rgb.assign(3 * vertex->count, 0);
  if (vertex_uvs) raw.vertex_uv.assign(2 * vertex->count, 0.f);
  raw.face_size.reserve(face->count);
  raw.face_index.reserve(3 * face->count);

  if (h.format == Format::Ascii) {
    AsciiCursor cur(path, bytes, h.data_offset, h.data_line);
    read_body(cur, h.elements, raw);
  } else {
    BinaryCursor cur(path, bytes, h.data_offset, h.format == Format::BinaryBig);
    read_body(cur, h.elements, raw);
  }

  // Build the mesh: fan-triangulate polygons, check indices, attach texture coordinates.
  Mesh mesh;
  mesh.name = fs::path(path).stem().string();
  const std::size_t nv = vertex->count;
  mesh.vertices.resize(nv);
  const double scale = options.scale;
  for (std::size_t i = 0; i < nv; ++i) {
    const Eigen::Vector3d p(raw.xyz[3 * i], raw.xyz[3 * i + 1], raw.xyz[3 * i + 2]);
    if (!p.allFinite()) throw FileError(path, "vertex " + std::to_string(i) + " has a non-finite coordinate");
    mesh.vertices[i] = (scale * p).cast<float>();
  }
  if (colours) {
    mesh.vertex_colors.resize(nv);
    for (std::size_t i = 0; i < nv; ++i)
      mesh.vertex_colors[i] = {raw.rgb[3 * i], raw.rgb[3 * i + 1], raw.rgb[3 * i + 2]};
  }
  const bool face_uvs = !raw.face_uv_size.empty();
  const bool want_uvs = (face_uvs || vertex_uvs) && !h.texture_file.empty();
  std::size_t offset = 0, uv_offset = 0;
  mesh.triangles.reserve(face->count);
  for (std::size_t f = 0; f < raw.face_size.size(); ++f) {
    const std::size_t n = raw.face_size[f];
    if (n < 3)
      throw FileError(
          path, "face " + std::to_string(f) + " has " + std::to_string(n) + " vertices; at least 3 needed");
    for (std::size_t k = 0; k < n; ++k) {
      const std::int64_t idx = raw.face_index[offset + k];
      if (idx < 0 || std::size_t(idx) >= nv)
        throw FileError(path, "face " + std::to_string(f) + " references vertex " + std::to_string(idx) +
                                  " but the file has " + std::to_string(nv) + " vertices (0-based)");
    }
    if (face_uvs && raw.face_uv_size[f] != 2 * n)
      throw FileError(path, "face " + std::to_string(f) + " has " + std::to_string(n) + " corners but " +
                                std::to_string(raw.face_uv_size[f]) + " texcoord values (expected " +
                                std::to_string(2 * n) + ")");
    for (std::size_t k = 1; k + 1 < n; ++k) {
      const std::size_t corners[3] = {0, k, k + 1};
      Eigen::Vector3i tri;
      for (int c = 0; c < 3; ++c) {
        tri[c] = int(raw.face_index[offset + corners[c]]);
        if (!want_uvs) continue;
        Eigen::Vector2f uv;
        if (face_uvs)
          uv = {raw.face_uv[uv_offset + 2 * corners[c]], raw.face_uv[uv_offset + 2 * corners[c] + 1]};
        else
          uv = {raw.vertex_uv[2 * tri[c]], raw.vertex_uv[2 * tri[c] + 1]};
        if (!uv.allFinite())
          throw FileError(path, "face " + std::to_string(f) + " has a non-finite texture coordinate");
        mesh.corner_uvs.push_back(uv);
      }
      mesh.triangles.push_back(tri);
    }
    offset += n;
    if (face_uvs) uv_offset += raw.face_uv_size[f];
  }
  if (want_uvs)
    mesh.texture =
        detail::load_texture(path, fs::path(path).parent_path(), h.texture_file, "'comment TextureFile'");
  try {
    mesh.validate();
  } catch (const InvalidInput& e) {
    throw FileError(path, e.what());
  }
  return mesh;
}

void save_ply(const std::string& path, const Mesh& mesh, bool binary) {
  mesh.validate();
  const bool colours = mesh.has_vertex_colors(), textured = mesh.has_texture();
  std::string texture_name;
  if (textured) texture_name = fs::path(path).stem().string() + ".png";

  std::ostringstream header;
  header << "ply\nformat " << (binary ? "binary_little_endian" : "ascii") << " 1.0\n"
         << "comment written by perch2 (units: metres)\n";
  if (textured) header << "comment TextureFile " << texture_name << "\n";
  header << "element vertex " << mesh.vertices.size()
         << "\nproperty float x\nproperty float y\nproperty float z\n";
  if (colours) header << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  header << "element face " << mesh.triangles.size() << "\nproperty list uchar int vertex_indices\n";
  if (textured) header << "property list uchar float texcoord\n";
  header << "end_header\n";
  std::string out = header.str();

  if (binary) {
    // Little-endian on the (little-endian) hosts perch2 targets; checked once here.
    const std::uint16_t one = 1;
    unsigned char first;
    std::memcpy(&first, &one, 1);
    if (first != 1)
      throw FileError(path, "binary PLY writing needs a little-endian host; use binary = false");
    auto put = [&out](const void* p, std::size_t n) { out.append(static_cast<const char*>(p), n); };
    out.reserve(out.size() + mesh.vertices.size() * 15 + mesh.triangles.size() * (textured ? 38 : 13));
    for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
      put(mesh.vertices[i].data(), 12);
      if (colours) put(&mesh.vertex_colors[i], 3);
    }
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
      const unsigned char three = 3, six = 6;
      put(&three, 1);
      put(mesh.triangles[t].data(), 12);
      if (textured) {
        put(&six, 1);
        for (int c = 0; c < 3; ++c) put(mesh.corner_uvs[3 * t + c].data(), 8);
      }
    }
  } else {
    std::ostringstream body;
    body.imbue(std::locale::classic());
    body.precision(std::numeric_limits<float>::max_digits10);  // exact float round trip
    for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
      const auto& v = mesh.vertices[i];
      body << v.x() << ' ' << v.y() << ' ' << v.z();
      if (colours) {
        const Rgb8 c = mesh.vertex_colors[i];
        body << ' ' << int(c.r) << ' ' << int(c.g) << ' ' << int(c.b);
      }
      body << '\n';
    }
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
      const auto& tri = mesh.triangles[t];
      body << "3 " << tri[0] << ' ' << tri[1] << ' ' << tri[2];
      if (textured) {
        body << " 6";
        for (int c = 0; c < 3; ++c)
          body << ' ' << mesh.corner_uvs[3 * t + c].x() << ' ' << mesh.corner_uvs[3 * t + c].y();
      }
      body << '\n';
    }
    out += body.str();
  }
  detail::write_file_bytes(path, out.data(), out.size());
  if (textured) save_color_image((fs::path(path).parent_path() / texture_name).string(), mesh.texture);
}

}  // namespace perch2::io
