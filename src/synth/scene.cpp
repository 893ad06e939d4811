#include "perch2/synth/scene.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <opencv2/imgproc.hpp>

#include "box_faces.hpp"
#include "textures.hpp"

namespace perch2::synth {

namespace {

constexpr float kPi = 3.14159265358979f;
using Vec2 = Eigen::Vector2f;
using Vec3 = Eigen::Vector3f;

void check(const SceneSettings& s) {
  auto bad = [](const char* what, const char* why) {
    throw InvalidInput(std::string("SceneSettings::") + what, why);
  };
  if (s.min_objects < 0 || s.max_objects < s.min_objects)
    bad("min_objects", "need 0 <= min_objects <= max_objects");
  if (s.min_distractors < 0 || s.max_distractors < s.min_distractors)
    bad("min_distractors", "need 0 <= min_distractors <= max_distractors");
  if (!(s.placement_radius_m > 0) || 2 * s.placement_radius_m > std::min(s.table_size_x_m, s.table_size_y_m))
    bad("placement_radius_m", "must be > 0 and the disc must fit on the table");
  if (!(s.camera_min_distance_m > 0) || s.camera_max_distance_m < s.camera_min_distance_m)
    bad("camera_min_distance_m", "need 0 < min <= max");
  if (!(s.height_cell_m > 0)) bad("height_cell_m", "must be > 0");
  if (s.placement_attempts < 1) bad("placement_attempts", "must be >= 1");
  if (!(s.distractor_min_size_m > 0) || s.distractor_max_size_m < s.distractor_min_size_m)
    bad("distractor_min_size_m", "need 0 < min <= max");
}

/// Pose with rotation R and translation t.
Pose make_pose(const Eigen::Matrix3f& R, const Vec3& t) {
  Pose T = Pose::Identity();
  T.linear() = R, T.translation() = t;
  return T;
}

// ---- 3-DoF footprints --------------------------------------------------------------------------------

using Polygon = std::vector<Vec2>;

Polygon footprint(const Mesh& mesh) {
  std::vector<cv::Point2f> pts, hull;
  for (const auto& v : mesh.vertices) pts.emplace_back(v.x(), v.y());
  cv::convexHull(pts, hull);
  Polygon out;
  for (const auto& p : hull) out.emplace_back(p.x, p.y);
  return out;
}

Polygon transformed(const Polygon& poly, float x, float y, float yaw) {
  const Eigen::Rotation2Df R(yaw);
  Polygon out;
  for (const auto& p : poly) out.push_back(R * p + Vec2(x, y));
  return out;
}

/// Separating-axis test for convex polygons: true if they come closer than `gap`.
bool overlap(const Polygon& a, const Polygon& b, float gap) {
  for (const Polygon* poly : {&a, &b})
    for (std::size_t i = 0; i < poly->size(); ++i) {
      const Vec2 e = (*poly)[(i + 1) % poly->size()] - (*poly)[i];
      if (e.squaredNorm() < 1e-12f) continue;
      const Vec2 n = Vec2(-e.y(), e.x()).normalized();
      float amin = 1e30f, amax = -1e30f, bmin = 1e30f, bmax = -1e30f;
      for (const auto& p : a) amin = std::min(amin, n.dot(p)), amax = std::max(amax, n.dot(p));
      for (const auto& p : b) bmin = std::min(bmin, n.dot(p)), bmax = std::max(bmax, n.dot(p));
      if (amax + gap <= bmin || bmax + gap <= amin) return false;
    }
  return true;
}

// ---- 6-DoF drop onto a height map ---------------------------------------------------------------------

/// Highest occupied z per table cell (the table top is z = 0).
class HeightMap {
 public:
  HeightMap(float size_x, float size_y, float cell)
      : cell_(cell),
        nx_(int(size_x / cell)),
        ny_(int(size_y / cell)),
        x0_(-size_x / 2),
        y0_(-size_y / 2),
        z_(std::size_t(nx_) * ny_, 0.f) {}

  /// Height at which points (world xy, offsets dz relative to the object origin) first touch the map;
  /// false if a point lies off the table.
  bool drop_height(const std::vector<Vec3>& pts, float& z) const {
    z = -1e30f;
    for (const auto& p : pts) {
      int i, j;
      if (!cell(p.x(), p.y(), i, j)) return false;
      z = std::max(z, z_[std::size_t(j) * nx_ + i] - p.z());
    }
    return true;
  }

