// Tracking (perch2/track/): the turns GICP cannot see, and the Tracker on short generated sequences (a
// hand-held camera circling a table, synth::camera_path) from ground-truth starts: it follows, an occluder
// makes it lost (never a confident wrong pose), and bad input is refused.
#include <doctest/doctest.h>

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <vector>

#include "perch2/search/sixdof.hpp"
#include "perch2/synth/synth.hpp"
#include "perch2/track/tracker.hpp"
#include "test_support.hpp"

using namespace perch2;

namespace {

Pose turn(int axis, float angle) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisf(angle, Eigen::Vector3f::Unit(axis)).toRotationMatrix();
  return T;
}

/// A generated sequence at 320 x 240: the scene, its frames and each object's true T_cam_obj per frame.
struct Sequence {
  std::vector<synth::ObjectModel> models;
  std::vector<RgbdFrame> frames;
  std::vector<std::vector<Pose>> gt;  ///< [frame][object]
  std::vector<int> model;             ///< per object
};

/// From frame `move_at` on, object 0 stands `move_m` (world frame) from where it was (pushed while hidden)
/// and, if `swap_to` (a built-in model) is given, is that model instead (a look-alike put in its place).
/// With a non-zero `copy_m`, an untracked copy of object 0 stands copy_m (world frame) from it throughout.
Sequence make_sequence(std::uint64_t seed, const std::vector<int>& model_ids, int frames,
                       float degrees_per_frame, int move_at = -1,
                       const Eigen::Vector3f& move_m = Eigen::Vector3f::Zero(), int swap_to = -1,
                       const Eigen::Vector3f& copy_m = Eigen::Vector3f::Zero()) {
  Sequence s;
  const auto all = synth::builtin_models();
  for (int id : model_ids) s.models.push_back(all[std::size_t(id)]);
  synth::SceneSettings ss;
  ss.mode = synth::Mode::SixDof;
  ss.min_objects = ss.max_objects = int(model_ids.size());
  ss.duplicate_probability = 0.f;
  ss.min_distractors = ss.max_distractors = 0;
  ss.placement_radius_m = 0.12f;
  ss.upright_probability = 1.f, ss.lean_probability = 0.f, ss.stack_probability = 0.f;
  ss.camera_min_distance_m = 0.55f, ss.camera_max_distance_m = 0.65f;
  synth::Rng rng(seed);
  synth::Scene scene = synth::compose_scene(s.models, ss, rng);
  const std::size_t tracked = scene.objects.size();
  if (!copy_m.isZero()) {
    scene.objects.push_back(scene.objects[0]);
    scene.objects.back().T_world_obj.translation() += copy_m;
  }
  synth::Scene moved = scene;
  moved.objects[0].T_world_obj.translation() += move_m;
  if (swap_to >= 0) {  // after compose_scene: the look-alike is never placed by it
    moved.objects[0].model = int(s.models.size());
    s.models.push_back(all[std::size_t(swap_to)]);
  }
  const synth::SceneRenderer renderer(s.models, scene), moved_renderer(s.models, moved);
  synth::VideoSettings video;
  video.frames = frames, video.degrees_per_frame = degrees_per_frame, video.burst_probability = 0.f;
  const std::vector<Pose> path = synth::camera_path(ss, video, rng);
  synth::SensorSettings sensor;
  sensor.camera = {307.5f, 307.5f, 159.5f, 119.5f, 320, 240};
  for (std::size_t k = 0; k < tracked; ++k) s.model.push_back(scene.objects[k].model);
  for (const Pose& T_world_cam : path) {
    const bool after = move_at >= 0 && int(s.frames.size()) >= move_at;
    const synth::Frame f = (after ? moved_renderer : renderer).render(T_world_cam, sensor, rng);
    s.frames.push_back({f.camera, f.depth_m, f.rgb});
    std::vector<Pose> gt;
    for (std::size_t k = 0; k < tracked; ++k)
      gt.push_back(T_world_cam.inverse() * (after ? moved : scene).objects[k].T_world_obj);
    s.gt.push_back(gt);
  }
  return s;
}

std::vector<SixDofModel> sixdof_models(const std::vector<synth::ObjectModel>& models) {
  std::vector<SixDofModel> out;
  for (const auto& m : models)
    out.push_back({m.mesh, ModelSymmetries::from(m.symmetries.discrete, m.symmetries.continuous)});
  return out;
}

std::vector<TrackStart> starts_at(const Sequence& s, std::size_t frame) {
  std::vector<TrackStart> out;
  for (std::size_t k = 0; k < s.model.size(); ++k) out.push_back({s.model[k], s.gt[frame][k]});
  return out;
}

