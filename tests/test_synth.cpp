// perch2::synth: built-in models (closed, outward, symmetric as declared, PLY round trip), scene composition
// (resting on the table, no interpenetration), sensor statistics, detections' RLE, and a whole generated
// BOP dataset read back file by file.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "perch2/dataset/bop.hpp"
#include "perch2/io/io.hpp"
#include "perch2/synth/synth.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using namespace perch2;
using namespace perch2::synth;
using Eigen::Vector3f;
using json = nlohmann::json;
using perch2::test::temp_path;

namespace {

std::array<long long, 3> weld_key(const Vector3f& v) {
  return {std::llround(v.x() * 1e6), std::llround(v.y() * 1e6), std::llround(v.z() * 1e6)};
}

/// Closed and consistently wound: after welding vertices by position, every directed edge appears exactly
/// once and its reverse exactly once. Returns the number of offending edges.
int open_or_inconsistent_edges(const Mesh& m) {
  std::map<std::array<long long, 3>, int> ids;
  std::vector<int> id(m.vertices.size());
  for (std::size_t i = 0; i < m.vertices.size(); ++i)
    id[i] = ids.emplace(weld_key(m.vertices[i]), int(ids.size())).first->second;
  std::map<std::pair<int, int>, int> directed;
  for (const auto& t : m.triangles)
    for (int c = 0; c < 3; ++c) ++directed[{id[t[c]], id[t[(c + 1) % 3]]}];
  int bad = 0;
  for (const auto& [e, n] : directed) {
    const auto rev = directed.find({e.second, e.first});
    bad += n != 1 || rev == directed.end() || rev->second != 1;
  }
  return bad;
}

double signed_volume(const Mesh& m) {
  double v = 0;
  for (const auto& t : m.triangles) v += m.vertices[t[0]].dot(m.vertices[t[1]].cross(m.vertices[t[2]])) / 6.0;
  return v;
}

/// Distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5).
float point_triangle_distance(const Vector3f& p, const Vector3f& a, const Vector3f& b, const Vector3f& c) {
  const Vector3f ab = b - a, ac = c - a, ap = p - a;
  const float d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return (p - a).norm();
  const Vector3f bp = p - b;
  const float d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return (p - b).norm();
  const float vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return (p - (a + ab * (d1 / (d1 - d3)))).norm();
  const Vector3f cp = p - c;
  const float d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return (p - c).norm();
  const float vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return (p - (a + ac * (d2 / (d2 - d6)))).norm();
  const float va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return (p - (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))))).norm();
  const float denom = 1.f / (va + vb + vc);
  return (p - (a + ab * (vb * denom) + ac * (vc * denom))).norm();
}

/// Largest distance from the model's vertices, moved by T, to the model's surface.
float symmetry_error(const Mesh& m, const Pose& T) {
  float worst = 0;
  for (std::size_t i = 0; i < m.vertices.size(); i += 3) {
    const Vector3f p = T * m.vertices[i];
    float best = 1e30f;
    for (const auto& t : m.triangles)
      best = std::min(best, point_triangle_distance(p, m.vertices[t[0]], m.vertices[t[1]], m.vertices[t[2]]));
    worst = std::max(worst, best);
  }
  return worst;
}

/// Ray-parity inside test against a closed mesh (world coordinates), ray direction off the axes.
bool inside(const Vector3f& p, const std::vector<Vector3f>& v, const std::vector<Eigen::Vector3i>& tris) {
  const Vector3f d = Vector3f(0.0123f, 0.0371f, 1.f).normalized();
  int crossings = 0;
  for (const auto& t : tris) {  // Moller-Trumbore
    const Vector3f e1 = v[t[1]] - v[t[0]], e2 = v[t[2]] - v[t[0]], h = d.cross(e2);
    const float a = e1.dot(h);
    if (std::abs(a) < 1e-12f) continue;
    const Vector3f s = p - v[t[0]];
    const float u = s.dot(h) / a;
    if (u < 0 || u > 1) continue;
    const Vector3f q = s.cross(e1);
    const float w = d.dot(q) / a;
    if (w < 0 || u + w > 1) continue;
    crossings += e2.dot(q) / a > 0;
  }
  return crossings % 2 == 1;
}

/// pycocotools-style decoder of compressed RLE strings (the inverse of rleToString), for checking ours.
std::vector<std::uint32_t> decode_rle_string(const std::string& s) {
  std::vector<std::uint32_t> counts;
  std::size_t p = 0;
  while (p < s.size()) {
    long long x = 0;
    int k = 0;
    bool more = true;
    while (more) {
      const long long c = s[p] - 48;
      x |= (c & 0x1f) << (5 * k);
      more = c & 0x20;
      ++p, ++k;
      if (!more && (c & 0x10)) x = (long long)((unsigned long long)x | (~0ULL << (5 * k)));  // sign-extend
    }
    if (counts.size() > 2) x += counts[counts.size() - 2];
    counts.push_back(std::uint32_t(x));
  }
  return counts;
}

MaskImage mask_from_counts(const std::vector<std::uint32_t>& counts, int w, int h) {
  MaskImage m(w, h, 0);
  std::size_t i = 0;
  for (std::size_t r = 0; r < counts.size(); ++r)
    for (std::uint32_t k = 0; k < counts[r]; ++k, ++i)
      if (r % 2) m(int(i / h), int(i % h)) = 255;
  return m;
}

json read_json(const fs::path& p) {
  std::ifstream f(p);
  REQUIRE_MESSAGE(f.good(), p.string());
  return json::parse(f);
}

Pose pose_from_bop(const json& R, const json& t) {
  Pose T = Pose::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) T.linear()(r, c) = R[3 * r + c].get<float>();
    T.translation()(r) = t[r].get<float>() * 0.001f;
  }
  return T;
}

const ObjectModel& by_id(const std::vector<ObjectModel>& models, int id) {
  for (const auto& m : models)
    if (m.obj_id == id) return m;
  FAIL("no model " << id);
  return models.front();
}

