// Bad files and bad arguments: every one raises FileError (file problems) or InvalidInput (bad arguments or
// contents), with a message naming the file and the reason. Nothing crashes, nothing returns garbage.
#include <cmath>
#include <filesystem>
#include <functional>

#include "perch2/io/io.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using perch2::Mesh;
using perch2::test::read_file;
using perch2::test::temp_path;
using perch2::test::write_file;

namespace {

/// Runs f, which must throw FileError whose message starts with `path` and contains `reason`.
void check_file_error(const std::function<void()>& f, const std::string& path, const std::string& reason) {
  try {
    f();
    FAIL_CHECK("no exception; expected FileError on " << path << " containing \"" << reason << "\"");
  } catch (const perch2::FileError& e) {
    const std::string what = e.what();
    INFO("message: " << what);
    CHECK(what.rfind(path + ": ", 0) == 0);
    CHECK(what.find(reason) != std::string::npos);
  } catch (const std::exception& e) {
    FAIL_CHECK("expected FileError containing \"" << reason << "\", got another exception: " << e.what());
  }
}

#define CHECK_FILE_ERROR(expr, path, reason) check_file_error([&] { (void)(expr); }, path, reason)

/// Replaces the first occurrence of `from` (which must exist) in `s`.
std::string replaced(std::string s, const std::string& from, const std::string& to) {
  const std::size_t at = s.find(from);
  REQUIRE_MESSAGE(at != std::string::npos, "test bug: '" << from << "' not in the text");
  return s.replace(at, from.size(), to);
}

const std::string kPly =
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";

/// Writes `text` to a fresh temporary PLY and loads it, expecting FileError with `reason`.
void check_ply(const std::string& name, const std::string& text, const std::string& reason) {
  const std::string path = temp_path(name + ".ply");
  write_file(path, text);
  CAPTURE(name);
  CHECK_FILE_ERROR(perch2::io::load_ply(path), path, reason);
}

Mesh triangle_mesh() {
  Mesh m;
  m.name = "tri";
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}};
  m.triangles = {{0, 1, 2}, {1, 3, 2}};
  m.vertex_colors = {{1, 2, 3}, {4, 5, 6}, {7, 8, 9}, {10, 11, 12}};
  return m;
}

}  // namespace

TEST_CASE("mesh files: missing, a folder, unsupported extension, bad scale") {
  const std::string missing = temp_path("no_such_mesh.ply");
  CHECK_FILE_ERROR(perch2::io::load_mesh(missing), missing, "file not found");
  CHECK_FILE_ERROR(perch2::io::load_obj(temp_path("no_such_mesh.obj")), temp_path("no_such_mesh.obj"),
                   "file not found");
  const std::string folder = temp_path("a_folder.ply");
  fs::create_directories(folder);
  CHECK_FILE_ERROR(perch2::io::load_ply(folder), folder, "is a folder");
  const std::string stl = temp_path("model.stl");
  write_file(stl, "solid x\nendsolid x\n");
  CHECK_FILE_ERROR(perch2::io::load_mesh(stl), stl, "unsupported mesh format '.stl'");
  const std::string good = temp_path("good.ply");
  write_file(good, kPly);
  CHECK_NOTHROW(perch2::io::load_mesh(good));
  for (const float scale : {0.f, -1.f, NAN, INFINITY})
    CHECK_THROWS_WITH_AS(perch2::io::load_mesh(good, {scale}), doctest::Contains("MeshLoadOptions::scale"),
                         perch2::InvalidInput);
}

