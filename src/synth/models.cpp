#include "perch2/synth/models.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "bop_json.hpp"
#include "box_faces.hpp"
#include "perch2/io/mesh_io.hpp"
#include "perch2/synth/random.hpp"
#include "textures.hpp"

namespace perch2::synth {

namespace {

namespace fs = std::filesystem;
constexpr float kPi = 3.14159265358979f;
using Vec2 = Eigen::Vector2f;
using Vec3 = Eigen::Vector3f;

double signed_volume(const Mesh& m) {
  double v = 0;
  for (const auto& t : m.triangles)
    v += double(m.vertices[t[0]].dot(m.vertices[t[1]].cross(m.vertices[t[2]]))) / 6.0;
  return v;
}

void flip_winding(Mesh& m) {
  for (std::size_t t = 0; t < m.triangles.size(); ++t) {
    std::swap(m.triangles[t][1], m.triangles[t][2]);
    if (!m.corner_uvs.empty()) std::swap(m.corner_uvs[3 * t + 1], m.corner_uvs[3 * t + 2]);
  }
}

/// Arc length of the profile up to each point, as a fraction of the whole.
std::vector<float> arc_fractions(const std::vector<Vec2>& profile) {
  std::vector<float> s(profile.size(), 0.f);
  for (std::size_t i = 1; i < profile.size(); ++i) s[i] = s[i - 1] + (profile[i] - profile[i - 1]).norm();
  for (float& x : s) x /= s.back();
  return s;
}

/// Shared can shape: rolled bottom rim, straight wall, necked top with a recessed lid. Radius 33 mm,
/// height 122 mm. The label spans profile points kCanLabel[0]..kCanLabel[1].
const std::vector<Vec2>& can_profile() {
  static const std::vector<Vec2> p{{0.f, 0.004f},     {0.026f, 0.003f},  {0.030f, 0.f},     {0.033f, 0.007f},
                                   {0.033f, 0.012f},  {0.033f, 0.106f},  {0.033f, 0.109f},  {0.0285f, 0.119f},
                                   {0.0285f, 0.122f}, {0.0265f, 0.122f}, {0.0255f, 0.118f}, {0.f, 0.118f}};
  return p;
}
constexpr int kCanLabel[2] = {4, 5}, kCanLid = 7;

/// Shared bottle shape: radius 32 mm, shoulder, neck and screw cap, height 210 mm.
const std::vector<Vec2>& bottle_profile() {
  static const std::vector<Vec2> p{{0.f, 0.005f},     {0.025f, 0.003f}, {0.029f, 0.f},     {0.032f, 0.005f},
                                   {0.032f, 0.035f},  {0.032f, 0.115f}, {0.032f, 0.13f},   {0.030f, 0.148f},
                                   {0.024f, 0.163f},  {0.017f, 0.174f}, {0.0135f, 0.182f}, {0.0135f, 0.186f},
                                   {0.0155f, 0.187f}, {0.0155f, 0.21f}, {0.f, 0.21f}};
  return p;
}
constexpr int kBottleLabel[2] = {4, 5}, kBottleCap = 12;

ObjectModel lathe_model(int id, const std::string& name, const std::vector<Vec2>& profile, int label0,
                        int label1, int cap, const detail::LabelDesign& design, cv::Scalar body,
                        cv::Scalar cap_colour, Material material, int tex_h) {
  ObjectModel m;
  m.obj_id = id, m.name = name, m.material = material;
  m.mesh = make_lathe(profile, 64);
  const auto s = arc_fractions(profile);
  m.mesh.texture = detail::lathe_texture(512, tex_h, s[label0], s[label1], design, body, cap_colour, s[cap]);
  m.mesh.name = name;
  centre_on_bounding_box(m.mesh);
  return m;
}

/// Words for printed surfaces (deterministic pseudo-text).
std::string pseudo_words(Rng& rng, int n) {
  static const char* words[] = {"whole",   "grain", "crisp", "oats", "honey", "net",  "wt",   "fiber",
                                "serving", "per",   "kcal",  "iron", "sugar", "made", "with", "corn"};
  std::string s;
  for (int k = 0; k < n; ++k) s += std::string(k ? " " : "") + words[rng.integer(0, 15)];
  return s;
}

/// The printed cereal box: a 24-vertex box with an atlas texture (faces side by side at `ppm`).
/// Atlas cells (x, y, w, h) in pixels of a box wx x wy x hz pixels: front, right, back, left, top, bottom.
std::array<cv::Rect, 6> box_atlas_cells(int wx, int wy, int hz) {
  return {cv::Rect{0, 0, wx, hz},   {wx, 0, wy, hz}, {wx + wy, 0, wx, hz},
          {2 * wx + wy, 0, wy, hz}, {0, hz, wx, wy}, {wx, hz, wx, wy}};
}

/// The cereal box print: brand and a bowl on the front, text and a barcode on the back, nutrition tables on
/// the sides, flaps on top and bottom.
cv::Mat cereal_box_print(int wx, int wy, int hz) {
  const auto cells = box_atlas_cells(wx, wy, hz);
  cv::Mat img(hz + wy, 2 * (wx + wy), CV_8UC3, cv::Scalar(245, 180, 30));
  Rng rng(1234);
  // Front: banner, brand, a bowl of cereal.
  const cv::Rect f = cells[0];
  cv::rectangle(img, {f.x, f.y + hz / 12, wx, hz / 5}, {200, 30, 40}, cv::FILLED);
  cv::putText(img, "CRUNCH", {f.x + wx / 12, f.y + hz / 12 + hz / 7}, cv::FONT_HERSHEY_TRIPLEX, wx / 190.0,
              {255, 255, 255}, 3, cv::LINE_AA);
  cv::ellipse(img, {f.x + wx / 2, f.y + int(0.62 * hz)}, {wx / 3, hz / 9}, 0, 0, 180, {240, 240, 250},
              cv::FILLED, cv::LINE_AA);
  for (int k = 0; k < 40; ++k)
    cv::circle(img,
               {f.x + wx / 2 + rng.integer(-wx / 4, wx / 4), f.y + int(0.6 * hz) + rng.integer(-hz / 14, 0)},
               rng.integer(6, 12), {200, 130, 40}, cv::FILLED, cv::LINE_AA);
  cv::putText(img, "NET WT 375g", {f.x + wx / 10, f.y + int(0.92 * hz)}, cv::FONT_HERSHEY_SIMPLEX, 0.9,
              {60, 30, 10}, 2, cv::LINE_AA);
  // Back: paragraphs and a barcode; sides: nutrition table.
  const cv::Rect b = cells[2];
  cv::rectangle(img, b, {250, 235, 190}, cv::FILLED);
  for (int line = 0; line < 14; ++line)
    cv::putText(img, pseudo_words(rng, 4), {b.x + 12, b.y + 40 + line * hz / 17}, cv::FONT_HERSHEY_SIMPLEX,
                0.7, {50, 40, 30}, 1, cv::LINE_AA);
  cv::rectangle(img, {b.x + wx / 2, b.y + int(0.85 * hz), wx / 3, hz / 10}, {255, 255, 255}, cv::FILLED);
  for (int x = b.x + wx / 2 + 6; x < b.x + wx / 2 + wx / 3 - 6; x += rng.integer(3, 6))
    cv::line(img, {x, b.y + int(0.86 * hz)}, {x, b.y + int(0.93 * hz)}, {0, 0, 0}, rng.integer(1, 2));
  for (int side : {1, 3}) {
    const cv::Rect s = cells[side];
    cv::rectangle(img, {s.x + 8, s.y + hz / 6, wy - 16, hz / 2}, {255, 255, 255}, cv::FILLED);
    for (int line = 0; line < 10; ++line)
      cv::line(img, {s.x + 12, s.y + hz / 6 + 20 + line * hz / 22},
               {s.x + wy - 12, s.y + hz / 6 + 20 + line * hz / 22}, {30, 30, 30}, 2);
    cv::putText(img, side == 1 ? "Nutrition" : "Facts", {s.x + 10, s.y + hz / 8}, cv::FONT_HERSHEY_SIMPLEX,
                0.8, {120, 20, 20}, 2, cv::LINE_AA);
  }
  for (int lid : {4, 5}) {
    const cv::Rect s = cells[lid];
    cv::rectangle(img, s, {235, 170, 25}, cv::FILLED);
    cv::line(img, {s.x, s.y + wy / 2}, {s.x + wx, s.y + wy / 2}, {150, 100, 20}, 3);
  }

  return img;
}

ObjectModel printed_box(int id) {
  const Vec3 size(0.14f, 0.06f, 0.20f);
  const float ppm = 2400.f;
  const int wx = int(size.x() * ppm), wy = int(size.y() * ppm), hz = int(size.z() * ppm);
  const int W = 2 * (wx + wy), H = hz + wy;
  const auto cells = box_atlas_cells(wx, wy, hz);
  ObjectModel m;
  m.obj_id = id, m.name = "box_crunch";
  m.material = {0.08f, 12.f};
  Mesh& mesh = m.mesh;
  mesh.name = m.name;
  const Vec3 h = size / 2;
  const auto& c = detail::kBoxFaces;
  for (int face = 0; face < 6; ++face) {
    const int base = int(mesh.vertices.size());
    for (int k = 0; k < 4; ++k)
      mesh.vertices.emplace_back(c[face][k][0] * h.x(), c[face][k][1] * h.y(), c[face][k][2] * h.z());
    const cv::Rect r = cells[face];
    const Vec2 uv[4] = {{float(r.x) / W, 1.f - float(r.y + r.height) / H},
                        {float(r.x + r.width) / W, 1.f - float(r.y + r.height) / H},
                        {float(r.x + r.width) / W, 1.f - float(r.y) / H},
                        {float(r.x) / W, 1.f - float(r.y) / H}};
    mesh.triangles.emplace_back(base, base + 1, base + 2);
    mesh.triangles.emplace_back(base, base + 2, base + 3);
    mesh.corner_uvs.insert(mesh.corner_uvs.end(), {uv[0], uv[1], uv[2], uv[0], uv[2], uv[3]});
  }
  mesh.texture = detail::to_color_image(cereal_box_print(wx, wy, hz));
  return m;
}

/// The bowl: thin-walled, glazed teal outside, cream inside; symmetric about z.
ObjectModel bowl(int id) {
  std::vector<Vec2> p{{0.f, 0.f}, {0.032f, 0.f}, {0.034f, 0.006f}};
  const int n = 10;
  for (int k = 1; k <= n; ++k) {  // outer wall: a quarter ellipse from the foot to the rim
    const float a = 0.5f * kPi * k / n;
    p.emplace_back(0.034f + 0.042f * std::sin(a), 0.006f + 0.052f * (1 - std::cos(a)));
  }
  p.emplace_back(0.0735f, 0.060f);
  for (int k = n; k >= 0; --k) {  // inner wall back down
    const float a = 0.5f * kPi * k / n;
    p.emplace_back(0.004f + 0.066f * std::sin(a), 0.010f + 0.048f * (1 - std::cos(a)));
  }
  p.emplace_back(0.f, 0.010f);
  ObjectModel m;
  m.obj_id = id, m.name = "bowl";
  m.material = {0.35f, 40.f};
  m.mesh = make_lathe(p, 72);
  m.mesh.name = m.name;
  m.mesh.corner_uvs.clear();
  m.mesh.texture = ColorImage();
  // make_lathe emits one ring per profile point (poles: 72 apexes, others 73 with the seam): the rings after
  // the rim are the inside.
  const std::size_t rim = 3 + n;
  for (std::size_t i = 0; i < p.size(); ++i) {
    const std::size_t count = p[i].x() <= 0.f ? 72 : 73;
    m.mesh.vertex_colors.insert(m.mesh.vertex_colors.end(), count,
                                i > rim ? Rgb8{235, 225, 200} : Rgb8{70, 140, 150});
  }
  centre_on_bounding_box(m.mesh);
  m.symmetries.continuous.push_back({Vec3::UnitZ(), Vec3::Zero()});
  return m;
}

/// The untextured block: three distinct edge lengths, so its symmetries are the three 180-degree turns.
ObjectModel block(int id) {
  ObjectModel m;
  m.obj_id = id, m.name = "block";
  m.material = {0.03f, 8.f};
  m.mesh = make_box({0.09f, 0.05f, 0.035f});
  m.mesh.name = m.name;
  m.mesh.vertex_colors.assign(m.mesh.vertices.size(), Rgb8{196, 150, 92});
  for (const Vec3 axis : {Vec3(Vec3::UnitX()), Vec3(Vec3::UnitY()), Vec3(Vec3::UnitZ())}) {
    Pose T = Pose::Identity();
    T.linear() = Eigen::AngleAxisf(kPi, axis).toRotationMatrix();
    m.symmetries.discrete.push_back(T);
  }
  return m;
}

}  // namespace

Mesh make_lathe(const std::vector<Eigen::Vector2f>& profile, int segments) {
  if (profile.size() < 2 || segments < 3)
    throw InvalidInput("lathe profile", "needs at least 2 points and 3 segments");
  Mesh m;
  m.name = "lathe";
  const auto s = arc_fractions(profile);
  std::vector<Vec2> uvs;
  std::vector<int> first(profile.size());  // first vertex of each ring
  for (std::size_t i = 0; i < profile.size(); ++i) {
    first[i] = int(m.vertices.size());
    const bool pole = profile[i].x() <= 0.f;
    const int count = pole ? segments : segments + 1;  // poles: one apex per segment (its own u)
    for (int k = 0; k < count; ++k) {
      const float u = pole ? (k + 0.5f) / segments : float(k) / segments, a = 2 * kPi * u;
      const float r = pole ? 0.f : profile[i].x();
      m.vertices.emplace_back(r * std::cos(a), r * std::sin(a), profile[i].y());
      uvs.emplace_back(u, s[i]);
    }
  }
  auto add = [&](int a, int b, int c) {
    m.triangles.emplace_back(a, b, c);
    m.corner_uvs.insert(m.corner_uvs.end(), {uvs[a], uvs[b], uvs[c]});
  };
  for (std::size_t i = 0; i + 1 < profile.size(); ++i) {
    const bool p0 = profile[i].x() <= 0.f, p1 = profile[i + 1].x() <= 0.f;
    for (int k = 0; k < segments; ++k) {
      const int a = first[i] + k, b = first[i] + (p0 ? k : k + 1);
      const int c = first[i + 1] + (p1 ? k : k + 1), d = first[i + 1] + k;
      if (p0 && p1) continue;
      if (p0)
        add(a, c, d);
      else if (p1)
        add(a, b, c);
      else
        add(a, b, c), add(a, c, d);
    }
  }
  m.texture = ColorImage(1, 1, Rgb8{200, 200, 200});
  if (signed_volume(m) < 0) flip_winding(m);
  return m;
}

Mesh make_box(const Eigen::Vector3f& size_m) {
  Mesh m;
  m.name = "box";
  for (int k = 0; k < 8; ++k)
    m.vertices.emplace_back((k & 1 ? 0.5f : -0.5f) * size_m.x(), (k & 2 ? 0.5f : -0.5f) * size_m.y(),
                            (k & 4 ? 0.5f : -0.5f) * size_m.z());
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads)
    m.triangles.emplace_back(q[0], q[1], q[2]), m.triangles.emplace_back(q[0], q[2], q[3]);
  return m;
}

