// climb_turns (perch2/search/local_search.hpp) on cost landscapes known in closed form: a pose is one angle
// per axis, its cost a function of the angles, so what the schedule finds is checked exactly.
#include <doctest/doctest.h>

#include <array>
#include <cmath>

#include "perch2/search/local_search.hpp"

using namespace perch2;

namespace {

using Angles = std::array<float, 2>;

/// Outlier counts of a landscape with one minimum at `best` (1e6 * (1 - cos) of each angle's distance):
/// both terms fall towards it.
CostBreakdown bowl_cost(const Angles& a, const Angles& best) {
  CostBreakdown b;
  const float d = 2e6f - 1e6f * (std::cos(a[0] - best[0]) + std::cos(a[1] - best[1]));
  b.rendered_depth_outliers = int(std::lround(d));
  b.observed_depth_outliers = int(std::lround(0.5f * d));
  b.total = float(b.rendered_depth_outliers + b.observed_depth_outliers);
  return b;
}

Angles turn(Angles a, int axis, float angle) {
  a[std::size_t(axis)] += angle;
  return a;
}

}  // namespace

TEST_CASE("climb_turns: the sweep reaches a far minimum, the levels home in on it") {
  const Angles best{2.5f, -0.05f};
  auto score = [&](const std::vector<Angles>& poses) {
    std::vector<CostBreakdown> c;
    for (const auto& p : poses) c.push_back(bowl_cost(p, best));
    return c;
  };
  TurnSchedule s;
  s.rotation_step_rad = 0.2f, s.levels = 5, s.moves_per_level = 3, s.sweep_turns = 8;
  std::vector<Angles> poses{{0.f, 0.f}, {2.4f, 0.1f}};
  std::size_t candidates = 0;
  const std::vector<CostBreakdown> c = climb_turns(poses, 2, 1, s, turn, score, &candidates);
  REQUIRE(c.size() == 2);
  const float last_step = 0.2f / 16;
  for (const auto& p : poses) {
    CHECK(std::abs(std::remainder(p[0] - best[0], 6.2831853f)) <= last_step);
    CHECK(std::abs(p[1] - best[1]) <= last_step);
  }
  CHECK(c[0].total == bowl_cost(poses[0], best).total);
  // The sweep (7 turns about axis 0 only) and at most 2 axes x 2 signs x 3 moves per level for each pose.
  CHECK(candidates >= 2 * 7 + 2 * 5 * 4);
  CHECK(candidates <= 2 * 7 + 2 * 5 * 3 * 4);
  // Without the sweep, steps of 0.2 halving cannot walk from 0 to 2.5 rad.
  s.sweep_turns = 0;
  std::vector<Angles> start{{0.f, 0.f}};
  climb_turns(start, 2, 1, s, turn, score);
  CHECK(std::abs(start[0][0] - best[0]) > 1.f);
}

TEST_CASE(
    "climb_turns: with sweep_starts, a narrow deep minimum beats a wide shallow one the sweep prefers") {
  // A narrow well at 2 rad (depth 1) and a wide one at -1.2 rad (depth 0.6): the sweep's samples (every
  // 45 deg from 0) score best near the wide one, but a sample lies inside the narrow one's basin.
  auto well = [](float a, float centre, float width) {
    const float d = std::remainder(a - centre, 6.2831853f) / width;
    return std::exp(-d * d);
  };
  auto score = [&](const std::vector<Angles>& poses) {
    std::vector<CostBreakdown> c;
    for (const auto& p : poses) {
      CostBreakdown b;
      const float d = 1e6f * (1.f - well(p[0], 2.f, 0.25f) - 0.6f * well(p[0], -1.2f, 0.8f));
      b.rendered_depth_outliers = int(std::lround(d));
      b.observed_depth_outliers = int(std::lround(0.5f * d));
      b.total = float(b.rendered_depth_outliers + b.observed_depth_outliers);
      c.push_back(b);
    }
    return c;
  };
  TurnSchedule s;
  s.rotation_step_rad = 0.2f, s.levels = 5, s.moves_per_level = 3, s.sweep_turns = 8;
  std::vector<Angles> one{{0.f, 0.f}}, three{{0.f, 0.f}};
  climb_turns(one, 1, 1, s, turn, score);
  CHECK(std::abs(std::remainder(one[0][0] + 1.2f, 6.2831853f)) < 0.05f);
  s.sweep_starts = 3;
  std::size_t candidates = 0;
  const auto c = climb_turns(three, 1, 1, s, turn, score, &candidates);
  CHECK(std::abs(std::remainder(three[0][0] - 2.f, 6.2831853f)) < 0.05f);
  CHECK(c[0].total == score(three)[0].total);
  CHECK(candidates >= 7 + 3 * 5 * 2);  // the sweep, then every level of every start
}

TEST_CASE("climb_turns: a turn that trades one term for the other is not taken with require_both_terms") {
  // The total falls towards 1 rad, but the observed term rises: a trade, not a better fit.
  auto score = [](const std::vector<Angles>& poses) {
    std::vector<CostBreakdown> c;
    for (const auto& p : poses) {
      CostBreakdown b;
      b.rendered_depth_outliers = int(std::lround(1000.f * std::abs(p[0] - 1.f)));
      b.observed_depth_outliers = int(std::lround(100.f * p[0]));
      b.total = float(b.rendered_depth_outliers + b.observed_depth_outliers);
      c.push_back(b);
    }
    return c;
  };
  TurnSchedule s;
  s.rotation_step_rad = 0.1f, s.levels = 3, s.moves_per_level = 20;
  std::vector<Angles> poses{{0.f, 0.f}};
  climb_turns(poses, 1, 1, s, turn, score);
  CHECK(poses[0][0] == 0.f);
  s.require_both_terms = false;
  climb_turns(poses, 1, 1, s, turn, score);
  CHECK(poses[0][0] == doctest::Approx(1.f).epsilon(0.01));
}

TEST_CASE("climb_turns: bad schedules are rejected naming the setting") {
  TurnSchedule s;
  s.rotation_step_rad = 0.f;
  CHECK_THROWS_WITH_AS(validate(s, "X.turns"), doctest::Contains("X.turns.rotation_step_rad"), InvalidInput);
  s.rotation_step_rad = std::nanf("");
  CHECK_THROWS_AS(validate(s, "X.turns"), InvalidInput);
  for (auto bad :
       {+[](TurnSchedule& t) { t.levels = -1; }, +[](TurnSchedule& t) { t.moves_per_level = -1; },
        +[](TurnSchedule& t) { t.sweep_turns = -2; }, +[](TurnSchedule& t) { t.sweep_starts = 0; }}) {
    TurnSchedule t;
    bad(t);
    CHECK_THROWS_WITH_AS(validate(t, "X.turns"), doctest::Contains("must be >= "), InvalidInput);
  }
  CHECK_NOTHROW(validate(TurnSchedule{}, "X.turns"));
}