/// A small, quick camera for dataset tests.
DatasetSettings small_dataset(Mode mode, std::uint64_t seed) {
  DatasetSettings s;
  s.scene.mode = mode;
  s.num_scenes = 1, s.images_per_scene = 2, s.seed = seed;
  s.sensor.camera = {307.5f, 307.5f, 159.5f, 119.5f, 320, 240};
  return s;
}

}  // namespace

TEST_CASE("built-in models: ids, closed outward surfaces, look-alike shapes with different labels") {
  const auto models = builtin_models();
  REQUIRE(models.size() == 8);
  for (std::size_t i = 0; i < models.size(); ++i) {
    const ObjectModel& m = models[i];
    INFO(m.name);
    CHECK(m.obj_id == int(i) + 1);
    CHECK_NOTHROW(m.mesh.validate());
    CHECK(open_or_inconsistent_edges(m.mesh) == 0);
    CHECK(signed_volume(m.mesh) > 0);  // outward winding
    // BOP model frame: origin at the bounding-box centre.
    CHECK(m.mesh.bounds().center().norm() < 1e-6f);
    CHECK((m.mesh.has_texture() || m.mesh.has_vertex_colors()));
  }
  // Cans 1-3 and bottles 4-5 share their geometry but not their labels.
  for (const auto& [a, b] : std::vector<std::pair<int, int>>{{0, 1}, {0, 2}, {3, 4}}) {
    REQUIRE(models[a].mesh.vertices.size() == models[b].mesh.vertices.size());
    float d = 0;
    for (std::size_t i = 0; i < models[a].mesh.vertices.size(); ++i)
      d = std::max(d, (models[a].mesh.vertices[i] - models[b].mesh.vertices[i]).norm());
    CHECK(d == 0.f);
    CHECK(models[a].mesh.texture.data.size() == models[b].mesh.texture.data.size());
    std::size_t differing = 0;
    for (std::size_t p = 0; p < models[a].mesh.texture.data.size(); ++p)
      differing += pack_rgb(models[a].mesh.texture.data[p]) != pack_rgb(models[b].mesh.texture.data[p]);
    CHECK(differing > models[a].mesh.texture.data.size() / 4);
  }
  // A flipped mesh is caught by the winding checks (they can fail).
  Mesh flipped = models[7].mesh;
  std::swap(flipped.triangles[0][1], flipped.triangles[0][2]);
  CHECK(open_or_inconsistent_edges(flipped) > 0);
}

TEST_CASE("built-in models: every declared symmetry maps the mesh onto itself, undeclared ones do not") {
  const auto models = builtin_models();
  const ObjectModel& bowl = by_id(models, 7);
  const ObjectModel& block = by_id(models, 8);
  REQUIRE(bowl.symmetries.continuous.size() == 1);
  REQUIRE(block.symmetries.discrete.size() == 3);
  for (const auto& m : models)
    if (m.obj_id != 7 && m.obj_id != 8) CHECK(m.symmetries.empty());
  for (const Pose& T : block.symmetries.discrete) CHECK(symmetry_error(block.mesh, T) < 1e-6f);
  // Continuous: any angle; the tessellation (72 segments, radius <= 76 mm) bounds the error by the sagitta
  // r (1 - cos(pi / 72)) = 0.07 mm.
  const auto& axis = bowl.symmetries.continuous[0];
  for (float angle : {0.3f, 1.1f, 2.9f}) {
    Pose T = Pose::Identity();
    T.linear() = Eigen::AngleAxisf(angle, axis.axis).toRotationMatrix();
    T.translation() = axis.offset_m - T.linear() * axis.offset_m;
    CHECK(symmetry_error(bowl.mesh, T) < 1e-4f);
  }
  Pose quarter = Pose::Identity();
  quarter.linear() = Eigen::AngleAxisf(float(M_PI / 2), Vector3f::UnitZ()).toRotationMatrix();
  CHECK(symmetry_error(block.mesh, quarter) > 0.01f);  // 90 mm x 50 mm block: not a symmetry
  Pose tilt = Pose::Identity();
  tilt.linear() = Eigen::AngleAxisf(float(M_PI / 2), Vector3f::UnitX()).toRotationMatrix();
  CHECK(symmetry_error(bowl.mesh, tilt) > 0.01f);
}

