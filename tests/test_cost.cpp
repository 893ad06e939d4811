// The cost stage: hand-built clouds with known counts, both colour rules, normalisation, the backends
// against each other on random data, and bad input.
#include <doctest/doctest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>

#include "perch2/cost/cost.hpp"
#include "perch2/knn/scan.hpp"
#include "test_support.hpp"

using namespace perch2;

namespace {

constexpr std::uint32_t kRed = 0xC81E1E, kBlue = 0x1E3CC8;

/// A 10 x 10 patch of points at depth z, spacing 2 mm (well below delta), in x from x0, one colour.
CloudBatch patch(float x0, float z, std::uint32_t rgb, int n = 10) {
  CloudBatch c;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      c.x.push_back(x0 + 0.002f * i), c.y.push_back(0.002f * j), c.z.push_back(z);
      c.rgb.push_back(rgb), c.pixel.push_back(-1), c.cloud.push_back(0);
    }
  c.offsets = {0, std::int64_t(c.size())};
  return c;
}

/// Concatenates clouds into one batch (one cloud each).
CloudBatch batch(const std::vector<CloudBatch>& clouds) {
  CloudBatch b;
  for (std::size_t k = 0; k < clouds.size(); ++k) {
    const CloudBatch& c = clouds[k];
    b.x.insert(b.x.end(), c.x.begin(), c.x.end()), b.y.insert(b.y.end(), c.y.begin(), c.y.end());
    b.z.insert(b.z.end(), c.z.begin(), c.z.end()), b.rgb.insert(b.rgb.end(), c.rgb.begin(), c.rgb.end());
    b.pixel.insert(b.pixel.end(), c.pixel.begin(), c.pixel.end());
    b.cloud.insert(b.cloud.end(), c.size(), std::int32_t(k));
    b.offsets.push_back(std::int64_t(b.size()));
  }
  return b;
}

CostRequest whole_segment(std::size_t n) {
  CostRequest r;
  for (std::size_t h = 0; h < n; ++h) r.add(0);
  return r;
}

Footprint square(float x0, float x1, float y0, float y1, float z0, float z1) {
  Footprint f;
  f.polygon_xy_m = {{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}};
  f.z_min_m = z0, f.z_max_m = z1;
  return f;
}

}  // namespace

TEST_CASE_TEMPLATE("cost counts of hand-built clouds", B, PERCH2_CPU_RUNNABLE_BACKENDS) {
  const CloudBatch observed = patch(0.f, 1.f, kRed);
  const typename B::Cost cost(observed);
  CostSettings rgbd, depth_only;
  depth_only.use_color = false;
  // 0: exactly on the observed points; 1: 1 cm behind them (> delta); 2: on them with another colour;
  // 3: nothing rendered (fully occluded).
  CloudBatch empty;
  const CloudBatch rendered =
      batch({patch(0.f, 1.f, kRed), patch(0.f, 1.01f, kRed), patch(0.f, 1.f, kBlue), empty});
  const CostResult r = cost.evaluate(rendered, whole_segment(4), rgbd);
  REQUIRE(r.size() == 4);
  const CostBreakdown& same = r.hypotheses[0];
  CHECK(same.rendered_points == 100);
  CHECK(same.rendered_inliers == 100);
  CHECK(same.observed_in_volume == 100);
  CHECK(same.observed_unexplained() == 0);
  CHECK(same.J_r == 0.f);
  CHECK(same.total == 0.f);

  const CostBreakdown& shifted = r.hypotheses[1];
  CHECK(shifted.rendered_depth_outliers == 100);
  CHECK(shifted.observed_depth_outliers == 100);
  CHECK(shifted.total == 200.f);

  const CostBreakdown& recoloured = r.hypotheses[2];
  CHECK(recoloured.rendered_color_outliers == 100);
  CHECK(recoloured.rendered_depth_outliers == 0);
  CHECK(recoloured.observed_color_outliers == 100);
  CHECK(recoloured.total == 200.f);

  const CostBreakdown& none = r.hypotheses[3];
  CHECK(none.rendered_points == 0);
  CHECK(none.observed_depth_outliers == 100);

  // The depth-only cost does not see the colour mismatch.
  const CostResult d = cost.evaluate(rendered, whole_segment(4), depth_only);
  CHECK(d.hypotheses[2].total == 0.f);
  CHECK(d.hypotheses[2].rendered_color_outliers == 0);
  CHECK(d.hypotheses[1].total == 200.f);
}

