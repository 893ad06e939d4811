// search_turns (perch2/search/local_search.hpp) on objects known in closed form: a pose is one angle per axis
// and a shift; its geometry is a function of them, and its appearance pairs are a printed band around axis 0
// seen over kPixels pixels (the visible half turn), so what the search finds is checked exactly.
#include <doctest/doctest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <utility>
#include <vector>

#include "perch2/search/local_search.hpp"

using namespace perch2;

namespace {

constexpr float kTwoPi = 6.2831853f, kPi = 3.1415927f;
constexpr int kPixels = 600;

struct Pose {
  std::array<float, 2> angle{0.f, 0.f};  ///< about axes 0 and 1, radians
  float shift_m = 0.f;
};

float wrap(float a) {
  return std::remainder(a, kTwoPi);
}
float bump(float x, float centre, float width) {
  const float d = wrap(x - centre) / width;
  return std::exp(-d * d);
}

Pose turn(Pose p, int axis, float a) {
  p.angle[std::size_t(axis)] = wrap(p.angle[std::size_t(axis)] + a);
  return p;
}
Pose shift(Pose p, int, float m) {
  p.shift_m += m;
  return p;
}

/// A print around axis 0: three letters 2 deg wide beside a wide band. `letters` 0: a plain band.
struct Print {
  float letters = 1.f;
  float operator()(float x) const {
    return letters * (bump(x, 0.3f, 0.035f) + bump(x, 0.5f, 0.035f) + bump(x, 0.9f, 0.035f)) +
           bump(x, -0.6f, 0.8f);
  }
};

/// The pairs of a pose whose print is seen at angle[0] while the truth is at `truth`: pixel i shows the band
/// at phi_i + angle (rendered) and phi_i + truth (observed). A second feature sees the shift: it lines up
/// within ~1 mm of truth_shift_m.
AppearanceSamples pairs_of(const Pose& p, const Print& print, float truth, float truth_shift_m) {
  AppearanceSamples out;
  for (int i = 0; i < kPixels; ++i) {
    const float phi = -kPi / 2 + kPi * (float(i) + 0.5f) / float(kPixels);
    const float s = (p.shift_m - truth_shift_m) / 0.001f;
    AppearanceSample a;
    a.pixel = i;
    a.rendered = {print(phi + p.angle[0]), std::sin(7.f * phi + 0.3f * s), 0.f};
    a.observed = {print(phi + truth), std::sin(7.f * phi), 0.f};
    out.push_back(a);
  }
  return out;
}

/// measure() over a closed-form object; counts the poses measured at each stride.
struct Measure {
  std::function<float(const Pose&)> geometry;
  Print print;
  float truth = 0.f, truth_shift_m = 0.f;
  std::vector<int> strides;
  std::vector<TurnSample> operator()(const std::vector<Pose>& poses, int stride, bool with_geometry) {
    std::vector<TurnSample> out;
    for (const Pose& p : poses) {
      out.push_back({with_geometry ? geometry(p) : 0.f, pairs_of(p, print, truth, truth_shift_m)});
      strides.push_back(stride);
    }
    return out;
  }
};

/// A can: flat about axis 0, axis 1 tilts it (the geometry rises fast).
float can_geometry(const Pose& p) {
  return 10.f * (1.f - std::cos(p.angle[1]));
}

}  // namespace

TEST_CASE("search_turns: a label's letters are lined up about a flat axis, from any start") {
  for (const float truth : {2.f, -2.7f, 0.4f}) {
    Measure m{can_geometry, Print{}, truth};
    TurnSearchSettings s;
    s.climb_shift_m = 0.f;
    std::vector<Pose> poses{Pose{}, Pose{{-1.f, 0.f}, 0.f}};
    std::size_t candidates = 0;
    const std::vector<TurnMeasure> out = search_turns(poses, 2, 0, kPixels, s, turn, shift, m, &candidates);
    REQUIRE(out.size() == 2);
    for (std::size_t h = 0; h < poses.size(); ++h) {
      INFO("truth " << truth << ", start " << h << ": found " << poses[h].angle[0]);
      // The fine sweep (2.5 deg) puts a start within 1.25 deg, the climb within a quarter of its first step.
      CHECK(std::abs(wrap(poses[h].angle[0] - truth)) <= s.climb_step_rad / 2);
      CHECK(poses[h].angle[1] == 0.f);  // axis 1 is not flat: never turned
      CHECK(out[h].appearance > 0.9f);
    }
    // Sweep: 2 axes x 35 turns per pose; the family: 143 turns about axis 0 and the pose; then the climb.
    CHECK(candidates >= 2 * (2 * 35 + 144));
    CHECK(std::count(m.strides.begin(), m.strides.end(), s.sweep_stride) == 2 * 71);
    CHECK(m.strides.back() == s.final_stride);
  }
}