TEST_CASE("BOP models folder: PLY in millimetres with textures round-trips through io::load_mesh") {
  const auto models = builtin_models();
  const std::string dir = temp_path("synth_models");
  fs::remove_all(dir);
  write_bop_models(dir, models);
  const json info = read_json(fs::path(dir) / "models_info.json");
  for (const auto& m : models) {
    INFO(m.name);
    char name[32];
    std::snprintf(name, sizeof name, "obj_%06d.ply", m.obj_id);
    io::MeshLoadOptions mm;
    mm.scale = 0.001f;
    const Mesh back = io::load_mesh((fs::path(dir) / name).string(), mm);
    REQUIRE(back.vertices.size() == m.mesh.vertices.size());
    REQUIRE(back.triangles.size() == m.mesh.triangles.size());
    float err = 0;
    for (std::size_t i = 0; i < back.vertices.size(); ++i)
      err = std::max(err, (back.vertices[i] - m.mesh.vertices[i]).norm());
    CHECK(err < 1e-7f);
    CHECK(back.has_texture() == m.mesh.has_texture());
    CHECK(back.has_vertex_colors() == m.mesh.has_vertex_colors());
    if (m.mesh.has_texture()) {
      CHECK(back.texture.data.size() == m.mesh.texture.data.size());
      CHECK(std::equal(back.corner_uvs.begin(), back.corner_uvs.end(), m.mesh.corner_uvs.begin()));
    }
    const json& j = info.at(std::to_string(m.obj_id));
    CHECK(j.at("diameter").get<double>() == doctest::Approx(1000.0 * model_diameter(m.mesh)).epsilon(1e-6));
    const Vector3f size = m.mesh.bounds().sizes() * 1000.f;
    CHECK(j.at("size_z").get<double>() == doctest::Approx(size.z()).epsilon(1e-5));
    CHECK(j.at("min_x").get<double>() == doctest::Approx(-size.x() / 2).epsilon(1e-4));
    CHECK(j.contains("symmetries_discrete") == !m.symmetries.discrete.empty());
    CHECK(j.contains("symmetries_continuous") == !m.symmetries.continuous.empty());
  }
  // The block's 180-degree turns as flattened 4x4 matrices (mm translation, here zero).
  const json& sym = info.at("8").at("symmetries_discrete");
  REQUIRE(sym.size() == 3);
  for (const auto& T : sym) {
    REQUIRE(T.size() == 16);
    CHECK(T[15].get<double>() == 1.0);
    CHECK(T[3].get<double>() == 0.0);
    double trace = T[0].get<double>() + T[5].get<double>() + T[10].get<double>();
    CHECK(trace == doctest::Approx(-1.0));  // a half turn
  }
  CHECK(info.at("7").at("symmetries_continuous")[0].at("axis") == json({0.0, 0.0, 1.0}));
  // The diameter of the 90 x 50 x 35 mm block is its space diagonal.
  CHECK(info.at("8").at("diameter").get<double>() ==
        doctest::Approx(std::sqrt(90.0 * 90 + 50 * 50 + 35 * 35)).epsilon(1e-5));

  // The same folder as user models: millimetres guessed, names from files, no symmetries.
  const auto user = load_user_models(dir);
  REQUIRE(user.size() == models.size());
  CHECK(user[0].name == "obj_000001");
  CHECK(user[6].symmetries.empty());
  CHECK((user[5].mesh.vertices[3] - models[5].mesh.vertices[3]).norm() < 1e-6f);
}

/// Surface points (1 cm apart) of one placed mesh that lie more than 2.5 mm inside another (the 6-DoF
/// height map has 2 mm cells). Checks only pairs whose world bounding boxes meet.
int deep_points(const Scene& scene, const std::vector<ObjectModel>& models) {
  struct Placed {
    const Mesh* mesh;
    Pose T;
    std::vector<Vector3f> verts;
    Eigen::AlignedBox3f box;
  };
  std::vector<Placed> all;
  auto add = [&](const Mesh& m, const Pose& T) {
    Placed p{&m, T, {}, {}};
    for (const auto& v : m.vertices) p.verts.push_back(T * v), p.box.extend(p.verts.back());
    all.push_back(std::move(p));
  };
  for (const auto& o : scene.objects) add(models[o.model].mesh, o.T_world_obj);
  for (const auto& d : scene.distractors) add(d.mesh, d.T_world_obj);
  int deep = 0;
  for (const auto& a : all)
    for (const auto& b : all) {
      if (&a == &b || !a.box.intersects(b.box)) continue;
      for (const auto& p0 : sample_surface(*a.mesh, 0.01f)) {
        const Vector3f p = a.T * p0;
        if (!b.box.contains(p) || !inside(p, b.verts, b.mesh->triangles)) continue;
        float depth = 1e9f;
        for (const auto& t : b.mesh->triangles)
          depth = std::min(depth, point_triangle_distance(p, b.verts[t[0]], b.verts[t[1]], b.verts[t[2]]));
        deep += depth > 0.0025f;
      }
    }
  return deep;
}

TEST_CASE("scene composition: 3-DoF upright on z = 0, 6-DoF resting, no interpenetration") {
  const auto models = builtin_models();
  for (Mode mode : {Mode::ThreeDof, Mode::SixDof})
    for (std::uint64_t seed : {1u, 2u, 3u}) {
      SceneSettings s;
      s.mode = mode;
      Rng rng(seed);
      Scene scene = compose_scene(models, s, rng);
      INFO("mode " << int(mode) << " seed " << seed);
      CHECK(scene.objects.size() >= 3);
      std::vector<std::pair<const Mesh*, Pose>> placed;
      for (const auto& o : scene.objects) placed.emplace_back(&models[o.model].mesh, o.T_world_obj);
      for (const auto& d : scene.distractors) placed.emplace_back(&d.mesh, d.T_world_obj);
      for (const auto& [mesh, T] : placed) {
        float zmin = 1e9f;
        for (const auto& v : mesh->vertices) zmin = std::min(zmin, (T * v).z());
        CHECK(zmin >= -1e-5f);  // never below the table top
        if (mode == Mode::ThreeDof) {
          CHECK(std::abs(zmin) < 1e-5f);                                               // standing on it
          CHECK((T.linear() * Vector3f::UnitZ() - Vector3f::UnitZ()).norm() < 1e-5f);  // upright
        }
      }
      CHECK(deep_points(scene, models) == 0);
      if (seed == 1) {  // the check sees an overlap: move object 1 onto object 0
        scene.objects[1].T_world_obj.translation() = scene.objects[0].T_world_obj.translation();
        CHECK(deep_points(scene, models) > 0);
      }
    }
}

TEST_CASE("COCO RLE: hand-encoded masks and round trips") {
  MaskImage a(2, 2, 0);  // column-major: (0,0) (0,1) (1,0) (1,1) = 0 0 1 0
  a(1, 0) = 255;
  CHECK(coco_rle_counts(a) == std::vector<std::uint32_t>{2, 1, 1});
  CHECK(coco_rle_string(a) == "211");
  MaskImage b(2, 7, 0);  // runs 5 0s, 3 1s, 4 0s, 2 1s; the 4th is stored as 2 - 3 = -1 -> 'O'
  b(0, 5) = b(0, 6) = b(1, 0) = b(1, 5) = b(1, 6) = 255;
  CHECK(coco_rle_counts(b) == std::vector<std::uint32_t>{5, 3, 4, 2});
  CHECK(coco_rle_string(b) == "534O");
  MaskImage empty(3, 2, 0);
  CHECK(coco_rle_counts(empty) == std::vector<std::uint32_t>{6});
  Rng rng(9);
  MaskImage r(37, 23, 0);
  for (auto& p : r.data) p = rng.chance(0.3f) ? 255 : 0;
  for (int k = 0; k < 50; ++k) r(rng.integer(0, 36), rng.integer(0, 22)) = 255;
  const auto counts = coco_rle_counts(r);
  CHECK(decode_rle_string(coco_rle_string(r)) == counts);
  CHECK(mask_from_counts(counts, 37, 23).data == r.data);
  CHECK(mask_bbox(a) == std::array<int, 4>{1, 0, 0, 0});
  CHECK(mask_bbox(empty) == std::array<int, 4>{-1, -1, -1, -1});
}

