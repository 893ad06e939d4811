// File I/O that works: PLY (ascii, binary little/big-endian, hand-written bytes), OBJ + MTL + texture, depth,
// colour and label PNGs, and the real scanned models in ../shared/data.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>

#include "perch2/io/io.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using perch2::Mesh;
using perch2::Rgb8;
using perch2::test::temp_path;
using perch2::test::write_file;

namespace {

bool same(Rgb8 a, Rgb8 b) {
  return a.r == b.r && a.g == b.g && a.b == b.b;
}

/// A small coloured mesh: a unit square pyramid (5 vertices, 6 triangles) with awkward float values.
Mesh pyramid(bool colours) {
  Mesh m;
  m.name = "pyramid";
  m.vertices = {
      {0.f, 0.f, 0.f}, {0.1f, 0.f, 0.f}, {0.1f, 0.2f, 0.f}, {0.f, 0.2f, 0.f}, {0.05f, 0.1f, 1.f / 3.f}};
  m.triangles = {{0, 2, 1}, {0, 3, 2}, {0, 1, 4}, {1, 2, 4}, {2, 3, 4}, {3, 0, 4}};
  if (colours) m.vertex_colors = {{255, 0, 0}, {0, 255, 0}, {0, 0, 255}, {12, 34, 56}, {255, 255, 255}};
  return m;
}

/// A 4x2 texture whose pixels all differ, so any flip or channel swap is visible.
perch2::ColorImage test_texture() {
  perch2::ColorImage t(4, 2);
  for (int v = 0; v < 2; ++v)
    for (int u = 0; u < 4; ++u)
      t(u, v) = Rgb8{std::uint8_t(60 * u), std::uint8_t(200 - 100 * v), std::uint8_t(7 + u + 10 * v)};
  return t;
}

void check_same_mesh(const Mesh& a, const Mesh& b) {
  REQUIRE(a.vertices.size() == b.vertices.size());
  REQUIRE(a.triangles.size() == b.triangles.size());
  for (std::size_t i = 0; i < a.vertices.size(); ++i) CHECK(a.vertices[i] == b.vertices[i]);  // exact
  for (std::size_t i = 0; i < a.triangles.size(); ++i) CHECK(a.triangles[i] == b.triangles[i]);
  REQUIRE(a.vertex_colors.size() == b.vertex_colors.size());
  for (std::size_t i = 0; i < a.vertex_colors.size(); ++i)
    CHECK(same(a.vertex_colors[i], b.vertex_colors[i]));
  REQUIRE(a.corner_uvs.size() == b.corner_uvs.size());
  for (std::size_t i = 0; i < a.corner_uvs.size(); ++i) CHECK(a.corner_uvs[i] == b.corner_uvs[i]);
  REQUIRE(a.texture.width == b.texture.width);
  REQUIRE(a.texture.height == b.texture.height);
  for (std::size_t i = 0; i < a.texture.data.size(); ++i) CHECK(same(a.texture.data[i], b.texture.data[i]));
}

/// Appends scalars in a chosen byte order (to hand-write binary PLY bodies).
struct Bytes {
  bool big_endian;
  std::string s;
  template <class T>
  Bytes& put(T v) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    if (big_endian) std::reverse(b, b + sizeof(T));
    s.append(b, sizeof(T));
    return *this;
  }
};

// Hand-made PNGs (Python zlib + struct), independent of perch2's writer:
// a 2x1 8-bit RGB image (red, blue) and a 3x1 16-bit grey image (0, 1000, 65535).
const char kRedBluePng[] =
    "\x89\x50\x4e\x47\x0d\x0a\x1a\x0a\x00\x00\x00\x0d\x49\x48\x44\x52\x00\x00\x00\x02\x00\x00\x00\x01\x08\x02"
    "\x00"
    "\x00\x00\x7b\x40\xe8\xdd\x00\x00\x00\x0d\x49\x44\x41\x54\x78\x9c\x63\xf8\xcf\x00\x04\xff\x01\x07\x00\x01"
    "\xff"
    "\xe2\x23\x9e\x59\x00\x00\x00\x00\x49\x45\x4e\x44\xae\x42\x60\x82";