  /// Height of the map under (x, y); -inf off the table.
  float at(float x, float y) const {
    int i, j;
    return cell(x, y, i, j) ? z_[std::size_t(j) * nx_ + i] : -1e30f;
  }

  /// Raises the map under the points (world coordinates), one cell around each for a conservative cover.
  void add(const std::vector<Vec3>& pts) {
    for (const auto& p : pts) {
      int i, j;
      if (!cell(p.x(), p.y(), i, j)) continue;
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const int a = std::clamp(i + di, 0, nx_ - 1), b = std::clamp(j + dj, 0, ny_ - 1);
          float& h = z_[std::size_t(b) * nx_ + a];
          h = std::max(h, p.z());
        }
    }
  }

 private:
  bool cell(float x, float y, int& i, int& j) const {
    i = int(std::floor((x - x0_) / cell_)), j = int(std::floor((y - y0_) / cell_));
    return i >= 0 && j >= 0 && i < nx_ && j < ny_;
  }
  float cell_;
  int nx_, ny_;
  float x0_, y0_;
  std::vector<float> z_;
};

/// A resting orientation: which object axis points down, a lean, and a yaw about world z.
Eigen::Matrix3f rest_rotation(const SceneSettings& s, Rng& rng, bool upright_only, bool& leaning) {
  Eigen::Matrix3f R_face = Eigen::Matrix3f::Identity();
  if (!upright_only) {
    const float r = float(rng.uniform());
    if (r < s.upright_probability) {
    } else if (r < s.upright_probability + s.upside_down_probability) {
      R_face = Eigen::AngleAxisf(kPi, Vec3::UnitX()).toRotationMatrix();
    } else {  // on a side: object axis +-x or +-y points down
      const Vec3 sides[4] = {Vec3::UnitX(), -Vec3::UnitX(), Vec3::UnitY(), -Vec3::UnitY()};
      const Vec3 down = sides[rng.integer(0, 3)];
      R_face = Eigen::Quaternionf::FromTwoVectors(down, -Vec3::UnitZ()).toRotationMatrix();
    }
  }
  Eigen::Matrix3f R_lean = Eigen::Matrix3f::Identity();
  leaning = !upright_only && rng.chance(s.lean_probability);
  if (leaning) {
    const float axis_angle = rng.uniform(0.f, 2 * kPi), tilt = rng.uniform(s.lean_min_rad, s.lean_max_rad);
    R_lean =
        Eigen::AngleAxisf(tilt, Vec3(std::cos(axis_angle), std::sin(axis_angle), 0.f)).toRotationMatrix();
  }
  const float yaw = rng.uniform(0.f, 2 * kPi);
  return Eigen::AngleAxisf(yaw, Vec3::UnitZ()).toRotationMatrix() * R_lean * R_face;
}

/// Static stability without physics: the object's centre (of its surface samples) must lie over the convex
/// hull of the points that touch what is below (within `contact_m`). Leaning objects pass when they touch
/// both the table and a neighbour.
bool is_stable(const std::vector<Vec3>& pts, const HeightMap& height, float contact_m) {
  std::vector<cv::Point2f> contacts, hull;
  Vec3 centre = Vec3::Zero();
  for (const auto& p : pts) {
    centre += p;
    if (p.z() - height.at(p.x(), p.y()) < contact_m) contacts.emplace_back(p.x(), p.y());
  }
  centre /= float(pts.size());
  if (contacts.size() < 3) return false;
  cv::convexHull(contacts, hull);
  return cv::pointPolygonTest(hull, cv::Point2f(centre.x(), centre.y()), true) >= -0.5 * contact_m;
}

/// A random point in the placement disc.
Vec2 random_in_disc(float radius, Rng& rng) {
  const float r = radius * std::sqrt(float(rng.uniform())), a = rng.uniform(0.f, 2 * kPi);
  return {r * std::cos(a), r * std::sin(a)};
}

// ---- props ---------------------------------------------------------------------------------------------

cv::Scalar random_colour(Rng& rng) {
  return {double(rng.integer(20, 235)), double(rng.integer(20, 235)), double(rng.integer(20, 235))};
}

ColorImage stripes_texture(Rng& rng) {
  cv::Mat img(128, 128, CV_8UC3, random_colour(rng));
  const cv::Scalar b = random_colour(rng);
  const int style = rng.integer(0, 2), period = rng.integer(10, 40);
  for (int k = 0; k < 128; k += period) {
    if (style == 0) cv::rectangle(img, {k, 0, period / 2, 128}, b, cv::FILLED);
    if (style == 1) cv::rectangle(img, {0, k, 128, period / 2}, b, cv::FILLED);
    if (style == 2) cv::circle(img, {64, 64}, k, b, period / 4, cv::LINE_AA);
  }
  return detail::to_color_image(img);
}

/// A random unannotated shape: box, cylinder, ball or cup-like frustum, centred on its bounding box.
Prop random_distractor(const SceneSettings& s, Rng& rng) {
  Prop p;
  const int kind = rng.integer(0, 3);
  const float lo = s.distractor_min_size_m, hi = s.distractor_max_size_m;
  if (kind == 0) {
    p.mesh = textured_box({rng.uniform(lo, hi), rng.uniform(lo, hi), rng.uniform(lo, hi)},
                          stripes_texture(rng), rng.uniform(0.03f, 0.12f));
  } else {
    std::vector<Vec2> profile;
    const float r = 0.5f * rng.uniform(lo, hi), h = rng.uniform(lo, hi);
    if (kind == 1) profile = {{0.f, 0.f}, {r, 0.f}, {r, h}, {0.f, h}};
    if (kind == 2)
      for (int k = 0; k <= 12; ++k)
        profile.emplace_back(r * std::sin(kPi * k / 12), r * (1 - std::cos(kPi * k / 12)));
    if (kind == 3) profile = {{0.f, 0.f}, {0.6f * r, 0.f}, {r, h}, {0.f, h}};  // a cup-like frustum
    p.mesh = make_lathe(profile, 40);
    p.mesh.texture = stripes_texture(rng);
  }
  p.mesh.name = "distractor";
  p.material = {rng.uniform(0.f, 0.4f), rng.uniform(5.f, 40.f)};
  centre_on_bounding_box(p.mesh);
  return p;
}

/// A textured quad (corners counter-clockwise seen from the side it faces), texture repeating every period.
Mesh quad(const Vec3 (&c)[4], ColorImage texture, float period) {
  Mesh m;
  const Vec3 ex = (c[1] - c[0]).normalized(), ey = (c[3] - c[0]).normalized();
  for (const auto& v : c) m.vertices.push_back(v);
  m.triangles = {{0, 1, 2}, {0, 2, 3}};
  for (int k : {0, 1, 2, 0, 2, 3})
    m.corner_uvs.emplace_back((c[k] - c[0]).dot(ex) / period, (c[k] - c[0]).dot(ey) / period);
  m.texture = std::move(texture);
  return m;
}

std::vector<Prop> environment(const SceneSettings& s, Rng& rng) {
  std::vector<Prop> env;
  Prop table;
  table.mesh = textured_box({s.table_size_x_m, s.table_size_y_m, s.table_thickness_m},
                            detail::wood_texture(512, unsigned(rng.next())), 0.9f);
  table.mesh.name = "table";
  table.material = {rng.uniform(0.05f, 0.25f), 20.f};
  table.T_world_obj.translation() = Vec3(0, 0, -s.table_thickness_m / 2);
  env.push_back(std::move(table));
  const float h = s.room_size_m / 2, z0 = s.floor_z_m, z1 = s.floor_z_m + s.wall_height_m;
  Prop floor;
  const Vec3 fc[4] = {{-h, -h, z0}, {h, -h, z0}, {h, h, z0}, {-h, h, z0}};
  floor.mesh = quad(fc, detail::floor_texture(256, {150, 140, 130}, {110, 100, 95}), 1.2f);
  floor.mesh.name = "floor";
  env.push_back(std::move(floor));
  const cv::Scalar paint(rng.integer(170, 235), rng.integer(170, 230), rng.integer(160, 220));
  for (int w = 0; w < 4; ++w) {  // walls facing inwards
    const Eigen::Matrix3f R = Eigen::AngleAxisf(w * kPi / 2, Vec3::UnitZ()).toRotationMatrix();
    // Counter-clockwise seen from inside the room.
    const Vec3 c[4] = {R * Vec3(-h, h, z0), R * Vec3(h, h, z0), R * Vec3(h, h, z1), R * Vec3(-h, h, z1)};
    Prop wall;
    wall.mesh = quad(c, detail::wall_texture(512, paint, unsigned(rng.next())), 2.f);
    wall.mesh.name = "wall";
    env.push_back(std::move(wall));
  }
  return env;
}

}  // namespace

