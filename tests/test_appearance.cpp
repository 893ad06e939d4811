// appearance_scores (perch2/cost/appearance.hpp) against a double-precision reference written here from the
// definitions (the sRGB transfer function and the logs in double, no table), and its invariances.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "perch2/cost/appearance.hpp"

using namespace perch2;

namespace {

constexpr int kW = 64, kH = 48;

double linear(std::uint8_t code) {
  const double c = code / 255.0;
  return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
}

/// The file comment's features, in double.
std::array<double, 3> reference_features(Rgb8 c) {
  const double r = linear(c.r) + 0.01, g = linear(c.g) + 0.01, b = linear(c.b) + 0.01;
  const double y = 0.2126729 * (r - 0.01) + 0.7151522 * (g - 0.01) + 0.0721750 * (b - 0.01) + 0.01;
  return {std::log(r / g), std::log(b / g), std::log(y)};
}

/// Mean over the features that vary of the normalised cross-correlation of the pairs, in double.
double reference_ncc(const std::vector<std::pair<Rgb8, Rgb8>>& pairs) {
  double sum = 0;
  int used = 0;
  for (int k = 0; k < 3; ++k) {
    double mr = 0, mo = 0;
    for (const auto& [r, o] : pairs) mr += reference_features(r)[k], mo += reference_features(o)[k];
    mr /= double(pairs.size()), mo /= double(pairs.size());
    double c = 0, vr = 0, vo = 0;
    for (const auto& [r, o] : pairs) {
      const double a = reference_features(r)[k] - mr, b = reference_features(o)[k] - mo;
      c += a * b, vr += a * a, vo += b * b;
    }
    vr /= double(pairs.size()), vo /= double(pairs.size()), c /= double(pairs.size());
    if (vr < 1e-6 || vo < 1e-6) continue;
    sum += c / std::sqrt(vr * vo), ++used;
  }
  return used ? sum / used : 0.0;
}

RgbdFrame frame_of(const std::vector<Rgb8>& rgb, float depth_m) {
  RgbdFrame f;
  f.camera = Intrinsics{50.f, 50.f, 31.5f, 23.5f, kW, kH};
  f.depth_m = DepthImage(kW, kH, depth_m);
  f.rgb = Image<Rgb8>(kW, kH, Rgb8{0, 0, 0});
  f.rgb.data = rgb;
  return f;
}

/// One cloud per colour list: point i at pixel i, depth z.
CloudBatch rendered_of(const std::vector<std::vector<Rgb8>>& clouds, float z) {
  CloudBatch b;
  for (std::size_t c = 0; c < clouds.size(); ++c) {
    for (std::size_t i = 0; i < clouds[c].size(); ++i) {
      b.x.push_back(0.f), b.y.push_back(0.f), b.z.push_back(z);
      b.rgb.push_back(pack_rgb(clouds[c][i])), b.pixel.push_back(std::int32_t(i)),
          b.cloud.push_back(std::int32_t(c));
    }
    b.offsets.push_back(std::int64_t(b.size()));
  }
  return b;
}

std::vector<Rgb8> random_colours(std::size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> d(20, 235);
  std::vector<Rgb8> out(n);
  for (auto& c : out) c = Rgb8{std::uint8_t(d(rng)), std::uint8_t(d(rng)), std::uint8_t(d(rng))};
  return out;
}

}  // namespace

TEST_CASE("appearance_scores: equals the double-precision reference on random print and frame colours") {
  const std::vector<Rgb8> observed = random_colours(std::size_t(kW * kH), 1);
  std::vector<Rgb8> print = random_colours(500, 2);
  for (std::size_t i = 0; i < 250; ++i) print[i] = observed[i];  // half the print matches the frame
  const RgbdFrame f = frame_of(observed, 1.f);
  const std::vector<AppearanceScore> s = appearance_scores(rendered_of({print}, 1.f), f, 0.01f);
  REQUIRE(s.size() == 1);
  std::vector<std::pair<Rgb8, Rgb8>> pairs;
  for (std::size_t i = 0; i < print.size(); ++i) pairs.push_back({print[i], observed[i]});
  CHECK(s[0].pairs == 500);
  CHECK(s[0].ncc == doctest::Approx(reference_ncc(pairs)).epsilon(1e-4));
  CHECK(s[0].ncc > 0.3f);
  CHECK(s[0].ncc < 0.7f);
}

