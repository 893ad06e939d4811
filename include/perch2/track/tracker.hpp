// Pose tracking over an RGB-D stream: the poses of known objects frame after frame, started by any of the
// global searches (or given poses), with a state per object that says when a pose must not be trusted.
//
//   perch2::Tracker<perch2::cuda::Backend> tracker({{mesh, symmetries}, ...});
//   tracker.start(frame0, perch2::track_starts(estimator.estimate_scene(frame0, objects)));
//   for (const RgbdFrame& f : stream)
//     for (const perch2::TrackedObject& o : tracker.update(f).objects)
//       if (o.state != perch2::TrackState::Lost) use(o.object, o.T_cam_obj, o.score);
//
// One update, every object at once (timed per stage in TrackResult::timings):
//   predict  constant velocity in SE(3): the last frame-to-frame motion (camera frame) applied again
//   rounds   (TrackSettings::rounds; a wide one for the prediction's error, then a tight one) render the
//            objects together at their poses on the render stride grid, assign the frame's readings around
//            them to the nearest silhouette within a depth gate (perch2/track/region.hpp; only cells near
//            the objects are visited), hide each render behind readings that are not its own (an
//            occluder, another object in front), and GICP each object's visible points onto its readings
//            (at most max_points_per_object of each)
//   turns    a printed can's turn about its axis, which GICP cannot see, is held by the appearance
//            (perch2/track/turn_hold.hpp, +-2 deg a frame) and, one object per frame, each every
//            sweep_every_frames, swept through a whole turn (a start or recovery facing its label away)
//   check    rendered at the refined poses, readings assigned tightly, the RGB-D cost: score = the
//            explained fraction of both clouds (the 6-DoF search's pose_score), visible fraction = the
//            part of the silhouette (also outside the frame) in view and not hidden
//   state    a check below min_score, min_visible_fraction or min_appearance (a printed object's print
//            against the frame's colours; a can is swept through a whole turn first), or a tracked pose
//            moved more than max_track_move_m from its prediction, makes the object lost: its pose coasts
//            with its last velocity (coast_frames), is refined from there every frame and is recovered
//            when a check passes recover_ratio of its usual score. A lost pose is a prediction, never a
//            confident answer.
//   search   a lost object is also searched for (RecoverySettings): the 6-DoF search without masks
//            over a window around its last pose, later over the whole frame, without the readings of
//            the objects still tracked; the found pose is refined and checked as above (and, far from
//            where the object was lost, taken only if the frame shows it left that place). Few searches per
//            update, spread over frames.
// The work per frame is bounded by the tracked objects' regions, independent of the catalogue.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <future>
#include <limits>
#include <memory>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/parallel.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/render/render.hpp"
#include "perch2/search/sixdof.hpp"
#include "perch2/track/region.hpp"
#include "perch2/track/settings.hpp"
#include "perch2/track/turn_hold.hpp"