void centre_on_bounding_box(Mesh& mesh) {
  const Vec3 c = mesh.bounds().center();
  for (auto& v : mesh.vertices) v -= c;
}

std::vector<ObjectModel> builtin_models() {
  using detail::LabelDesign;
  const cv::Scalar silver(200, 200, 205), lid(185, 185, 190);
  const Material metal{0.45f, 35.f}, plastic{0.3f, 25.f};
  std::vector<ObjectModel> out;
  const auto& can = can_profile();
  out.push_back(lathe_model(
      1, "can_cola", can, kCanLabel[0], kCanLabel[1], kCanLid,
      LabelDesign{{200, 20, 30}, {250, 250, 250}, {255, 255, 255}, {30, 30, 30}, "COLA", "classic taste", 0},
      silver, lid, metal, 512));
  out.push_back(lathe_model(
      2, "can_cherry", can, kCanLabel[0], kCanLabel[1], kCanLid,
      LabelDesign{{180, 25, 50}, {250, 200, 40}, {250, 230, 120}, {250, 200, 40}, "FIZZ", "cherry twist", 1},
      silver, lid, metal, 512));
  out.push_back(lathe_model(
      3, "can_aqua", can, kCanLabel[0], kCanLabel[1], kCanLid,
      LabelDesign{
          {25, 70, 170}, {210, 215, 225}, {255, 255, 255}, {120, 200, 240}, "AQUA", "sparkling water", 2},
      silver, lid, metal, 512));
  const auto& bottle = bottle_profile();
  out.push_back(lathe_model(
      4, "bottle_lime", bottle, kBottleLabel[0], kBottleLabel[1], kBottleCap,
      LabelDesign{{245, 245, 235}, {60, 160, 60}, {30, 110, 40}, {200, 220, 40}, "LIME", "fresh squeezed", 0},
      {40, 130, 60}, {230, 230, 230}, plastic, 640));
  out.push_back(lathe_model(
      5, "bottle_malt", bottle, kBottleLabel[0], kBottleLabel[1], kBottleCap,
      LabelDesign{{235, 150, 40}, {120, 60, 20}, {70, 30, 10}, {250, 240, 200}, "MALT", "brewed slowly", 1},
      {110, 60, 20}, {200, 160, 40}, plastic, 640));
  out.push_back(printed_box(6));
  out.push_back(bowl(7));
  out.push_back(block(8));
  return out;
}