Mesh textured_box(const Eigen::Vector3f& size_m, ColorImage texture, float texture_period_m) {
  Mesh m;
  m.name = "box";
  const Vec3 h = size_m / 2;
  for (const auto& face : detail::kBoxFaces) {
    const int base = int(m.vertices.size());
    Vec3 c[4];
    for (int k = 0; k < 4; ++k) c[k] = Vec3(face[k][0] * h.x(), face[k][1] * h.y(), face[k][2] * h.z());
    const Vec3 ex = (c[1] - c[0]).normalized(), ey = (c[3] - c[0]).normalized();
    for (int k = 0; k < 4; ++k) m.vertices.push_back(c[k]);
    m.triangles.emplace_back(base, base + 1, base + 2);
    m.triangles.emplace_back(base, base + 2, base + 3);
    for (int k : {0, 1, 2, 0, 2, 3})
      m.corner_uvs.emplace_back(c[k].dot(ex) / texture_period_m, c[k].dot(ey) / texture_period_m);
  }
  m.texture = std::move(texture);
  return m;
}

std::vector<Eigen::Vector3f> sample_surface(const Mesh& mesh, float spacing_m) {
  std::vector<Vec3> out;
  for (const auto& t : mesh.triangles) {
    const Vec3 a = mesh.vertices[t[0]], b = mesh.vertices[t[1]], c = mesh.vertices[t[2]];
    const float longest = std::max({(b - a).norm(), (c - b).norm(), (a - c).norm()});
    const int n = std::max(1, int(std::ceil(longest / spacing_m)));
    for (int i = 0; i <= n; ++i)
      for (int j = 0; i + j <= n; ++j) out.push_back(a + (b - a) * (float(i) / n) + (c - a) * (float(j) / n));
  }
  return out;
}