const char kDepth16Png[] =
    "\x89\x50\x4e\x47\x0d\x0a\x1a\x0a\x00\x00\x00\x0d\x49\x48\x44\x52\x00\x00\x00\x03\x00\x00\x00\x01\x10\x00"
    "\x00"
    "\x00\x00\x6e\x1b\x97\x2b\x00\x00\x00\x0f\x49\x44\x41\x54\x78\x9c\x63\x60\x60\x60\x7e\xf1\xff\x3f\x00\x05"
    "\xc8"
    "\x02\xea\x94\x66\x84\x05\x00\x00\x00\x00\x49\x45\x4e\x44\xae\x42\x60\x82";

}  // namespace

TEST_CASE("PLY round trip, ascii and binary, with and without vertex colours") {
  for (const bool colours : {false, true})
    for (const bool binary : {false, true}) {
      CAPTURE(colours);
      CAPTURE(binary);
      const Mesh m = pyramid(colours);
      const std::string path = temp_path(std::string("pyramid_") + (binary ? "bin" : "ascii") + ".ply");
      perch2::io::save_ply(path, m, binary);
      CHECK(perch2::test::read_file(path).rfind(binary ? "format binary_little_endian 1.0"
                                                       : "format ascii 1.0") != std::string::npos);
      // Floats are written with max_digits10 in ascii, as raw bytes in binary: the round trip is exact.
      const Mesh back = perch2::io::load_ply(path);
      check_same_mesh(m, back);
      CHECK(back.name == fs::path(path).stem().string());
      CHECK(!back.has_texture());
    }
}

TEST_CASE("PLY round trip of a textured mesh writes and reads the texture beside it") {
  Mesh m = pyramid(false);
  m.texture = test_texture();
  for (std::size_t t = 0; t < m.triangles.size(); ++t)
    for (int c = 0; c < 3; ++c)
      m.corner_uvs.push_back({0.1f * float(t) + 0.01f * float(c), 0.3f + 0.1f * float(c)});
  for (const bool binary : {false, true}) {
    CAPTURE(binary);
    const std::string path = temp_path(std::string("textured_") + (binary ? "bin" : "ascii") + ".ply");
    perch2::io::save_ply(path, m, binary);
    CHECK(fs::exists(fs::path(path).replace_extension(".png")));
    const Mesh back = perch2::io::load_ply(path);
    CHECK(back.has_texture());
    check_same_mesh(m, back);
  }
}

namespace {

/// The same mesh as hand-written PLY bytes: mixed scalar types, properties and elements perch2 must skip
/// (normals, alpha, an "edge" element with lists, a face flag before the index list, an extra face list), and
/// a quad that must be fan-triangulated. `aliases` uses the int8/uint8/.../float64 type names.
std::string handmade_ply(const std::string& format, bool aliases) {
  auto T = [&](const char* classic, const char* alias) { return std::string(aliases ? alias : classic); };
  std::string header = "ply\nformat " + format + " 1.0\ncomment hand-written for test_io\nobj_info nothing\n";
  header += "element vertex 4\nproperty " + T("double", "float64") + " x\nproperty " + T("float", "float32") +
            " y\nproperty " + T("short", "int16") + " z\nproperty " + T("float", "float32") +
            " nx\nproperty " + T("uchar", "uint8") + " red\nproperty " + T("uchar", "uint8") +
            " green\nproperty " + T("uchar", "uint8") + " blue\nproperty " + T("uchar", "uint8") + " alpha\n";
  header += "element edge 1\nproperty list " + T("ushort", "uint16") + " " + T("uint", "uint32") +
            " links\nproperty " + T("int", "int32") + " flag\n";
  header += "element face 2\nproperty " + T("char", "int8") + " flags\nproperty list " + T("uchar", "uint8") +
            " " + T("uint", "uint32") + " vertex_indices\nproperty list " + T("int", "int32") + " " +
            T("float", "float32") + " extra\nend_header\n";
  if (format == "ascii")
    return header +
           "0.5 -1.25 -2 9 10 20 30 255\n"
           "1.5 0.75 0 9 40 50 60 255\n"
           "-0.25 2 3 9 70 80 90 0\n"
           "4 4 5 9 100 110 120 128\n"
           "3 0 1 2 -7\n"
           "-1 4 0 1 2 3 2 0.5 0.25\n"
           "0 3 3 2 1 0\n";
  Bytes b{format == "binary_big_endian", header};
  const double x[4] = {0.5, 1.5, -0.25, 4};
  const float y[4] = {-1.25f, 0.75f, 2.f, 4.f};
  const std::int16_t z[4] = {-2, 0, 3, 5};
  for (int i = 0; i < 4; ++i)
    b.put(x[i])
        .put(y[i])
        .put(z[i])
        .put(9.f)
        .put(std::uint8_t(10 + 30 * i))
        .put(std::uint8_t(20 + 30 * i))
        .put(std::uint8_t(30 + 30 * i))
        .put(std::uint8_t(i == 2 ? 0 : 255));
  b.put(std::uint16_t(3))
      .put(std::uint32_t(0))
      .put(std::uint32_t(1))
      .put(std::uint32_t(2))
      .put(std::int32_t(-7));
  b.put(std::int8_t(-1)).put(std::uint8_t(4));
  for (std::uint32_t i : {0u, 1u, 2u, 3u}) b.put(i);
  b.put(std::int32_t(2)).put(0.5f).put(0.25f);
  b.put(std::int8_t(0)).put(std::uint8_t(3));
  for (std::uint32_t i : {3u, 2u, 1u}) b.put(i);
  b.put(std::int32_t(0));
  return b.s;
}

}  // namespace

