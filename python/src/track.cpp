// Tracking: perch2.Tracker over an RGB-D stream on the backend chosen by name, its settings, states and
// results (perch2/track/).
#include "common.hpp"
#include "perch2/cpu/estimators.hpp"
#include "perch2/cuda/estimators.hpp"
#include "perch2/track/tracker.hpp"

namespace perch2_py {

using namespace perch2;

namespace {

template <class B>
using TrackerOf = Tracker<B>;
using PyTracker = PerBackend<TrackerOf>;

/// Starts from TrackStart values, (model, 4 x 4 pose) pairs, or a SixDofResult / SixDofSceneResult.
std::vector<TrackStart> starts_from(nb::handle starts) {
  if (nb::isinstance<SixDofResult>(starts)) return track_starts(nb::cast<const SixDofResult&>(starts));
  if (nb::isinstance<SixDofSceneResult>(starts))
    return track_starts(nb::cast<const SixDofSceneResult&>(starts));
  std::vector<TrackStart> out;
  std::size_t k = 0;
  for (nb::handle s : starts) {
    const std::string who = "starts[" + std::to_string(k++) + "]";
    if (nb::isinstance<TrackStart>(s)) {
      out.push_back(nb::cast<TrackStart>(s));
      continue;
    }
    if (nb::isinstance<SixDofPose>(s)) {
      const auto& p = nb::cast<const SixDofPose&>(s);
      if (p.found) out.push_back({p.model, p.T_cam_obj});
      continue;
    }
    nb::sequence pair;
    if (!nb::try_cast(s, pair, false) || nb::len(pair) != 2)
      throw InvalidInput(who, "must be a perch2.TrackStart, a perch2.SixDofPose or (model, 4 x 4 pose)");
    int model = 0;
    if (!nb::try_cast(pair[0], model, false)) throw InvalidInput(who, "model must be an int");
    out.push_back({model, pose_from(pair[1], who + " pose")});
  }
  return out;
}

template <class T>
void pose_ro(nb::class_<T>& cls, const char* name, Pose T::*field, const char* key) {
  cls.def_prop_ro(
      name, [field](const T& x) { return pose_array(x.*field); }, nb::rv_policy::move,
      (std::string(doc(key)) + " (4 x 4 float32; a new array on each read)").c_str());
}

}  // namespace

void bind_track(nb::module_& m) {
  nb::enum_<TrackState> state(m, "TrackState", doc("TrackState"));
  PERCH2_ENUM(state, TrackState, Tracking);
  PERCH2_ENUM(state, TrackState, Lost);
  PERCH2_ENUM(state, TrackState, Recovered);

  nb::class_<TrackStart> start(m, "TrackStart", doc("TrackStart"));
  start.def(
      "__init__",
      [](TrackStart* self, int model, nb::handle T) {
        new (self) TrackStart{model, pose_from(T, "T_cam_obj")};
      },
      nb::arg("model"), nb::arg("T_cam_obj"));
  PERCH2_RW(start, TrackStart, model);
  start.def_prop_rw(
      "T_cam_obj", [](const TrackStart& s) { return pose_array(s.T_cam_obj); },
      [](TrackStart& s, nb::handle v) { s.T_cam_obj = pose_from(v, "T_cam_obj"); }, nb::rv_policy::move,
      "model -> camera, metres (4 x 4 float32; a new array on each read)");

  nb::class_<TrackRound> round(m, "TrackRound", doc("TrackRound"));
  round.def(nb::init<>());
  PERCH2_RW(round, TrackRound, margin_px);
  PERCH2_RW(round, TrackRound, depth_gate_m);
  round.def_rw("gicp", &TrackRound::gicp, "the round's GICP");

  nb::class_<TurnHoldSettings> hold(m, "TurnHoldSettings", doc("TurnHoldSettings"));
  hold.def(nb::init<>());
  PERCH2_RW(hold, TurnHoldSettings, levels);
  PERCH2_RW(hold, TurnHoldSettings, step_rad);
  PERCH2_RW(hold, TurnHoldSettings, stride);
  PERCH2_RW(hold, TurnHoldSettings, min_gain);
  PERCH2_RW(hold, TurnHoldSettings, depth_tolerance_m);
  PERCH2_RW(hold, TurnHoldSettings, sweep_every_frames);
  PERCH2_RW(hold, TurnHoldSettings, sweep_turns);
  PERCH2_RW(hold, TurnHoldSettings, sweep_stride);
  PERCH2_RW(hold, TurnHoldSettings, sweep_min_gain);

  nb::class_<RecoverySettings> rec(m, "RecoverySettings", doc("RecoverySettings"));
  rec.def(nb::init<>());
  PERCH2_RW(rec, RecoverySettings, per_frame);
  PERCH2_RW(rec, RecoverySettings, every_frames);
  PERCH2_RW(rec, RecoverySettings, window_searches);
  PERCH2_RW(rec, RecoverySettings, window_factor);
  PERCH2_RW(rec, RecoverySettings, window_margin_px);
  PERCH2_RW(rec, RecoverySettings, min_window_readings);
  PERCH2_RW(rec, RecoverySettings, refinements);
  PERCH2_RW(rec, RecoverySettings, max_jump_m);
  PERCH2_RW(rec, RecoverySettings, contradicted_fraction);
  PERCH2_RW(rec, RecoverySettings, background);
  PERCH2_RW(rec, RecoverySettings, search);

  nb::class_<TrackSettings> ts(m, "TrackSettings", doc("TrackSettings"));
  ts.def(nb::init<>());
  PERCH2_RW(ts, TrackSettings, render_stride);
  PERCH2_RW(ts, TrackSettings, observed_stride);
  PERCH2_RW(ts, TrackSettings, rounds);
  PERCH2_RW(ts, TrackSettings, turn_hold);
  PERCH2_RW(ts, TrackSettings, check_margin_px);
  PERCH2_RW(ts, TrackSettings, check_depth_gate_m);
  PERCH2_RW(ts, TrackSettings, cost);
  PERCH2_RW(ts, TrackSettings, occlusion_margin_m);
  PERCH2_RW(ts, TrackSettings, velocity_factor);
  PERCH2_RW(ts, TrackSettings, coast_frames);
  PERCH2_RW(ts, TrackSettings, min_segment_points);
  PERCH2_RW(ts, TrackSettings, min_score);
  PERCH2_RW(ts, TrackSettings, min_visible_ratio);
  PERCH2_RW(ts, TrackSettings, min_visible_points);
  PERCH2_RW(ts, TrackSettings, min_appearance);
  PERCH2_RW(ts, TrackSettings, recover_ratio);
  PERCH2_RW(ts, TrackSettings, max_recovery_move_m);
  PERCH2_RW(ts, TrackSettings, max_track_move_m);
  PERCH2_RW(ts, TrackSettings, max_points_per_object);
  PERCH2_RW(ts, TrackSettings, max_recovery_turn_rad);
  PERCH2_RW(ts, TrackSettings, recovery);

  nb::class_<TrackedObject> to(m, "TrackedObject", doc("TrackedObject"));
  PERCH2_RO(to, TrackedObject, object);
  PERCH2_RO(to, TrackedObject, model);
  pose_ro(to, "T_cam_obj", &TrackedObject::T_cam_obj, "TrackedObject.T_cam_obj");
  PERCH2_RO(to, TrackedObject, state);
  PERCH2_RO(to, TrackedObject, score);
  PERCH2_RO(to, TrackedObject, visible_fraction);
  PERCH2_RO(to, TrackedObject, visible_points);
  PERCH2_RO(to, TrackedObject, segment_points);
  PERCH2_RO(to, TrackedObject, frames_lost);
  PERCH2_RO(to, TrackedObject, searches);
  PERCH2_RO(to, TrackedObject, appearance);
  PERCH2_RO(to, TrackedObject, cost);
  to.def("__repr__", [](const TrackedObject& o) {
    return "TrackedObject(object=" + std::to_string(o.object) + ", model=" + std::to_string(o.model) +
           ", state=" + to_string(o.state) + ", score=" + std::to_string(o.score) + ")";
  });

  nb::class_<TrackTimings> tt(m, "TrackTimings", doc("TrackTimings"));
  for (auto [name, field] : {std::pair{"predict", &TrackTimings::predict},
                             {"render", &TrackTimings::render},
                             {"region", &TrackTimings::region},
                             {"refine", &TrackTimings::refine},
                             {"turn_hold", &TrackTimings::turn_hold},
                             {"check", &TrackTimings::check},
                             {"search", &TrackTimings::search},
                             {"total", &TrackTimings::total}})
    tt.def_ro(name, field, "seconds, wall clock, of one frame");

  nb::class_<TrackResult> tr(m, "TrackResult", doc("TrackResult"));
  PERCH2_RO(tr, TrackResult, objects);
  PERCH2_RO(tr, TrackResult, timings);
  PERCH2_RO(tr, TrackResult, frame);
  PERCH2_RO(tr, TrackResult, searched);

  m.def("track_starts", &starts_from, nb::arg("starts"),
        "Tracking starts from a SixDofResult / SixDofSceneResult (its found poses), SixDofPose values, "
        "TrackStart values or (model, 4 x 4 pose) pairs.");

  static const std::string tracker_doc =
      std::string(doc("file:perch2/track/tracker.hpp")) +
      "\n\nTracker(models, backend=\"thrust_omp\", settings=None): models as for SixDofEstimator.\n"
      "start(frame, starts) or start(depth, rgb, K, starts, depth_scale_m=None): starts as track_starts() "
      "takes.\n"
      "update(frame) or update(depth, rgb, K, depth_scale_m=None) -> TrackResult. The GIL is released while\n"
      "they run; a background recovery search (TrackSettings.recovery.background) goes on between calls.";
  nb::class_<PyTracker> tracker(m, "Tracker", tracker_doc.c_str());
  tracker
      .def(
          "__init__",
          [](PyTracker* self, nb::handle models, const std::string& backend,
             std::optional<TrackSettings> settings) {
            std::vector<SixDofModel> ms = sixdof_models(models);
            const BackendId id = parse_backend(backend);
            nb::gil_scoped_release release;
            new (self) PyTracker(backend_name(id), std::move(ms), settings.value_or(TrackSettings{}));
          },
          nb::arg("models"), nb::arg("backend") = "thrust_omp", nb::arg("settings").none() = nb::none())
      .def_prop_ro(
          "settings",
          [](PyTracker& t) -> TrackSettings& {
            return t.with([](auto& x) -> TrackSettings& { return x.settings(); });
          },
          nb::rv_policy::reference_internal,
          "The tracker's settings (a live reference: changes apply from the next start() or update(); nested "
          "settings such as settings.recovery.per_frame are settable in place).")
      .def_prop_ro("backend", [](const PyTracker& t) { return backend_name(t.backend); })
      .def_prop_ro(
          "objects", [](const PyTracker& t) { return t.with([](const auto& x) { return x.objects(); }); },
          "The tracked objects after the last frame (copies; empty before start()).")
      .def(
          "start",
          [](const PyTracker& t, const RgbdFrame& frame, nb::handle starts) {
            const std::vector<TrackStart> s = starts_from(starts);
            return t.call([&](auto& x) { return x.start(frame, s); });
          },
          nb::arg("frame"), nb::arg("starts"), doc("Tracker.start"))
      .def(
          "start",
          [](const PyTracker& t, nb::handle depth, nb::handle rgb, nb::handle K, nb::handle starts,
             std::optional<float> depth_scale_m) {
            const RgbdFrame frame = frame_from(depth, rgb, K, depth_scale_m);
            const std::vector<TrackStart> s = starts_from(starts);
            return t.call([&](auto& x) { return x.start(frame, s); });
          },
          nb::arg("depth"), nb::arg("rgb").none(), nb::arg("K"), nb::arg("starts"),
          nb::arg("depth_scale_m").none() = nb::none())
      .def(
          "update",
          [](const PyTracker& t, const RgbdFrame& frame) {
            return t.call([&](auto& x) { return x.update(frame); });
          },
          nb::arg("frame"), doc("Tracker.update"))
      .def(
          "update",
          [](const PyTracker& t, nb::handle depth, nb::handle rgb, nb::handle K,
             std::optional<float> depth_scale_m) {
            const RgbdFrame frame = frame_from(depth, rgb, K, depth_scale_m);
            return t.call([&](auto& x) { return x.update(frame); });
          },
          nb::arg("depth"), nb::arg("rgb").none(), nb::arg("K"),
          nb::arg("depth_scale_m").none() = nb::none());
}

}  // namespace perch2_py