TEST_CASE_TEMPLATE("J_o counts only observed points inside the hypothesis' volume", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  // Observed: two patches at x in [0, 0.018] and [0.05, 0.068]. Rendered: only the first.
  const CloudBatch observed = batch({[] {
    CloudBatch a = patch(0.f, 1.f, kRed), b = patch(0.05f, 1.f, kRed);
    CloudBatch c = batch({a, b});
    c.offsets = {0, std::int64_t(c.size())};
    c.cloud.assign(c.size(), 0);
    return c;
  }()});
  const typename B::Cost cost(observed);
  const CloudBatch rendered = batch({patch(0.f, 1.f, kRed), patch(0.f, 1.f, kRed), patch(0.f, 1.f, kRed)});
  CostRequest req;
  req.footprints = {square(-0.01f, 0.03f, -0.01f, 0.03f, 0.95f, 1.05f),   // around the first patch only
                    square(-0.01f, 0.09f, -0.01f, 0.03f, 0.95f, 1.05f)};  // around both
  req.add(0, 0, Pose::Identity());
  req.add(0, 1, Pose::Identity());
  // The first footprint moved 5 cm in x by its pose: around the second patch only.
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3f(0.05f, 0.f, 0.f);
  req.add(0, 0, T);
  const CostResult r = cost.evaluate(rendered, req);
  CHECK(r.hypotheses[0].observed_in_volume == 100);
  CHECK(r.hypotheses[0].observed_unexplained() == 0);  // the unexplained second patch is outside
  CHECK(r.hypotheses[1].observed_in_volume == 200);
  CHECK(r.hypotheses[1].observed_depth_outliers == 100);
  CHECK(r.hypotheses[2].observed_in_volume == 100);
  CHECK(r.hypotheses[2].observed_depth_outliers == 100);
  for (const auto& h : r.hypotheses) CHECK(h.rendered_inliers == 100);

  // A height range below the points: nothing inside.
  req.footprints[0].z_min_m = 0.5f, req.footprints[0].z_max_m = 0.99f;
  CHECK(cost.evaluate(rendered, req).hypotheses[0].observed_in_volume == 0);
}

TEST_CASE_TEMPLATE("colour rules: the nearest neighbour decides, or any neighbour within delta", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  // One observed red point; rendered: a blue point 1 mm away and a red point 5 mm away (both within delta).
  CloudBatch observed = patch(0.f, 1.f, kRed, 1);
  const typename B::Cost cost(observed);
  CloudBatch rendered = patch(0.001f, 1.f, kBlue, 1);
  rendered.x.push_back(0.f), rendered.y.push_back(0.f), rendered.z.push_back(1.005f);
  rendered.rgb.push_back(kRed), rendered.pixel.push_back(-1), rendered.cloud.push_back(0);
  rendered.offsets = {0, 2};
  CostSettings nearest, any;
  nearest.color_rule = ColorRule::Nearest;
  any.color_rule = ColorRule::AnyNeighbour;
  const CostBreakdown n = cost.evaluate(rendered, whole_segment(1), nearest).hypotheses[0];
  const CostBreakdown a = cost.evaluate(rendered, whole_segment(1), any).hypotheses[0];
  CHECK(n.observed_color_outliers == 1);  // its nearest rendered point is blue
  CHECK(a.observed_color_outliers == 0);  // the red one within delta explains it
  // Rendered side: the blue point's only neighbour is red (outlier under both rules); the red point's is red.
  CHECK(n.rendered_color_outliers == 1);
  CHECK(a.rendered_color_outliers == 1);
  CHECK(n.rendered_inliers == 1);
}

/// The colour a camera reports for a surface of colour `rgb` lit `k` times as brightly (linear light).
std::uint32_t shaded(std::uint32_t rgb, float k) {
  const Rgb8 c = unpack_rgb(rgb);
  auto encode = [k](std::uint8_t code) {
    const float lin = std::min(1.f, k * color_math::srgb_to_linear<float>(code));
    const float v = lin <= 0.0031308f ? 12.92f * lin : 1.055f * std::pow(lin, 1.f / 2.4f) - 0.055f;
    return std::uint8_t(std::lround(255.f * v));
  };
  return pack_rgb(Rgb8{encode(c.r), encode(c.g), encode(c.b)});
}