TEST_CASE("hand-written PLY bytes: ascii, little- and big-endian binary give the same mesh") {
  const double scale = 2.0;
  for (const std::string format : {"ascii", "binary_little_endian", "binary_big_endian"})
    for (const bool aliases : {false, true}) {
      CAPTURE(format);
      CAPTURE(aliases);
      const std::string path = temp_path("handmade_" + format + (aliases ? "_alias" : "") + ".ply");
      write_file(path, handmade_ply(format, aliases));
      const Mesh m = perch2::io::load_ply(path, {float(scale)});
      REQUIRE(m.vertices.size() == 4);
      // All values are exact in float, and so are their doubles.
      CHECK(m.vertices[0] == Eigen::Vector3f(1.f, -2.5f, -4.f));
      CHECK(m.vertices[1] == Eigen::Vector3f(3.f, 1.5f, 0.f));
      CHECK(m.vertices[2] == Eigen::Vector3f(-0.5f, 4.f, 6.f));
      CHECK(m.vertices[3] == Eigen::Vector3f(8.f, 8.f, 10.f));
      REQUIRE(m.vertex_colors.size() == 4);
      for (int i = 0; i < 4; ++i)
        CHECK(same(m.vertex_colors[i],
                   Rgb8{std::uint8_t(10 + 30 * i), std::uint8_t(20 + 30 * i), std::uint8_t(30 + 30 * i)}));
      // The quad 0 1 2 3 becomes the fan (0 1 2), (0 2 3); then the triangle 3 2 1.
      REQUIRE(m.triangles.size() == 3);
      CHECK(m.triangles[0] == Eigen::Vector3i(0, 1, 2));
      CHECK(m.triangles[1] == Eigen::Vector3i(0, 2, 3));
      CHECK(m.triangles[2] == Eigen::Vector3i(3, 2, 1));
      CHECK(m.corner_uvs.empty());
      CHECK(m.name == fs::path(path).stem().string());
    }
}

