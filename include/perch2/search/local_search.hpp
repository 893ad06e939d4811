// The turns of a pose that its geometry cannot see, decided by appearance: a printed can or bottle about
// its axis, a box's printed front against its plain-looking back. Shared by the 6-DoF local search (turns
// about the model's own axes, SixDofSettings::local) and the 3-DoF yaw search (turns about the table
// normal, TabletopSettings::yaw_search).
//
//   std::vector<TurnMeasure> m =
//       search_turns(poses, /*axes=*/3, /*shift_axes=*/0, image_width, settings, turn, shift, measure);
//
// turn(pose, axis, angle_rad) returns the pose turned by angle_rad about axis (0 .. axes - 1, the caller's:
// a model axis, the table normal), shift(pose, axis, metres) the pose moved along one of its shift_axes;
// measure(poses, stride, geometry) returns each pose's TurnSample from a render at that stride: its
// appearance pairs (perch2/cost/appearance.hpp) and, if `geometry`, its geometry (a depth-only cost, lower is
// better). Appearance is compared within each pose's family (the turns below) weighted by where the family's
// print varies (PrintVariation), so a can's lid and a label's plain background do not drown its letters.
// Per pose:
//   sweep      the turns by 2 pi k / sweep_turns about every axis, at sweep_stride. A turn whose geometry
//              is at most geometry_tolerance worse than the pose's is a look-alike; an axis whose first
//              turns either way are look-alikes is flat (the geometry does not fix the turn about it)
//   fine       about each flat axis, the turns by 2 pi k / fine_turns, at fine_stride, appearance only: a
//              label's letters line up within a few degrees only, a coarser sweep steps over them
//   starts     the pose and its best turns by appearance at fine_stride (the fine sweep's, and the sweep's
//              look-alikes about the other axes, e.g. a box's half turn), at most `starts - 1`, each more
//              than two steps from the others about its axis; a pose with neither keeps its pose
//   climb      the best climbed_starts starts (0: all) at climb_stride (0: fine_stride), each turned about
//              the flat axes by +-climb_step_rad, halving over `levels`: a move is taken when it raises the
//              appearance
//   choose     the climbed starts compared at final_stride (fine print decides between look-alike sides):
//              the best appearance among those whose geometry is within the tolerance of the pose's wins,
//              if it beats the pose's own
// A pose whose model is untextured has appearance 0 everywhere and keeps its pose; a pose whose geometry
// fixes every turn (no look-alike, no flat axis: a scanned cat) is left as the geometry placed it.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <string>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/cost/appearance.hpp"