TEST_CASE_TEMPLATE("shading-invariant colours: a shaded surface matches its albedo, other hues do not", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  constexpr std::uint32_t kWhite = 0xF5F5F5, kYellow = 0xFAC828;
  for (const std::uint32_t albedo : {kRed, kWhite})
    for (const float k : {0.25f, 0.5f, 1.3f}) {  // in the shadow (ambient light only) ... a highlight
      CAPTURE(albedo);
      CAPTURE(k);
      const typename B::Cost cost(patch(0.f, 1.f, shaded(albedo, k)));
      CostSettings raw, invariant;
      raw.shading_invariant = false;
      const CloudBatch model = patch(0.f, 1.f, albedo), other = patch(0.f, 1.f, kYellow);
      const CostBreakdown r = cost.evaluate(model, whole_segment(1), raw).hypotheses[0];
      const CostBreakdown i = cost.evaluate(model, whole_segment(1), invariant).hypotheses[0];
      const CostBreakdown y = cost.evaluate(other, whole_segment(1), invariant).hypotheses[0];
      // Raw CIEDE2000 (kL = 2) fails a white label in the shadow.
      if (albedo == kWhite && k == 0.25f) CHECK(r.rendered_color_outliers == 100);
      CHECK(i.rendered_color_outliers == 0);
      CHECK(i.observed_color_outliers == 0);
      CHECK(y.rendered_color_outliers == 100);  // a yellow label explains neither a red nor a white one
      CHECK(y.observed_color_outliers == 100);
    }
}

TEST_CASE_TEMPLATE("normalisation and weights are applied as documented", B, PERCH2_CPU_RUNNABLE_BACKENDS) {
  const typename B::Cost cost(patch(0.f, 1.f, kRed));
  // Rendered: the rows y <= 0.008 m of the patch on the points, plus 50 points 2 cm in front.
  CloudBatch left = patch(0.f, 1.f, kRed, 10);
  left.resize(50);
  left.offsets = {0, 50};
  CloudBatch front = patch(0.f, 0.98f, kRed);
  front.resize(50);
  front.offsets = {0, 50};
  CloudBatch both = batch({left, front});
  both.offsets = {0, 100};
  both.cloud.assign(100, 0);
  CostSettings s;
  s.normalization = Normalization::Fractions;
  s.weight_rendered = 2.f, s.weight_observed = 0.5f;
  const CostBreakdown b = cost.evaluate(both, whole_segment(1), s).hypotheses[0];
  CHECK(b.rendered_depth_outliers == 50);
  // Rows y = 0.016 and 0.018 m are more than delta from the rendered rows (y <= 0.008 m); y <= 0.014 are not.
  CHECK(b.observed_depth_outliers == 20);
  CHECK(b.J_r == doctest::Approx(0.5f));
  CHECK(b.J_o == doctest::Approx(0.2f));
  CHECK(b.total == doctest::Approx(2.f * 0.5f + 0.5f * 0.2f));
}

namespace {

/// Random points in a 6 cm cube around (0, 0, 0.8) with colours from a small palette (so colour tests
/// matter and near-threshold pairs occur), split into `clouds` clouds of random sizes (some empty).
CloudBatch random_batch(std::mt19937& rng, int clouds, int max_points) {
  std::uniform_real_distribution<float> u(-0.03f, 0.03f);
  std::uniform_int_distribution<int> size(0, max_points), colour(0, 4);
  const std::uint32_t palette[5] = {kRed, kBlue, 0xC8281E, 0x20A040, 0x808080};
  CloudBatch b;
  for (int c = 0; c < clouds; ++c) {
    const int n = c % 7 == 3 ? 0 : size(rng);
    for (int i = 0; i < n; ++i) {
      const float x = u(rng), y = u(rng), z = 0.8f + u(rng);
      b.x.push_back(x), b.y.push_back(y), b.z.push_back(z);
      b.rgb.push_back(palette[colour(rng)]), b.pixel.push_back(-1), b.cloud.push_back(c);
    }
    b.offsets.push_back(std::int64_t(b.size()));
  }
  return b;
}

}  // namespace