TEST_CASE("PLY float colours in [0, 1], per-vertex and per-face texture coordinates, TextureFile") {
  const std::string tex_path = temp_path("ply_texture.png");
  perch2::io::save_color_image(tex_path, test_texture());
  const std::string vertices =
      "0 0 0 0 0.5 1 0.0 0.0\n"
      "1 0 0 1 1 1 1.0 0.0\n"
      "1 1 0 0.2 0.4 0.6 1.0 1.0\n"
      "0 1 0 0 0 0 0.0 1.0\n";
  const std::string header =
      "ply\nformat ascii 1.0\ncomment TextureFile ply_texture.png\nelement vertex 4\n"
      "property float x\nproperty float y\nproperty float z\n"
      "property float red\nproperty float green\nproperty float blue\n";

  SUBCASE("per-vertex texture_u / texture_v become per-corner coordinates") {
    const std::string path = temp_path("uv_vertex.ply");
    write_file(path, header +
                         "property float texture_u\nproperty float texture_v\nelement face 1\n"
                         "property list uchar int vertex_indices\nend_header\n" +
                         vertices + "4 0 1 2 3\n");
    const Mesh m = perch2::io::load_ply(path);
    REQUIRE(m.vertex_colors.size() == 4);
    // 0.5 * 255 = 127.5 rounds to even (128); 0.2 * 255 = 51; 0.4 * 255 = 102; 0.6 * 255 = 153.
    CHECK(same(m.vertex_colors[0], Rgb8{0, 128, 255}));
    CHECK(same(m.vertex_colors[2], Rgb8{51, 102, 153}));
    REQUIRE(m.has_texture());
    CHECK(m.texture.width == 4);
    CHECK(same(m.texture(3, 1), test_texture()(3, 1)));
    REQUIRE(m.corner_uvs.size() == 6);  // triangles (0 1 2), (0 2 3)
    const Eigen::Vector2f uv[4] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    const int corner_vertex[6] = {0, 1, 2, 0, 2, 3};
    for (int k = 0; k < 6; ++k) CHECK(m.corner_uvs[k] == uv[corner_vertex[k]]);
  }
  SUBCASE("u / v aliases and a face texcoord list, which takes precedence") {
    const std::string path = temp_path("uv_face.ply");
    write_file(path, header +
                         "property float u\nproperty float v\nelement face 1\n"
                         "property list uchar int vertex_index\nproperty list uchar float texcoord\n"
                         "end_header\n" +
                         vertices + "4 0 1 2 3 8 0.1 0.2 0.3 0.4 0.5 0.6 0.7 0.8\n");
    const Mesh m = perch2::io::load_ply(path);
    REQUIRE(m.corner_uvs.size() == 6);
    const Eigen::Vector2f uv[4] = {{0.1f, 0.2f}, {0.3f, 0.4f}, {0.5f, 0.6f}, {0.7f, 0.8f}};
    const int corner[6] = {0, 1, 2, 0, 2, 3};
    for (int k = 0; k < 6; ++k) CHECK(m.corner_uvs[k] == uv[corner[k]]);
  }
  SUBCASE("texture coordinates without a TextureFile are dropped (nothing to sample)") {
    const std::string path = temp_path("uv_no_texture.ply");
    std::string h = header;
    h.replace(h.find("comment TextureFile ply_texture.png\n"), 36, "");
    write_file(path, h +
                         "property float s\nproperty float t\nelement face 1\n"
                         "property list uchar int vertex_indices\nend_header\n" +
                         vertices + "3 0 1 2\n");
    const Mesh m = perch2::io::load_ply(path);
    CHECK(m.corner_uvs.empty());
    CHECK(m.texture.empty());
    CHECK(m.vertex_colors.size() == 4);
  }
}