namespace {

/// The colour with its hue turned by `degrees` (HSV), saturation at least `min_saturation`, value kept.
Rgb8 turn_hue(Rgb8 c, float degrees, float min_saturation) {
  const float r = c.r / 255.f, g = c.g / 255.f, b = c.b / 255.f;
  const float v = std::max({r, g, b}), d = v - std::min({r, g, b});
  float h = 0;  // degrees
  if (d > 0)
    h = v == r   ? 60 * std::fmod((g - b) / d + 6, 6.f)
        : v == g ? 60 * ((b - r) / d + 2)
                 : 60 * ((r - g) / d + 4);
  const float sat = std::max(v > 0 ? d / v : 0.f, min_saturation);
  h = std::fmod(h + degrees + 360.f, 360.f);
  const float c2 = v * sat, x = c2 * (1 - std::abs(std::fmod(h / 60, 2.f) - 1)), m = v - c2;
  float rgb[3];
  const int sector = int(h / 60) % 6;
  const float table[6][3] = {{c2, x, 0}, {x, c2, 0}, {0, c2, x}, {0, x, c2}, {x, 0, c2}, {c2, 0, x}};
  for (int k = 0; k < 3; ++k) rgb[k] = table[sector][k] + m;
  auto to8 = [](float f) { return std::uint8_t(std::clamp(std::lround(f * 255), 0l, 255l)); };
  return {to8(rgb[0]), to8(rgb[1]), to8(rgb[2])};
}

/// Every colour of the mesh (texture, vertex colours, base colour) with its hue turned.
void turn_hues(Mesh& m, float degrees) {
  constexpr float kMinSaturation = 0.5f;
  for (auto& c : m.texture.data) c = turn_hue(c, degrees, kMinSaturation);
  for (auto& c : m.vertex_colors) c = turn_hue(c, degrees, kMinSaturation);
  m.base_color = turn_hue(m.base_color, degrees, kMinSaturation);
}

}  // namespace