namespace perch2 {

/// What measure() gives search_turns of a pose (see the file comment).
struct TurnSample {
  float geometry = 0.f;       ///< depth-only cost, lower is better (e.g. J_r + J_o as fractions)
  AppearanceSamples samples;  ///< its render's appearance pairs with the frame
};

/// What search_turns compares of a pose (see the file comment).
struct TurnMeasure {
  float geometry = 0.f;  ///< depth-only cost, lower is better (e.g. J_r + J_o as fractions)
  float appearance =
      0.f;  ///< agreement of the print with the frame, within its family (AppearanceScore::ncc)
};

/// How search_turns searches (see the file comment).
struct TurnSearchSettings {
  /// Turns by 2 pi k / sweep_turns about each axis, whose geometry finds the look-alikes and the flat axes
  /// (>= 3): every 10 deg.
  int sweep_turns = 36;
  int sweep_stride = 4;  ///< render stride of the sweep (>= 1)
  /// A turn is a look-alike of the pose if its geometry is at most this much worse (>= 0; in the measure's
  /// units: 0.02 = 2 % of the points with J_r + J_o as fractions). On the 29 real LINEMOD-cat frames (a
  /// scanned cat, no symmetry) a 10 deg turn about any axis costs 0.04-0.17 more, a 5 deg turn 0.01-0.04.
  float geometry_tolerance = 0.02f;
  /// Turns by 2 pi k / fine_turns about each flat axis, compared by appearance (>= 2): every 2.5 deg, so a
  /// label's letters, which line up within a few degrees only, are not stepped over.
  int fine_turns = 144;
  int fine_stride = 2;  ///< render stride of the fine sweep and of the climb (>= 1)
  /// Render stride of the climb if finer than the fine sweep's (>= 0; 0 = fine_stride): the sweep only has
  /// to rank the turns, the climb's few renders decide between the best starts (re-measured at this stride).
  int climb_stride = 0;
  int starts = 4;  ///< the pose and at most starts - 1 of its best turns are climbed and compared (>= 1)
  /// Of each pose's starts, only the best this many by appearance at the climb's stride are climbed and
  /// compared (>= 0; 0 = all): the climb, at the finest stride but the final one, is most of the search's
  /// time, and a start that the climb's own stride ranks low rarely climbs past the best.
  int climbed_starts = 0;
  float climb_step_rad = 0.0109f;  ///< the climb's first turn, radians (> 0): half the fine sweep's step
  /// The climb also shifts each start by +-climb_shift_m along the caller's shift axes, halving with the
  /// turn (>= 0; 0 = turns only): a label's letters line up only within a pixel or two, and the geometry
  /// leaves a pose a millimetre or two off.
  float climb_shift_m = 0.001f;
  int levels = 2;           ///< the climb's step halves each level (>= 0)
  int moves_per_level = 2;  ///< most accepted moves per level (>= 0)
  /// Render stride at which the climbed starts are compared (>= 1): the finest print decides. bench_turns on
  /// 30 generated tabletop scenes (110 printed objects, turns every 2 deg from the ground truth): the best
  /// look-alike turn lay within 5 deg of the truth for 109 at stride 1, 106 at stride 2 and 97 at stride 4.
  int final_stride = 1;
};

/// Throws InvalidInput naming `who` unless the settings are usable.
inline void validate(const TurnSearchSettings& s, const std::string& who) {
  if (s.sweep_turns < 3) throw InvalidInput(who + ".sweep_turns", "must be >= 3");
  if (s.fine_turns < 2) throw InvalidInput(who + ".fine_turns", "must be >= 2");
  if (s.sweep_stride < 1 || s.fine_stride < 1 || s.final_stride < 1)
    throw InvalidInput(who, "sweep_stride, fine_stride and final_stride must be >= 1");
  if (s.climb_stride < 0) throw InvalidInput(who + ".climb_stride", "must be >= 0 (0 = fine_stride)");
  if (!(std::isfinite(s.geometry_tolerance) && s.geometry_tolerance >= 0))
    throw InvalidInput(who + ".geometry_tolerance", "must be finite and >= 0");
  if (s.starts < 1) throw InvalidInput(who + ".starts", "must be >= 1");
  if (s.climbed_starts < 0) throw InvalidInput(who + ".climbed_starts", "must be >= 0 (0 = all starts)");
  if (!(std::isfinite(s.climb_step_rad) && s.climb_step_rad > 0))
    throw InvalidInput(who + ".climb_step_rad", "must be finite and > 0");
  if (!(std::isfinite(s.climb_shift_m) && s.climb_shift_m >= 0))
    throw InvalidInput(who + ".climb_shift_m", "must be finite and >= 0");
  if (s.levels < 0 || s.moves_per_level < 0)
    throw InvalidInput(who, "levels and moves_per_level must be >= 0");
}

namespace turn_search_detail {

/// A turn of a pose: about `axis` by `step` of `of` steps of a full turn.
struct Turn {
  int axis = 0, step = 0, of = 1;
  float angle() const { return 6.2831853f * float(step) / float(of); }
  /// Whether `o` lies within `steps` of this turn's steps, about the same axis (the pose itself, step 0,
  /// is on every axis).
  bool near(const Turn& o, int steps) const {
    const bool same_axis = step == 0 || o.step == 0 || axis == o.axis;
    return same_axis && std::abs(angle_to(o)) <= float(steps) * 6.2831853f / float(of) + 1e-6f;
  }
  float angle_to(const Turn& o) const { return std::remainder(angle() - o.angle(), 6.2831853f); }
};

}  // namespace turn_search_detail

/// Moves every pose of `poses` to the turn search's choice (see the file comment) and returns each pose's
/// measure at final_stride there. `image_width`: the frame's, in pixels (the appearance pairs' pixel
/// indices). `candidates`, if given, is increased by the turned poses measured.
template <class P, class TurnFn, class ShiftFn, class Measure>
std::vector<TurnMeasure> search_turns(std::vector<P>& poses, int axes, int shift_axes, int image_width,
                                      const TurnSearchSettings& s, TurnFn&& turn, ShiftFn&& shift,
                                      Measure&& measure, std::size_t* candidates = nullptr) {
  using turn_search_detail::Turn;
  const std::size_t H = poses.size();
  if (H == 0) return {};
  auto count = [&](std::size_t k) {
    if (candidates) *candidates += k;
  };
  auto turned = [&](std::size_t h, const Turn& t) {
    return t.step == 0 ? poses[h] : turn(poses[h], t.axis, t.angle());
  };
  auto unweighted = [](const std::vector<TurnSample>& m) {
    std::vector<TurnMeasure> out;
    for (const TurnSample& x : m) out.push_back({x.geometry, appearance_score(x.samples).ncc});
    return out;
  };

  // ---- sweep: every turn of every pose, at sweep_stride: look-alikes and flat axes
  const int n = s.sweep_turns;
  std::vector<P> batch = poses;
  for (std::size_t h = 0; h < H; ++h)
    for (int a = 0; a < axes; ++a)
      for (int k = 1; k < n; ++k) batch.push_back(turned(h, {a, k, n}));
  count(batch.size() - H);
  const std::vector<TurnSample> swept = measure(batch, s.sweep_stride, true);
  auto alike = [&](std::size_t h, int a, int k) {  // k in 1 .. n - 1
    const std::size_t i = H + h * std::size_t(axes * (n - 1)) + std::size_t(a * (n - 1) + k - 1);
    return swept[i].geometry <= swept[h].geometry + s.geometry_tolerance;
  };
  std::vector<std::vector<bool>> flat(H, std::vector<bool>(std::size_t(axes), false));
  std::vector<std::vector<Turn>> options(H);  // per pose: the turns compared at fine_stride
  for (std::size_t h = 0; h < H; ++h)
    for (int a = 0; a < axes; ++a) {
      flat[h][std::size_t(a)] = alike(h, a, 1) && alike(h, a, n - 1);
      if (!flat[h][std::size_t(a)])
        for (int k = 2; k < n - 1; ++k)
          if (alike(h, a, k)) options[h].push_back({a, k, n});
    }
  for (std::size_t h = 0; h < H; ++h)
    for (int a = 0; a < axes; ++a)
      if (flat[h][std::size_t(a)])
        for (int k = 1; k < s.fine_turns; ++k) options[h].push_back({a, k, s.fine_turns});

  // ---- family: each pose and its options at fine_stride; their print's variation weighs the pairs
  std::vector<P> fine;
  std::vector<std::pair<std::size_t, Turn>> of_fine;
  for (std::size_t h = 0; h < H; ++h)
    if (!options[h].empty()) {
      fine.push_back(poses[h]), of_fine.push_back({h, Turn{}});
      for (const Turn& t : options[h]) fine.push_back(turned(h, t)), of_fine.push_back({h, t});
    }
  if (fine.empty()) return unweighted(measure(poses, s.final_stride, true));
  count(fine.size());
  const std::vector<TurnSample> fm = measure(fine, s.fine_stride, false);
  std::vector<PrintVariation> variation(H, PrintVariation(image_width, s.fine_stride));
  for (std::size_t i = 0; i < fine.size(); ++i) variation[of_fine[i].first].add(fm[i].samples);
  auto appearance = [&](std::size_t h, const TurnSample& x) {
    return appearance_score(x.samples, &variation[h]).ncc;
  };

  // ---- starts: the pose and its best options
  struct Start {
    std::size_t pose;
    P p;
    float appearance;
  };
  std::vector<Start> starts;
  for (std::size_t begin = 0; begin < fine.size();) {
    const std::size_t h = of_fine[begin].first;
    std::size_t end = begin;
    while (end < fine.size() && of_fine[end].first == h) ++end;
    std::vector<float> a(end - begin);
    for (std::size_t i = begin; i < end; ++i) a[i - begin] = appearance(h, fm[i]);
    std::vector<std::size_t> order;
    for (std::size_t i = begin + 1; i < end; ++i) order.push_back(i);
    std::stable_sort(order.begin(), order.end(),
                     [&](std::size_t x, std::size_t y) { return a[x - begin] > a[y - begin]; });
    std::vector<Turn> taken{Turn{}};
    starts.push_back({h, poses[h], a[0]});
    for (const std::size_t i : order) {
      if (int(taken.size()) >= s.starts) break;
      const Turn& t = of_fine[i].second;
      if (std::any_of(taken.begin(), taken.end(), [&](const Turn& o) { return t.near(o, 2); })) continue;
      taken.push_back(t);
      starts.push_back({h, fine[i], a[i - begin]});
    }
    begin = end;
  }

  // ---- climb each start about its pose's flat axes (and along the shift axes), at climb_stride
  const int climb_stride = s.climb_stride > 0 ? s.climb_stride : s.fine_stride;
  if (climb_stride != s.fine_stride) {  // the starts' appearance at the climb's stride, to compare with
    std::vector<P> at;
    for (const Start& st : starts) at.push_back(st.p);
    count(at.size());
    const std::vector<TurnSample> m = measure(at, climb_stride, false);
    for (std::size_t i = 0; i < starts.size(); ++i) starts[i].appearance = appearance(starts[i].pose, m[i]);
  }
  if (s.climbed_starts > 0) {  // per pose, its best starts at the climb's stride (the earlier on a tie)
    auto ahead = [&](std::size_t j, std::size_t i) {
      return starts[j].pose == starts[i].pose && (starts[j].appearance > starts[i].appearance ||
                                                  (starts[j].appearance == starts[i].appearance && j < i));
    };
    std::vector<Start> kept;
    for (std::size_t i = 0; i < starts.size(); ++i) {
      int better = 0;
      for (std::size_t j = 0; j < starts.size(); ++j) better += ahead(j, i);
      if (better < s.climbed_starts) kept.push_back(starts[i]);
    }
    starts = std::move(kept);
  }
  float step = s.climb_step_rad, step_m = s.climb_shift_m;
  for (int level = 0; level < s.levels; ++level, step *= 0.5f, step_m *= 0.5f) {
    std::vector<bool> active(starts.size(), true);
    for (int move = 0; move < s.moves_per_level; ++move) {
      std::vector<P> moved;
      std::vector<std::size_t> parent;
      for (std::size_t i = 0; i < starts.size(); ++i) {
        if (!active[i]) continue;
        for (int a = 0; a < axes; ++a)
          if (flat[starts[i].pose][std::size_t(a)])
            for (const float d : {-step, step}) moved.push_back(turn(starts[i].p, a, d)), parent.push_back(i);
        if (step_m > 0)
          for (int a = 0; a < shift_axes; ++a)
            for (const float d : {-step_m, step_m})
              moved.push_back(shift(starts[i].p, a, d)), parent.push_back(i);
      }
      if (moved.empty()) break;
      count(moved.size());
      const std::vector<TurnSample> m = measure(moved, climb_stride, false);
      std::vector<std::ptrdiff_t> best(starts.size(), -1);
      std::vector<float> best_appearance(starts.size());
      for (std::size_t j = 0; j < moved.size(); ++j) {
        const std::size_t i = parent[j];
        const float a = appearance(starts[i].pose, m[j]);
        if (a > (best[i] < 0 ? starts[i].appearance : best_appearance[i]))
          best[i] = std::ptrdiff_t(j), best_appearance[i] = a;
      }
      std::fill(active.begin(), active.end(), false);
      for (std::size_t i = 0; i < starts.size(); ++i)
        if (best[i] >= 0)
          starts[i].p = moved[std::size_t(best[i])], starts[i].appearance = best_appearance[i],
          active[i] = true;
      if (std::none_of(active.begin(), active.end(), [](bool x) { return x; })) break;
    }
  }

  // ---- choose at final_stride: the best appearance within the geometry limit, if it beats the pose's
  std::vector<P> final_batch = poses;
  for (const Start& st : starts) final_batch.push_back(st.p);
  const std::vector<TurnSample> fin = measure(final_batch, s.final_stride, true);
  std::vector<TurnMeasure> out = unweighted({fin.begin(), fin.begin() + std::ptrdiff_t(H)});
  std::vector<bool> searched(H, false);
  for (const Start& st : starts) searched[st.pose] = true;
  for (std::size_t h = 0; h < H; ++h)
    if (searched[h]) out[h].appearance = appearance(h, fin[h]);
  for (std::size_t i = 0; i < starts.size(); ++i) {
    const std::size_t h = starts[i].pose;
    const float a = appearance(h, fin[H + i]);
    if (fin[H + i].geometry <= fin[h].geometry + s.geometry_tolerance && a > out[h].appearance)
      poses[h] = starts[i].p, out[h] = {fin[H + i].geometry, a};
  }
  return out;
}

}  // namespace perch2