TEST_CASE("sensor: depth noise follows sigma(z) = 1.2 mm + 1.9 mm (z - 0.4)^2, quantised to 1 mm") {
  const auto models = builtin_models();
  SceneSettings ss;
  ss.min_objects = ss.max_objects = 1, ss.min_distractors = ss.max_distractors = 0;
  Rng rng(4);
  const Scene scene = compose_scene(models, ss, rng);
  const SceneRenderer renderer(models, scene);
  SensorSettings s;
  s.camera = {307.5f, 307.5f, 159.5f, 119.5f, 320, 240};
  for (float range : {0.7f, 1.2f}) {
    // Straight down onto the table top from a known height.
    const Frame f = renderer.render(look_at({0.3f, 0.2f, range}, {0.3f, 0.2f, 0.f}), s, rng);
    double sum = 0, sum2 = 0;
    int n = 0, off_grid = 0;
    for (std::size_t p = 0; p < f.depth_m.data.size(); ++p) {
      const float t = f.true_depth_m.data[p], d = f.depth_m.data[p];
      if (d <= 0 || std::abs(t - range) > 0.005f) continue;
      const double mm = d * 1000.0;
      off_grid += std::abs(mm - std::round(mm)) > 1e-3;
      sum += d - t, sum2 += double(d - t) * (d - t), ++n;
    }
    REQUIRE(n > 20000);
    CHECK(off_grid == 0);
    const double mean = sum / n, sd = std::sqrt(sum2 / n - mean * mean);
    const double sigma = 0.0012 + 0.0019 * (range - 0.4) * (range - 0.4);
    const double expected = std::sqrt(sigma * sigma + 1e-6 / 12);  // plus 1 mm quantisation
    INFO("range " << range << " sd " << sd << " expected " << expected);
    CHECK(std::abs(mean) < 0.0003);
    CHECK(sd == doctest::Approx(expected).epsilon(0.08));
  }
  // Missing readings concentrate at depth edges: a view with objects.
  const Frame f = renderer.render(look_at({0.5f, -0.5f, 0.6f}, {0.f, 0.f, 0.05f}), s, rng);
  const int W = f.camera.width, H = f.camera.height;
  long edge_n = 0, edge_missing = 0, flat_n = 0, flat_missing = 0;
  for (int v = 1; v + 1 < H; ++v)
    for (int u = 1; u + 1 < W; ++u) {
      const float z = f.true_depth_m(u, v);
      if (z <= 0) continue;
      bool edge = false;
      for (int d = -1; d <= 1; d += 2)
        edge = edge || std::abs(f.true_depth_m(u + d, v) - z) > 0.03f ||
               std::abs(f.true_depth_m(u, v + d) - z) > 0.03f;
      const bool missing = f.depth_m(u, v) == 0;
      (edge ? edge_n : flat_n)++;
      (edge ? edge_missing : flat_missing) += missing;
    }
  REQUIRE(edge_n > 100);
  const double edge_rate = double(edge_missing) / edge_n, flat_rate = double(flat_missing) / flat_n;
  INFO("missing at edges " << edge_rate << ", elsewhere " << flat_rate);
  CHECK(edge_rate > 0.4);
  CHECK(edge_rate > 5 * flat_rate);
}