namespace perch2 {

/// Tracking starts from a search's found poses (SixDofEstimator::estimate or estimate_scene or detect).
inline std::vector<TrackStart> track_starts(const std::vector<SixDofPose>& poses) {
  std::vector<TrackStart> out;
  for (const SixDofPose& p : poses)
    if (p.found) out.push_back({p.model, p.T_cam_obj});
  return out;
}
inline std::vector<TrackStart> track_starts(const SixDofResult& r) {
  return track_starts(r.poses);
}
inline std::vector<TrackStart> track_starts(const SixDofSceneResult& r) {
  return track_starts(r.poses);
}

namespace track_detail {

using Clock = std::chrono::steady_clock;
inline double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

/// The camera-frame motion that took T_from to T_to (T_to = motion * T_from).
inline Pose motion(const Pose& T_from, const Pose& T_to) {
  return T_to * T_from.inverse();
}

/// `m` scaled along its rotation angle and translation by f in [0, 1] (f = 1: m itself).
inline Pose scaled(const Pose& m, float f) {
  if (f == 1.f) return m;
  const Eigen::AngleAxisf aa(m.linear());
  Pose out = Pose::Identity();
  out.linear() = Eigen::AngleAxisf(aa.angle() * f, aa.axis()).toRotationMatrix();
  out.translation() = f * m.translation();
  return out;
}

/// How far the object's origin moved from T_from to T, metres: not the camera-frame motion's translation,
/// which holds a turn's lever arm (3 deg about the object's own centre at 0.9 m: 4.5 cm).
inline float origin_move_m(const Pose& T_from, const Pose& T) {
  return (T.translation() - T_from.translation()).norm();
}

inline Pose rigid(Pose T) {
  T.linear() = Eigen::Quaternionf(T.linear()).normalized().toRotationMatrix();
  return T;
}

/// `batch` with at most `max_points` of each cloud (every k-th point, k = ceil(size / max_points)); all of
/// it when max_points is 0 (TrackSettings::max_points_per_object).
inline CloudBatch thinned(const CloudBatch& batch, int max_points) {
  if (max_points <= 0) return batch;
  CloudBatch out;
  for (std::size_t c = 0; c < batch.num_clouds(); ++c) {
    const std::size_t n = batch.cloud_size(c),
                      step = std::max<std::size_t>(
                          1, (n + std::size_t(max_points) - 1) / std::size_t(max_points));
    for (auto i = std::size_t(batch.offsets[c]); i < std::size_t(batch.offsets[c + 1]); i += step) {
      out.x.push_back(batch.x[i]), out.y.push_back(batch.y[i]), out.z.push_back(batch.z[i]);
      out.rgb.push_back(batch.rgb[i]), out.pixel.push_back(batch.pixel[i]);
      out.cloud.push_back(std::int32_t(c));
    }
    out.offsets.push_back(std::int64_t(out.size()));
  }
  return out;
}

inline bool same_camera(const Intrinsics& a, const Intrinsics& b) {
  return a.width == b.width && a.height == b.height && a.fx == b.fx && a.fy == b.fy && a.cx == b.cx &&
         a.cy == b.cy;
}

}  // namespace track_detail

template <class Backend>
class Tracker {
 public:
  /// Validates the models and settings and uploads the models to the backend's renderer. Throws
  /// InvalidInput on no models, a bad mesh or bad settings.
  explicit Tracker(std::vector<SixDofModel> models, TrackSettings settings = {})
      : models_(std::move(models)),
        settings_(std::move(settings)),
        renderer_(meshes(models_)),
        search_(std::make_unique<SixDofEstimator<Backend>>(models_, settings_.recovery.search)) {
    validate(settings_);
    for (const SixDofModel& m : models_) {
      flat_axes_.push_back(track_detail::flat_axes(m.mesh)),
          printed_.push_back(track_detail::printed(m.mesh));
      float r = 0.f;
      for (const Eigen::Vector3f& p : m.mesh.vertices) r = std::max(r, p.norm());
      radius_m_.push_back(r);
    }
  }

  /// Waits for a background search.
  ~Tracker() { drop_search(); }
  Tracker(Tracker&&) = default;
  Tracker& operator=(Tracker&&) =
      delete;  ///< the old tracker's background search would outlive its estimator

  const TrackSettings& settings() const { return settings_; }
  /// Changed settings are validated by the next start() or update().
  TrackSettings& settings() { return settings_; }
  const std::vector<SixDofModel>& models() const { return models_; }
  /// The tracked objects after the last frame (empty before start()).
  const std::vector<TrackedObject>& objects() const { return last_.objects; }

  /// Starts tracking `starts` (forgetting what was tracked): the poses are refined on `frame` as by
  /// update() (with no motion) and checked, so a start that does not explain the frame is lost from the
  /// start. Throws InvalidInput on a malformed frame, no starts, an unknown model or a non-finite pose.
  TrackResult start(const RgbdFrame& frame, const std::vector<TrackStart>& starts) {
    validate(settings_);
    frame.validate("tracking start frame");
    if (starts.empty()) throw InvalidInput("tracking starts", "no objects to track");
    for (std::size_t i = 0; i < starts.size(); ++i) {
      const std::string who = "tracking start " + std::to_string(i);
      if (starts[i].model < 0 || std::size_t(starts[i].model) >= models_.size())
        throw InvalidInput(who, "model " + std::to_string(starts[i].model) + " is not one of the " +
                                    std::to_string(models_.size()) + " models");
      if (!starts[i].T_cam_obj.matrix().allFinite()) throw InvalidInput(who, "pose is not finite");
    }
    drop_search();
    camera_ = frame.camera;
    states_.clear();
    for (std::size_t i = 0; i < starts.size(); ++i) {
      State s;
      s.out.object = int(i), s.out.model = starts[i].model;
      s.out.T_cam_obj = track_detail::rigid(starts[i].T_cam_obj);
      states_.push_back(s);
    }
    frame_ = 0;
    return step(frame);
  }

  /// Tracks every object into `frame` (see the file comment). Throws InvalidInput before start(), on a
  /// malformed frame or one whose camera differs from the start frame's, and on bad settings.
  TrackResult update(const RgbdFrame& frame) {
    if (states_.empty()) throw InvalidInput("Tracker::update", "call start() first");
    validate(settings_);
    frame.validate("tracking frame " + std::to_string(frame_ + 1));
    if (!track_detail::same_camera(frame.camera, camera_))
      throw InvalidInput("tracking frame " + std::to_string(frame_ + 1),
                         "its camera differs from the start frame's (" + std::to_string(frame.camera.width) +
                             "x" + std::to_string(frame.camera.height) + " vs " +
                             std::to_string(camera_.width) + "x" + std::to_string(camera_.height) +
                             " or other intrinsics): start() again");
    ++frame_;
    return step(frame);
  }