TEST_CASE(
    "cost: cpu, thrust_omp (whole hypotheses) and its GPU pass structure agree exactly on random data") {
  std::mt19937 rng(7);
  const CloudBatch observed = random_batch(rng, 2, 3000);
  const CloudBatch rendered = random_batch(rng, 60, 400);
  CostRequest req;
  req.footprints = {square(-0.02f, 0.02f, -0.015f, 0.025f, -0.01f, 0.02f),
                    square(-0.01f, 0.03f, -0.03f, 0.0f, -0.03f, 0.03f)};
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (int h = 0; h < 60; ++h) {
    const float a = u(rng), b = u(rng), c = u(rng), angle = 3.f * u(rng);
    Pose T = Pose::Identity();
    T.linear() = Eigen::AngleAxisf(angle, Eigen::Vector3f(a, b, c + 2.f).normalized()).toRotationMatrix();
    const float tx = 0.01f * u(rng), ty = 0.01f * u(rng), tz = 0.8f + 0.01f * u(rng);
    T.translation() = Eigen::Vector3f(tx, ty, tz);
    req.add(h % 2, h % 5 == 4 ? -1 : h % 2, T);
  }
  const cpu::Cost reference(observed);
  const thrust_omp::Backend::Cost thrust(observed);
  static_assert(thrust_backend::OmpSystem::cost_whole_hypotheses &&
                !thrust_backend::OmpPassesSystem::cost_whole_hypotheses);
  const thrust_backend::Cost<thrust_backend::OmpPassesSystem> passes(observed);
  for (const bool colour : {true, false})
    for (const ColorRule rule : {ColorRule::Nearest, ColorRule::AnyNeighbour})
      for (const bool invariant : {true, false}) {
        CostSettings s;
        s.use_color = colour, s.color_rule = rule, s.delta_m = 0.004f, s.tau_c = 12.5f;
        s.shading_invariant = invariant;
        const CostResult a = reference.evaluate(rendered, req, s), b = thrust.evaluate(rendered, req, s),
                         c = passes.evaluate(rendered, req, s);
        REQUIRE(a.size() == b.size());
        REQUIRE(a.size() == c.size());
        int differences = 0, colour_outliers = 0, in_volume = 0, depth_outliers = 0;
        for (std::size_t h = 0; h < a.size(); ++h) {
          const CostBreakdown &x = a.hypotheses[h], &y = b.hypotheses[h], &z = c.hypotheses[h];
          const auto same = [](const CostBreakdown& u, const CostBreakdown& v) {
            return u.rendered_inliers == v.rendered_inliers &&
                   u.rendered_depth_outliers == v.rendered_depth_outliers &&
                   u.rendered_color_outliers == v.rendered_color_outliers &&
                   u.observed_in_volume == v.observed_in_volume &&
                   u.observed_depth_outliers == v.observed_depth_outliers &&
                   u.observed_color_outliers == v.observed_color_outliers && u.total == v.total;
          };
          differences += !same(x, y) + !same(x, z);
          colour_outliers += x.rendered_color_outliers + x.observed_color_outliers;
          depth_outliers += x.rendered_depth_outliers + x.observed_depth_outliers;
          in_volume += x.observed_in_volume;
        }
        CAPTURE(colour);
        CAPTURE(int(rule));
        CAPTURE(invariant);
        CHECK(differences == 0);
        // The data exercises every branch: points in volumes, depth outliers and (RGB-D) colour outliers.
        CHECK(in_volume > 1000);
        CHECK(depth_outliers > 100);
        CHECK((colour_outliers > 100) == colour);
      }
}