TEST_CASE("malformed PLY headers") {
  check_ply("empty", "", "not a PLY file");
  check_ply("bad_magic", replaced(kPly, "ply\n", "plx\n"), "not a PLY file");
  check_ply("no_end_header", kPly.substr(0, kPly.find("end_header")), "no 'end_header' line");
  check_ply("unknown_format", replaced(kPly, "ascii", "utf8"), "unknown format 'utf8'");
  check_ply("no_version", replaced(kPly, "ascii 1.0", "ascii"), "no version");
  check_ply("no_format", replaced(kPly, "format ascii 1.0\n", ""), "no 'format' line");
  check_ply("unknown_type", replaced(kPly, "float x", "real x"), "unknown property type 'real'");
  check_ply("unknown_list_type", replaced(kPly, "list uchar int", "list uchar integer"), "unknown type");
  check_ply("float_list_count", replaced(kPly, "list uchar int", "list float int"),
            "count type must be an integer");
  check_ply("bad_count", replaced(kPly, "vertex 3", "vertex three"), "expected 'element <name> <count>'");
  check_ply("negative_count", replaced(kPly, "vertex 3", "vertex -3"), "expected 'element <name> <count>'");
  check_ply("property_first", replaced(kPly, "element vertex", "property float w\nelement vertex"),
            "line 3: property before any element");
  check_ply("unknown_keyword", replaced(kPly, "element face", "elemnt face"), "unknown keyword 'elemnt'");
  check_ply("no_x", replaced(kPly, "float x", "float w"), "lacks x, y or z");
  check_ply("twice_x", replaced(kPly, "float y", "float x"), "'x' is declared twice");
  check_ply("no_faces_element", replaced(kPly, "element face 1", "element edge 1"), "no 'face' element");
  check_ply("no_vertex_element", replaced(kPly, "element vertex 3", "element point 3"),
            "no 'vertex' element");
  check_ply("no_indices", replaced(kPly, "vertex_indices", "vertex_ids"), "no list 'vertex_indices'");
  check_ply("scalar_indices", replaced(kPly, "list uchar int vertex_indices", "int vertex_indices"),
            "must be a list");
  check_ply("float_indices", replaced(kPly, "list uchar int", "list uchar float"), "must list integers");
  check_ply("huge_count", replaced(kPly, "vertex 3", "vertex 4000000000"), "more than the");
}

TEST_CASE("malformed and truncated ascii PLY data") {
  check_ply("zero_vertices", replaced(replaced(kPly, "vertex 3", "vertex 0"), "0 0 0\n1 0 0\n0 1 0\n", ""),
            "empty mesh: the PLY declares 0 vertices");
  check_ply("zero_faces", replaced(replaced(kPly, "face 1", "face 0"), "3 0 1 2\n", ""), "0 faces");
  check_ply("fewer_vertices", kPly.substr(0, kPly.find("0 1 0\n")),
            "truncated: the data ends after 2 of 3 'vertex' rows");
  check_ply("fewer_faces", replaced(kPly, "face 1", "face 2"),
            "truncated: the data ends after 1 of 2 'face' rows");
  check_ply("cut_line", kPly.substr(0, kPly.size() - 3),
            "truncated: the data ends inside line 13, 'face' row 0 of 1");
  check_ply("extra_value", replaced(kPly, "1 0 0\n", "1 0 0 7\n"), "line 11 ('vertex' row 1): more values");
  check_ply("missing_value", replaced(kPly, "1 0 0\n", "1 0\n"), "line 11 ('vertex' row 1): too few values");
  check_ply("non_numeric", replaced(kPly, "1 0 0\n", "1 abc 0\n"),
            "non-numeric value 'abc' for property 'y'");
  check_ply("trailing_junk", replaced(kPly, "1 0 0\n", "1.0x 0 0\n"), "non-numeric value '1.0x'");
  check_ply("uchar_range", replaced(kPly, "3 0 1 2", "300 0 1 2"), "value '300' for the length of list");
  check_ply("fractional_index", replaced(kPly, "3 0 1 2", "3 0 1 2.5"), "is not a valid int");
  check_ply("index_range", replaced(kPly, "3 0 1 2", "3 0 1 7"),
            "face 0 references vertex 7 but the file has 3");
  check_ply("negative_index", replaced(kPly, "3 0 1 2", "3 0 -1 2"), "references vertex -1");
  check_ply("two_corners", replaced(kPly, "3 0 1 2", "2 0 1"), "face 0 has 2 vertices; at least 3 needed");
  check_ply("nan_vertex", replaced(kPly, "1 0 0\n", "nan 0 0\n"), "vertex 1 has a non-finite coordinate");
  const std::string textured =
      replaced(replaced(kPly, "end_header", "property list uchar float texcoord\nend_header"),
               "format ascii 1.0\n", "format ascii 1.0\ncomment TextureFile missing_texture.png\n");
  check_ply("texcoord_count", replaced(textured, "3 0 1 2", "3 0 1 2 4 0 0 1 1"),
            "3 corners but 4 texcoord values (expected 6)");
  check_ply("missing_texture", replaced(textured, "3 0 1 2", "3 0 1 2 6 0 0 1 0 0 1"),
            "texture 'missing_texture.png' named by 'comment TextureFile' not found");
}