 private:
  static constexpr int kNever = -1000000;  ///< a frame long before any
  struct State {
    TrackedObject out;
    Pose velocity = Pose::Identity();  ///< the last frame-to-frame motion, camera frame
    float usual_visible = -1.f;        ///< running mean of the visible fraction while tracked (-1: none yet)
    float usual_score = -1.f;          ///< running mean of the score while tracked (-1: none yet)
    int next_search = 1;               ///< frames_lost at which it may be searched for again
    int last_search = -1;              ///< frame of its last search launch (-1: none since it was lost)
    int last_sweep = kNever;           ///< frame of its last turn sweep (TurnHoldSettings)
  };

  static std::vector<Mesh> meshes(const std::vector<SixDofModel>& models) {
    if (models.empty()) throw InvalidInput("tracking models", "no models given");
    std::vector<Mesh> out;
    for (const auto& m : models) out.push_back(m.mesh);
    return out;
  }

  /// Renders every object at `poses` through the padded camera.
  CloudBatch render(const std::vector<Pose>& poses, const track_detail::PaddedCamera& pc,
                    TrackTimings& t) const {
    const auto t0 = track_detail::Clock::now();
    std::vector<Hypothesis> hyps(states_.size());
    for (std::size_t i = 0; i < hyps.size(); ++i)
      hyps[i].model = states_[i].out.model, hyps[i].T_cam_obj = poses[i];
    RenderSettings rs;
    rs.stride = settings_.render_stride;
    CloudBatch out = renderer_.render(hyps, pc.camera, rs);
    t.render += track_detail::seconds_since(t0);
    return out;
  }

  /// One round: readings assigned around the renders at `poses`, each object with enough of them refined
  /// by GICP (poses moved).
  void round(const RgbdFrame& frame, const TrackRound& r, const track_detail::PaddedCamera& pc,
             std::vector<Pose>& poses, TrackTimings& t) const {
    const CloudBatch rendered = render(poses, pc, t);
    auto t0 = track_detail::Clock::now();
    track_detail::Regions regions(rendered, pc, settings_.render_stride, lost());
    regions.grow(r.margin_px, r.depth_gate_m);
    const int cap = settings_.max_points_per_object;
    const CloudBatch targets = track_detail::thinned(regions.segments(frame, settings_.observed_stride), cap);
    const CloudBatch visible =
        track_detail::thinned(regions.visible(rendered, pc, frame, settings_.occlusion_margin_m), cap);
    t.region += track_detail::seconds_since(t0);
    t0 = track_detail::Clock::now();
    // Only objects with enough readings and visible points are refined (the others coast).
    CloudBatch sources;
    std::vector<std::int32_t> segment;
    std::vector<std::size_t> object;
    for (std::size_t c = 0; c < states_.size(); ++c) {
      if (targets.cloud_size(c) < std::size_t(settings_.min_segment_points) ||
          visible.cloud_size(c) < std::size_t(std::max(r.gicp.min_inliers, 3)))
        continue;
      for (auto i = std::size_t(visible.offsets[c]); i < std::size_t(visible.offsets[c + 1]); ++i) {
        sources.x.push_back(visible.x[i]), sources.y.push_back(visible.y[i]),
            sources.z.push_back(visible.z[i]);
        sources.rgb.push_back(visible.rgb[i]), sources.pixel.push_back(visible.pixel[i]);
        sources.cloud.push_back(std::int32_t(object.size()));
      }
      sources.offsets.push_back(std::int64_t(sources.size()));
      segment.push_back(std::int32_t(c)), object.push_back(c);
    }
    if (!object.empty()) {
      const auto registration =
          build_index(targets.size(), [&] { return typename Backend::Registration(targets); });
      const RegistrationResult res = registration.gicp(sources, segment, r.gicp);
      for (std::size_t k = 0; k < object.size(); ++k) {
        Pose& T = poses[object[k]];
        Pose moved = track_detail::rigid(res.T_corr[k] * T);
        for (const int axis : flat_axes_[std::size_t(states_[object[k]].out.model)])
          moved = track_detail::rigid(track_detail::without_turn(T, moved, axis));
        T = moved;
      }
    }
    t.refine += track_detail::seconds_since(t0);
  }