/// ADD over the mesh's vertices (ADD-S for a model with symmetries), metres.
double pose_error(const Pose& est, const Pose& gt, const synth::ObjectModel& m) {
  if (!m.symmetries.discrete.empty() || !m.symmetries.continuous.empty())
    return test::adds_vertices(est, gt, m.mesh);
  double sum = 0;
  for (const auto& p : m.mesh.vertices) sum += double((est * p - gt * p).norm());
  return sum / double(m.mesh.vertices.size());
}

/// Settings for 320 x 240 frames (half the resolution the defaults are for): strides and margins halved.
TrackSettings test_settings() {
  TrackSettings t;
  t.render_stride = 2, t.observed_stride = 2;
  t.rounds[0].margin_px = 12, t.rounds[1].margin_px = 4, t.check_margin_px = 4;
  t.turn_hold.stride = 1, t.turn_hold.sweep_stride = 1;
  t.recovery.background = false;  // reproducible: the search's answer is taken in the frame it ran on
  return t;
}

/// Frame f of `s` with a flat occluder 25 cm in front of object 0 (a hand passing), 91 x 91 px.
RgbdFrame occluded(const Sequence& s, std::size_t f) {
  RgbdFrame frame = s.frames[f];
  const Eigen::Vector3f c = s.gt[f][0].translation();
  const Vec2f uv = frame.camera.project({c.x(), c.y(), c.z()});
  for (int v = int(uv.y) - 45; v <= int(uv.y) + 45; ++v)
    for (int u = int(uv.x) - 45; u <= int(uv.x) + 45; ++u)
      if (u >= 0 && v >= 0 && u < frame.camera.width && v < frame.camera.height)
        frame.depth_m(u, v) = c.z() - 0.25f, frame.rgb(u, v) = Rgb8{220, 180, 150};
  return frame;
}

}  // namespace

TEST_CASE("flat axes: a can's and a bowl's axis, none for a box or a block") {
  const auto all = synth::builtin_models();
  for (const auto& m : all) {
    INFO(m.name);
    const std::vector<int> axes = track_detail::flat_axes(m.mesh);
    if (m.name.rfind("can", 0) == 0 || m.name.rfind("bottle", 0) == 0 || m.name == "bowl")
      CHECK(axes == std::vector<int>{2});
    else
      CHECK(axes.empty());
  }
}

TEST_CASE("without_turn drops the move's turn about the model axis and keeps its tilt and translation") {
  Pose T = turn(0, 0.4f) * turn(1, -0.7f);
  T.translation() = Eigen::Vector3f(0.1f, -0.05f, 0.7f);
  Pose T_new = T * turn(0, 0.1f) * turn(2, 0.3f);  // tilt about model x, then a turn about model z
  T_new.translation() += Eigen::Vector3f(0.01f, 0.f, -0.02f);
  const Pose out = track_detail::without_turn(T, T_new, 2);
  CHECK((out.translation() - T_new.translation()).norm() < 1e-6f);
  // The model's z axis ends where the move put it (the tilt is kept) ...
  CHECK((out.linear().col(2) - T_new.linear().col(2)).norm() < 1e-5f);
  // ... but the turn about it is gone: the model x axis is the tilt's alone.
  const Eigen::Matrix3f tilt_only = (T * turn(0, 0.1f)).linear();
  CHECK((out.linear() - tilt_only).norm() < 1e-4f);
  // No turn to remove: the move itself.
  const Pose tilt = T * turn(1, 0.2f);
  CHECK((track_detail::without_turn(T, tilt, 2).matrix() - tilt.matrix()).norm() < 1e-5f);
}

TEST_CASE("thinned keeps at most max_points of each cloud, evenly, and every point with 0") {
  CloudBatch b;
  for (const int n : {10, 3, 0, 7}) {
    for (int i = 0; i < n; ++i) {
      b.x.push_back(float(i)), b.y.push_back(0.f), b.z.push_back(1.f);
      b.rgb.push_back(0u), b.pixel.push_back(i), b.cloud.push_back(std::int32_t(b.num_clouds()));
    }
    b.offsets.push_back(std::int64_t(b.size()));
  }
  const CloudBatch t = track_detail::thinned(b, 4);
  t.validate("thinned");
  REQUIRE(t.num_clouds() == 4);
  CHECK(t.cloud_size(0) == 4);  // every 3rd of 10: 0 3 6 9
  CHECK(t.x[std::size_t(t.offsets[0]) + 3] == 9.f);
  CHECK(t.cloud_size(1) == 3);
  CHECK(t.cloud_size(2) == 0);
  CHECK(t.cloud_size(3) == 4);  // every 2nd of 7
  CHECK(track_detail::thinned(b, 0).size() == b.size());
}