TEST_CASE("search_turns: a finer climb than the fine sweep re-measures its starts and climbs at its stride") {
  const float truth = -2.7f;
  TurnSearchSettings s;
  s.climb_shift_m = 0.f;
  s.sweep_stride = 8, s.fine_stride = 4, s.final_stride = 2, s.climb_stride = 1;  // all distinct
  Measure m{can_geometry, Print{}, truth};
  std::vector<Pose> poses{Pose{}};
  search_turns(poses, 2, 0, kPixels, s, turn, shift, m);
  CHECK(std::abs(wrap(poses[0].angle[0] - truth)) <= s.climb_step_rad / 2);
  // The fine sweep (the pose and 143 turns) at fine_stride; the starts (at most s.starts) again, then every
  // climb move, at climb_stride.
  CHECK(std::count(m.strides.begin(), m.strides.end(), s.fine_stride) == 144);
  const auto at_climb = std::count(m.strides.begin(), m.strides.end(), s.climb_stride);
  CHECK(at_climb >= 3);  // at least one start and one move
  CHECK(at_climb <= s.starts * (1 + 2 * s.levels * s.moves_per_level));
  s.climb_stride = -1;
  CHECK_THROWS_WITH_AS(validate(s, "turns"), doctest::Contains("turns.climb_stride"), InvalidInput);
}

TEST_CASE("search_turns: climbed_starts climbs only the best starts at the climb's stride") {
  const float truth = 0.4f;
  TurnSearchSettings s;
  s.climb_shift_m = 0.f;
  s.sweep_stride = 8, s.fine_stride = 4, s.final_stride = 2, s.climb_stride = 1;
  auto climbed = [&](int climbed_starts, std::vector<Pose>& poses) {
    s.climbed_starts = climbed_starts;
    Measure m{can_geometry, Print{}, truth};
    search_turns(poses, 2, 0, kPixels, s, turn, shift, m);
    const auto at_climb = std::count(m.strides.begin(), m.strides.end(), s.climb_stride);
    const auto at_final = std::count(m.strides.begin(), m.strides.end(), s.final_stride);
    return std::pair{at_climb, at_final};
  };
  std::vector<Pose> all{Pose{}}, best{Pose{}};
  const auto [climb_all, final_all] = climbed(0, all);
  const auto [climb_best, final_best] = climbed(1, best);
  // Every start is measured at the climb's stride; one of them is climbed (one flat axis: two moves per
  // step) and compared at final_stride beside the pose.
  CHECK(climb_best <= s.starts + 2 * s.levels * s.moves_per_level);
  CHECK(climb_best < climb_all);
  CHECK(final_best == 2);
  CHECK(final_all > final_best);
  CHECK(std::abs(wrap(best[0].angle[0] - truth)) <= s.climb_step_rad / 2);
  CHECK(best[0].angle[0] == all[0].angle[0]);  // the best start is the one that climbs to the truth
  s.climbed_starts = -1;
  CHECK_THROWS_WITH_AS(validate(s, "turns"), doctest::Contains("turns.climbed_starts"), InvalidInput);
}

TEST_CASE("search_turns: a box's half turn is taken only when its print agrees better") {
  // Axis 0: the geometry repeats every half turn (a box seen end on); the print's truth is 0 or pi.
  for (const float printed : {0.f, kPi}) {
    auto box = [](const Pose& p) {
      return 1.f - std::cos(2.f * p.angle[0]) + 10.f * (1.f - std::cos(p.angle[1]));
    };
    Measure m{box, Print{}, printed};
    TurnSearchSettings s;
    s.climb_shift_m = 0.f;
    std::vector<Pose> poses{Pose{{0.01f, 0.f}, 0.f}};
    search_turns(poses, 2, 0, kPixels, s, turn, shift, m);
    CHECK(std::abs(wrap(poses[0].angle[0] - printed)) < 0.02f);
    CHECK(poses[0].angle[1] == 0.f);
    // No flat axis: nothing climbed or swept finely, only the pose and its half turn compared.
    CHECK(std::count(m.strides.begin(), m.strides.end(), s.fine_stride) == 2);
  }
}