TEST_CASE("OBJ with MTL, texture, quads and Kd, OBJ vertex colours, load_mesh dispatch") {
  const std::string tex_path = temp_path("obj_texture.png");
  perch2::io::save_color_image(tex_path, test_texture());
  write_file(temp_path("quad.mtl"),
             "# test material\nnewmtl paper\nKa 1 1 1\nKd 0.2 0.4 1.0\nmap_Kd obj_texture.png\n");
  const std::string path = temp_path("quad.obj");
  write_file(path,
             "# a textured quad and a triangle\nmtllib quad.mtl\no quad\n"
             "v 0 0 0\nv 2 0 0\nv 2 1 0\nv 0 1 0\nv 1 1 1\n"
             "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
             "vn 0 0 1\n"
             "usemtl paper\ns off\n"
             "f 1/1/1 2/2/1 3/3/1 4/4/1\n"
             "f -2/-1/-1 -3/-2/-1 -1/-3/-1\n");
  const Mesh m = perch2::io::load_obj(path, {0.5f});
  CHECK(m.name == "quad");
  REQUIRE(m.vertices.size() == 5);
  CHECK(m.vertices[1] == Eigen::Vector3f(1.f, 0.f, 0.f));  // scaled by 0.5
  CHECK(m.vertices[4] == Eigen::Vector3f(0.5f, 0.5f, 0.5f));
  // tinyobjloader splits the quad into two triangles; together they cover the corners 0..3 once each side.
  REQUIRE(m.triangles.size() == 3);
  CHECK(m.triangles[2] == Eigen::Vector3i(3, 2, 4));  // negative (relative) indices resolved
  REQUIRE(m.corner_uvs.size() == 9);
  const Eigen::Vector2f uv_of_vertex[4] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  for (int t = 0; t < 2; ++t)
    for (int c = 0; c < 3; ++c) CHECK(m.corner_uvs[3 * t + c] == uv_of_vertex[m.triangles[t][c]]);
  CHECK(m.corner_uvs[6] == Eigen::Vector2f(0, 1));  // corner -2/-1: the last vt
  CHECK(m.corner_uvs[7] == Eigen::Vector2f(1, 1));
  CHECK(m.corner_uvs[8] == Eigen::Vector2f(1, 0));
  // The two quad triangles cover the scaled 1 x 0.5 rectangle exactly once.
  float area = 0;
  for (int t = 0; t < 2; ++t) {
    const auto& tri = m.triangles[t];
    area += 0.5f *
            (m.vertices[tri[1]] - m.vertices[tri[0]]).cross(m.vertices[tri[2]] - m.vertices[tri[0]]).norm();
  }
  CHECK(area == doctest::Approx(0.5));
  // Kd 0.2 0.4 1.0 -> 51 102 255.
  CHECK(same(m.base_color, Rgb8{51, 102, 255}));
  REQUIRE(m.has_texture());
  for (int v = 0; v < 2; ++v)
    for (int u = 0; u < 4; ++u) CHECK(same(m.texture(u, v), test_texture()(u, v)));
  CHECK(!m.has_vertex_colors());

  SUBCASE("vertex colours, floats in [0, 1] and 0..255") {
    const std::string p1 = temp_path("coloured_unit.obj"), p2 = temp_path("coloured_255.obj");
    write_file(p1, "v 0 0 0 1 0 0.5\nv 1 0 0 0 1 0\nv 0 1 0 0.2 0.4 0.6\nf 1 2 3\n");
    write_file(p2, "v 0 0 0 255 0 128\nv 1 0 0 0 255 0\nv 0 1 0 51 102 153\nf 1 2 3\n");
    for (const auto& p : {p1, p2}) {
      CAPTURE(p);
      const Mesh c = perch2::io::load_mesh(p);
      REQUIRE(c.vertex_colors.size() == 3);
      CHECK(same(c.vertex_colors[0], Rgb8{255, 0, 128}));
      CHECK(same(c.vertex_colors[2], Rgb8{51, 102, 153}));
      CHECK(!c.has_texture());
      CHECK(same(c.base_color, Mesh{}.base_color));  // no material: the default
    }
  }
  SUBCASE("load_mesh dispatches on the extension, case-insensitively") {
    const std::string upper = temp_path("UPPER.PLY");
    perch2::io::save_ply(upper, pyramid(true));
    CHECK(perch2::io::load_mesh(upper).triangles.size() == 6);
    CHECK(perch2::io::load_mesh(path).triangles.size() == 3);
  }
}

TEST_CASE("depth PNG round trip with a depth scale") {
  perch2::DepthImage depth(5, 3, 0.f);
  // 0 = no reading; values on and off the unit grid; the 16-bit maximum at each scale.
  const float values[5] = {0.f, 0.001f, 1.23456f, 0.7f, 3.f};
  for (int u = 0; u < 5; ++u) depth(u, 0) = values[u];
  for (int u = 0; u < 5; ++u) depth(u, 1) = 0.25f * float(u);
  for (const float mpu : {0.001f, 0.0001f}) {
    CAPTURE(mpu);
    depth(0, 2) = 65535.f * mpu;  // largest representable depth
    const std::string path = temp_path("depth.png");
    perch2::io::save_depth_png(path, depth, mpu);
    const perch2::DepthImage back = perch2::io::load_depth_png(path, mpu);
    REQUIRE(back.width == 5);
    REQUIRE(back.height == 3);
    CHECK(back(0, 0) == 0.f);
    CHECK(back(4, 2) == 0.f);
    for (std::size_t i = 0; i < depth.data.size(); ++i) {
      // Rounding to the nearest unit: error at most half a unit (plus float rounding of the product).
      CHECK(std::abs(back.data[i] - depth.data[i]) <= 0.5f * mpu + 1e-6f * depth.data[i]);
    }
    CHECK(back(2, 0) == doctest::Approx(mpu == 0.001f ? 1.235 : 1.2346).epsilon(1e-6));
    CHECK(back(0, 2) == doctest::Approx(65535.0 * mpu).epsilon(1e-6));
  }
  SUBCASE("a hand-made 16-bit PNG reads as value * metres_per_unit") {
    const std::string path = temp_path("handmade_depth.png");
    write_file(path, std::string(kDepth16Png, sizeof(kDepth16Png) - 1));
    const perch2::DepthImage d = perch2::io::load_depth_png(path);
    REQUIRE(d.width == 3);
    REQUIRE(d.height == 1);
    CHECK(d(0, 0) == 0.f);
    CHECK(d(1, 0) == doctest::Approx(1.0).epsilon(1e-6));
    CHECK(d(2, 0) == doctest::Approx(65.535).epsilon(1e-6));
    const perch2::DepthImage d10 = perch2::io::load_depth_png(path, 0.0001f);
    CHECK(d10(1, 0) == doctest::Approx(0.1).epsilon(1e-6));
  }
}