TEST_CASE("camera_path: a smooth orbit at the set speed, refused with bad settings") {
  synth::SceneSettings ss;
  synth::VideoSettings v;
  v.frames = 40, v.burst_probability = 0.f, v.shake_m = 0.f, v.shake_rad = 0.f, v.elevation_swing_rad = 0.f;
  synth::Rng rng(3);
  const std::vector<Pose> path = synth::camera_path(ss, v, rng);
  REQUIRE(path.size() == 40);
  for (std::size_t f = 1; f < path.size(); ++f) {
    const float angle = Eigen::AngleAxisf(path[f - 1].linear().transpose() * path[f].linear()).angle();
    CHECK(angle * 180.f / 3.14159265f == doctest::Approx(v.degrees_per_frame).epsilon(0.05));
  }
  v.frames = 0;
  CHECK_THROWS_WITH_AS(synth::camera_path(ss, v, rng), doctest::Contains("VideoSettings::frames"),
                       InvalidInput);
}

TEST_CASE("video events: a pushed object moves push_m, an occluder crosses in front of one object") {
  const auto all = synth::builtin_models();
  synth::SceneSettings ss;
  ss.mode = synth::Mode::SixDof;
  synth::Rng rng(9);
  const synth::Scene scene = synth::compose_scene(all, ss, rng);
  synth::VideoSettings v;
  v.frames = 60, v.push_probability = 1.f, v.occluder_probability = 1.f;
  const std::vector<Pose> path = synth::camera_path(ss, v, rng);
  const synth::VideoEvents e = synth::draw_events(scene, v, rng);
  REQUIRE(e.pushed >= 0);
  REQUIRE(e.occluded >= 0);
  const auto moved = [&](int f) {
    const synth::Scene at = synth::scene_at(scene, e, v, f, path[std::size_t(f)]);
    return (at.objects[std::size_t(e.pushed)].T_world_obj.translation() -
            scene.objects[std::size_t(e.pushed)].T_world_obj.translation())
        .norm();
  };
  CHECK(moved(0) < 1e-6f);
  CHECK(moved(59) == doctest::Approx(v.push_m).epsilon(1e-4));
  for (int f = 0; f < 60; ++f) {
    const synth::Scene at = synth::scene_at(scene, e, v, f, path[std::size_t(f)]);
    const bool crossing = f >= e.occluder_start && f < e.occluder_start + v.occluder_frames;
    REQUIRE(at.distractors.size() == scene.distractors.size() + (crossing ? 1 : 0));
    if (!crossing) continue;
    // Between the camera and the object, within 12 cm of the line of sight.
    const Eigen::Vector3f eye = path[std::size_t(f)].translation();
    const Eigen::Vector3f to = at.objects[std::size_t(e.occluded)].T_world_obj.translation() - eye;
    const Eigen::Vector3f hand = at.distractors.back().T_world_obj.translation() - eye;
    CHECK(hand.dot(to.normalized()) == doctest::Approx(v.occluder_fraction * to.norm()).epsilon(0.01));
    CHECK((hand - hand.dot(to.normalized()) * to.normalized()).norm() <= 0.1201f);
  }
  v.occluder_fraction = 1.f;
  CHECK_THROWS_WITH_AS(synth::draw_events(scene, v, rng), doctest::Contains("occluder_fraction"),
                       InvalidInput);
}

TEST_CASE_TEMPLATE("Tracker follows a circling camera from the true start within 1 cm", B,
                   PERCH2_TEST_BACKENDS) {
  // A can (printed: its turn is held by the appearance) and a box.
  const Sequence s = make_sequence(11, {0, 5}, 24, 1.5f);
  Tracker<B> tracker(sixdof_models(s.models), test_settings());
  TrackResult r = tracker.start(s.frames[0], starts_at(s, 0));
  REQUIRE(r.objects.size() == 2);
  double worst = 0;
  for (std::size_t f = 1; f < s.frames.size(); ++f) {
    r = tracker.update(s.frames[f]);
    CHECK(r.frame == int(f));
    CHECK(r.timings.total > 0);
    for (const TrackedObject& o : r.objects) {
      const double e =
          pose_error(o.T_cam_obj, s.gt[f][std::size_t(o.object)], s.models[std::size_t(o.model)]);
      INFO("frame " << f << " object " << o.object << " (" << s.models[std::size_t(o.model)].name
                    << ") error " << e * 1e3 << " mm, score " << o.score << ", visible "
                    << o.visible_fraction);
      CHECK(o.state == TrackState::Tracking);
      CHECK(o.score > 0.6f);
      worst = std::max(worst, e);
    }
  }
  MESSAGE("worst error over 23 frames: " << worst * 1e3 << " mm");
  CHECK(worst < 0.01);
}