namespace {

/// The definitions evaluated by brute force: every pair of points compared (knn_sq_distance <= delta^2),
/// every observed point of the segment tested against the volume, OutlierVote in both directions.
CostResult brute_force_cost(const CloudBatch& observed, const CloudBatch& rendered, const CostRequest& req,
                            const CostSettings& s) {
  const std::vector<Lab<float>> olab = lab_colors(observed, s.shading_invariant),
                                rlab = lab_colors(rendered, s.shading_invariant);
  const PackedVolumes vol = pack_volumes(req);
  const bool any = s.color_rule == ColorRule::AnyNeighbour;
  const float delta2 = s.delta_m * s.delta_m;
  auto classify = [&](Vec3f p, Lab<float> lab, const CloudBatch& other,
                      const std::vector<Lab<float>>& other_lab, std::int64_t b, std::int64_t e) {
    OutlierVote v{lab, other_lab.data(), s.tau_c, s.lightness_factor, s.use_color, any};
    for (std::int64_t j = b; j < e; ++j) {
      const float d2 = knn_sq_distance(p, other.point(std::size_t(j)));
      if (d2 <= delta2) v(std::int32_t(j), d2);
    }
    return v.result();
  };
  CostResult out;
  out.hypotheses.resize(rendered.num_clouds());
  for (std::size_t h = 0; h < rendered.num_clouds(); ++h) {
    CostBreakdown& b = out.hypotheses[h];
    const auto seg = std::size_t(req.observed_segment[h]);
    const std::int64_t ob = observed.offsets[seg], oe = observed.offsets[seg + 1];
    const std::int64_t rb = rendered.offsets[h], re = rendered.offsets[h + 1];
    for (std::int64_t i = rb; i < re; ++i) {
      const std::uint8_t c =
          classify(rendered.point(std::size_t(i)), rlab[std::size_t(i)], observed, olab, ob, oe);
      b.rendered_inliers += c == kInlier, b.rendered_depth_outliers += c == kDepthOutlier;
      b.rendered_color_outliers += c == kColorOutlier;
    }
    for (std::int64_t i = ob; i < oe; ++i) {
      const Vec3f p = observed.point(std::size_t(i));
      if (vol.views[h].radius_m >= 0.f && !inside_volume(vol.views[h], vol.vertices.data(), p)) continue;
      ++b.observed_in_volume;
      const std::uint8_t c = classify(p, olab[std::size_t(i)], rendered, rlab, rb, re);
      b.observed_depth_outliers += c == kDepthOutlier, b.observed_color_outliers += c == kColorOutlier;
    }
    b.rendered_points = std::int32_t(re - rb);
    finish_cost(b, s);
  }
  return out;
}

/// Number of hypotheses whose breakdowns differ in any count or the total.
int count_differences(const CostResult& a, const CostResult& b) {
  int differences = 0;
  for (std::size_t h = 0; h < a.size(); ++h) {
    const CostBreakdown &x = a.hypotheses[h], &y = b.hypotheses[h];
    differences += x.rendered_points != y.rendered_points || x.rendered_inliers != y.rendered_inliers ||
                   x.rendered_depth_outliers != y.rendered_depth_outliers ||
                   x.rendered_color_outliers != y.rendered_color_outliers ||
                   x.observed_in_volume != y.observed_in_volume ||
                   x.observed_depth_outliers != y.observed_depth_outliers ||
                   x.observed_color_outliers != y.observed_color_outliers || x.total != y.total;
  }
  return differences;
}

}  // namespace

TEST_CASE_TEMPLATE("cost equals a brute-force evaluation of its definitions", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  // Random clouds in a 6 cm cube (dense enough that most points have several neighbours within delta, some
  // none), two observed segments, volumes posed at random (some hypotheses score the whole segment).
  std::mt19937 rng(11);
  const CloudBatch observed = random_batch(rng, 2, 2500);
  CloudBatch rendered = random_batch(rng, 40, 300);
  // A few packed colours with bits above 0xRRGGBB (ignored by unpack_rgb, outside FailedColours' keys).
  for (std::size_t i = 0; i < rendered.size(); i += 10) rendered.rgb[i] |= 0xFF000000u;
  CostRequest req;
  req.footprints = {square(-0.02f, 0.02f, -0.015f, 0.025f, -0.01f, 0.02f)};
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (int h = 0; h < 40; ++h) {
    const float angle = 3.f * u(rng), tx = 0.01f * u(rng), ty = 0.01f * u(rng), tz = 0.8f + 0.01f * u(rng);
    Pose T = Pose::Identity();
    T.linear() = Eigen::AngleAxisf(angle, Eigen::Vector3f(0.3f, 0.2f, 1.f).normalized()).toRotationMatrix();
    T.translation() = Eigen::Vector3f(tx, ty, tz);
    req.add(h % 2, h % 4 == 3 ? -1 : 0, T);
  }
  const typename B::Cost cost(observed);
  for (const bool colour : {true, false})
    for (const ColorRule rule : {ColorRule::Nearest, ColorRule::AnyNeighbour}) {
      CostSettings s;
      s.use_color = colour, s.color_rule = rule, s.delta_m = 0.004f;
      s.shading_invariant = rule == ColorRule::AnyNeighbour;  // both comparison colours, both rules below
      CAPTURE(colour);
      CAPTURE(int(rule));
      const CostResult expected = brute_force_cost(observed, rendered, req, s);
      CHECK(count_differences(cost.evaluate(rendered, req, s), expected) == 0);
      int colour_outliers = 0, in_volume = 0;
      for (const auto& b : expected.hypotheses)
        colour_outliers += b.observed_color_outliers, in_volume += b.observed_in_volume;
      CHECK(in_volume > 1000);
      CHECK((colour_outliers > 50) == colour);
    }
}