TEST_CASE("colour images: RGB order, PNG exact round trip, JPEG close") {
  SUBCASE("a hand-made PNG reads in RGB order") {
    const std::string path = temp_path("red_blue.png");
    write_file(path, std::string(kRedBluePng, sizeof(kRedBluePng) - 1));
    const perch2::ColorImage c = perch2::io::load_color_image(path);
    REQUIRE(c.width == 2);
    REQUIRE(c.height == 1);
    CHECK(same(c(0, 0), Rgb8{255, 0, 0}));
    CHECK(same(c(1, 0), Rgb8{0, 0, 255}));
  }
  perch2::ColorImage img(32, 24);
  for (int v = 0; v < 24; ++v)
    for (int u = 0; u < 32; ++u)
      img(u, v) = Rgb8{std::uint8_t(8 * u), std::uint8_t(10 * v), std::uint8_t(128)};
  SUBCASE("PNG is lossless") {
    const std::string path = temp_path("gradient.png");
    perch2::io::save_color_image(path, img);
    const perch2::ColorImage back = perch2::io::load_color_image(path);
    REQUIRE(back.width == 32);
    REQUIRE(back.height == 24);
    for (std::size_t i = 0; i < img.data.size(); ++i) CHECK(same(back.data[i], img.data[i]));
  }
  SUBCASE("JPEG is lossy but close") {
    const std::string path = temp_path("gradient.jpg");
    perch2::io::save_color_image(path, img);
    const perch2::ColorImage back = perch2::io::load_color_image(path);
    REQUIRE(back.width == 32);
    REQUIRE(back.height == 24);
    // Quality 95 on a smooth gradient: chroma subsampling and quantisation move values by a few levels; a
    // channel swap or a flip would move them by ~100.
    double sum = 0;
    int worst = 0;
    for (std::size_t i = 0; i < img.data.size(); ++i) {
      const int d[3] = {std::abs(back.data[i].r - img.data[i].r), std::abs(back.data[i].g - img.data[i].g),
                        std::abs(back.data[i].b - img.data[i].b)};
      for (int k = 0; k < 3; ++k) sum += d[k], worst = std::max(worst, d[k]);
    }
    CHECK(sum / (3.0 * double(img.data.size())) < 3.0);
    CHECK(worst <= 16);
  }
}

TEST_CASE("label PNG round trip, 8- and 16-bit") {
  perch2::LabelImage labels(6, 4, 0);
  for (int u = 0; u < 6; ++u) labels(u, 1) = 50 * u;  // up to 250: written 8-bit
  labels(5, 3) = 255;
  const std::string p8 = temp_path("labels8.png");
  perch2::io::save_label_png(p8, labels);
  const perch2::LabelImage back8 = perch2::io::load_label_png(p8);
  REQUIRE(back8.width == 6);
  REQUIRE(back8.height == 4);
  CHECK(back8.data == labels.data);
  // A grey PNG read as colour is replicated to RGB.
  CHECK(same(perch2::io::load_color_image(p8)(1, 1), Rgb8{50, 50, 50}));
  // Written as 8-bit, so it is not a depth image.
  CHECK_THROWS_WITH_AS(perch2::io::load_depth_png(p8), doctest::Contains("8-bit 1-channel"),
                       perch2::FileError);

  labels(0, 0) = 65535;
  labels(1, 0) = 256;
  const std::string p16 = temp_path("labels16.png");
  perch2::io::save_label_png(p16, labels);
  CHECK(perch2::io::load_label_png(p16).data == labels.data);
  // 16-bit labels are also a valid depth image: value 256 -> 0.256 m.
  CHECK(perch2::io::load_depth_png(p16)(1, 0) == doctest::Approx(0.256).epsilon(1e-6));
}