TEST_CASE("Tracker started by the search (no masks, the objects given) follows within 1 cm") {
  const Sequence s = make_sequence(11, {0, 5}, 16, 1.5f);
  const std::vector<SixDofModel> models = sixdof_models(s.models);
  SixDofEstimator<thrust_omp::Backend> search(models);
  const SixDofSceneResult found = search.estimate_scene(s.frames[0], {{0, 1}, {1, 1}});
  REQUIRE(track_starts(found).size() == 2);
  Tracker<thrust_omp::Backend> tracker(models, test_settings());
  tracker.start(s.frames[0], track_starts(found));
  double worst = 0;
  for (std::size_t f = 1; f < s.frames.size(); ++f) {
    const TrackResult r = tracker.update(s.frames[f]);
    for (const TrackedObject& o : r.objects) {
      // The search's order is its own: each pose against the true pose of its model.
      std::size_t k = 0;
      while (s.model[k] != o.model) ++k;
      const double e = pose_error(o.T_cam_obj, s.gt[f][k], s.models[std::size_t(o.model)]);
      INFO("frame " << f << " model " << o.model << " error " << e * 1e3 << " mm");
      CHECK(o.state == TrackState::Tracking);
      worst = std::max(worst, e);
    }
  }
  MESSAGE("search start: worst error over 15 frames " << worst * 1e3 << " mm");
  CHECK(worst < 0.01);
}

TEST_CASE("Tracker: an occluder over an object makes it lost, never a confident wrong pose, then recovered") {
  const Sequence s = make_sequence(5, {5, 7}, 50, 0.5f);
  Tracker<thrust_omp::Backend> tracker(sixdof_models(s.models), test_settings());
  tracker.start(s.frames[0], starts_at(s, 0));
  // A flat occluder 25 cm in front of object 0 (a hand passing) over frames 10 .. 29.
  int lost = 0, recovered_at = -1, searches = 0;
  double search_s = 0;
  for (std::size_t f = 1; f < s.frames.size(); ++f) {
    const bool covered = f >= 10 && f < 30;
    const TrackResult r = tracker.update(covered ? occluded(s, f) : s.frames[f]);
    searches += int(r.searched.size());
    search_s += r.timings.search;
    const TrackedObject& o = r.objects[0];
    const double e = pose_error(o.T_cam_obj, s.gt[f][0], s.models[std::size_t(o.model)]);
    INFO("frame " << f << ": " << std::string(to_string(o.state)) << ", error " << e * 1e3 << " mm, score "
                  << o.score << ", visible " << o.visible_fraction << ", readings " << o.segment_points);
    if (covered) CHECK(o.state == TrackState::Lost);
    if (o.state != TrackState::Lost) CHECK(e < 0.02);  // never a confident wrong pose
    lost += o.state == TrackState::Lost;
    if (o.state == TrackState::Recovered && recovered_at < 0) recovered_at = int(f);
    CHECK(r.objects[1].state != TrackState::Lost);  // the other object is tracked throughout
  }
  MESSAGE("lost " << lost << " frames, " << searches << " searches (" << search_s
                  << " s), recovered at frame " << recovered_at);
  CHECK(lost >= 20);
  CHECK(searches > 0);
  CHECK(recovered_at >= 30);
  CHECK(recovered_at < 30 + 30);  // within 30 frames of the occluder leaving
  CHECK(tracker.objects()[0].state != TrackState::Lost);
}

TEST_CASE("Tracker: an object moved while hidden is found again by the search (here and in the background)") {
  // Object 0 (a box) is pushed 7 cm along the table at frame 15, while the occluder covers it (frames
  // 10 .. 19): its coasted pose is far off, only the search finds it. Refined from the coasted pose it
  // slides onto the table where it stood (a confident wrong pose without max_recovery_move_m).
  const Sequence s = make_sequence(5, {5, 7}, 40, 0.5f, 15, {0.f, 0.07f, 0.f});
  for (const bool background : {false, true}) {
    INFO("background " << background);
    TrackSettings ts = test_settings();
    ts.recovery.background = background;
    Tracker<thrust_omp::Backend> tracker(sixdof_models(s.models), ts);
    tracker.start(s.frames[0], starts_at(s, 0));
    int searches = 0, recovered_at = -1;
    // The last frame repeats (a still camera) until the background search has answered (two minutes at most:
    // sanitizer builds are slow).
    const auto t0 = std::chrono::steady_clock::now();
    for (std::size_t k = 1;
         recovered_at < 0 && std::chrono::steady_clock::now() - t0 < std::chrono::seconds(120); ++k) {
      const std::size_t f = std::min(k, s.frames.size() - 1);
      const TrackResult r = tracker.update(f >= 10 && f < 20 ? occluded(s, f) : s.frames[f]);
      searches += int(r.searched.size());
      const TrackedObject& o = r.objects[0];
      const double e = pose_error(o.T_cam_obj, s.gt[f][0], s.models[std::size_t(o.model)]);
      INFO("update " << k << ": " << std::string(to_string(o.state)) << ", error " << e * 1e3 << " mm");
      if (o.state != TrackState::Lost) CHECK(e < 0.02);
      if (o.state == TrackState::Recovered) recovered_at = int(k);
    }
    MESSAGE("background " << background << ": " << searches << " searches, recovered at update "
                          << recovered_at);
    CHECK(recovered_at >= 15);
    if (!background) CHECK(recovered_at < 15 + 30);
    CHECK(searches > 0);
  }
}

