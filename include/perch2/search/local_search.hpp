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
#include <string>
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
}

/// Moves every pose of `poses` by the schedule's hill climbing (see the file comment) and returns their
/// costs at the poses found. `candidates`, if given, is increased by the turned poses scored.
template <class P, class Turn, class Score>
std::vector<CostBreakdown> climb_turns(std::vector<P>& poses, int axes, int swept_axes, const TurnSchedule& s,
                                       Turn&& turn, Score&& score, std::size_t* candidates = nullptr) {
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