  /// The turn hold (TurnHoldSettings) of every printed object with a flat axis, at `poses` (moved).
  void hold_turns(const RgbdFrame& frame, std::vector<Pose>& poses, TrackTimings& t) const {
    const TurnHoldSettings& h = settings_.turn_hold;
    std::vector<std::size_t> held;
    for (std::size_t i = 0; i < states_.size(); ++i)
      if (const auto m = std::size_t(states_[i].out.model); printed_[m] && !flat_axes_[m].empty())
        held.push_back(i);
    if (held.empty() || frame.rgb.empty() || h.levels == 0) return;
    const auto t0 = track_detail::Clock::now();
    RenderSettings rs;
    rs.stride = h.stride;
    float step = h.step_rad;
    for (int level = 0; level < h.levels; ++level, step *= 0.5f) {
      // Per held object: its pose, then +-step about each flat axis.
      std::vector<Hypothesis> batch;
      std::vector<std::size_t> first;
      for (const std::size_t i : held) {
        first.push_back(batch.size());
        const int model = states_[i].out.model;
        batch.push_back({model, poses[i], -1});
        for (const int axis : flat_axes_[std::size_t(model)])
          for (const float sign : {-1.f, 1.f})
            batch.push_back({model, track_detail::turned(poses[i], axis, sign * step), -1});
      }
      first.push_back(batch.size());
      const CloudBatch rendered = renderer_.render(batch, frame.camera, rs);
      const std::vector<AppearanceSamples> samples = appearance_samples(rendered, frame, h.depth_tolerance_m);
      for (std::size_t k = 0; k < held.size(); ++k) {
        PrintVariation variation(frame.camera.width, h.stride);
        for (std::size_t b = first[k]; b < first[k + 1]; ++b) variation.add(samples[b]);
        float best = appearance_score(samples[first[k]], &variation).ncc + h.min_gain;
        for (std::size_t b = first[k] + 1; b < first[k + 1]; ++b)
          if (const float a = appearance_score(samples[b], &variation).ncc; a > best)
            best = a, poses[held[k]] = batch[b].T_cam_obj;
      }
    }
    t.turn_hold += track_detail::seconds_since(t0);
  }

  /// The turn sweep (TurnHoldSettings::sweep_*) of the tracked printed object with a flat axis whose last
  /// sweep is oldest, if that is sweep_every_frames ago: a whole turn about its flat axes (poses moved).
  void sweep_turns(const RgbdFrame& frame, std::vector<Pose>& poses, TrackTimings& t) {
    const TurnHoldSettings& h = settings_.turn_hold;
    std::size_t best_i = states_.size();
    for (std::size_t i = 0; i < states_.size(); ++i) {
      if (!sweepable(frame, i) || frame_ - states_[i].last_sweep < h.sweep_every_frames) continue;
      if (best_i == states_.size() || states_[i].last_sweep < states_[best_i].last_sweep) best_i = i;
    }
    if (best_i < states_.size()) sweep(frame, poses, best_i, t);
  }

  /// Whether object i may be swept: a tracked printed object with a flat axis, sweeps on, a colour frame.
  bool sweepable(const RgbdFrame& frame, std::size_t i) const {
    const auto m = std::size_t(states_[i].out.model);
    return settings_.turn_hold.sweep_every_frames > 0 && !frame.rgb.empty() && printed_[m] &&
           !flat_axes_[m].empty() && states_[i].out.state != TrackState::Lost;
  }

  /// Object i turned through a whole turn about its flat axes; the best turn is taken if its appearance
  /// beats the pose's by sweep_min_gain (poses[i] and the last pose moved).
  void sweep(const RgbdFrame& frame, std::vector<Pose>& poses, std::size_t best_i, TrackTimings& t) {
    const TurnHoldSettings& h = settings_.turn_hold;
    const auto t0 = track_detail::Clock::now();
    State& st = states_[best_i];
    st.last_sweep = frame_;
    std::vector<Hypothesis> batch{{st.out.model, poses[best_i], -1}};
    for (const int axis : flat_axes_[std::size_t(st.out.model)])
      for (int k = 1; k < h.sweep_turns; ++k)
        batch.push_back(
            {st.out.model,
             track_detail::turned(poses[best_i], axis, 2.f * 3.14159265f * float(k) / float(h.sweep_turns)),
             -1});
    RenderSettings rs;
    rs.stride = h.sweep_stride;
    const CloudBatch rendered = renderer_.render(batch, frame.camera, rs);
    const std::vector<AppearanceSamples> samples = appearance_samples(rendered, frame, h.depth_tolerance_m);
    PrintVariation variation(frame.camera.width, h.sweep_stride);
    for (const AppearanceSamples& a : samples) variation.add(a);
    const float own = appearance_score(samples[0], &variation).ncc;
    float best = own + h.sweep_min_gain;
    std::size_t chosen = 0;
    for (std::size_t b = 1; b < batch.size(); ++b)
      if (const float a = appearance_score(samples[b], &variation).ncc; a > best) best = a, chosen = b;
    if (chosen > 0) {
      // A correction of the estimate, not a motion: the last pose turns with it, so that the velocity
      // (settle) does not repeat the turn on the next frame.
      st.out.T_cam_obj.linear() =
          st.out.T_cam_obj.linear() * (poses[best_i].linear().transpose() * batch[chosen].T_cam_obj.linear());
      poses[best_i] = batch[chosen].T_cam_obj;
    }
    t.turn_hold += track_detail::seconds_since(t0);
  }