TEST_CASE("real YCB banana: OBJ + MTL + 4096x4096 texture, metres") {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/ycb_011_banana/textured_simple.obj");
  const Mesh m = perch2::io::load_mesh(path);
  CHECK(m.name == "textured_simple");
  CHECK(m.triangles.size() == 15728);
  REQUIRE(m.has_texture());
  CHECK(m.texture.width == 4096);
  CHECK(m.texture.height == 4096);
  REQUIRE(m.corner_uvs.size() == 3 * m.triangles.size());
  for (const auto& uv : m.corner_uvs) {
    CHECK(uv.x() >= 0.f);
    CHECK(uv.x() <= 1.f);
    CHECK(uv.y() >= 0.f);
    CHECK(uv.y() <= 1.f);
  }
  CHECK(!m.has_vertex_colors());
  // Kd 0.639216 -> 163.
  CHECK(same(m.base_color, Rgb8{163, 163, 163}));
  // A banana about 0.2 m long (measured 0.196 m): metres, not millimetres.
  const Eigen::Vector3f extent = m.bounds().sizes();
  CHECK(extent.maxCoeff() > 0.15f);
  CHECK(extent.maxCoeff() < 0.25f);

  // Texture lookup: the triangles' centre UVs, with v = 0 at the image bottom, land on yellow texels. 75% of
  // the atlas is black background; without the flip most samples land there, and with R and B swapped none is
  // yellow.
  auto yellow_fraction = [&](bool flip_v) {
    std::size_t yellow = 0;
    for (std::size_t t = 0; t < m.triangles.size(); ++t) {
      const Eigen::Vector2f uv =
          (m.corner_uvs[3 * t] + m.corner_uvs[3 * t + 1] + m.corner_uvs[3 * t + 2]) / 3.f;
      const int u = std::clamp(int(uv.x() * float(m.texture.width)), 0, m.texture.width - 1);
      const float v_from_top = flip_v ? 1.f - uv.y() : uv.y();
      const int v = std::clamp(int(v_from_top * float(m.texture.height)), 0, m.texture.height - 1);
      const Rgb8 c = m.texture(u, v);
      if (c.r > c.b + 40 && c.g > c.b + 40) ++yellow;
    }
    return double(yellow) / double(m.triangles.size());
  };
  const double correct = yellow_fraction(true), unflipped = yellow_fraction(false);
  CHECK(correct > 0.99);   // measured 0.999
  CHECK(unflipped < 0.5);  // measured 0.32
}

TEST_CASE("real LINEMOD cat: ascii PLY in millimetres with RGBA vertex colours") {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/linemod_obj_06/obj_06.ply");
  const Mesh m = perch2::io::load_mesh(path, {0.001f});
  CHECK(m.name == "obj_06");
  REQUIRE(m.vertices.size() == 15736);
  CHECK(m.triangles.size() == 31468);
  REQUIRE(m.vertex_colors.size() == 15736);
  CHECK(!m.has_texture());
  // First data line: "-10.8309 -53.9783 -19.356 <normal> 185 114 125 255" (mm); float rounding of value *
  // 0.001.
  CHECK(m.vertices[0].x() == doctest::Approx(-0.0108309).epsilon(1e-6));
  CHECK(m.vertices[0].y() == doctest::Approx(-0.0539783).epsilon(1e-6));
  CHECK(m.vertices[0].z() == doctest::Approx(-0.019356).epsilon(1e-6));
  CHECK(same(m.vertex_colors[0], Rgb8{185, 114, 125}));
  // A cat figurine 0.1-0.2 m tall (measured 0.128 m) once the millimetres are scaled.
  const Eigen::Vector3f extent = m.bounds().sizes();
  CHECK(extent.maxCoeff() > 0.1f);
  CHECK(extent.maxCoeff() < 0.2f);

  // The scale option multiplies every coordinate (float rounding: 1e-6 relative).
  const Mesh mm = perch2::io::load_ply(path);
  for (std::size_t i = 0; i < m.vertices.size(); i += 997)
    CHECK((0.001f * mm.vertices[i] - m.vertices[i]).norm() <= 1e-6f * mm.vertices[i].norm() * 0.001f + 1e-9f);

  // Writing the real model and reading it back (binary and ascii) is exact.
  for (const bool binary : {true, false}) {
    const std::string copy = temp_path(std::string("obj_06_copy_") + (binary ? "bin" : "ascii") + ".ply");
    perch2::io::save_ply(copy, m, binary);
    Mesh back = perch2::io::load_ply(copy);
    back.name = m.name;
    check_same_mesh(m, back);
  }
}
