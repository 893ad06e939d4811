// Appearance agreement of rendered hypotheses with the frame's colours: how well the print of a model
// (texture or vertex colours) lines up with what the camera sees, independently of how the scene was lit
// and of the camera's colour pipeline. What decides the turns the geometry cannot see (a printed can about
// its axis, a box's front and back; perch2/search/local_search.hpp).
//
//   std::vector<AppearanceSamples> pairs = appearance_samples(rendered, frame, /*depth_tolerance_m=*/0.01f);
//   AppearanceScore a = appearance_score(pairs[h]);          // or weighted by a family's PrintVariation
//
// Pairs: each rendered point and the frame's colour at its pixel, where the frame's depth there is within
// depth_tolerance_m of the rendered depth (the camera sees that surface; occluders are the renderer's
// business). Features of a colour, in linear RGB with e = 0.01 (about one sRGB code at black):
//   log((R + e) / (G + e)), log((B + e) / (G + e))   chromaticity: shading, shadows and exposure scale R, G
//                                                    and B alike and cancel; a white balance adds a constant
//   log(Y + e)                                       luminance (dark print on a light label): shading adds a
//                                                    smooth field, exposure a constant
// Per feature, the zero-mean normalised cross-correlation of the rendered and the observed values over the
// pairs, which is blind to a constant added (white balance, exposure) and to a scale (a gamma-like tone
// curve scales the logs); the score is the mean over the features that vary on both sides (a single
// coloured render has no chromaticity to correlate).
//
// Comparing a family of renders of one object (its turns about an axis the geometry cannot fix), most
// pixels show the same print in every member: a can's lid, a label's plain background. They correlate alike
// for every turn and drown the few that tell the turns apart (a label's letters). PrintVariation weighs
// each pair by how much the family's print varies at its pixel, v / (v + kVariationScale), v the variance
// of the rendered features over the family. bench/bench_turns, turns every 2 deg about the model's z axis
// from the ground truth at stride 2, the look-alikes (depth-only cost within 0.02) compared: the best turn
// lay within 5 deg of the truth for 66 of the 73 printed cans, bottles and boxes of 20 generated cluttered
// scenes (64 unweighted, 66 for the fewest nearest-colour CIEDE2000 failures, ColorRule::Nearest), 65 /
// 62 / 52 after a strong white balance, a filmic tone curve and desaturation of the frame's colours, and for
// 106 / 102 / 101 of the 110 on 30 generated tabletop scenes.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "perch2/color/ciede2000.hpp"
#include "perch2/core/cloud.hpp"
#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"

namespace perch2 {

/// One pair: a rendered point's pixel and the features of its rendered and observed colours.
struct AppearanceSample {
  std::int32_t pixel = 0;
  std::array<float, 3> rendered{}, observed{};
};
using AppearanceSamples = std::vector<AppearanceSample>;

/// A hypothesis' appearance agreement with the frame.
struct AppearanceScore {
  /// Mean normalised cross-correlation of the features (file comment) over the pairs, in [-1, 1]; 0 when
  /// no feature varies on both sides (nothing to compare: an untextured model, or too few pairs).
  float ncc = 0.f;
  std::int32_t pairs = 0;  ///< rendered points whose pixel shows their surface (file comment)
};

namespace appearance_detail {

constexpr int kFeatures = 3;
constexpr int kMinPairs = 10;  ///< fewer pairs correlate nothing
/// A feature whose variance over the pairs is below this (log units squared) does not vary.
constexpr double kMinVariance = 1e-6;

/// The features of every 8-bit sRGB colour are log(linear + e) per channel: a table of 256 entries.
inline const std::array<float, 256>& log_linear() {
  static const std::array<float, 256> table = [] {
    std::array<float, 256> t{};
    for (int c = 0; c < 256; ++c)
      t[std::size_t(c)] = std::log(color_math::srgb_to_linear<float>(std::uint8_t(c)) + 0.01f);
    return t;
  }();
  return table;
}

/// exp of log_linear(), in double: the luminance's terms, looked up instead of computed per colour.
inline const std::array<double, 256>& exp_log_linear() {
  static const std::array<double, 256> table = [] {
    std::array<double, 256> t{};
    for (int c = 0; c < 256; ++c) t[std::size_t(c)] = std::exp(double(log_linear()[std::size_t(c)]));
    return t;
  }();
  return table;
}

inline std::array<float, kFeatures> features(Rgb8 c) {
  const std::array<float, 256>& lg = log_linear();
  const std::array<double, 256>& ex = exp_log_linear();
  const double r = lg[c.r], g = lg[c.g], b = lg[c.b];
  const double y = std::log(0.2126729 * ex[c.r] + 0.7151522 * ex[c.g] + 0.0721750 * ex[c.b]);
  return {float(r - g), float(b - g), float(y)};
}

}  // namespace appearance_detail

/// How much a family of renders of one object varies in print at each pixel (see the file comment), on a
/// grid of `cell` x `cell` pixels (the stride the family was rendered at: a finer render of the same object
/// looks up the cell its pixel falls in).
class PrintVariation {
 public:
  /// A rendered feature variance of this much (log units squared) weighs half: a label's letters against
  /// its background vary by ~1, a region every member shows alike by 0.
  static constexpr double kVariationScale = 0.01;