TEST_CASE("truncated binary PLY: every proper prefix of a small file raises FileError") {
  const std::string path = temp_path("small_binary.ply");
  perch2::io::save_ply(path, triangle_mesh(), true);
  const std::string bytes = read_file(path);
  REQUIRE(perch2::io::load_ply(path).triangles.size() == 2);
  const std::string cut = temp_path("small_binary_cut.ply");
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    CAPTURE(n);
    write_file(cut, bytes.substr(0, n));
    CHECK_THROWS_AS(perch2::io::load_ply(cut), perch2::FileError);
  }
  write_file(cut, bytes.substr(0, bytes.size() - 5));
  CHECK_FILE_ERROR(perch2::io::load_ply(cut), cut,
                   "truncated: the binary data ends inside 'face' row 1 of 2");

  // A signed list length that is negative.
  std::string header =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list char int vertex_indices\nend_header\n";
  std::string body(36, '\0');
  body += char(-3);
  write_file(cut, header + body);
  CHECK_FILE_ERROR(perch2::io::load_ply(cut), cut, "'face' row 0: negative length");
}

TEST_CASE("prefixes of ascii PLY and OBJ files and corrupted header bytes never crash") {
  // A prefix is FileError, or a valid file whose text ends at a complete line (all numbers here have one
  // digit, so a cut inside a line always removes a value). An OBJ has no declared counts: a cut at a line end
  // after a complete face is a valid, smaller mesh that no reader can tell from the original.
  const std::string ply_path = temp_path("prefix.ply"), obj_path = temp_path("prefix.obj");
  const std::string obj =
      "# square\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
      "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n";
  const std::size_t first_face_end = obj.find("3/3\n") + 4;
  for (const auto& case_ : {std::pair{ply_path, kPly}, std::pair{obj_path, obj}}) {
    const std::string& path = case_.first;  // not structured bindings: doctest's macros capture them
    const std::string& text = case_.second;
    for (std::size_t n = 0; n <= text.size(); ++n) {
      CAPTURE(path);
      CAPTURE(n);
      write_file(path, text.substr(0, n));
      try {
        const Mesh m = perch2::io::load_mesh(path);
        CHECK_NOTHROW(m.validate());
        const bool complete = n + 1 >= text.size();  // at most the final newline is missing
        const bool one_face = path == obj_path && n + 1 >= first_face_end && n <= first_face_end;
        CHECK((complete || one_face));
        CHECK(m.triangles.size() == (one_face ? 1u : path == obj_path ? 2u : 1u));
      } catch (const perch2::FileError&) {
      }
    }
  }
  // Corrupt every header byte of a binary PLY in turn: FileError or a valid mesh, never another exception.
  const std::string bin_path = temp_path("corrupt.ply");
  perch2::io::save_ply(bin_path, triangle_mesh(), true);
  const std::string good = read_file(bin_path);
  const std::size_t header_size = good.find("end_header\n") + 11;
  int errors = 0;
  for (std::size_t i = 0; i < header_size; ++i)
    for (const char c : {'\0', 'x', '9', ' ', '\n', '\xff'}) {
      std::string bad = good;
      bad[i] = c;
      write_file(bin_path, bad);
      CAPTURE(i);
      CAPTURE(int(c));
      try {
        const Mesh m = perch2::io::load_ply(bin_path);
        CHECK_NOTHROW(m.validate());
      } catch (const perch2::FileError&) {
        ++errors;
      }
    }
  MESSAGE(errors << " of " << 6 * header_size << " header corruptions detected");
  CHECK(errors > int(header_size));  // most corruptions are detected (the rest hit comments or spaces)
}