std::vector<ObjectModel> make_decoys(const std::vector<ObjectModel>& models, int first_obj_id) {
  if (first_obj_id < 1) throw InvalidInput("make_decoys first_obj_id", "must be >= 1");
  std::vector<ObjectModel> out;
  for (const ObjectModel& m : models) {
    ObjectModel reprint = m, small = m, recolour = m;
    reprint.name = m.name + "_reprint", small.name = m.name + "_small", recolour.name = m.name + "_recolour";
    for (auto& uv : reprint.mesh.corner_uvs) uv.x() = 1 - uv.x();  // the print mirrored ...
    turn_hues(reprint.mesh, 150);                                  // ... in other hues
    constexpr float kScale = 0.8f;
    for (auto& v : small.mesh.vertices) v *= kScale;
    for (auto& d : small.symmetries.discrete) d.translation() *= kScale;
    for (auto& c : small.symmetries.continuous) c.offset_m *= kScale;
    turn_hues(recolour.mesh, 90);
    for (ObjectModel* d : {&reprint, &small, &recolour}) {
      d->obj_id = first_obj_id + int(out.size());
      d->mesh.name = d->name;
      out.push_back(std::move(*d));
    }
  }
  return out;
}

std::vector<ObjectModel> load_user_models(const std::string& dir, const UserModelSettings& settings) {
  if (!fs::is_directory(dir)) throw FileError(dir, "model folder not found");
  std::vector<fs::path> files;  // relative to dir, any depth (e.g. YCB's one folder per object)
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    std::string ext = e.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return char(std::tolower(c)); });
    if (e.is_regular_file() && (ext == ".ply" || ext == ".obj")) files.push_back(fs::relative(e.path(), dir));
  }
  if (files.empty()) throw FileError(dir, "holds no .ply or .obj model");
  std::sort(files.begin(), files.end());
  std::vector<ObjectModel> out;
  for (const auto& f : files) {
    ObjectModel m;
    m.obj_id = int(out.size()) + 1;
    m.name = (f.parent_path() / f.stem()).generic_string();
    std::replace(m.name.begin(), m.name.end(), '/', '_');
    io::MeshLoadOptions opt;
    opt.scale = settings.scale > 0 ? settings.scale : 1.f;
    m.mesh = io::load_mesh((fs::path(dir) / f).string(), opt);
    if (settings.scale <= 0 && m.mesh.bounds().diagonal().norm() > settings.mm_guess_threshold)
      for (auto& v : m.mesh.vertices) v *= 0.001f;
    centre_on_bounding_box(m.mesh);
    out.push_back(std::move(m));
  }
  return out;
}