  /// The check at `poses`: per object its cost, score, visible fraction and readings. Returns the check's
  /// assignment of the readings.
  track_detail::Regions check(const RgbdFrame& frame, const track_detail::PaddedCamera& pc,
                              const std::vector<Pose>& poses, std::vector<TrackedObject>& out,
                              TrackTimings& t) const {
    const CloudBatch rendered = render(poses, pc, t);
    const auto t0 = track_detail::Clock::now();
    track_detail::Regions regions(rendered, pc, settings_.render_stride, lost());
    regions.grow(settings_.check_margin_px, settings_.check_depth_gate_m);
    const CloudBatch targets = regions.segments(frame, settings_.observed_stride);
    const CloudBatch visible = regions.visible(rendered, pc, frame, settings_.occlusion_margin_m);
    std::vector<CostBreakdown> costs(states_.size());
    if (targets.size() > 0) {
      const auto cost = build_index(targets.size(), [&] { return typename Backend::Cost(targets); });
      CostRequest request;
      for (std::size_t c = 0; c < states_.size(); ++c) request.add(std::int32_t(c));
      costs = cost.evaluate(visible, request, settings_.cost).hypotheses;
    }
    const std::vector<AppearanceScore> prints = print_agreement(frame, poses);
    for (std::size_t c = 0; c < states_.size(); ++c) {
      out[c].cost = costs[c];
      out[c].appearance = prints[c].ncc;
      out[c].segment_points = int(targets.cloud_size(c));
      out[c].score = targets.cloud_size(c) > 0 ? sixdof_detail::pose_score(costs[c]) : 0.f;
      const int all = regions.rendered_points(c);
      out[c].visible_fraction = all > 0 ? float(visible.cloud_size(c)) / float(all) : 0.f;
      out[c].visible_points = int(visible.cloud_size(c));
    }
    t.check += track_detail::seconds_since(t0);
    return regions;
  }

  /// Per object: its rendered print's correlation with the frame (unweighted, at TurnHoldSettings::stride);
  /// none for unprinted models or a frame without colour.
  std::vector<AppearanceScore> print_agreement(const RgbdFrame& frame, const std::vector<Pose>& poses) const {
    std::vector<AppearanceScore> out(states_.size());
    if (frame.rgb.empty()) return out;
    std::vector<Hypothesis> batch;
    std::vector<std::size_t> which;
    for (std::size_t i = 0; i < states_.size(); ++i)
      if (printed_[std::size_t(states_[i].out.model)])
        batch.push_back({states_[i].out.model, poses[i], -1}), which.push_back(i);
    if (batch.empty()) return out;
    RenderSettings rs;
    rs.stride = settings_.turn_hold.stride;
    const std::vector<AppearanceScore> scores = appearance_scores(
        renderer_.render(batch, frame.camera, rs), frame, settings_.turn_hold.depth_tolerance_m);
    for (std::size_t k = 0; k < which.size(); ++k) out[which[k]] = scores[k];
    return out;
  }

  /// Whether check `c` finds the print against the frame (TrackSettings::min_appearance; 0: nothing
  /// compared).
  bool print_disagrees(const TrackedObject& c) const {
    return c.appearance != 0.f && c.appearance < settings_.min_appearance;
  }

  /// The motion object i's prediction applies: its own last one while tracked; while lost, that of the
  /// tracked object nearest to it (`borrowed`: the camera's, if the scene around it is still; its own last
  /// one was measured while it was being hidden), or its own if none is tracked.
  const Pose& velocity_of(std::size_t i, bool& borrowed) const {
    borrowed = false;
    if (states_[i].out.state != TrackState::Lost) return states_[i].velocity;
    const Pose* out = &states_[i].velocity;
    float nearest = std::numeric_limits<float>::infinity();
    for (std::size_t j = 0; j < states_.size(); ++j) {
      if (states_[j].out.state == TrackState::Lost) continue;
      const float d =
          (states_[j].out.T_cam_obj.translation() - states_[i].out.T_cam_obj.translation()).norm();
      if (d < nearest) nearest = d, out = &states_[j].velocity, borrowed = true;
    }
    return *out;
  }

  /// Per object: lost (its render yields to the others' in the Regions).
  std::vector<bool> lost() const {
    std::vector<bool> out;
    for (const State& st : states_) out.push_back(st.out.state == TrackState::Lost);
    return out;
  }

