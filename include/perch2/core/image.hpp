// Row-major images and the RGB-D frame. Depth is float metres; 0 means "no reading".
#pragma once

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

}  // namespace perch2