TEST_CASE_TEMPLATE("cost at the delta boundary, volume edges and nearest-neighbour ties", B,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  // delta = 0.25 m and coordinates in multiples of 1/8 m make every squared distance exact, so pairs sit
  // exactly at delta (neighbours: the test is inclusive) or one step beyond it.
  CostSettings s;
  s.delta_m = 0.25f;
  auto cloud = [](const std::vector<std::array<float, 3>>& pts, const std::vector<std::uint32_t>& rgb) {
    CloudBatch c;
    for (std::size_t i = 0; i < pts.size(); ++i) {
      c.x.push_back(pts[i][0]), c.y.push_back(pts[i][1]), c.z.push_back(pts[i][2]);
      c.rgb.push_back(rgb[i]), c.pixel.push_back(-1), c.cloud.push_back(0);
    }
    c.offsets = {0, std::int64_t(c.size())};
    return c;
  };
  // Observed: o0 at the origin (red), o1 at x = 1 (red), o2 at x = 2 (blue).
  const CloudBatch observed = cloud({{0.f, 0.f, 2.f}, {1.f, 0.f, 2.f}, {2.f, 0.f, 2.f}}, {kRed, kRed, kBlue});
  // Rendered: r0 exactly delta from o0 (blue), r1 exactly delta from o0 on the other side (red): o0's two
  // neighbours tie at the same distance; r2 0.375 m from o1 (beyond delta); r3 exactly delta from o2 (red).
  const CloudBatch rendered =
      cloud({{0.25f, 0.f, 2.f}, {-0.25f, 0.f, 2.f}, {1.375f, 0.f, 2.f}, {2.f, 0.25f, 2.f}},
            {kBlue, kRed, kRed, kRed});
  const typename B::Cost cost(observed);
  CostRequest whole = whole_segment(1);
  // A volume whose face passes exactly through o1 (boundary included) and excludes o2.
  CostRequest edge;
  edge.footprints = {square(-0.5f, 1.f, -0.5f, 0.5f, 1.5f, 2.5f)};
  edge.add(0, 0, Pose::Identity());
  for (const ColorRule rule : {ColorRule::Nearest, ColorRule::AnyNeighbour})
    for (const CostRequest* req : {&whole, &edge}) {
      s.color_rule = rule;
      CAPTURE(int(rule));
      const CostResult expected = brute_force_cost(observed, rendered, *req, s);
      CHECK(count_differences(cost.evaluate(rendered, *req, s), expected) == 0);
    }
  // The definitions themselves, spelled out: o0's tied neighbours are r0 (blue, index 0) and r1 (red), so
  // Nearest (smaller index wins) calls it a colour outlier and AnyNeighbour an inlier.
  s.color_rule = ColorRule::Nearest;
  const CostBreakdown n = cost.evaluate(rendered, edge, s).hypotheses[0];
  CHECK(n.observed_in_volume == 2);       // o0 and o1 (on the face)
  CHECK(n.observed_color_outliers == 1);  // o0
  CHECK(n.observed_depth_outliers == 1);  // o1: r2 is beyond delta
  s.color_rule = ColorRule::AnyNeighbour;
  const CostBreakdown a = cost.evaluate(rendered, whole, s).hypotheses[0];
  CHECK(a.observed_in_volume == 3);
  CHECK(a.observed_color_outliers == 1);  // o2: its only neighbour r3 is red
  CHECK(a.observed_depth_outliers == 1);  // o1
  CHECK(a.rendered_depth_outliers == 1);  // r2
  CHECK(a.rendered_color_outliers == 2);  // r0 (blue on red o0), r3 (red on blue o2)
}