  /// The lost rule (TrackSettings): does check `c` of `st` (at `T`, refined from `T_from`) pass? A tracked
  /// object must not have moved more than max_track_move_m in the rounds; a lost one must also reach
  /// recover_ratio of its usual score and have moved little (max_recovery_move_m, _turn_rad).
  bool passes(const State& st, const TrackedObject& c, const Pose& T_from, const Pose& T) const {
    const TrackSettings& s = settings_;
    const float usual = st.usual_visible < 0.f ? c.visible_fraction : st.usual_visible;
    const bool checked =
        c.segment_points >= s.min_segment_points && c.visible_points >= s.min_visible_points &&
        c.visible_fraction >= s.min_visible_ratio * usual && c.score >= s.min_score && !print_disagrees(c);
    const float moved_m = track_detail::origin_move_m(T_from, T);
    if (!checked || st.out.state != TrackState::Lost) return checked && moved_m <= s.max_track_move_m;
    const float turned_rad = Eigen::AngleAxisf(T.linear() * T_from.linear().transpose()).angle();
    return c.score >= s.recover_ratio * st.usual_score && moved_m <= s.max_recovery_move_m &&
           turned_rad <= s.max_recovery_turn_rad;
  }

  /// `st` after check `c`: tracking (or recovered) at `T` if it passed, else lost at `T`.
  static void settle(State& st, const TrackedObject& c, bool pass, const Pose& T) {
    const bool was_lost = st.out.state == TrackState::Lost;
    const Pose T_before = st.out.T_cam_obj;
    st.out.cost = c.cost, st.out.score = c.score, st.out.visible_fraction = c.visible_fraction;
    st.out.segment_points = c.segment_points, st.out.visible_points = c.visible_points;
    st.out.appearance = c.appearance;
    st.out.T_cam_obj = T;
    if (pass) {
      if (!was_lost) st.velocity = track_detail::motion(T_before, T);  // a lost one keeps its last
      auto running = [](float mean, float x) { return mean < 0.f ? x : 0.9f * mean + 0.1f * x; };
      st.usual_visible = running(st.usual_visible, c.visible_fraction);
      st.usual_score = running(st.usual_score, c.score);
      st.out.state = was_lost ? TrackState::Recovered : TrackState::Tracking;
      st.out.frames_lost = 0, st.out.searches = 0, st.next_search = 1, st.last_search = -1;
      if (was_lost) st.last_sweep = kNever;  // a search's or a coasted pose's turn: swept first
    } else {
      st.out.state = TrackState::Lost;
      ++st.out.frames_lost;
    }
  }

  /// A copy of `frame` with only the readings the search for lost object `i` may use: those in its window
  /// (RecoverySettings; the whole frame when `whole`) that no tracked object owns. `readings` counts them.
  RgbdFrame search_window(const RgbdFrame& frame, const track_detail::Regions& regions, std::size_t i,
                          bool whole, int& readings) const {
    const RecoverySettings& r = settings_.recovery;
    const Pose& T = states_[i].out.T_cam_obj;
    const Eigen::Vector3f c = T.translation();
    const Intrinsics& cam = frame.camera;
    whole = whole || c.z() < 0.05f;
    const Vec2f centre = whole ? Vec2f{0.f, 0.f} : cam.project({c.x(), c.y(), c.z()});
    const float radius_px =
        cam.fx * radius_m_[std::size_t(states_[i].out.model)] / std::max(c.z(), 0.05f) * r.window_factor +
        float(r.window_margin_px);
    RgbdFrame out = frame;
    readings = 0;
    for (int v = 0; v < cam.height; ++v)
      for (int u = 0; u < cam.width; ++u) {
        float& d = out.depth_m(u, v);
        if (d <= 0.f) continue;
        const float du = float(u) - centre.x, dv = float(v) - centre.y;
        const std::int32_t o = regions.owner_of(u, v, d);
        const bool owned =
            o >= 0 && std::size_t(o) != i && states_[std::size_t(o)].out.state != TrackState::Lost;
        if (owned || (!whole && du * du + dv * dv > radius_px * radius_px))
          d = 0.f;
        else
          ++readings;
      }
    return out;
  }