/// Writes a small dataset and reads every file back, checking it against the models and itself.
static void check_generated_dataset(Mode mode) {
  const auto models = builtin_models();
  const DatasetSettings s = small_dataset(mode, 11);
  const fs::path root = temp_path(mode == Mode::ThreeDof ? "synth_bop3" : "synth_bop6");
  fs::remove_all(root);
  int calls = 0;
  const DatasetSummary summary = generate_dataset(models, s, root.string(), [&](int, int) { ++calls; });
  CHECK(calls == 2);
  CHECK(summary.images == 2);
  const json camera = read_json(root / "camera.json");
  CHECK(camera.at("width") == 320);
  CHECK(camera.at("depth_scale") == 1.0);
  const fs::path scene = root / "test" / "000001";
  const json scam = read_json(scene / "scene_camera.json"), sgt = read_json(scene / "scene_gt.json");
  const json sinfo = read_json(scene / "scene_gt_info.json"),
             targets = read_json(root / "test_targets_bop19.json");
  REQUIRE(sgt.size() == 2);
  std::map<std::pair<int, int>, int> expected_targets;  // (im_id, obj_id) -> instances >= 10 % visible
  for (int im = 0; im < 2; ++im) {
    const std::string key = std::to_string(im);
    const json& cam = scam.at(key);
    const auto& Kj = cam.at("cam_K");
    const Intrinsics K{
        Kj[0].get<float>(), Kj[4].get<float>(), Kj[2].get<float>(), Kj[5].get<float>(), 320, 240};
    CHECK(Kj[1] == 0.0);
    CHECK(Kj[8] == 1.0);
    const Pose T_cam_world = pose_from_bop(cam.at("cam_R_w2c"), cam.at("cam_t_w2c"));
    char name[32];
    std::snprintf(name, sizeof name, "%06d.png", im);
    const DepthImage depth =
        io::load_depth_png((scene / "depth" / name).string(), 0.001f * cam.at("depth_scale").get<float>());
    CHECK(io::load_color_image((scene / "rgb" / name).string()).width == 320);
    const json& gts = sgt.at(key);
    const json& infos = sinfo.at(key);
    REQUIRE(gts.size() == infos.size());
    for (std::size_t k = 0; k < gts.size(); ++k) {
      INFO("image " << im << " gt " << k);
      const int obj_id = gts[k].at("obj_id");
      const Mesh& mesh = by_id(models, obj_id).mesh;
      const Pose T_cam_obj = pose_from_bop(gts[k].at("cam_R_m2c"), gts[k].at("cam_t_m2c"));
      CHECK(is_valid_pose(T_cam_obj, 1e-5f));
      // World frame: z up, every 3-DoF object upright with its lowest point on the table top (z = 0).
      const Pose T_world_obj = T_cam_world.inverse() * T_cam_obj;
      float zmin = 1e9f;
      for (const auto& v : mesh.vertices) zmin = std::min(zmin, (T_world_obj * v).z());
      CHECK(zmin > -1e-4f);  // never below the table top
      if (mode == Mode::ThreeDof) {
        CHECK((T_world_obj.linear().col(2) - Vector3f::UnitZ()).norm() < 1e-4f);
        CHECK(std::abs(zmin) < 1e-4f);
      }
      // Masks: visible part inside the silhouette; the GT pose projects every vertex onto the silhouette.
      char mname[32];
      std::snprintf(mname, sizeof mname, "%06d_%06zu.png", im, k);
      const LabelImage mask = io::load_label_png((scene / "mask" / mname).string());
      const LabelImage visib = io::load_label_png((scene / "mask_visib" / mname).string());
      int in_image = 0, on_mask = 0, px_all = 0, px_visib = 0, px_valid = 0, visib_outside = 0;
      for (const auto& v : mesh.vertices) {
        const Vector3f p = T_cam_obj * v;
        const int u = int(std::lround(K.fx * p.x() / p.z() + K.cx)),
                  w = int(std::lround(K.fy * p.y() / p.z() + K.cy));
        if (u < 1 || w < 1 || u >= 319 || w >= 239) continue;
        ++in_image;
        bool hit = false;
        for (int dv = -1; dv <= 1; ++dv)
          for (int du = -1; du <= 1; ++du) hit = hit || mask(u + du, w + dv) != 0;
        on_mask += hit;
      }
      CHECK(on_mask == in_image);
      for (std::size_t p = 0; p < mask.data.size(); ++p) {
        px_all += mask.data[p] != 0, px_visib += visib.data[p] != 0;
        px_valid += mask.data[p] != 0 && depth.data[p] > 0;
        visib_outside += visib.data[p] != 0 && mask.data[p] == 0;
      }
      CHECK(visib_outside == 0);
      const json& info = infos[k];
      const double fraction = info.at("visib_fract");
      CHECK(fraction >= 0.0);
      CHECK(fraction <= 1.0);
      CHECK(info.at("px_count_visib") == px_visib);
      CHECK(info.at("px_count_valid") == px_valid);
      CHECK(info.at("px_count_all").get<int>() >= px_all);  // plus any part outside the image
      if (info.at("px_count_all").get<int>() > 0)
        CHECK(fraction == doctest::Approx(double(px_visib) / info.at("px_count_all").get<int>()));
      if (px_visib > 0) {
        MaskImage m(320, 240, 0);
        for (std::size_t p = 0; p < m.data.size(); ++p) m.data[p] = visib.data[p] ? 255 : 0;
        CHECK(info.at("bbox_visib") == json(mask_bbox(m)));
      } else {
        CHECK(info.at("bbox_visib") == json({-1, -1, -1, -1}));
      }
      if (fraction >= 0.1) ++expected_targets[{im, obj_id}];
    }
  }
  std::map<std::pair<int, int>, int> listed;
  for (const auto& t : targets) {
    CHECK(t.at("scene_id") == 1);
    listed[{t.at("im_id").get<int>(), t.at("obj_id").get<int>()}] = t.at("inst_count");
  }
  CHECK(listed == expected_targets);

  // Detections: decodable masks of the image size, boxes inside, most overlapping their object well.
  const json dets = read_json(root / "detections_synth.json");
  REQUIRE(!dets.empty());
  int good = 0, total = 0;
  for (const auto& d : dets) {
    for (const char* field : {"scene_id", "image_id", "category_id", "score", "bbox", "segmentation", "time"})
      CHECK(d.contains(field));
    CHECK(d.at("segmentation").at("size") == json({240, 320}));
    const auto counts = decode_rle_string(d.at("segmentation").at("counts").get<std::string>());
    std::uint64_t sum = 0;
    for (auto c : counts) sum += c;
    CHECK(sum == 320u * 240u);
    const auto& b = d.at("bbox");
    CHECK(b[0].get<int>() >= 0);
    CHECK(b[0].get<int>() + b[2].get<int>() < 320);
    CHECK(b[1].get<int>() + b[3].get<int>() < 240);
    const float score = d.at("score");
    CHECK(score > 0.f);
    CHECK(score < 1.f);
    // Best IoU with a ground-truth visible mask of the same image.
    const MaskImage m = mask_from_counts(counts, 320, 240);
    const int im = d.at("image_id");
    double best = 0;
    for (std::size_t k = 0; k < sgt.at(std::to_string(im)).size(); ++k) {
      char mname[32];
      std::snprintf(mname, sizeof mname, "%06d_%06zu.png", im, k);
      const LabelImage visib = io::load_label_png((scene / "mask_visib" / mname).string());
      int inter = 0, uni = 0;
      for (std::size_t p = 0; p < m.data.size(); ++p)
        inter += m.data[p] && visib.data[p], uni += m.data[p] || visib.data[p];
      if (uni) best = std::max(best, double(inter) / uni);
    }
    ++total;
    good += best > 0.5 && best < 0.999;  // degraded, but on the object
  }
  CHECK(good >= total - 1 - summary.spurious);
}