TEST_CASE("truncated copies of the real LINEMOD cat PLY (ascii and binary)") {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/linemod_obj_06/obj_06.ply");
  const std::string bytes = read_file(path);
  const std::string cut = temp_path("obj_06_truncated.ply");
  // 50% of the bytes ends inside the vertex rows (15,736 lines of ~70 bytes), 90% inside the face rows.
  write_file(cut, bytes.substr(0, bytes.size() / 2));
  CHECK_FILE_ERROR(perch2::io::load_ply(cut, {0.001f}), cut, "truncated: the data ends inside line");
  CHECK_FILE_ERROR(perch2::io::load_ply(cut, {0.001f}), cut, "'vertex' row");
  write_file(cut, bytes.substr(0, bytes.size() * 9 / 10));
  CHECK_FILE_ERROR(perch2::io::load_ply(cut, {0.001f}), cut, "of 31468");
  // Cut exactly at a line end: the rows run out.
  const std::size_t line_end = bytes.rfind('\n', bytes.size() * 9 / 10) + 1;
  write_file(cut, bytes.substr(0, line_end));
  CHECK_FILE_ERROR(perch2::io::load_ply(cut, {0.001f}), cut, "of 31468 'face' rows");

  const Mesh cat = perch2::io::load_ply(path, {0.001f});
  const std::string bin = temp_path("obj_06_binary.ply");
  perch2::io::save_ply(bin, cat, true);
  const std::string bin_bytes = read_file(bin);
  write_file(cut, bin_bytes.substr(0, bin_bytes.size() - 100));
  CHECK_FILE_ERROR(perch2::io::load_ply(cut), cut, "truncated: the binary data ends inside 'face' row");
  write_file(cut, bin_bytes.substr(0, bin_bytes.size() / 4));
  CHECK_FILE_ERROR(perch2::io::load_ply(cut), cut, "truncated: the binary data ends inside 'vertex' row");
}

namespace {

void check_obj(const std::string& name, const std::string& text, const std::string& reason) {
  const std::string path = temp_path(name + ".obj");
  write_file(path, text);
  CAPTURE(name);
  CHECK_FILE_ERROR(perch2::io::load_obj(path), path, reason);
}

}  // namespace