TEST_CASE(
    "appearance_scores: 1 for the frame's own colours, whatever its white balance, exposure and gamma") {
  const std::vector<Rgb8> observed = random_colours(std::size_t(kW * kH), 3);
  const std::vector<Rgb8> print(observed.begin(), observed.begin() + 800);
  // The camera's pipeline: per-channel gains (white balance, exposure) and a gamma, in linear light.
  std::vector<Rgb8> piped = observed;
  auto encode = [](double x) {
    x = std::clamp(x, 0.0, 1.0);
    return std::uint8_t(
        std::lround(255 * (x <= 0.0031308 ? 12.92 * x : 1.055 * std::pow(x, 1 / 2.4) - 0.055)));
  };
  for (Rgb8& c : piped)
    c = Rgb8{encode(std::pow(0.8 * linear(c.r), 0.8)), encode(std::pow(0.7 * linear(c.g), 0.8)),
             encode(std::pow(0.5 * linear(c.b), 0.8))};
  const auto same = appearance_scores(rendered_of({print}, 1.f), frame_of(observed, 1.f), 0.01f);
  const auto other = appearance_scores(rendered_of({print}, 1.f), frame_of(piped, 1.f), 0.01f);
  CHECK(same[0].ncc == doctest::Approx(1.f).epsilon(1e-5));
  CHECK(other[0].ncc > 0.97f);  // 8-bit rounding of the darker colours is all that differs
  // A print that does not match (another random pattern) correlates with nothing.
  const auto unrelated =
      appearance_scores(rendered_of({random_colours(800, 4)}, 1.f), frame_of(piped, 1.f), 0.01f);
  CHECK(std::abs(unrelated[0].ncc) < 0.15f);
}

TEST_CASE(
    "appearance_scores: pairs only where the frame sees the rendered surface; one colour compares nothing") {
  const std::vector<Rgb8> observed = random_colours(std::size_t(kW * kH), 5);
  RgbdFrame f = frame_of(observed, 1.f);
  for (int i = 0; i < 100; ++i) f.depth_m.data[std::size_t(i)] = 0.9f;   // something in front: 10 cm nearer
  for (int i = 100; i < 150; ++i) f.depth_m.data[std::size_t(i)] = 0.f;  // no reading
  CloudBatch b = rendered_of({std::vector<Rgb8>(observed.begin(), observed.begin() + 400),
                              std::vector<Rgb8>(400, Rgb8{200, 30, 30})},
                             1.005f);
  b.pixel[399] = -1;  // a point without a pixel
  const auto s = appearance_scores(b, f, 0.01f);
  CHECK(s[0].pairs == 400 - 100 - 50 - 1);
  CHECK(s[0].ncc == doctest::Approx(1.f).epsilon(1e-5));
  CHECK(s[1].pairs == 400 - 150);
  CHECK(s[1].ncc == 0.f);  // an untextured model: no feature varies on the rendered side
  CHECK(appearance_scores(b, f, 0.001f)[0].pairs == 0);  // 5 mm behind the readings: none within 1 mm
  CHECK(appearance_scores(b, f, 0.001f)[0].ncc == 0.f);
}

TEST_CASE("appearance_scores: bad inputs raise clear errors") {
  const RgbdFrame f = frame_of(random_colours(std::size_t(kW * kH), 6), 1.f);
  const CloudBatch b = rendered_of({random_colours(20, 7)}, 1.f);
  RgbdFrame no_rgb = f;
  no_rgb.rgb = Image<Rgb8>();
  CHECK_THROWS_WITH_AS(appearance_scores(b, no_rgb, 0.01f), doctest::Contains("no colour image"),
                       InvalidInput);
  CHECK_THROWS_WITH_AS(appearance_scores(b, f, 0.f), doctest::Contains("depth_tolerance_m"), InvalidInput);
  CHECK_THROWS_AS(appearance_scores(b, f, NAN), InvalidInput);
  CloudBatch outside = b;
  outside.pixel[3] = kW * kH;
  CHECK_THROWS_WITH_AS(appearance_scores(outside, f, 0.01f), doctest::Contains("outside the frame"),
                       InvalidInput);
  CloudBatch torn = b;
  torn.rgb.pop_back();
  CHECK_THROWS_WITH_AS(appearance_scores(torn, f, 0.01f), doctest::Contains("different lengths"),
                       InvalidInput);
}
