// Row-major images and the RGB-D frame. Depth is float metres; 0 means "no reading".
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "perch2/core/camera.hpp"
#include "perch2/core/device.hpp"
#include "perch2/core/error.hpp"

namespace perch2 {

template <class T>
struct Image {
  int width = 0, height = 0;
  std::vector<T> data;  ///< row-major, data[v * width + u]

  Image() = default;
  Image(int w, int h, T fill = T{}) : width(w), height(h), data(std::size_t(w) * std::size_t(h), fill) {}
  bool empty() const { return data.empty(); }
  T& operator()(int u, int v) { return data[std::size_t(v) * width + u]; }
  const T& operator()(int u, int v) const { return data[std::size_t(v) * width + u]; }
};

using DepthImage = Image<float>;         ///< metres, 0 = no reading
using ColorImage = Image<Rgb8>;          ///< 8-bit sRGB
using LabelImage = Image<std::int32_t>;  ///< per-pixel instance label, 0 = background

/// Throws InvalidInput if the image is not width x height.
template <class T>
void check_size(const Image<T>& image, int width, int height, const std::string& name) {
  if (image.width != width || image.height != height || image.data.size() != std::size_t(width) * height)
    throw InvalidInput(name, "expected " + std::to_string(width) + "x" + std::to_string(height) + ", got " +
                                 std::to_string(image.width) + "x" + std::to_string(image.height));
}

/// Throws InvalidInput on NaN, infinite or negative depth (use 0 for "no reading").
inline void check_depth_values(const DepthImage& depth_m, const std::string& name) {
  for (std::size_t i = 0; i < depth_m.data.size(); ++i) {
    const float d = depth_m.data[i];
    if (!std::isfinite(d) || d < 0)
      throw InvalidInput(name, "depth at pixel (" + std::to_string(i % depth_m.width) + ", " +
                                   std::to_string(i / depth_m.width) + ") is " + std::to_string(d) +
                                   "; depth must be finite and >= 0 (0 = no reading)");
  }
}

/// One registered RGB-D frame: depth and colour share the camera.
struct RgbdFrame {
  Intrinsics camera;
  DepthImage depth_m;
  ColorImage rgb;

  void validate(const std::string& name = "RGB-D frame") const {
    camera.validate(name + " camera");
    check_size(depth_m, camera.width, camera.height, name + " depth");
    if (!rgb.empty()) check_size(rgb, camera.width, camera.height, name + " colour");
    check_depth_values(depth_m, name + " depth");
  }
};

/// Bounding box (x, y, w = x_max - x_min, h = y_max - y_min) of a mask's non-zero pixels, as bop_toolkit's
/// calc_2d_bbox; {-1, -1, -1, -1} if there are none.
inline std::array<int, 4> mask_bbox(const Image<std::uint8_t>& mask) {
  int x0 = mask.width, y0 = mask.height, x1 = -1, y1 = -1;
  for (int v = 0; v < mask.height; ++v)
    for (int u = 0; u < mask.width; ++u)
      if (mask(u, v)) x0 = std::min(x0, u), x1 = std::max(x1, u), y0 = std::min(y0, v), y1 = std::max(y1, v);
  if (x1 < 0) return {-1, -1, -1, -1};
  return {x0, y0, x1 - x0, y1 - y0};
}

}  // namespace perch2