  /// Searches for the lost objects whose wait is over (RecoverySettings), the one waiting longest since its
  /// last search first: in the background (one search at a time; its answer is taken by the first update
  /// after it finished) or here. A found pose is moved into this frame, refined (with every object at its
  /// pose) and checked, and the object is recovered if the check passes. Changes the states and `result`.
  void recover(const RgbdFrame& frame, const track_detail::PaddedCamera& pc,
               const track_detail::Regions& regions, TrackResult& result) {
    const RecoverySettings& r = settings_.recovery;
    const auto t0 = track_detail::Clock::now();
    if (pending_.valid() && pending_.wait_for(std::chrono::seconds(0)) == std::future_status::ready) {
      const SixDofSceneResult found = pending_.get();
      place(frame, pc, launched_, found, result);
    }
    std::vector<std::size_t> due;
    for (std::size_t i = 0; i < states_.size(); ++i)
      if (states_[i].out.state == TrackState::Lost && states_[i].out.frames_lost >= states_[i].next_search &&
          !(pending_.valid() && launched_.object == i))
        due.push_back(i);
    // The one waiting longest since its last search (or since it was lost) first: an object lost for good
    // must not take every search from one lost later.
    auto waited = [&](std::size_t i) {
      const State& st = states_[i];
      return st.last_search < 0 ? st.out.frames_lost : frame_ - st.last_search;
    };
    std::stable_sort(due.begin(), due.end(),
                     [&](std::size_t a, std::size_t b) { return waited(a) > waited(b); });
    due.resize(std::min(due.size(), std::size_t(r.per_frame)));
    for (const std::size_t i : due) {
      if (pending_.valid()) break;  // one background search at a time
      State& st = states_[i];
      st.next_search = st.out.frames_lost + r.every_frames;
      st.last_search = frame_;
      ++st.out.searches;
      result.searched.push_back(int(i));
      int readings = 0;
      RgbdFrame window = search_window(frame, regions, i, st.out.searches > r.window_searches, readings);
      if (readings < r.min_window_readings) continue;
      Launch launch{i, frame_, {}, {}};
      for (const State& other : states_)
        launch.T_cam_obj.push_back(other.out.T_cam_obj),
            launch.tracked.push_back(other.out.state != TrackState::Lost);
      search_->settings() = r.search;
      const std::vector<SixDofObject> objects{{st.out.model, 1}};
      if (r.background) {
        launched_ = std::move(launch);
        pending_ =
            std::async(std::launch::async, [search = search_.get(), window = std::move(window), objects] {
              return search->estimate_scene(window, objects);
            });
      } else {
        place(frame, pc, launch, search_->estimate_scene(window, objects), result);
      }
    }
    result.timings.search += track_detail::seconds_since(t0);
  }

  /// A search launched on an earlier frame: which object, when, and every object's pose then.
  struct Launch {
    std::size_t object = 0;
    int frame = 0;
    std::vector<Pose> T_cam_obj;
    std::vector<bool> tracked;
  };

  /// The camera's motion since `launch`, from the tracked object nearest to `T` (the scene around a lost
  /// object is taken as still); identity when no object was tracked then and now.
  Pose motion_since(const Launch& launch, const Pose& T) const {
    Pose out = Pose::Identity();
    float nearest = std::numeric_limits<float>::infinity();
    for (std::size_t j = 0; j < states_.size(); ++j) {
      if (j == launch.object || !launch.tracked[j] || states_[j].out.state == TrackState::Lost) continue;
      const float d = (launch.T_cam_obj[j].translation() - T.translation()).norm();
      if (d < nearest) nearest = d, out = track_detail::motion(launch.T_cam_obj[j], states_[j].out.T_cam_obj);
    }
    return out;
  }

  /// A search's answer for `launch.object`, moved into `frame` (motion_since), refined with every object at
  /// its pose and checked: recovered if the check passes.
  void place(const RgbdFrame& frame, const track_detail::PaddedCamera& pc, const Launch& launch,
             const SixDofSceneResult& found, TrackResult& result) {
    State& st = states_[launch.object];
    if (st.out.state != TrackState::Lost || found.poses.empty() || !found.poses[0].found) return;
    Pose T = track_detail::rigid(found.poses[0].T_cam_obj);
    if (launch.frame != frame_) T = track_detail::rigid(motion_since(launch, T) * T);
    std::vector<Pose> poses;
    for (const State& other : states_) poses.push_back(other.out.T_cam_obj);
    poses[launch.object] = T;
    TrackTimings scratch;
    // A search's pose can lie 4-9 cm off (one depth, few viewpoints) and the rounds take it to within a few
    // millimetres in more than one go: refined `refinements` times, and the recovery rule's move is that of
    // the last (a pose sliding onto something else keeps moving; one that found its object stays).
    const int refinements = settings_.recovery.refinements;
    for (int pass = 0; pass < refinements; ++pass) {
      if (pass + 1 == refinements) T = poses[launch.object];
      for (const TrackRound& round_settings : settings_.rounds)
        round(frame, round_settings, pc, poses, scratch);
    }
    hold_turns(frame, poses, scratch);
    std::vector<TrackedObject> checked(states_.size());
    check(frame, pc, poses, checked, scratch);
    if (!passes(st, checked[launch.object], T, poses[launch.object])) return;
    if (!left_its_place(frame, pc, launch.object, poses, scratch)) return;
    --st.out.frames_lost;  // settle() counted this frame as lost once already
    settle(st, checked[launch.object], true, poses[launch.object]);
    result.objects[launch.object] = st.out;
  }