TEST_CASE("search_turns: a pose the geometry fixes, or an untextured one, keeps its pose") {
  // Every turn raises the geometry (no look-alike, no flat axis): the print, whose truth is elsewhere, is
  // never consulted.
  auto cat = [](const Pose& p) { return 10.f * (2.f - std::cos(p.angle[0]) - std::cos(p.angle[1])); };
  Measure m{cat, Print{}, 1.f};
  TurnSearchSettings s;
  std::vector<Pose> poses{Pose{{0.05f, -0.02f}, 0.f}};
  const Pose before = poses[0];
  std::size_t candidates = 0;
  search_turns(poses, 2, 2, kPixels, s, turn, shift, m, &candidates);
  CHECK(poses[0].angle == before.angle);
  CHECK(poses[0].shift_m == before.shift_m);
  CHECK(candidates == std::size_t(2 * (s.sweep_turns - 1)));  // the sweep only
  // A plain band (no letters, one wide band) about a flat axis: its turns vary the print, so the band is
  // lined up; a model without print (flat geometry, a constant colour) keeps its pose.
  auto flat = [](const Pose&) { return 0.1f; };
  Measure plain{flat, Print{0.f}, 1.f};
  std::vector<Pose> band{Pose{{0.3f, 0.f}, 0.002f}};
  search_turns(band, 1, 0, kPixels, s, turn, shift, plain);
  CHECK(std::abs(wrap(band[0].angle[0] - 1.f)) < 0.05f);
  struct Untextured : Measure {
    std::vector<TurnSample> operator()(const std::vector<Pose>& poses, int stride, bool g) {
      std::vector<TurnSample> out = Measure::operator()(poses, stride, g);
      for (TurnSample& t : out)
        for (AppearanceSample& a : t.samples) a.rendered = {0.2f, 0.1f, -1.f};
      return out;
    }
  } bowl{{flat, Print{}, 1.f}};
  std::vector<Pose> bowls{Pose{{0.3f, 0.f}, 0.002f}};
  search_turns(bowls, 1, 1, kPixels, s, turn, shift, bowl);
  CHECK(bowls[0].angle[0] == 0.3f);
  CHECK(bowls[0].shift_m == 0.002f);
}

TEST_CASE("search_turns: the climb's shifts line up a label the geometry left a millimetre off") {
  auto flat = [](const Pose&) { return 0.05f; };
  Measure m{flat, Print{}, 1.f, 0.003f};
  TurnSearchSettings s;
  s.climb_shift_m = 0.002f, s.levels = 4, s.moves_per_level = 4;
  std::vector<Pose> poses{Pose{{0.f, 0.f}, 0.0015f}};
  search_turns(poses, 1, 1, kPixels, s, turn, shift, m);
  CHECK(std::abs(poses[0].shift_m - 0.003f) <= 0.00026f);
  CHECK(std::abs(wrap(poses[0].angle[0] - 1.f)) <= 0.011f);
  // Without shifts the angle is still found; the shift stays where it was.
  s.climb_shift_m = 0.f;
  std::vector<Pose> unshifted{Pose{{0.f, 0.f}, 0.0015f}};
  search_turns(unshifted, 1, 1, kPixels, s, turn, shift, m);
  CHECK(unshifted[0].shift_m == 0.0015f);
  CHECK(std::abs(wrap(unshifted[0].angle[0] - 1.f)) <= 0.011f);
}

TEST_CASE("search_turns: bad settings are rejected naming the setting") {
  for (auto bad :
       {+[](TurnSearchSettings& t) { t.sweep_turns = 2; }, +[](TurnSearchSettings& t) { t.fine_turns = 1; },
        +[](TurnSearchSettings& t) { t.sweep_stride = 0; },
        +[](TurnSearchSettings& t) { t.final_stride = 0; },
        +[](TurnSearchSettings& t) { t.geometry_tolerance = -1.f; },
        +[](TurnSearchSettings& t) { t.geometry_tolerance = NAN; },
        +[](TurnSearchSettings& t) { t.starts = 0; }, +[](TurnSearchSettings& t) { t.climb_step_rad = 0.f; },
        +[](TurnSearchSettings& t) { t.climb_shift_m = -0.001f; },
        +[](TurnSearchSettings& t) { t.levels = -1; }}) {
    TurnSearchSettings t;
    bad(t);
    CHECK_THROWS_WITH_AS(validate(t, "X.turns"), doctest::Contains("X.turns"), InvalidInput);
  }
  CHECK_NOTHROW(validate(TurnSearchSettings{}, "X.turns"));
}