TEST_CASE("generated 3-DoF BOP dataset: every file, consistent content, world frame, targets, detections") {
  check_generated_dataset(Mode::ThreeDof);
}

TEST_CASE("generated 6-DoF BOP dataset: every file, consistent content, targets, detections") {
  check_generated_dataset(Mode::SixDof);
}

TEST_CASE("generated datasets are deterministic for a seed, and 6-DoF mode writes them too") {
  const auto models = builtin_models();
  auto files = [](const fs::path& root) {
    std::map<std::string, std::string> out;
    for (const auto& e : fs::recursive_directory_iterator(root))
      if (e.is_regular_file())
        out[fs::relative(e.path(), root).string()] = perch2::test::read_file(e.path().string());
    return out;
  };
  DatasetSettings s = small_dataset(Mode::SixDof, 21);
  s.images_per_scene = 1;
  const fs::path a = temp_path("synth_det_a"), b = temp_path("synth_det_b"), c = temp_path("synth_det_c");
  for (const auto& p : {a, b, c}) fs::remove_all(p);
  generate_dataset(models, s, a.string());
  generate_dataset(models, s, b.string());
  s.seed = 22;
  generate_dataset(models, s, c.string());
  const auto fa = files(a), fb = files(b), fc = files(c);
  CHECK(fa.size() > 20);
  CHECK(fa == fb);
  CHECK(fa.at("test/000001/rgb/000000.png") != fc.at("test/000001/rgb/000000.png"));
  CHECK(fa.at("models/models_info.json") == fc.at("models/models_info.json"));
  // Scene 1 does not depend on how many scenes follow it.
  s.seed = 21, s.num_scenes = 2;
  const fs::path d = temp_path("synth_det_d");
  fs::remove_all(d);
  generate_dataset(models, s, d.string());
  const auto fd = files(d);
  CHECK(fd.at("test/000001/rgb/000000.png") == fa.at("test/000001/rgb/000000.png"));
  CHECK(fd.at("test/000001/scene_gt.json") == fa.at("test/000001/scene_gt.json"));
  CHECK(fd.count("test/000002/scene_gt.json") == 1);
  // Nor on the scenes before it: scene 2 alone (first_scene) is scene 2 of the two.
  s.first_scene = 2, s.num_scenes = 1;
  const fs::path e = temp_path("synth_det_e");
  fs::remove_all(e);
  generate_dataset(models, s, e.string());
  const auto fe = files(e);
  CHECK(fe.count("test/000001/scene_gt.json") == 0);
  CHECK(fe.at("test/000002/rgb/000000.png") == fd.at("test/000002/rgb/000000.png"));
  CHECK(fe.at("test/000002/scene_gt.json") == fd.at("test/000002/scene_gt.json"));
}

TEST_CASE("user models from a folder tree: units guessed per file, re-centred, no symmetries") {
  PERCH2_REQUIRE_SHARED_DATA(cat, "models/linemod_obj_06/obj_06.ply");
  const std::string dir = fs::path(cat).parent_path().parent_path().string();
  const auto models = load_user_models(dir);
  REQUIRE(models.size() == 3);  // cat (PLY, mm), banana and scissors (OBJ, metres) in their own folders
  CHECK(models[0].name == "linemod_obj_06_obj_06");
  CHECK(models[1].name == "ycb_011_banana_textured_simple");
  for (const auto& m : models) {
    INFO(m.name);
    const float size = m.mesh.bounds().sizes().maxCoeff();
    CHECK(size > 0.05f);
    CHECK(size < 0.3f);  // metres, whatever the file's unit
    CHECK(m.mesh.bounds().center().norm() < 1e-5f);
    CHECK(m.symmetries.empty());
  }
  CHECK(models[1].mesh.has_texture());
  // Scans have more than 4000 vertices, so model_diameter searches extreme vertices only: compare with all
  // pairs.
  for (const auto& m : models) {
    REQUIRE(m.mesh.vertices.size() > 4000);
    float exact = 0;
    for (std::size_t i = 0; i < m.mesh.vertices.size(); ++i)
      for (std::size_t j = i + 1; j < m.mesh.vertices.size(); ++j)
        exact = std::max(exact, (m.mesh.vertices[i] - m.mesh.vertices[j]).squaredNorm());
    CHECK(model_diameter(m.mesh) == doctest::Approx(std::sqrt(exact)).epsilon(1e-4));
  }
}