float model_diameter(const Mesh& mesh) {
  // The farthest pair lies on the hull; vertices extreme in many directions contain it for the smooth and
  // boxy shapes used here, and keep the pairwise search small for large scans.
  std::vector<Vec3> pts = mesh.vertices;
  if (pts.size() > 4000) {
    std::vector<char> keep(pts.size(), 0);
    Rng rng(7);
    for (int d = 0; d < 4000; ++d) {
      Vec3 dir(rng.normal(), rng.normal(), rng.normal());
      std::size_t best = 0;
      float best_v = -1e30f;
      for (std::size_t i = 0; i < pts.size(); ++i)
        if (pts[i].dot(dir) > best_v) best_v = pts[i].dot(dir), best = i;
      keep[best] = 1;
    }
    std::vector<Vec3> hull;
    for (std::size_t i = 0; i < pts.size(); ++i)
      if (keep[i]) hull.push_back(pts[i]);
    pts.swap(hull);
  }
  float best = 0;
  for (std::size_t i = 0; i < pts.size(); ++i)
    for (std::size_t j = i + 1; j < pts.size(); ++j) best = std::max(best, (pts[i] - pts[j]).squaredNorm());
  return std::sqrt(best);
}

void write_bop_models(const std::string& dir, const std::vector<ObjectModel>& models) {
  detail::make_folder(dir);
  nlohmann::ordered_json info = nlohmann::ordered_json::object();
  for (const auto& m : models) {
    char name[32];
    std::snprintf(name, sizeof name, "obj_%06d.ply", m.obj_id);
    Mesh mm = m.mesh;
    for (auto& v : mm.vertices) v *= 1000.f;  // BOP models are in millimetres
    io::save_ply((fs::path(dir) / name).string(), mm, /*binary=*/false);
    const auto box = mm.bounds();
    nlohmann::ordered_json j;
    j["diameter"] = 1000.0 * model_diameter(m.mesh);
    j["min_x"] = box.min().x(), j["min_y"] = box.min().y(), j["min_z"] = box.min().z();
    j["size_x"] = box.sizes().x(), j["size_y"] = box.sizes().y(), j["size_z"] = box.sizes().z();
    if (!m.symmetries.discrete.empty()) {
      auto& list = j["symmetries_discrete"] = nlohmann::ordered_json::array();
      for (const Pose& T : m.symmetries.discrete) {
        Eigen::Matrix4d M = T.matrix().cast<double>();
        M.block<3, 1>(0, 3) *= 1000.0;
        std::vector<double> flat;
        for (int r = 0; r < 4; ++r)
          for (int c = 0; c < 4; ++c)
            flat.push_back(std::abs(M(r, c)) < 1e-9 ? 0.0 : std::round(M(r, c) * 1e9) / 1e9);
        list.push_back(flat);
      }
    }
    if (!m.symmetries.continuous.empty()) {
      auto& list = j["symmetries_continuous"] = nlohmann::ordered_json::array();
      for (const auto& s : m.symmetries.continuous)
        list.push_back(
            {{"axis", {s.axis.x(), s.axis.y(), s.axis.z()}},
             {"offset", {1000.0 * s.offset_m.x(), 1000.0 * s.offset_m.y(), 1000.0 * s.offset_m.z()}}});
    }
    info[std::to_string(m.obj_id)] = j;
  }
  detail::write_bop_json((fs::path(dir) / "models_info.json").string(), info);
}

}  // namespace perch2::synth