  PrintVariation(int width, int cell) : width_(std::max(width, 1)), cell_(std::max(cell, 1)) {}

  /// Adds one member's pairs (its rendered features).
  void add(const AppearanceSamples& member) {
    if (member.empty()) return;
    Box b = box_;
    for (const AppearanceSample& a : member) b = b.with(row(a.pixel), col(a.pixel));
    if (!(b == box_)) relayout(b);
    for (const AppearanceSample& a : member) {
      Moments& m = cells_[index(a.pixel)];
      for (int k = 0; k < appearance_detail::kFeatures; ++k)
        m.sum[k] += a.rendered[k], m.squares[k] += double(a.rendered[k]) * a.rendered[k];
      m.n += 1;
    }
  }

  /// v / (v + kVariationScale) at the pixel's cell; 0 where no member was seen.
  double weight(std::int32_t pixel) const {
    const std::int64_t r = row(pixel), c = col(pixel);
    if (!box_.holds(r, c)) return 0;
    const Moments& m = cells_[box_.index(r, c)];
    if (!(m.n > 0)) return 0;
    double v = 0;
    for (int k = 0; k < appearance_detail::kFeatures; ++k)
      v += std::max(0.0, m.squares[k] / m.n - (m.sum[k] / m.n) * (m.sum[k] / m.n));
    return v / (v + kVariationScale);
  }