TEST_CASE("simulated detector: masks within the boundary shift, misses, spurious detections, scores") {
  // A hand-made frame: object 0 fully visible (a 30 x 40 rectangle), object 1 20 % visible, a distractor.
  Frame f;
  f.camera = {100.f, 100.f, 49.5f, 49.5f, 100, 100};
  f.visible = LabelImage(100, 100, 0);
  f.masks.assign(2, MaskImage(100, 100, 0));
  for (int v = 20; v < 60; ++v)
    for (int u = 10; u < 40; ++u) f.visible(u, v) = 1, f.masks[0](u, v) = 255;
  for (int v = 70; v < 80; ++v)
    for (int u = 60; u < 70; ++u) f.visible(u, v) = 2;
  for (int v = 10; v < 20; ++v)
    for (int u = 70; u < 90; ++u) f.visible(u, v) = -1;
  f.px_count_all = {1200, 500};
  const auto models = builtin_models();
  DetectionSettings s;
  const float reach = s.boundary_shift_px + s.boundary_wobble_px + 1.5f;  // pixels a boundary may move
  int found[2] = {0, 0}, spurious = 0, confused = 0, within = 0;
  double score[2] = {0, 0};
  const int runs = 300;
  for (int run = 0; run < runs; ++run) {
    Rng rng(std::uint64_t(run) + 1);
    for (const Detection& d : simulate_detections(f, {1, 4}, models, s, rng)) {
      if (d.gt_index < 0) {
        ++spurious;
        continue;
      }
      ++found[d.gt_index];
      score[d.gt_index] += d.score;
      confused += d.category_id != (d.gt_index == 0 ? 1 : 4);
      if (d.gt_index != 0) continue;
      bool ok = true;  // every mask pixel within `reach` of the rectangle, every deep-inside pixel kept
      for (int v = 0; v < 100; ++v)
        for (int u = 0; u < 100; ++u) {
          const float dx = std::max({10.f - u, u - 39.f, 0.f}), dy = std::max({20.f - v, v - 59.f, 0.f});
          const bool far_out = std::hypot(dx, dy) > reach;
          const bool deep_in = u >= 10 + reach && u <= 39 - reach && v >= 20 + reach && v <= 59 - reach;
          ok = ok && !(d.mask(u, v) && far_out) && !(!d.mask(u, v) && deep_in);
        }
      within += ok;
    }
  }
  const double full_miss = 1.0 - double(found[0]) / runs, partial_miss = 1.0 - double(found[1]) / runs;
  INFO("misses " << full_miss << " / " << partial_miss << ", spurious " << spurious << ", confused "
                 << confused);
  CHECK(full_miss < 0.1);     // 3 % expected
  CHECK(partial_miss > 0.1);  // 3 % + 35 % x 0.8^2 = 25 % expected
  CHECK(partial_miss < 0.45);
  CHECK(within == found[0]);
  CHECK(score[0] / found[0] > score[1] / found[1]);  // less visible, less confident
  CHECK(spurious > runs / 6);                        // 30 % expected
  CHECK(spurious < runs / 2);
  CHECK(confused > 0);  // cans and bottles have look-alikes
  CHECK(confused < runs / 5);
  Rng rng(1);
  CHECK_THROWS_AS(simulate_detections(f, {1}, models, s, rng), InvalidInput);  // one obj_id per object
}

TEST_CASE("degrade_mask: seeded, each error does what it says, bad settings rejected") {
  MaskImage mask(160, 120, 0);  // an 80 x 60 px ellipse
  for (int v = 0; v < mask.height; ++v)
    for (int u = 0; u < mask.width; ++u)
      if (std::pow((u - 80) / 40.0, 2) + std::pow((v - 60) / 30.0, 2) <= 1) mask(u, v) = 255;
  auto area = [](const MaskImage& m) {
    return std::count_if(m.data.begin(), m.data.end(), [](auto x) { return x != 0; });
  };
  auto overlap = [](const MaskImage& a, const MaskImage& b) {
    long n = 0;
    for (std::size_t i = 0; i < a.data.size(); ++i) n += a.data[i] && b.data[i];
    return n;
  };
  const long full = long(area(mask));
  {  // same stream, same mask; the default degradation stays a detector's mask of the object
    Rng a = Rng::stream(1, 2, 3), b = Rng::stream(1, 2, 3);
    CHECK(degrade_mask(mask, MaskDegradation{}, a).data == degrade_mask(mask, MaskDegradation{}, b).data);
    int changed = 0;
    for (std::uint64_t s = 0; s < 20; ++s) {
      Rng r = Rng::stream(7, s);
      const MaskImage d = degrade_mask(mask, MaskDegradation{}, r);
      changed += d.data != mask.data;
      const long both = overlap(d, mask), either = long(area(d)) + full - both;
      CHECK(double(both) / double(either) > 0.5);  // IoU
    }
    CHECK(changed == 20);
  }
  MaskDegradation none;
  none.boundary_shift_px = none.boundary_wobble_px = none.offset_px = 0;
  none.bleed_probability = none.cut_probability = 0;
  Rng r(5);
  CHECK(degrade_mask(mask, none, r).data == mask.data);
  MaskDegradation bleed = none, cut = none;
  bleed.bleed_probability = 1, cut.cut_probability = 1;
  const MaskImage bled = degrade_mask(mask, bleed, r), cut_mask = degrade_mask(mask, cut, r);
  CHECK(overlap(bled, mask) == full);  // only adds
  CHECK(long(area(bled)) > full);
  CHECK(long(area(cut_mask)) == overlap(cut_mask, mask));  // only removes
  CHECK(long(area(cut_mask)) < full);
  MaskDegradation shift = none;
  shift.offset_px = 2;
  for (int k = 0; k < 5; ++k) CHECK(long(area(degrade_mask(mask, shift, r))) <= full);  // moved, not grown
  for (auto bad :
       {+[](MaskDegradation& d) { d.boundary_shift_px = -1; }, +[](MaskDegradation& d) { d.offset_px = NAN; },
        +[](MaskDegradation& d) { d.bleed_probability = 1.5f; },
        +[](MaskDegradation& d) { d.cut_probability = -0.1f; },
        +[](MaskDegradation& d) { d.blob_size = -1; }}) {
    MaskDegradation d;
    bad(d);
    CHECK_THROWS_WITH_AS(degrade_mask(mask, d, r), doctest::Contains("MaskDegradation::"), InvalidInput);
  }
}

TEST_CASE("a tiny camera still gives a complete dataset (no size assumptions in the detector or noise)") {
  DatasetSettings s = small_dataset(Mode::SixDof, 5);
  s.images_per_scene = 1;
  s.sensor.camera = {30.f, 30.f, 19.5f, 14.5f, 40, 30};
  s.detection.spurious_probability = 1.f;
  const fs::path root = temp_path("synth_tiny");
  fs::remove_all(root);
  const DatasetSummary summary = generate_dataset(builtin_models(), s, root.string());
  CHECK(summary.images == 1);
  CHECK(io::load_color_image((root / "test/000001/rgb/000000.png").string()).width == 40);
  CHECK(read_json(root / "detections_synth.json").is_array());
}