TEST_CASE("Tracker: a hidden object is not recovered on a copy of it standing elsewhere") {
  // An untracked copy of object 0 (a box) stands 20 cm from it; the occluder hides object 0 over frames
  // 10 .. 29. The search finds the copy, but object 0's place is hidden, not contradicted (no readings
  // behind it): it stays lost until it shows again. The control (max_jump_m 1 m) takes the copy.
  const Sequence s = make_sequence(5, {5, 7}, 50, 0.5f, -1, Eigen::Vector3f::Zero(), -1, {0.f, 0.2f, 0.f});
  for (const float max_jump_m : {0.1f, 1.f}) {
    TrackSettings ts = test_settings();
    ts.recovery.max_jump_m = max_jump_m;
    Tracker<thrust_omp::Backend> tracker(sixdof_models(s.models), ts);
    tracker.start(s.frames[0], starts_at(s, 0));
    int wrong = 0, recovered_at = -1;
    for (std::size_t f = 1; f < s.frames.size(); ++f) {
      const TrackResult r = tracker.update(f >= 10 && f < 30 ? occluded(s, f) : s.frames[f]);
      const TrackedObject& o = r.objects[0];
      const double e = pose_error(o.T_cam_obj, s.gt[f][0], s.models[std::size_t(o.model)]);
      INFO("max_jump_m " << max_jump_m << ", frame " << f << ": " << std::string(to_string(o.state))
                         << ", error " << e * 1e3 << " mm");
      wrong += o.state != TrackState::Lost && e > 0.05;
      if (o.state == TrackState::Recovered && recovered_at < 0) recovered_at = int(f);
    }
    MESSAGE("max_jump_m " << max_jump_m << ": " << wrong << " confident frames > 5 cm off, recovered at "
                          << recovered_at);
    if (max_jump_m < 1.f) {
      CHECK(wrong == 0);
      CHECK(recovered_at >= 30);
      CHECK(recovered_at < 30 + 30);
    } else {
      CHECK(wrong > 0);  // the copy taken for it: what the rule prevents
    }
  }
}

TEST_CASE("Tracker: an object lost for good does not take every search from one lost later") {
  // Object 2 is a model that is not on the table (lost from the start, never found). Object 0 is hidden
  // over frames 4 .. 9 and pushed 7 cm at frame 6 (only the search finds it, here as soon as what shows
  // of it around the occluder suffices). One search per update, in
  // turns: object 0 is searched for and recovered (the longest lost first would search object 2 every time).
  const Sequence s = make_sequence(5, {5, 7}, 30, 0.5f, 6, {0.f, 0.07f, 0.f});
  std::vector<SixDofModel> models = sixdof_models(s.models);
  models.push_back(sixdof_models({synth::builtin_models()[3]}).front());
  TrackSettings ts = test_settings();
  ts.recovery.per_frame = 1, ts.recovery.every_frames = 1;
  Tracker<thrust_omp::Backend> tracker(models, ts);
  std::vector<TrackStart> starts = starts_at(s, 0);
  starts.push_back({2, s.gt[0][0] * Pose(Eigen::Translation3f(0.f, 0.f, 0.3f))});
  tracker.start(s.frames[0], starts);
  int searched_0 = 0, searched_2 = 0, recovered_at = -1;
  for (std::size_t f = 1; f < s.frames.size() && recovered_at < 0; ++f) {
    const TrackResult r = tracker.update(f >= 4 && f < 10 ? occluded(s, f) : s.frames[f]);
    for (const int i : r.searched) (i == 0 ? searched_0 : searched_2) += i == 0 || i == 2;
    CHECK(r.objects[2].state == TrackState::Lost);
    const TrackedObject& o = r.objects[0];
    if (o.state != TrackState::Lost) CHECK(pose_error(o.T_cam_obj, s.gt[f][0], s.models[0]) < 0.02);
    if (o.state == TrackState::Recovered) recovered_at = int(f);
  }
  MESSAGE("searches: object 0 " << searched_0 << ", object 2 " << searched_2
                                << "; object 0 recovered at frame " << recovered_at);
  CHECK(searched_2 > 0);
  CHECK(recovered_at >= 6);  // pushed at frame 6
  CHECK(recovered_at < 10 + 10);
}

