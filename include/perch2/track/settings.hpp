// Tracking's public types: the settings of the per-frame update and of the lost rule, the state of each
// tracked object, and what update() returns.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/registration/registration.hpp"
#include "perch2/search/sixdof/settings.hpp"

namespace perch2 {

/// tracking: the pose explains the frame; lost: it does not (hidden, out of view, or the object moved
/// away), the pose is a prediction and must not be acted on; recovered: found again this frame after
/// being lost (tracking from the next frame on).
enum class TrackState : std::uint8_t { Tracking, Lost, Recovered };

inline const char* to_string(TrackState s) {
  return s == TrackState::Tracking ? "tracking" : s == TrackState::Lost ? "lost" : "recovered";
}

/// Where tracking of one object starts: a model and its pose in the start frame (from any global search,
/// or given).
struct TrackStart {
  int model = 0;
  Pose T_cam_obj = Pose::Identity();
};

/// One refinement round of the update: the objects rendered at their current poses, the frame's readings
/// around them assigned to the nearest silhouette, GICP of each object onto its readings.
struct TrackRound {
  /// Readings up to this many pixels outside an object's predicted silhouette are its candidates (the
  /// prediction's error in the image), pixels.
  int margin_px = 24;
  /// Readings farther than this in depth from the object's rendered depth (at their cell; in the margin at
  /// the nearest cell of its silhouette) are not its own (an occluder in front, the table or the room
  /// behind), metres.
  float depth_gate_m = 0.04f;
  GicpSettings gicp;
};

/// Each frame, printed objects are turned about their flat axes by the appearance
/// (perch2/track/turn_hold.hpp).
struct TurnHoldSettings {
  int levels = 2;           ///< turns by +-step_rad, then halved, ... (0: off), >= 0
  float step_rad = 0.035f;  ///< the first level's turn, radians (2 deg): a frame's wander is smaller
  int stride = 2;           ///< render stride of the comparison, >= 1
  float min_gain = 0.005f;  ///< a turn must raise the appearance correlation by this to be taken, >= 0
  float depth_tolerance_m = 0.01f;  ///< a rendered point is compared where the reading lies this near, metres
  /// The sweep: a whole turn, for a turn that is wrong by more than the hold can climb (a search's start
  /// on a partly hidden can, whose print showed little). One tracked object per update, each at most every
  /// sweep_every_frames (0: never), is turned about its flat axes by 2 pi k / sweep_turns at sweep_stride;
  /// the best turn is taken if its appearance beats the pose's by sweep_min_gain.
  int sweep_every_frames = 10;   ///< >= 0
  int sweep_turns = 36;          ///< >= 2 (every 10 deg; the hold climbs the rest)
  int sweep_stride = 2;          ///< >= 1
  float sweep_min_gain = 0.05f;  ///< >= 0
};

/// How a lost object is found again: the 6-DoF search without masks (SixDofEstimator::estimate_scene with
/// that one object) over a window of the frame around its last pose, then over the whole frame, with the
/// readings of the objects still tracked withheld. A search costs a few hundred milliseconds, so few are
/// run per update and each object waits between its searches; the found pose is refined and checked in
/// the same frame as a tracked one and is `recovered` only if the check passes the recovery rule.
struct RecoverySettings {
  int per_frame = 1;     ///< searches in one update at most (the longest waiting first), >= 0 (0: no search)
  int every_frames = 4;  ///< frames an object waits between its searches, >= 1
  int window_searches = 2;  ///< searches in the window before the whole frame is searched, >= 0
  /// The window: a disc around the last pose's projected centre, of radius this times the model's radius
  /// in pixels there plus window_margin_px (the object moved while lost, or was lost because the pose slid).
  float window_factor = 2.f;
  int window_margin_px = 40;  ///< pixels, >= 0
  /// A window with fewer readings than this is not searched (the object is out of view), >= 1.
  int min_window_readings = 200;
  /// Refinements of a found pose (TrackSettings::rounds each), >= 1: the recovery rule's move
  /// (max_recovery_move_m) is that of the last one, so a search's pose a few centimetres off may converge
  /// first. Generated videos (seeds 901, 903; background search, two runs each): ADD(-S) 84.1-84.7 with one,
  /// 87.0-88.8 with two.
  int refinements = 2;
  /// A pose found farther than this from where the object was lost (its coasted pose) is taken only if
  /// the frame contradicts that old place: more than contradicted_fraction of what shows of the object
  /// rendered there has readings behind it (it left; hidden there, it is taken to be there still).
  float max_jump_m = 0.1f;              ///< metres, > 0
  float contradicted_fraction = 0.25f;  ///< in [0, 1]
  /// Run the search in a background thread (its OpenMP threads share the cores with the update): the
  /// updates go on at their rate and the answer, found on an earlier frame, is moved into the current one
  /// by the camera's motion since (from the tracked object nearest to it). false: in update() itself, which
  /// then takes as long as the search (reproducible; tests).
  bool background = true;
  /// The search's settings (SixDofEstimator), cheaper than the single-frame search's, as a search repeats
  /// every few frames, the check rejects what it gets wrong and, in the background, it takes the cores
  /// from the updates: 12 viewpoints at one depth (GICP closes the rest), the screen (ScreenSettings) on,
  /// and a coarser turn search (the tracker's sweep turns a can's label right). Whole-frame searches on 640
  /// x 480 frames 0.37 -> 0.26 s on average, the same answers; generated videos in the background (seeds
  /// 901, 903, 905): update p95 47-54 -> 35-49 ms, ADD(-S) within the runs' spread (docs/tracking.md).
  SixDofSettings search = [] {
    SixDofSettings s;
    s.proposals.viewpoints = 12;
    s.proposals.max_depths = 1;
    s.screen.in_scene = true;
    s.local.turns.fine_turns = 72, s.local.turns.final_stride = 2;
    return s;
  }();
};

struct TrackSettings {
  int render_stride = 4;    ///< renders of the tracked objects sample full-resolution pixels (s i, s j), >= 1
  int observed_stride = 4;  ///< the frame's readings on this grid are the registration targets, >= 1
  /// The rounds' GICP takes at most this many of an object's rendered points and of its readings (every
  /// k-th; 0: all): a near box had 1,500 of 2,900 in a frame. Generated videos (seeds 901, 903, 905): the
  /// refinement 17 -> 13.6 ms on 5 objects at 0.6 m, ADD(-S) the same or better (docs/tracking.md). >= 0.
  int max_points_per_object = 500;
  /// The rounds of each update: a wide one for the prediction's error, then a tight one.
  std::vector<TrackRound> rounds = [] {
    TrackRound wide;
    wide.gicp.max_correspondence_distance_m = 0.03f;
    wide.gicp.icp_warmup_iterations = 4;
    wide.gicp.max_iterations = 10;
    TrackRound tight;
    tight.margin_px = 8;
    tight.depth_gate_m = 0.015f;
    tight.gicp.max_correspondence_distance_m = 0.01f;
    tight.gicp.max_iterations = 10;
    return std::vector<TrackRound>{wide, tight};
  }();
  TurnHoldSettings turn_hold;
  /// The check after the rounds: readings of the final silhouette (this margin and gate) against the
  /// render at the refined pose.
  int check_margin_px = 8;
  float check_depth_gate_m = 0.015f;
  CostSettings cost = [] {
    CostSettings c;
    c.delta_m = 0.01f;
    return c;
  }();
  float occlusion_margin_m = 0.01f;  ///< a reading nearer by more than this hides a rendered point, metres
  /// Constant velocity in SE(3): the next pose is the last frame-to-frame motion applied again, scaled by
  /// this (1: all of it; 0: no prediction). In [0, 1].
  float velocity_factor = 1.f;
  /// A lost object's pose moves on with the motion of the tracked object nearest to it (the camera's
  /// motion, where the scene is still) as long as one is tracked; with none, with its own last motion for
  /// this many frames, then it stays, frames >= 0.
  int coast_frames = 30;
  /// An object with fewer readings than this in its region is not refined this frame (coasts), >= 3.
  int min_segment_points = 20;
  // ---- the lost rule: a frame whose check fails any of these makes the object lost
  float min_score = 0.6f;  ///< pose_score of the check (explained fraction of both clouds), in [0, 1]
  /// The visible fraction (the part of the rendered silhouette, also outside the frame, in view and not
  /// hidden by a nearer reading) below this times the object's usual one (its running mean while tracked):
  /// an occluder passing in front, the object leaving the view. Relative, so that an object half hidden
  /// behind another all along is tracked. In [0, 1].
  float min_visible_ratio = 0.4f;
  int min_visible_points = 15;  ///< fewer visible rendered points than this (render stride) is lost, >= 0
  /// A printed object whose print correlates with the frame's colours below this (TrackedObject::appearance)
  /// is lost: a same-shape look-alike with another print, a wrong turn. A can or bottle is first swept
  /// through a whole turn (TurnHoldSettings). In [-1, 1]. Generated videos (seeds 901, 903, 905): 0.4 % of
  /// correct tracked frames below 0.1, 89 % of confident poses more than 5 cm off.
  float min_appearance = 0.1f;
  /// A lost object is recovered when its check passes with a score of at least this times its usual one
  /// (the running mean while tracked; stricter than min_score alone: it was found from a prediction, not
  /// followed), in [0, 1].
  float recover_ratio = 0.9f;
  /// A lost object is recovered only if the rounds moved it at most this far from where they started (its
  /// coasted prediction, or the search's pose): a lost pose refined far away has slid onto something else
  /// (a box's face onto the table it stood on), metres and radians (> 0).
  float max_recovery_move_m = 0.03f, max_recovery_turn_rad = 0.35f;
  /// A tracked object whose rounds moved its origin farther than this from its prediction has slid onto
  /// something else and is lost (the 99.9th percentile of correct tracks' moves on generated videos at
  /// 1.5-4 deg per frame: 2.6-2.8 cm; a 21 %-visible block recovered and then carried 8 cm), metres > 0.
  float max_track_move_m = 0.06f;
  RecoverySettings recovery;
};

/// One tracked object after a frame.
struct TrackedObject {
  int object = 0;  ///< index in the order of start()'s starts
  int model = 0;
  Pose T_cam_obj = Pose::Identity();
  TrackState state = TrackState::Tracking;
  /// pose_score of the check: the explained fraction of its rendered points and its readings, in [0, 1]
  /// (0 when lost without readings).
  float score = 0;
  float visible_fraction = 0;  ///< see TrackSettings::min_visible_ratio
  int visible_points = 0;      ///< rendered points in view and not hidden (render stride)
  int segment_points = 0;      ///< readings assigned to it in the check
  int frames_lost = 0;         ///< consecutive frames lost (0 while tracking)
  int searches = 0;            ///< searches run for it since it was lost (RecoverySettings)
  /// The check's correlation of the rendered print with the frame's colours (perch2/cost/appearance.hpp,
  /// unweighted, TurnHoldSettings::stride), in [-1, 1]; 0 for an unprinted model or when nothing varies.
  float appearance = 0;
  CostBreakdown cost;  ///< the check's cost
};

struct TrackTimings {  ///< seconds, wall clock, of one frame
  double predict = 0, render = 0, region = 0, refine = 0, check = 0, total = 0;
  double turn_hold = 0;  ///< the turn hold and the turn sweep (TurnHoldSettings)
  double search = 0;     ///< the recovery's searches and the check of what they found
};

struct TrackResult {
  std::vector<TrackedObject> objects;  ///< in start() order
  TrackTimings timings;
  int frame = 0;              ///< frames since start() (start() itself is frame 0)
  std::vector<int> searched;  ///< the objects searched for in this frame (RecoverySettings)
};

/// InvalidInput naming the field.
inline void validate(const TrackSettings& s) {
  auto positive = [](float x) { return std::isfinite(x) && x > 0.f; };
  auto fraction = [](float x) { return x >= 0.f && x <= 1.f; };
  if (s.render_stride < 1) throw InvalidInput("TrackSettings::render_stride", "must be >= 1");
  if (s.observed_stride < 1) throw InvalidInput("TrackSettings::observed_stride", "must be >= 1");
  if (s.rounds.empty()) throw InvalidInput("TrackSettings::rounds", "needs at least one round");
  for (std::size_t r = 0; r < s.rounds.size(); ++r) {
    const std::string who = "TrackSettings::rounds[" + std::to_string(r) + "]";
    if (s.rounds[r].margin_px < 0) throw InvalidInput(who + ".margin_px", "must be >= 0");
    if (!positive(s.rounds[r].depth_gate_m))
      throw InvalidInput(who + ".depth_gate_m", "must be finite and > 0");
    try {
      perch2::validate(s.rounds[r].gicp);
    } catch (const InvalidInput& e) {
      throw InvalidInput(who + ".gicp", e.what());
    }
  }
  if (s.turn_hold.levels < 0) throw InvalidInput("TrackSettings::turn_hold.levels", "must be >= 0");
  if (!positive(s.turn_hold.step_rad))
    throw InvalidInput("TrackSettings::turn_hold.step_rad", "must be finite and > 0");
  if (s.turn_hold.stride < 1) throw InvalidInput("TrackSettings::turn_hold.stride", "must be >= 1");
  if (!(std::isfinite(s.turn_hold.min_gain) && s.turn_hold.min_gain >= 0.f))
    throw InvalidInput("TrackSettings::turn_hold.min_gain", "must be finite and >= 0");
  if (!positive(s.turn_hold.depth_tolerance_m))
    throw InvalidInput("TrackSettings::turn_hold.depth_tolerance_m", "must be finite and > 0");
  if (s.turn_hold.sweep_every_frames < 0)
    throw InvalidInput("TrackSettings::turn_hold.sweep_every_frames", "must be >= 0");
  if (s.turn_hold.sweep_turns < 2) throw InvalidInput("TrackSettings::turn_hold.sweep_turns", "must be >= 2");
  if (s.turn_hold.sweep_stride < 1)
    throw InvalidInput("TrackSettings::turn_hold.sweep_stride", "must be >= 1");
  if (!(std::isfinite(s.turn_hold.sweep_min_gain) && s.turn_hold.sweep_min_gain >= 0.f))
    throw InvalidInput("TrackSettings::turn_hold.sweep_min_gain", "must be finite and >= 0");
  if (s.check_margin_px < 0) throw InvalidInput("TrackSettings::check_margin_px", "must be >= 0");
  if (!positive(s.check_depth_gate_m))
    throw InvalidInput("TrackSettings::check_depth_gate_m", "must be finite and > 0");
  if (!positive(s.cost.delta_m)) throw InvalidInput("TrackSettings::cost.delta_m", "must be finite and > 0");
  if (!(std::isfinite(s.occlusion_margin_m) && s.occlusion_margin_m >= 0.f))
    throw InvalidInput("TrackSettings::occlusion_margin_m", "must be finite and >= 0");
  if (!fraction(s.velocity_factor)) throw InvalidInput("TrackSettings::velocity_factor", "must be in [0, 1]");
  if (s.coast_frames < 0) throw InvalidInput("TrackSettings::coast_frames", "must be >= 0");
  if (s.min_segment_points < 3) throw InvalidInput("TrackSettings::min_segment_points", "must be >= 3");
  if (!fraction(s.min_score)) throw InvalidInput("TrackSettings::min_score", "must be in [0, 1]");
  if (!fraction(s.min_visible_ratio))
    throw InvalidInput("TrackSettings::min_visible_ratio", "must be in [0, 1]");
  if (s.min_visible_points < 0) throw InvalidInput("TrackSettings::min_visible_points", "must be >= 0");
  if (!(s.min_appearance >= -1.f && s.min_appearance <= 1.f))
    throw InvalidInput("TrackSettings::min_appearance", "must be in [-1, 1]");
  if (!fraction(s.recover_ratio)) throw InvalidInput("TrackSettings::recover_ratio", "must be in [0, 1]");
  if (!positive(s.max_recovery_move_m))
    throw InvalidInput("TrackSettings::max_recovery_move_m", "must be finite and > 0");
  if (s.max_points_per_object < 0)
    throw InvalidInput("TrackSettings::max_points_per_object", "must be >= 0 (0: all points)");
  if (!positive(s.max_track_move_m))
    throw InvalidInput("TrackSettings::max_track_move_m", "must be finite and > 0");
  if (!positive(s.max_recovery_turn_rad))
    throw InvalidInput("TrackSettings::max_recovery_turn_rad", "must be finite and > 0");
  const RecoverySettings& r = s.recovery;
  if (r.per_frame < 0) throw InvalidInput("TrackSettings::recovery.per_frame", "must be >= 0");
  if (r.every_frames < 1) throw InvalidInput("TrackSettings::recovery.every_frames", "must be >= 1");
  if (r.window_searches < 0) throw InvalidInput("TrackSettings::recovery.window_searches", "must be >= 0");
  if (!(std::isfinite(r.window_factor) && r.window_factor >= 0.f))
    throw InvalidInput("TrackSettings::recovery.window_factor", "must be finite and >= 0");
  if (r.window_margin_px < 0) throw InvalidInput("TrackSettings::recovery.window_margin_px", "must be >= 0");
  if (r.refinements < 1) throw InvalidInput("TrackSettings::recovery.refinements", "must be >= 1");
  if (!(std::isfinite(r.max_jump_m) && r.max_jump_m > 0.f))
    throw InvalidInput("TrackSettings::recovery.max_jump_m", "must be finite and > 0");
  if (!(r.contradicted_fraction >= 0.f && r.contradicted_fraction <= 1.f))
    throw InvalidInput("TrackSettings::recovery.contradicted_fraction", "must be in [0, 1]");
  if (r.min_window_readings < 1)
    throw InvalidInput("TrackSettings::recovery.min_window_readings", "must be >= 1");
}

}  // namespace perch2