Pose look_at(const Eigen::Vector3f& eye, const Eigen::Vector3f& target) {
  const Vec3 z = (target - eye).normalized();
  Vec3 x = z.cross(Vec3::UnitZ());
  if (x.norm() < 1e-6f) x = Vec3::UnitX();  // looking straight down
  x.normalize();
  Eigen::Matrix3f R;
  R.col(0) = x, R.col(1) = z.cross(x), R.col(2) = z;
  return make_pose(R, eye);
}

Pose sample_camera_pose(const SceneSettings& s, Rng& rng) {
  const float d = rng.uniform(s.camera_min_distance_m, s.camera_max_distance_m);
  const float el = rng.uniform(s.camera_min_elevation_rad, s.camera_max_elevation_rad);
  const float az = rng.uniform(0.f, 2 * kPi);
  const Vec3 target(rng.uniform(-s.look_at_jitter_m, s.look_at_jitter_m),
                    rng.uniform(-s.look_at_jitter_m, s.look_at_jitter_m), s.look_at_height_m);
  const Vec3 eye = target + d * Vec3(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
  const float roll = rng.uniform(-s.camera_roll_rad, s.camera_roll_rad);
  return look_at(eye, target) *
         make_pose(Eigen::AngleAxisf(roll, Vec3::UnitZ()).toRotationMatrix(), Vec3::Zero());
}

namespace {

/// Something to place: a model instance or a distractor.
struct Item {
  const Mesh* mesh;
  int model;  ///< index into the models, -1 for a distractor
  int distractor;
};

using Accept = std::function<void(const Item&, const Pose&)>;

/// 3-DoF: upright at random (x, y, yaw) where the convex footprint keeps min_gap_m from the others.
void place_upright(const std::vector<Item>& items, const SceneSettings& s, Rng& rng, const Accept& accept) {
  std::vector<Polygon> placed;
  for (const Item& it : items) {
    const Polygon fp = footprint(*it.mesh);
    const float z = -it.mesh->bounds().min().z();  // resting on z = 0
    for (int attempt = 0; attempt < s.placement_attempts; ++attempt) {
      const Vec2 xy = random_in_disc(s.placement_radius_m, rng);
      const float yaw = rng.uniform(0.f, 2 * kPi);
      const Polygon moved = transformed(fp, xy.x(), xy.y(), yaw);
      if (std::any_of(placed.begin(), placed.end(),
                      [&](const Polygon& p) { return overlap(p, moved, s.min_gap_m); }))
        continue;
      placed.push_back(moved);
      accept(it,
             make_pose(Eigen::AngleAxisf(yaw, Vec3::UnitZ()).toRotationMatrix(), Vec3(xy.x(), xy.y(), z)));
      break;
    }
  }
}

/// 6-DoF: a random resting orientation dropped onto the height map (beside a neighbour when leaning, over one
/// when stacking), kept when it is statically stable and not too high.
void place_resting(const std::vector<Item>& items, const SceneSettings& s, Rng& rng, const Accept& accept) {
  HeightMap height(s.table_size_x_m, s.table_size_y_m, s.height_cell_m);
  std::vector<Vec2> centres;
  for (const Item& it : items) {
    const std::vector<Vec3> samples = sample_surface(*it.mesh, 1.5f * s.height_cell_m);
    for (int attempt = 0; attempt < s.placement_attempts; ++attempt) {
      bool leaning = false;
      const Eigen::Matrix3f R = rest_rotation(s, rng, it.model < 0, leaning);
      Vec2 xy = random_in_disc(s.placement_radius_m, rng);
      const float r_stack = float(rng.uniform()), a = rng.uniform(0.f, 2 * kPi),
                  d = rng.uniform(s.lean_min_distance_m, s.lean_max_distance_m);
      const Vec2 base = centres.empty() ? xy : centres[rng.integer(0, int(centres.size()) - 1)];
      if (!centres.empty() && leaning)  // lean against a neighbour
        xy = base + d * Vec2(std::cos(a), std::sin(a));
      else if (!centres.empty() && r_stack < s.stack_probability)  // on top of it
        xy = base + s.stack_jitter_m * Vec2(rng.normal(), rng.normal());
      std::vector<Vec3> pts;
      pts.reserve(samples.size());
      for (const auto& p : samples) pts.push_back(R * p + Vec3(xy.x(), xy.y(), 0.f));
      float z;
      if (!height.drop_height(pts, z)) continue;
      z += s.clearance_m;
      float top = -1e30f;
      for (auto& p : pts) p.z() += z, top = std::max(top, p.z());
      if (top > s.max_stack_height_m || !is_stable(pts, height, s.contact_m)) continue;
      height.add(pts);
      centres.push_back(xy);
      accept(it, make_pose(R, Vec3(xy.x(), xy.y(), z)));
      break;
    }
  }
}

/// Which models to place: distinct ones first (shuffled), with the odd duplicate.
std::vector<int> choose_models(std::size_t num_models, const SceneSettings& s, Rng& rng) {
  const int count = rng.integer(s.min_objects, s.max_objects);
  std::vector<int> order(num_models);
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = int(i);
  for (std::size_t i = order.size(); i > 1; --i) std::swap(order[i - 1], order[rng.integer(0, int(i) - 1)]);
  std::vector<int> chosen;
  std::size_t next = 0;  // next unused model in the shuffled order
  for (int k = 0; k < count; ++k) {
    const bool dup = !chosen.empty() && (rng.chance(s.duplicate_probability) || next >= order.size());
    chosen.push_back(dup ? chosen[rng.integer(0, int(chosen.size()) - 1)] : order[next++]);
  }
  return chosen;
}

}  // namespace

Scene compose_scene(const std::vector<ObjectModel>& models, const SceneSettings& s, Rng& rng) {
  if (models.empty()) throw InvalidInput("models", "no object models to place");
  check(s);
  Scene scene;
  scene.environment = environment(s, rng);
  const std::vector<int> chosen = choose_models(models.size(), s, rng);
  const int num_distractors = rng.integer(s.min_distractors, s.max_distractors);
  std::vector<Prop> distractors;
  for (int k = 0; k < num_distractors; ++k) distractors.push_back(random_distractor(s, rng));

  std::vector<Item> items;  // objects first, then distractors fill the gaps
  for (int m : chosen) items.push_back({&models[m].mesh, m, -1});
  for (int d = 0; d < num_distractors; ++d) items.push_back({&distractors[d].mesh, -1, d});
  const Accept accept = [&](const Item& it, const Pose& T) {
    if (it.model >= 0) {
      scene.objects.push_back({it.model, T});
    } else {
      distractors[it.distractor].T_world_obj = T;
      scene.distractors.push_back(std::move(distractors[it.distractor]));
    }
  };
  if (s.mode == Mode::ThreeDof)
    place_upright(items, s, rng, accept);
  else
    place_resting(items, s, rng, accept);
  return scene;
}

}  // namespace perch2::synth