TEST_CASE_TEMPLATE("cost rejects bad input with a clear error", B, PERCH2_CPU_RUNNABLE_BACKENDS) {
  const CloudBatch observed = patch(0.f, 1.f, kRed);
  const typename B::Cost cost(observed);
  const CloudBatch rendered = batch({patch(0.f, 1.f, kRed)});
  CHECK_THROWS_WITH_AS(cost.evaluate(batch({}), CostRequest{}), doctest::Contains("no hypotheses"),
                       InvalidInput);
  CHECK_THROWS_WITH_AS(cost.evaluate(rendered, whole_segment(2)), doctest::Contains("one observed_segment"),
                       InvalidInput);
  CostRequest bad_segment;
  bad_segment.add(1);
  CHECK_THROWS_WITH_AS(cost.evaluate(rendered, bad_segment), doctest::Contains("observed segment 1"),
                       InvalidInput);
  CostRequest bad_footprint;
  bad_footprint.add(0, 0);
  CHECK_THROWS_WITH_AS(cost.evaluate(rendered, bad_footprint), doctest::Contains("footprint 0 out of range"),
                       InvalidInput);
  bad_footprint.footprints = {square(0.f, 0.01f, 0.f, 0.01f, 0.f, 1.f)};
  std::swap(bad_footprint.footprints[0].polygon_xy_m[1], bad_footprint.footprints[0].polygon_xy_m[3]);
  CHECK_THROWS_WITH_AS(cost.evaluate(rendered, bad_footprint), doctest::Contains("counter-clockwise"),
                       InvalidInput);
  bad_footprint.footprints = {square(0.f, 0.01f, 0.f, 0.01f, 0.f, 1.f)};
  bad_footprint.T_cam_volume[0].translation().x() = std::nanf("");
  CHECK_THROWS_WITH_AS(cost.evaluate(rendered, bad_footprint), doctest::Contains("T_cam_volume"),
                       InvalidInput);
  CloudBatch nan_rendered = rendered;
  nan_rendered.y[17] = std::nanf("");
  CHECK_THROWS_WITH_AS(cost.evaluate(nan_rendered, whole_segment(1)), doctest::Contains("point 17"),
                       InvalidInput);
  CloudBatch short_rendered = rendered;
  short_rendered.rgb.pop_back();
  CHECK_THROWS_AS(cost.evaluate(short_rendered, whole_segment(1)), InvalidInput);
  CostSettings s;
  s.delta_m = 0.f;
  CHECK_THROWS_WITH_AS(cost.evaluate(rendered, whole_segment(1), s), doctest::Contains("delta_m"),
                       InvalidInput);
  s = {};
  s.tau_c = std::nanf("");
  CHECK_THROWS_WITH_AS(cost.evaluate(rendered, whole_segment(1), s), doctest::Contains("tau_c"),
                       InvalidInput);
  CloudBatch nan_observed = observed;
  nan_observed.z[3] = std::numeric_limits<float>::infinity();
  CHECK_THROWS_WITH_AS(typename B::Cost{nan_observed}, doctest::Contains("observed cloud"), InvalidInput);
  CHECK_THROWS_WITH_AS(typename B::Cost{CloudBatch{}}, doctest::Contains("no segments"), InvalidInput);
}

TEST_CASE(
    "CIEDE2000's lightness factor: kL = 1 is the reference formula, kL = 2 halves pure lightness steps") {
  const Lab<float> grey{50.f, 0.f, 0.f}, lighter{60.f, 0.f, 0.f}, red{50.f, 60.f, 30.f};
  CHECK(ciede2000<float>(grey, red, 1.f) == ciede2000<float>(grey, red));
  // Equal (zero) chroma: Delta E = |Delta L| / (kL S_L).
  CHECK(ciede2000<float>(grey, lighter, 2.f) == doctest::Approx(0.5f * ciede2000<float>(grey, lighter)));
  CostSettings s;
  s.lightness_factor = 0.5f;
  const cpu::Cost cost(patch(0.f, 1.f, kRed));
  CHECK_THROWS_WITH_AS(cost.evaluate(batch({patch(0.f, 1.f, kRed)}), whole_segment(1), s),
                       doctest::Contains("lightness_factor"), InvalidInput);
}