  /// Whether lost object i, found at poses[i], may be recovered there: yes when it is near where it was
  /// lost (RecoverySettings::max_jump_m from its coasted pose); farther only if the frame shows it is no
  /// longer at that old place: rendered there, more than contradicted_fraction of what shows of it has
  /// readings behind it. Hidden there (a hand in front), it is still taken to be there: a search finds
  /// look-alike surfaces (a plain block on the passing hand) more often than objects carried off unseen.
  bool left_its_place(const RgbdFrame& frame, const track_detail::PaddedCamera& pc, std::size_t i,
                      const std::vector<Pose>& poses, TrackTimings& t) const {
    const RecoverySettings& r = settings_.recovery;
    const Pose& T_old = states_[i].out.T_cam_obj;
    if ((poses[i].translation() - T_old.translation()).norm() <= r.max_jump_m) return true;
    std::vector<Pose> at_old = poses;
    at_old[i] = T_old;
    std::vector<TrackedObject> checked(states_.size());
    check(frame, pc, at_old, checked, t);
    const TrackedObject& c = checked[i];
    return c.visible_points >= settings_.min_visible_points &&
           float(c.cost.rendered_depth_outliers) > r.contradicted_fraction * float(c.visible_points);
  }

  /// Waits for a background search and forgets it (start() again, the tracker destroyed).
  void drop_search() {
    if (pending_.valid()) pending_.wait();
    pending_ = {};
  }

  TrackResult step(const RgbdFrame& frame) {
    const auto t_start = track_detail::Clock::now();
    const TrackSettings& s = settings_;
    TrackResult result;
    result.frame = frame_;
    // ---- predict
    auto t0 = track_detail::Clock::now();
    std::vector<Pose> predicted(states_.size()), poses(states_.size());
    for (std::size_t i = 0; i < states_.size(); ++i) {
      const State& st = states_[i];
      bool borrowed = false;
      const Pose& v = velocity_of(i, borrowed);
      const bool moving =
          st.out.state != TrackState::Lost || borrowed || st.out.frames_lost <= s.coast_frames;
      predicted[i] = moving
                         ? track_detail::rigid(track_detail::scaled(v, s.velocity_factor) * st.out.T_cam_obj)
                         : st.out.T_cam_obj;
    }
    poses = predicted;
    result.timings.predict = track_detail::seconds_since(t0);
    // ---- rounds, check
    const track_detail::PaddedCamera pc(frame.camera, s.render_stride);
    for (const TrackRound& r : s.rounds) round(frame, r, pc, poses, result.timings);
    hold_turns(frame, poses, result.timings);
    // Not in the frame that takes a background search's answer (its refinements are this frame's work).
    if (!(pending_.valid() && pending_.wait_for(std::chrono::seconds(0)) == std::future_status::ready))
      sweep_turns(frame, poses, result.timings);
    std::vector<TrackedObject> checked(states_.size());
    track_detail::Regions regions = check(frame, pc, poses, checked, result.timings);
    // A tracked can or bottle whose print disagrees may be turned wrong: swept now, and checked again.
    bool swept = false;
    for (std::size_t i = 0; i < states_.size(); ++i)
      if (sweepable(frame, i) && print_disagrees(checked[i]) && states_[i].last_sweep != frame_)
        sweep(frame, poses, i, result.timings), swept = true;
    if (swept) regions = check(frame, pc, poses, checked, result.timings);
    // ---- state: tracking objects must pass the check; lost ones must pass recover_ratio of their usual
    // score
    for (std::size_t i = 0; i < states_.size(); ++i) {
      State& st = states_[i];
      const TrackedObject& c = checked[i];
      const bool was_lost = st.out.state == TrackState::Lost;
      // A tracked pose refined onto readings is the best guess even when it fails the check; a lost one
      // coasts (refined onto what failed the check, it could wander off onto anything).
      const bool refined = c.segment_points >= s.min_segment_points && !was_lost &&
                           track_detail::origin_move_m(predicted[i], poses[i]) <= s.max_track_move_m;
      const bool pass = passes(st, c, predicted[i], poses[i]);
      settle(st, c, pass, pass || refined ? poses[i] : predicted[i]);
      result.objects.push_back(st.out);
    }
    recover(frame, pc, regions, result);
    result.timings.total = track_detail::seconds_since(t_start);
    last_ = result;
    return result;
  }

  std::vector<SixDofModel> models_;
  TrackSettings settings_;
  typename Backend::Renderer renderer_;
  /// The recovery's search (RecoverySettings); on the heap, so that a background search keeps it while
  /// the tracker is moved.
  std::unique_ptr<SixDofEstimator<Backend>> search_;
  std::future<SixDofSceneResult> pending_;   ///< the background search, if one runs
  Launch launched_;                          ///< what it was launched with
  std::vector<float> radius_m_;              ///< per model: the farthest vertex from its origin, metres
  std::vector<std::vector<int>> flat_axes_;  ///< per model: the turns GICP cannot see (track/turn_hold.hpp)
  std::vector<bool> printed_;                ///< per model: whose turns the turn hold holds
  std::vector<State> states_;
  Intrinsics camera_;
  int frame_ = 0;
  TrackResult last_;
};

}  // namespace perch2