TEST_CASE("Tracker: a can started with its print half a turn wrong is turned right by the sweep") {
  // The search's start on a partly hidden can may face its label the wrong way; the hold climbs a few
  // degrees a frame and never gets there. The sweep (a whole turn, every sweep_every_frames) turns it
  // right, and the velocity does not repeat the sweep's turn on the next frame. Control: no sweep. No
  // recovery search in either (it would find the can again once the wrong print fails the check).
  const Sequence s = make_sequence(11, {0, 5}, 24, 1.5f);
  std::size_t can = 0;
  while (s.model[can] != 0) ++can;
  const auto axes = track_detail::flat_axes(s.models[0].mesh);
  REQUIRE(axes.size() == 1);
  for (const int every : {10, 0}) {
    TrackSettings ts = test_settings();
    ts.turn_hold.sweep_every_frames = every;
    ts.recovery.per_frame = 0;
    Tracker<thrust_omp::Backend> tracker(sixdof_models(s.models), ts);
    std::vector<TrackStart> starts = starts_at(s, 0);
    starts[can].T_cam_obj = track_detail::turned(starts[can].T_cam_obj, axes[0], 2.6f);  // 150 deg
    tracker.start(s.frames[0], starts);
    int right = 0;
    for (std::size_t f = 1; f < s.frames.size(); ++f) {
      const TrackedObject o = tracker.update(s.frames[f]).objects[can];
      const double e = pose_error(o.T_cam_obj, s.gt[f][can], s.models[0]);
      INFO("sweep every " << every << ", frame " << f << ": error " << e * 1e3 << " mm, "
                          << std::string(to_string(o.state)));
      right += e < 0.01;
      if (every > 0) CHECK(e < 0.01);  // swept in the start's frame
      if (every > 0) CHECK(o.state != TrackState::Lost);
    }
    if (every == 0) CHECK(right == 0);
  }
}

TEST_CASE("Tracker: a can whose print disagrees is swept in that frame, beside the periodic sweep") {
  // Two cans started in one frame, the second with its print half a turn wrong: the periodic sweep takes
  // one object per frame (the first), so the second is righted only by the sweep its disagreeing print
  // asks for (TrackSettings::min_appearance); without it the start would be lost. These labels between
  // silver rims still correlate at 0.47 half a turn off (0.84 right), so the bar is set between the two.
  const Sequence s = make_sequence(11, {2, 0, 5}, 3, 1.f);
  std::vector<std::size_t> cans;
  for (std::size_t k = 0; k < s.model.size(); ++k)
    if (s.model[k] < 2) cans.push_back(k);
  REQUIRE(cans.size() == 2);
  const std::size_t wrong = cans[1];
  const auto axes = track_detail::flat_axes(s.models[std::size_t(s.model[wrong])].mesh);
  REQUIRE(axes.size() == 1);
  TrackSettings ts = test_settings();
  ts.min_appearance = 0.6f;
  Tracker<thrust_omp::Backend> tracker(sixdof_models(s.models), ts);
  std::vector<TrackStart> starts = starts_at(s, 0);
  starts[wrong].T_cam_obj = track_detail::turned(starts[wrong].T_cam_obj, axes[0], 2.6f);  // 150 deg
  const TrackResult r = tracker.start(s.frames[0], starts);
  for (const std::size_t k : cans) {
    const TrackedObject& o = r.objects[k];
    const double e = pose_error(o.T_cam_obj, s.gt[0][k], s.models[std::size_t(o.model)]);
    INFO("can " << k << ": " << std::string(to_string(o.state)) << ", error " << e * 1e3 << " mm, appearance "
                << o.appearance);
    CHECK(o.state == TrackState::Tracking);
    CHECK(e < 0.01);
  }
}

