#include "perch2/synth/preview.hpp"

#include <algorithm>
#include <cmath>

namespace perch2::synth {

ColorImage depth_preview(const DepthImage& depth_m, float near_m, float far_m) {
  if (!(far_m > near_m)) throw InvalidInput("depth_preview", "far_m must exceed near_m");
  ColorImage out(depth_m.width, depth_m.height, Rgb8{0, 0, 0});
  for (std::size_t p = 0; p < depth_m.data.size(); ++p) {
    const float d = depth_m.data[p];
    if (d <= 0) continue;
    const float t = std::clamp((d - near_m) / (far_m - near_m), 0.f, 1.f);
    // A short piecewise-linear rainbow: red, yellow, green, cyan, blue.
    const float r = std::clamp(2.f - 4.f * t, 0.f, 1.f), b = std::clamp(4.f * t - 2.f, 0.f, 1.f);
    const float g = t < 0.25f ? 4.f * t : t > 0.75f ? 4.f * (1.f - t) : 1.f;
    out.data[p] = {std::uint8_t(255 * r), std::uint8_t(230 * g), std::uint8_t(255 * b)};
  }
  return out;
}

ColorImage label_overlay(const ColorImage& rgb, const LabelImage& labels) {
  check_size(labels, rgb.width, rgb.height, "label_overlay labels");
  static const Rgb8 palette[] = {{230, 25, 75},  {60, 180, 75},  {255, 225, 25}, {0, 130, 200},
                                 {245, 130, 48}, {145, 30, 180}, {70, 240, 240}, {240, 50, 230},
                                 {210, 245, 60}, {250, 190, 212}};
  ColorImage out(rgb.width, rgb.height);
  for (int v = 0; v < rgb.height; ++v)
    for (int u = 0; u < rgb.width; ++u) {
      const Rgb8 c = rgb(u, v);
      const int l = labels(u, v);
      Rgb8 o{std::uint8_t(c.r / 3), std::uint8_t(c.g / 3), std::uint8_t(c.b / 3)};
      if (l > 0) {
        const Rgb8 t = palette[(l - 1) % 10];
        const bool edge = (u > 0 && labels(u - 1, v) != l) || (v > 0 && labels(u, v - 1) != l) ||
                          (u + 1 < rgb.width && labels(u + 1, v) != l) ||
                          (v + 1 < rgb.height && labels(u, v + 1) != l);
        o = edge ? Rgb8{255, 255, 255}
                 : Rgb8{std::uint8_t((c.r + 2 * t.r) / 3), std::uint8_t((c.g + 2 * t.g) / 3),
                        std::uint8_t((c.b + 2 * t.b) / 3)};
      } else if (l < 0 && (u + v) % 6 < 2) {
        o = {150, 150, 150};
      }
      out(u, v) = o;
    }
  return out;
}

}  // namespace perch2::synth