 private:
  struct Moments {
    std::array<double, appearance_detail::kFeatures> sum{}, squares{};
    double n = 0;
  };
  /// The cells held: rows [r0, r1) x columns [c0, c1), row-major (a dense grid over the members' pixels, not
  /// the whole frame).
  struct Box {
    std::int64_t r0 = 0, r1 = 0, c0 = 0, c1 = 0;
    bool empty() const { return r1 <= r0 || c1 <= c0; }
    bool holds(std::int64_t r, std::int64_t c) const { return r >= r0 && r < r1 && c >= c0 && c < c1; }
    std::size_t index(std::int64_t r, std::int64_t c) const {
      return std::size_t((r - r0) * (c1 - c0) + c - c0);
    }
    Box with(std::int64_t r, std::int64_t c) const {
      if (empty()) return {r, r + 1, c, c + 1};
      return {std::min(r0, r), std::max(r1, r + 1), std::min(c0, c), std::max(c1, c + 1)};
    }
    bool operator==(const Box& o) const { return r0 == o.r0 && r1 == o.r1 && c0 == o.c0 && c1 == o.c1; }
  };
  std::int64_t row(std::int32_t pixel) const { return (pixel / width_) / cell_; }
  std::int64_t col(std::int32_t pixel) const { return (pixel % width_) / cell_; }
  std::size_t index(std::int32_t pixel) const { return box_.index(row(pixel), col(pixel)); }
  void relayout(const Box& b) {
    std::vector<Moments> cells(std::size_t((b.r1 - b.r0) * (b.c1 - b.c0)));
    for (std::int64_t r = box_.r0; r < box_.r1; ++r)
      for (std::int64_t c = box_.c0; c < box_.c1; ++c) cells[b.index(r, c)] = cells_[box_.index(r, c)];
    cells_ = std::move(cells), box_ = b;
  }
  int width_, cell_;
  Box box_;
  std::vector<Moments> cells_;
};

/// The appearance score of one hypothesis' pairs (see the file comment), each weighted by `variation` if
/// given (weight 1 otherwise).
inline AppearanceScore appearance_score(const AppearanceSamples& pairs,
                                        const PrintVariation* variation = nullptr) {
  using namespace appearance_detail;
  AppearanceScore out;
  out.pairs = std::int32_t(pairs.size());
  if (pairs.size() < std::size_t(kMinPairs)) return out;
  double n = 0;
  std::array<double, kFeatures> r{}, o{}, rr{}, oo{}, ro{};
  for (const AppearanceSample& a : pairs) {
    const double w = variation ? variation->weight(a.pixel) : 1.0;
    if (!(w > 0)) continue;
    n += w;
    for (int k = 0; k < kFeatures; ++k) {
      const double x = a.rendered[std::size_t(k)], y = a.observed[std::size_t(k)];
      r[k] += w * x, o[k] += w * y, rr[k] += w * x * x, oo[k] += w * y * y, ro[k] += w * x * y;
    }
  }
  if (!(n > 0)) return out;
  double sum = 0;
  int used = 0;
  for (int k = 0; k < kFeatures; ++k) {
    const double vr = rr[k] / n - (r[k] / n) * (r[k] / n), vo = oo[k] / n - (o[k] / n) * (o[k] / n);
    if (vr < kMinVariance || vo < kMinVariance) continue;
    sum += (ro[k] / n - (r[k] / n) * (o[k] / n)) / std::sqrt(vr * vo), ++used;
  }
  out.ncc = used > 0 ? float(sum / used) : 0.f;
  return out;
}

/// The pairs of every cloud of `rendered` (a renderer's output: points with their full-resolution pixel and
/// colour) with `frame` (see the file comment). Throws InvalidInput if the frame has no colour image, a
/// malformed batch, a pixel outside the frame or a non-positive tolerance.
inline std::vector<AppearanceSamples> appearance_samples(const CloudBatch& rendered, const RgbdFrame& frame,
                                                         float depth_tolerance_m) {
  using appearance_detail::features;
  rendered.validate("appearance: rendered clouds");
  if (frame.rgb.empty()) throw InvalidInput("appearance: frame", "has no colour image");
  if (!(depth_tolerance_m > 0)) throw InvalidInput("appearance: depth_tolerance_m", "must be > 0");
  const std::int64_t pixels = std::int64_t(frame.depth_m.data.size());
  if (std::any_of(rendered.pixel.begin(), rendered.pixel.end(), [&](std::int32_t p) { return p >= pixels; }))
    throw InvalidInput("appearance: rendered clouds", "a pixel lies outside the frame");
  std::vector<AppearanceSamples> out(rendered.num_clouds());
  // Clouds in parallel (a turn search compares hundreds per call; the features take logs).
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, 8)
#endif
  for (std::int64_t c = 0; c < std::int64_t(rendered.num_clouds()); ++c)
    for (auto i = std::size_t(rendered.offsets[std::size_t(c)]);
         i < std::size_t(rendered.offsets[std::size_t(c) + 1]); ++i) {
      const std::int32_t p = rendered.pixel[i];
      if (p < 0) continue;
      const float d = frame.depth_m.data[std::size_t(p)];
      if (!(d > 0) || std::abs(d - rendered.z[i]) > depth_tolerance_m) continue;
      out[std::size_t(c)].push_back(
          {p, features(unpack_rgb(rendered.rgb[i])), features(frame.rgb.data[std::size_t(p)])});
    }
  return out;
}

/// The unweighted appearance score of every cloud of `rendered` against `frame` (appearance_samples, then
/// appearance_score).
inline std::vector<AppearanceScore> appearance_scores(const CloudBatch& rendered, const RgbdFrame& frame,
                                                      float depth_tolerance_m) {
  std::vector<AppearanceScore> out;
  for (const AppearanceSamples& s : appearance_samples(rendered, frame, depth_tolerance_m))
    out.push_back(appearance_score(s));
  return out;
}

}  // namespace perch2