TEST_CASE("Tracker: a look-alike put in a tracked can's place is not followed") {
  // A can (cola print) and a box; at frame 10 the can is swapped for the same can with another print
  // (cherry) at the same pose: the cola can is gone, its pose must not stay confident. Without the swap
  // (the control) it is tracked throughout.
  for (const int swap_to : {-1, 1}) {
    const Sequence s = make_sequence(11, {0, 5}, 24, 1.f, 10, Eigen::Vector3f::Zero(), swap_to);
    Tracker<thrust_omp::Backend> tracker(sixdof_models(s.models), test_settings());
    tracker.start(s.frames[0], starts_at(s, 0));
    int confident_after = 0;
    for (std::size_t f = 1; f < s.frames.size(); ++f) {
      const TrackResult r = tracker.update(s.frames[f]);
      const TrackedObject& o = r.objects[0];
      INFO("swap " << swap_to << ", frame " << f << ": " << std::string(to_string(o.state)) << ", score "
                   << o.score << ", colour outliers " << o.cost.rendered_color_outliers << " of "
                   << o.cost.rendered_points);
      if (f < 10) CHECK(o.state == TrackState::Tracking);
      if (f >= 13) confident_after += o.state != TrackState::Lost;
      CHECK(r.objects[1].state != TrackState::Lost);
    }
    if (swap_to < 0)
      CHECK(confident_after == int(s.frames.size()) - 13);
    else
      CHECK(confident_after == 0);
  }
}

TEST_CASE("Tracker: the move rules measure the object's own move, not the camera-frame motion") {
  // A box 0.43 m from the camera, lost under the occluder at the start with its pose turned 7 deg about its
  // own origin: refined in the next frame, the turn is undone and the origin barely moves, so it is
  // recovered (as a camera-frame motion, the turn's lever arm alone is over 4 cm, beyond the 3 cm limit).
  const Sequence s = make_sequence(5, {5, 7}, 4, 0.5f);
  TrackSettings ts = test_settings();
  ts.recovery.per_frame = 0;  // recovered by the refinement alone
  Tracker<thrust_omp::Backend> tracker(sixdof_models(s.models), ts);
  std::vector<TrackStart> starts = starts_at(s, 0);
  starts[0].T_cam_obj = starts[0].T_cam_obj * turn(0, 0.12f);
  RgbdFrame blank = s.frames[0];
  std::fill(blank.depth_m.data.begin(), blank.depth_m.data.end(), 0.f);
  // The turn as a camera-frame motion moves 4 cm (the lever arm to the camera), the origin itself not.
  REQUIRE(track_detail::motion(starts[0].T_cam_obj, s.gt[0][0]).translation().norm() > 0.04f);
  CHECK(tracker.start(blank, starts).objects[0].state == TrackState::Lost);
  const TrackedObject o = tracker.update(s.frames[1]).objects[0];
  INFO(std::string(to_string(o.state)) << ", score " << o.score);
  CHECK(o.state == TrackState::Recovered);
  CHECK(pose_error(o.T_cam_obj, s.gt[1][0], s.models[std::size_t(o.model)]) < 0.01);

  // A tracked object the rounds move farther than max_track_move_m is lost at its prediction (here its
  // start, 2 cm off); with the default limit it is tracked.
  for (const float limit : {0.005f, 0.06f}) {
    TrackSettings t2 = test_settings();
    t2.max_track_move_m = limit;
    Tracker<thrust_omp::Backend> t(sixdof_models(s.models), t2);
    std::vector<TrackStart> off = starts_at(s, 0);
    off[0].T_cam_obj.translation().y() += 0.02f;
    const TrackedObject a = t.start(s.frames[0], off).objects[0];
    INFO("limit " << limit << ": " << std::string(to_string(a.state)));
    if (limit < 0.01f) {
      CHECK(a.state == TrackState::Lost);
      CHECK((a.T_cam_obj.translation() - off[0].T_cam_obj.translation()).norm() < 1e-4);
    } else {
      CHECK(a.state == TrackState::Tracking);
      CHECK(pose_error(a.T_cam_obj, s.gt[0][0], s.models[std::size_t(a.model)]) < 0.01);
    }
  }
}

TEST_CASE("Tracker: a start on a look-alike with another print is lost from the start") {
  // A cola can stands on the table; the tracker starts a cherry can (same shape, another print, a red
  // label between silver rims too) on it. Its geometry and colours pass the check; its print correlates
  // less than the cola's (TrackSettings::min_appearance, here set between the two; the default 0.1 was
  // measured on generated videos, whose look-alikes correlate below 0). A lime bottle started as a malt
  // one fails the check's colours already.
  const Sequence s = make_sequence(11, {0, 5}, 3, 1.f);
  std::size_t can = 0;
  while (s.model[can] != 0) ++can;
  std::vector<SixDofModel> models = sixdof_models(s.models);
  models.push_back(sixdof_models({synth::builtin_models()[1]})[0]);  // can_cherry
  for (const float min_appearance : {-1.f, 0.52f})
    for (const bool lookalike : {false, true}) {
      TrackSettings ts = test_settings();
      ts.min_appearance = min_appearance;
      Tracker<thrust_omp::Backend> tracker(models, ts);
      std::vector<TrackStart> starts = starts_at(s, 0);
      if (lookalike) starts[can].model = int(models.size()) - 1;
      const TrackedObject o = tracker.start(s.frames[0], starts).objects[can];
      INFO("min_appearance " << min_appearance << ", look-alike " << lookalike << ": "
                             << std::string(to_string(o.state)) << ", score " << o.score << ", appearance "
                             << o.appearance);
      CHECK(o.score > 0.7f);
      if (lookalike)
        CHECK(o.appearance < 0.5f);
      else
        CHECK(o.appearance > 0.55f);
      CHECK((o.state == TrackState::Lost) == (lookalike && min_appearance > 0.f));
    }
}

