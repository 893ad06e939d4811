// Coarse-to-fine hill climbing over turns of poses, scored by the explanation cost: what decides a turn
// the geometry cannot see (a printed can or bottle about its axis). Shared by the 6-DoF local search
// (turns about the model's own axes, SixDofSettings::local) and the 3-DoF yaw search (turns about the
// table normal, TabletopSettings::yaw_search).
//
//   std::vector<CostBreakdown> c = climb_turns(poses, /*axes=*/3, /*swept_axes=*/1, schedule, turn, score);
//
// turn(pose, axis, angle_rad) returns the pose moved by angle_rad along axis (0 .. axes - 1, meaning the
// caller's: a turn about a model axis, or a shift scaled to the turn); score(poses) returns their costs,
// in order. Each pose is scored, then (sweep) turned once by 2 pi k / sweep_turns along each of the first
// swept_axes axes, then at each level moved by +-step along every axis, the step halving from level to
// level: a pose moves to its lowest-cost candidate when that lowers its total (and, with
// require_both_terms, raises neither term), repeatedly, at most moves_per_level times per level.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdlib>
#include <string>
#include <utility>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/cost/cost.hpp"

namespace perch2 {

/// Which turns climb_turns tries (see the file comment).
struct TurnSchedule {
  float rotation_step_rad = 0.3f;  ///< the first level's turn, radians (> 0)
  int levels = 4;                  ///< the step halves each level (>= 0)
  int moves_per_level = 3;         ///< most accepted turns per level (>= 0; a level ends at no improvement)
  /// Turns by 2 pi k / sweep_turns (k = 1 .. sweep_turns - 1) about each axis, tried once before the
  /// levels: the right turn can be further than the first step reaches. 0 or 1 = none (>= 0).
  int sweep_turns = 0;
  /// 1: the pose moves to the sweep's best turn (if that improves it) and climbs from there. n > 1: it
  /// climbs from itself and from its n - 1 best sweep turns (each more than one sweep step from the others
  /// on its axis) and ends at the best of those climbs: a label's right turn can score worse than a
  /// look-alike's turn until both are a step or two closer (>= 1).
  int sweep_starts = 1;
  /// A turn is taken only if it lowers the total without raising either term (rendered outliers,
  /// unexplained observed points): a turn that only trades one term for the other (e.g. a pose showing
  /// fewer points) is not a better fit, and an untextured object keeps its pose.
  bool require_both_terms = true;
};

/// Throws InvalidInput naming `who` unless the schedule is usable.
inline void validate(const TurnSchedule& s, const std::string& who) {
  if (!(std::isfinite(s.rotation_step_rad) && s.rotation_step_rad > 0))
    throw InvalidInput(who + ".rotation_step_rad", "must be finite and > 0");
  if (s.levels < 0 || s.moves_per_level < 0 || s.sweep_turns < 0)
    throw InvalidInput(who, "levels, moves_per_level and sweep_turns must be >= 0");
  if (s.sweep_starts < 1) throw InvalidInput(who + ".sweep_starts", "must be >= 1");
}

template <class P, class Turn, class Score>
std::vector<CostBreakdown> climb_turns(std::vector<P>& poses, int axes, int swept_axes, const TurnSchedule& s,
                                       Turn&& turn, Score&& score, std::size_t* candidates = nullptr);

/// climb_turns with sweep_starts > 1 (see TurnSchedule): sweeps, climbs from each pose and its best
/// distinct sweep turns, and keeps per pose the lowest-cost climb (that, with require_both_terms, raises
/// neither term of the pose). The sweep is ranked by sweep_score (e.g. a cheaper render of the same cost:
/// its values are only compared with each other), everything else by score.
template <class P, class Turn, class Score, class SweepScore>
std::vector<CostBreakdown> climb_from_sweep_starts(std::vector<P>& poses, int axes, int swept_axes,
                                                   const TurnSchedule& s, Turn&& turn, Score&& score,
                                                   SweepScore&& sweep_score,
                                                   std::size_t* candidates = nullptr) {
  const std::vector<CostBreakdown> original = score(poses);
  const int n = s.sweep_turns;
  std::vector<P> turned;
  for (const P& p : poses)
    for (int axis = 0; axis < swept_axes; ++axis)
      for (int k = 1; k < n; ++k) turned.push_back(turn(p, axis, 6.2831853f * float(k) / float(n)));
  if (candidates) *candidates += turned.size();
  const std::vector<CostBreakdown> c = sweep_score(turned);
  const std::size_t per_pose = std::size_t(swept_axes) * std::size_t(n - 1);
  std::vector<P> starts;
  std::vector<std::size_t> start_of;  // starts' pose
  for (std::size_t h = 0; h < poses.size(); ++h) {
    std::vector<std::size_t> order(per_pose);
    for (std::size_t i = 0; i < per_pose; ++i) order[i] = h * per_pose + i;
    std::stable_sort(order.begin(), order.end(),
                     [&](std::size_t a, std::size_t b) { return c[a].total < c[b].total; });
    // (axis, k) of the starts: the pose itself is k = 0 on every axis.
    std::vector<std::pair<int, int>> taken;
    for (int axis = 0; axis < swept_axes; ++axis) taken.push_back({axis, 0});
    starts.push_back(poses[h]), start_of.push_back(h);
    for (const std::size_t i : order) {
      if (int(taken.size()) - swept_axes + 1 >= s.sweep_starts) break;
      const int axis = int((i - h * per_pose) / std::size_t(n - 1)),
                k = int((i - h * per_pose) % std::size_t(n - 1)) + 1;
      const bool apart = std::none_of(taken.begin(), taken.end(), [&](const std::pair<int, int>& t) {
        const int d = std::abs(t.second - k);
        return t.first == axis && std::min(d, n - d) <= 1;
      });
      if (apart) taken.push_back({axis, k}), starts.push_back(turned[i]), start_of.push_back(h);
    }
  }
  TurnSchedule levels_only = s;
  levels_only.sweep_turns = 0;
  const std::vector<CostBreakdown> climbed =
      climb_turns(starts, axes, swept_axes, levels_only, turn, score, candidates);
  std::vector<CostBreakdown> out = original;
  for (std::size_t i = 0; i < starts.size(); ++i) {
    const std::size_t h = start_of[i];
    const bool both = climbed[i].rendered_outliers() <= original[h].rendered_outliers() &&
                      climbed[i].observed_unexplained() <= original[h].observed_unexplained();
    if (climbed[i].total < out[h].total && (!s.require_both_terms || both))
      poses[h] = starts[i], out[h] = climbed[i];
  }
  return out;
}

/// Moves every pose of `poses` by the schedule's hill climbing (see the file comment) and returns their
/// costs at the poses found. `candidates`, if given, is increased by the turned poses scored.
template <class P, class Turn, class Score>
std::vector<CostBreakdown> climb_turns(std::vector<P>& poses, int axes, int swept_axes, const TurnSchedule& s,
                                       Turn&& turn, Score&& score, std::size_t* candidates) {
  if (s.sweep_turns > 1 && s.sweep_starts > 1)
    return climb_from_sweep_starts(poses, axes, swept_axes, s, turn, score, score, candidates);
  std::vector<CostBreakdown> current = score(poses);
  // Tries `angles` along the first n axes of each active pose; moves each to its best improving candidate.
  // Returns which moved.
  auto try_turns = [&](const std::vector<float>& angles, const std::vector<bool>& active, int n) {
    std::vector<P> turned;
    std::vector<std::size_t> parent;
    for (std::size_t h = 0; h < poses.size(); ++h) {
      if (!active[h]) continue;
      for (int axis = 0; axis < n; ++axis)
        for (const float a : angles) turned.push_back(turn(poses[h], axis, a)), parent.push_back(h);
    }
    std::vector<bool> moved(poses.size(), false);
    if (turned.empty()) return moved;
    if (candidates) *candidates += turned.size();
    const std::vector<CostBreakdown> c = score(turned);
    std::vector<std::ptrdiff_t> best(poses.size(), -1);
    for (std::size_t i = 0; i < turned.size(); ++i) {
      const std::size_t h = parent[i];
      const CostBreakdown& to_beat = best[h] < 0 ? current[h] : c[std::size_t(best[h])];
      const bool both = c[i].rendered_outliers() <= current[h].rendered_outliers() &&
                        c[i].observed_unexplained() <= current[h].observed_unexplained();
      if (c[i].total < to_beat.total && (!s.require_both_terms || both)) best[h] = std::ptrdiff_t(i);
    }
    for (std::size_t h = 0; h < poses.size(); ++h)
      if (best[h] >= 0) {
        poses[h] = turned[std::size_t(best[h])];
        current[h] = c[std::size_t(best[h])];
        moved[h] = true;
      }
    return moved;
  };
  if (s.sweep_turns > 1) {
    std::vector<float> angles;
    for (int k = 1; k < s.sweep_turns; ++k) angles.push_back(6.2831853f * float(k) / float(s.sweep_turns));
    try_turns(angles, std::vector<bool>(poses.size(), true), swept_axes);
  }
  float step = s.rotation_step_rad;
  for (int level = 0; level < s.levels; ++level, step *= 0.5f) {
    std::vector<bool> active(poses.size(), true);
    for (int move = 0; move < s.moves_per_level; ++move) {
      active = try_turns({-step, step}, active, axes);
      if (std::none_of(active.begin(), active.end(), [](bool a) { return a; })) break;
    }
  }
  return current;
}

}  // namespace perch2