TEST_CASE("malformed OBJ files") {
  const std::string v = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  const std::string ok_path = temp_path("ok.obj");
  write_file(ok_path, v + "f 1 2 3\n");
  REQUIRE(perch2::io::load_obj(ok_path).triangles.size() == 1);
  check_obj("empty", "", "empty mesh: no vertices");
  check_obj("no_faces", v, "empty mesh: no faces");
  check_obj("non_numeric", "v 0 0 0\nv 1 abc 0\nv 0 1 0\nf 1 2 3\n",
            "line 2: non-numeric value 'abc' in vertex");
  check_obj("short_vertex", "v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", "line 2: vertex 'v' has 2 values");
  check_obj("nan_vertex", "v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n", "line 2: non-finite value");
  check_obj("short_normal", v + "vn 0 1\nf 1//1 2//1 3//1\n", "line 4: normal 'vn' has 2 values");
  check_obj("index_range", v + "f 1 2 9\n", "line 4: face refers to vertex 9 but the file defines 3");
  check_obj("index_zero", v + "f 0 1 2\n", "line 4: face corner '0' has an invalid index '0'");
  check_obj("relative_range", v + "f -5 1 2\n", "refers to vertex -5 but only 3 are defined");
  check_obj("bad_corner", v + "vt 0 0\nf 1/1 2/1 3/\n", "line 5: malformed face corner '3/'");
  check_obj("mixed_layout", v + "vt 0 0\nf 1/1 2/1 3\n", "mix index layouts");
  check_obj("two_corners", v + "f 1 2\n", "face has 2 corners; at least 3");
  check_obj("texcoord_range", v + "vt 0 0\nf 1/1 2/9 3/1\n", "face refers to texture coordinate 9");
  check_obj("some_colours", "v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "1 of 3 vertices have colours");
  check_obj("missing_mtl", "mtllib nowhere.mtl\n" + v + "f 1 2 3\n",
            "line 1: material library 'nowhere.mtl' not found");

  // Materials and textures.
  perch2::ColorImage tex(2, 2, perch2::Rgb8{1, 2, 3});
  perch2::io::save_color_image(temp_path("tex_a.png"), tex);
  perch2::io::save_color_image(temp_path("tex_b.png"), tex);
  write_file(temp_path("mats.mtl"),
             "newmtl a\nKd 1 0 0\nmap_Kd tex_a.png\nnewmtl b\nKd 0 1 0\nmap_Kd tex_b.png\n"
             "newmtl plain\nKd 0 0 1\nnewmtl lost\nKd 1 1 1\nmap_Kd no_such_texture.png\n");
  const std::string vt = "mtllib mats.mtl\n" + v + "v 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n";
  check_obj("unknown_material", vt + "usemtl nosuch\nf 1/1 2/2 3/3\n",
            "line 9: 'usemtl nosuch' names a material that no material library defines");
  check_obj("missing_texture", vt + "usemtl lost\nf 1/1 2/2 3/3\n",
            "texture 'no_such_texture.png' named by map_Kd in its material library not found");
  check_obj("two_textures", vt + "usemtl a\nf 1/1 2/2 3/3\nusemtl b\nf 2/2 4/1 3/3\n",
            "faces use 2 different textures ('tex_a.png', 'tex_b.png'); meshes with several textures are not "
            "supported");
  check_obj("mixed_texturing", vt + "usemtl a\nf 1/1 2/2 3/3\nusemtl plain\nf 2/2 4/1 3/3\n",
            "1 of 2 triangles use a material without a texture");
  check_obj("textured_without_uv", vt + "usemtl a\nf 1/1 2/2 3/3\nf 2 4 3\n",
            "triangle 1 has no texture coordinates although its material has the texture 'tex_a.png'");
  // One texture used by two materials is fine.
  const std::string ok = temp_path("one_texture.obj");
  write_file(ok, vt + "usemtl a\nf 1/1 2/2 3/3\nusemtl a\nf 2/2 4/1 3/3\n");
  CHECK(perch2::io::load_obj(ok).has_texture());
}

TEST_CASE("truncated copies of the real YCB banana OBJ") {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/ycb_011_banana/textured_simple.obj");
  const std::string bytes = read_file(path);
  const std::string cut = temp_path("banana_truncated.obj");
  // Cut inside a face line ("f 6621/87"): the last face has a single corner.
  const std::size_t face = bytes.find("\nf ", bytes.size() * 6 / 10);
  REQUIRE(face != std::string::npos);
  write_file(cut, bytes.substr(0, face + 10));
  CHECK_FILE_ERROR(perch2::io::load_obj(cut), cut, "truncated line?");
  // Cut inside the vertex list ("v 0.045474 0.01"): the last vertex has two coordinates.
  const std::size_t vertex = bytes.find("\nv ", bytes.size() / 8);
  write_file(cut, bytes.substr(0, vertex + 16));
  CHECK_FILE_ERROR(perch2::io::load_obj(cut), cut, "vertex 'v' has 2 values");
  // Cut at a line end inside the texture coordinates: faces refer to vertices and UVs that are not there.
  const std::size_t vt = bytes.find("\nvt ", bytes.size() / 4);
  std::string no_tail = bytes.substr(0, vt + 1) + bytes.substr(bytes.find("\nusemtl") + 1);
  write_file(cut, no_tail);
  CHECK_FILE_ERROR(perch2::io::load_obj(cut), cut, "face refers to texture coordinate");
}

TEST_CASE("image files: missing, wrong kind, corrupt, truncated") {
  const std::string missing = temp_path("no_such_image.png");
  CHECK_FILE_ERROR(perch2::io::load_depth_png(missing), missing, "file not found");
  CHECK_FILE_ERROR(perch2::io::load_color_image(missing), missing, "file not found");
  CHECK_FILE_ERROR(perch2::io::load_label_png(missing), missing, "file not found");

  const std::string text = temp_path("not_an_image.png");
  write_file(text, "hello, I am text\n");
  CHECK_FILE_ERROR(perch2::io::load_depth_png(text), text, "not a PNG file");
  CHECK_FILE_ERROR(perch2::io::load_color_image(text), text, "not a PNG or JPEG file");
  const std::string empty = temp_path("empty.png");
  write_file(empty, "");
  CHECK_FILE_ERROR(perch2::io::load_color_image(empty), empty, "empty file");

  perch2::ColorImage rgb(40, 30);
  for (int v = 0; v < 30; ++v)
    for (int u = 0; u < 40; ++u)
      rgb(u, v) = perch2::Rgb8{std::uint8_t(u * 6), std::uint8_t(v * 8), std::uint8_t(u ^ v)};
  const std::string rgb_png = temp_path("rgb.png"), rgb_jpg = temp_path("rgb.jpg");
  perch2::io::save_color_image(rgb_png, rgb);
  perch2::io::save_color_image(rgb_jpg, rgb);
  perch2::DepthImage depth(40, 30, 1.5f);
  const std::string depth_png = temp_path("depth16.png");
  perch2::io::save_depth_png(depth_png, depth);

  // The wrong kind of image.
  CHECK_FILE_ERROR(perch2::io::load_depth_png(rgb_png), rgb_png,
                   "expected a 16-bit single-channel depth PNG, got a 8-bit 3-channel 40x30 image");
  CHECK_FILE_ERROR(perch2::io::load_depth_png(rgb_jpg), rgb_jpg, "not a PNG file (a PNG is required)");
  CHECK_FILE_ERROR(perch2::io::load_color_image(depth_png), depth_png,
                   "expected an 8-bit colour image, got a 16-bit");
  CHECK_FILE_ERROR(perch2::io::load_label_png(rgb_png), rgb_png,
                   "expected an 8- or 16-bit single-channel label PNG");

  // Truncated files.
  const std::string cut = temp_path("cut.png"), cut_jpg = temp_path("cut.jpg");
  const std::string png_bytes = read_file(rgb_png), jpg_bytes = read_file(rgb_jpg);
  write_file(cut, png_bytes.substr(0, png_bytes.size() / 2));
  CHECK_FILE_ERROR(perch2::io::load_color_image(cut), cut, "truncated PNG");
  write_file(cut, read_file(depth_png).substr(0, 40));
  CHECK_FILE_ERROR(perch2::io::load_depth_png(cut), cut, "truncated PNG");
  write_file(cut_jpg, jpg_bytes.substr(0, jpg_bytes.size() * 2 / 3));
  CHECK_FILE_ERROR(perch2::io::load_color_image(cut_jpg), cut_jpg, "truncated JPEG");

  // Corrupt bytes inside the compressed data (the file still ends with IEND): zlib or the CRC check fails.
  std::string corrupt = png_bytes;
  const std::size_t idat = corrupt.find("IDAT");
  REQUIRE(idat != std::string::npos);
  for (std::size_t i = idat + 20; i < idat + 60; ++i) corrupt[i] = char(corrupt[i] ^ 0x5a);
  write_file(cut, corrupt);
  CHECK_FILE_ERROR(perch2::io::load_color_image(cut), cut, "corrupt PNG data");

  CHECK_THROWS_WITH_AS(perch2::io::load_depth_png(depth_png, 0.f), doctest::Contains("metres_per_unit"),
                       perch2::InvalidInput);
  CHECK_THROWS_WITH_AS(perch2::io::load_depth_png(depth_png, NAN), doctest::Contains("metres_per_unit"),
                       perch2::InvalidInput);
}

TEST_CASE("writing images and meshes: bad contents, bad paths, missing folders") {
  perch2::DepthImage depth(4, 3, 1.f);
  const std::string ok = temp_path("write_ok.png");
  CHECK_NOTHROW(perch2::io::save_depth_png(ok, depth));
  const std::string nowhere = temp_path("no_such_folder/depth.png");
  CHECK_FILE_ERROR(perch2::io::save_depth_png(nowhere, depth), nowhere, "does not exist");

  depth(1, 2) = 70.f;  // 70000 mm > 65535
  CHECK_THROWS_WITH_AS(perch2::io::save_depth_png(ok, depth), doctest::Contains("(1, 2) is 70"),
                       perch2::InvalidInput);
  CHECK_THROWS_WITH_AS(perch2::io::save_depth_png(ok, depth), doctest::Contains("beyond the 16-bit maximum"),
                       perch2::InvalidInput);
  CHECK_NOTHROW(perch2::io::save_depth_png(ok, depth, 0.002f));  // 35000 units of 2 mm fit
  depth(1, 2) = -0.5f;
  CHECK_THROWS_WITH_AS(perch2::io::save_depth_png(ok, depth), doctest::Contains("must be finite and >= 0"),
                       perch2::InvalidInput);
  depth(1, 2) = NAN;
  CHECK_THROWS_WITH_AS(perch2::io::save_depth_png(ok, depth), doctest::Contains("must be finite and >= 0"),
                       perch2::InvalidInput);
  depth(1, 2) = 1.f;
  CHECK_THROWS_WITH_AS(perch2::io::save_depth_png(temp_path("depth.jpg"), depth),
                       doctest::Contains("must end in .png"), perch2::InvalidInput);
  CHECK_THROWS_WITH_AS(perch2::io::save_depth_png(ok, depth, -1.f), doctest::Contains("metres_per_unit"),
                       perch2::InvalidInput);
  CHECK_THROWS_WITH_AS(perch2::io::save_depth_png(ok, perch2::DepthImage{}), doctest::Contains("empty"),
                       perch2::InvalidInput);

  perch2::ColorImage rgb(4, 3, perch2::Rgb8{1, 2, 3});
  CHECK_THROWS_WITH_AS(perch2::io::save_color_image(temp_path("rgb.bmp"), rgb), doctest::Contains("'.bmp'"),
                       perch2::InvalidInput);
  CHECK_THROWS_WITH_AS(perch2::io::save_color_image(ok, perch2::ColorImage{}), doctest::Contains("empty"),
                       perch2::InvalidInput);
  const std::string nowhere_rgb = temp_path("no_such_folder/rgb.jpg");
  CHECK_FILE_ERROR(perch2::io::save_color_image(nowhere_rgb, rgb), nowhere_rgb, "does not exist");

  perch2::LabelImage labels(4, 3, 0);
  labels(2, 1) = -1;
  CHECK_THROWS_WITH_AS(perch2::io::save_label_png(ok, labels), doctest::Contains("label -1 at pixel (2, 1)"),
                       perch2::InvalidInput);
  labels(2, 1) = 70000;
  CHECK_THROWS_WITH_AS(perch2::io::save_label_png(ok, labels), doctest::Contains("outside [0, 65535]"),
                       perch2::InvalidInput);

  Mesh bad = triangle_mesh();
  bad.triangles.push_back({0, 1, 4});
  CHECK_THROWS_WITH_AS(perch2::io::save_ply(temp_path("bad.ply"), bad),
                       doctest::Contains("references vertex 4"), perch2::InvalidInput);
  const std::string nowhere_ply = temp_path("no_such_folder/mesh.ply");
  CHECK_FILE_ERROR(perch2::io::save_ply(nowhere_ply, triangle_mesh()), nowhere_ply, "does not exist");
}