TEST_CASE("Tracker refuses bad input with the input named") {
  const Sequence s = make_sequence(2, {7}, 2, 1.f);
  const auto models = sixdof_models(s.models);
  Tracker<cpu::Backend> tracker(models);
  CHECK_THROWS_WITH_AS(tracker.update(s.frames[1]), doctest::Contains("start() first"), InvalidInput);
  CHECK_THROWS_WITH_AS(tracker.start(s.frames[0], {}), doctest::Contains("no objects"), InvalidInput);
  CHECK_THROWS_WITH_AS(tracker.start(s.frames[0], {{3, Pose::Identity()}}), doctest::Contains("model 3"),
                       InvalidInput);
  Pose nan = Pose::Identity();
  nan.translation().x() = NAN;
  CHECK_THROWS_WITH_AS(tracker.start(s.frames[0], {{0, nan}}), doctest::Contains("not finite"), InvalidInput);
  tracker.start(s.frames[0], starts_at(s, 0));
  RgbdFrame bad = s.frames[1];
  bad.depth_m.data[100] = NAN;
  CHECK_THROWS_WITH_AS(tracker.update(bad), doctest::Contains("tracking frame 1"), InvalidInput);
  RgbdFrame smaller;
  smaller.camera = {150.f, 150.f, 79.5f, 59.5f, 160, 120};
  smaller.depth_m = DepthImage(160, 120, 0.f);
  CHECK_THROWS_WITH_AS(tracker.update(smaller), doctest::Contains("camera differs"), InvalidInput);
  CHECK_THROWS_WITH_AS(Tracker<cpu::Backend>({}), doctest::Contains("no models"), InvalidInput);
  TrackSettings ts;
  ts.rounds.clear();
  CHECK_THROWS_WITH_AS(Tracker<cpu::Backend>(models, ts), doctest::Contains("rounds"), InvalidInput);
  ts = {};
  ts.rounds[0].gicp.k_neighbors = 1;
  CHECK_THROWS_WITH_AS(Tracker<cpu::Backend>(models, ts), doctest::Contains("rounds[0].gicp"), InvalidInput);
  ts = {};
  ts.min_visible_ratio = 1.5f;
  CHECK_THROWS_WITH_AS(Tracker<cpu::Backend>(models, ts), doctest::Contains("min_visible_ratio"),
                       InvalidInput);
  ts = {};
  ts.recovery.refinements = 0;
  CHECK_THROWS_WITH_AS(Tracker<cpu::Backend>(models, ts), doctest::Contains("recovery.refinements"),
                       InvalidInput);
  ts = {};
  ts.recovery.max_jump_m = NAN;
  CHECK_THROWS_WITH_AS(Tracker<cpu::Backend>(models, ts), doctest::Contains("recovery.max_jump_m"),
                       InvalidInput);
  ts = {};
  ts.turn_hold.sweep_turns = 1;
  CHECK_THROWS_WITH_AS(Tracker<cpu::Backend>(models, ts), doctest::Contains("turn_hold.sweep_turns"),
                       InvalidInput);
  ts = {};
  ts.turn_hold.sweep_min_gain = -0.1f;
  CHECK_THROWS_WITH_AS(Tracker<cpu::Backend>(models, ts), doctest::Contains("turn_hold.sweep_min_gain"),
                       InvalidInput);
  ts = {};
  ts.max_track_move_m = 0.f;
  CHECK_THROWS_WITH_AS(Tracker<cpu::Backend>(models, ts), doctest::Contains("max_track_move_m"),
                       InvalidInput);
  ts = {};
  ts.max_points_per_object = -1;
  CHECK_THROWS_WITH_AS(Tracker<cpu::Backend>(models, ts), doctest::Contains("max_points_per_object"),
                       InvalidInput);
  ts = {};
  ts.min_appearance = 1.5f;
  CHECK_THROWS_WITH_AS(Tracker<cpu::Backend>(models, ts), doctest::Contains("min_appearance"), InvalidInput);
  // A valid frame after the refused ones still tracks.
  CHECK(tracker.update(s.frames[1]).objects.size() == 1);
}