TEST_CASE(
    "decoys: another print, a smaller size, other colours; in models/ with bop24 targets, never placed") {
  const auto models = builtin_models();
  const auto decoys = make_decoys(models, 9);
  REQUIRE(decoys.size() == 3 * models.size());
  auto mean_colour = [](const Mesh& m) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    const auto& px = m.has_texture() ? m.texture.data : std::vector<Rgb8>{m.base_color};
    for (const Rgb8& c : px) sum += Eigen::Vector3d(c.r, c.g, c.b);
    return Eigen::Vector3d(sum / double(px.size()));
  };
  for (std::size_t k = 0; k < models.size(); ++k) {
    const ObjectModel &m = models[k], &reprint = decoys[3 * k], &small = decoys[3 * k + 1],
                      &recolour = decoys[3 * k + 2];
    INFO(m.name);
    CHECK(reprint.obj_id == 9 + int(3 * k));
    CHECK(recolour.name == m.name + "_recolour");
    // The same shape with other colours; the small one the same colours at 0.8x (diameter and symmetries).
    CHECK(reprint.mesh.vertices == m.mesh.vertices);
    CHECK(recolour.mesh.vertices == m.mesh.vertices);
    CHECK(model_diameter(small.mesh) == doctest::Approx(0.8 * model_diameter(m.mesh)).epsilon(1e-4));
    CHECK((mean_colour(small.mesh) - mean_colour(m.mesh)).norm() == 0.0);
    CHECK((mean_colour(reprint.mesh) - mean_colour(m.mesh)).norm() > 20);  // grey ones too (block, bowl)
    CHECK((mean_colour(recolour.mesh) - mean_colour(m.mesh)).norm() > 20);
    CHECK((mean_colour(recolour.mesh) - mean_colour(reprint.mesh)).norm() > 10);
    for (const Pose& T : small.symmetries.discrete) CHECK(symmetry_error(small.mesh, T) < 1e-6f);
    if (m.mesh.has_texture()) CHECK(reprint.mesh.corner_uvs[0].x() == 1 - m.mesh.corner_uvs[0].x());
  }
  CHECK_THROWS_AS(make_decoys(models, 0), InvalidInput);

  DatasetSettings s = small_dataset(Mode::SixDof, 5);
  s.images_per_scene = 1, s.decoys = true, s.detection_targets = true;
  const fs::path root = temp_path("synth_decoys");
  fs::remove_all(root);
  generate_dataset(models, s, root.string());
  CHECK(read_json(root / "models/models_info.json").size() == 4 * models.size());
  CHECK(fs::exists(root / "models/obj_000032.ply"));
  CHECK_FALSE(fs::exists(root / "test_targets_bop19.json"));
  const json targets = read_json(root / "test_targets_bop24.json");
  REQUIRE(targets.size() == 1);
  CHECK(targets[0] == json{{"im_id", 0}, {"scene_id", 1}});
  for (const auto& gt : read_json(root / "test/000001/scene_gt.json")["0"])
    CHECK(gt["obj_id"].get<int>() <= 8);  // only the originals are placed
  // The dataset reads as a detection task over the 32-model catalogue.
  const dataset::BopDataset data(root.string());
  CHECK(data.target_task() == dataset::TargetTask::Detection);
  CHECK(data.models_info().size() == 32);
}

TEST_CASE("bad inputs are rejected with the input named") {
  const auto models = builtin_models();
  DatasetSettings s = small_dataset(Mode::ThreeDof, 1);
  const std::string out = temp_path("synth_bad");
  s.num_scenes = 0;
  CHECK_THROWS_WITH_AS(generate_dataset(models, s, out), doctest::Contains("num_scenes"), InvalidInput);
  s.num_scenes = 1;
  s.first_scene = 0;
  CHECK_THROWS_WITH_AS(generate_dataset(models, s, out), doctest::Contains("first_scene"), InvalidInput);
  s.first_scene = 1;
  CHECK_THROWS_AS(generate_dataset({}, s, out), InvalidInput);
  auto twins = models;
  twins[1].obj_id = 1;
  CHECK_THROWS_WITH_AS(generate_dataset(twins, s, out), doctest::Contains("unique"), InvalidInput);
  perch2::test::write_file(temp_path("synth_a_file"), "x");  // a file where the output folder should go
  CHECK_THROWS_WITH_AS(generate_dataset(models, s, temp_path("synth_a_file")),
                       doctest::Contains("synth_a_file"), FileError);
  s.sensor.depth_scale_mm = 0;
  CHECK_THROWS_WITH_AS(generate_dataset(models, s, out), doctest::Contains("depth_scale_mm"), InvalidInput);
  SceneSettings bad;
  bad.min_objects = 5, bad.max_objects = 2;
  Rng rng(1);
  CHECK_THROWS_WITH_AS(compose_scene(models, bad, rng), doctest::Contains("min_objects"), InvalidInput);
  CHECK_THROWS_AS(load_user_models(temp_path("no_such_folder")), FileError);
  fs::create_directories(temp_path("synth_empty_models"));
  CHECK_THROWS_WITH_AS(load_user_models(temp_path("synth_empty_models")), doctest::Contains("no .ply"),
                       FileError);
  CHECK_THROWS_AS(make_lathe({{0.f, 0.f}}, 16), InvalidInput);
  Scene scene;
  scene.objects.push_back({42, Pose::Identity()});
  CHECK_THROWS_WITH_AS(SceneRenderer(models, scene), doctest::Contains("scene object 0"), InvalidInput);
  scene.objects.clear();
  const SceneRenderer renderer(models, scene);
  SensorSettings sensor;
  sensor.grazing_cos_none = 0.f;
  CHECK_THROWS_WITH_AS(renderer.render(Pose::Identity(), sensor, rng), doctest::Contains("grazing_cos_none"),
                       InvalidInput);
  sensor = SensorSettings{};
  Pose nan = Pose::Identity();
  nan.translation().x() = NAN;
  CHECK_THROWS_WITH_AS(renderer.render(nan, sensor, rng), doctest::Contains("T_world_cam"), InvalidInput);
}
