// Pinhole intrinsics in the OpenCV frame (x right, y down, z forward); pixel centres at integer (u, v).
#pragma once

#include <cmath>
#include <string>

#include "perch2/core/device.hpp"
#include "perch2/core/error.hpp"

namespace perch2 {

struct Intrinsics {
  float fx = 0, fy = 0;  ///< focal lengths, pixels
  float cx = 0, cy = 0;  ///< principal point, pixels
  int width = 0, height = 0;

  /// Pixel coordinates of a camera-frame point (z > 0).
  PERCH2_HD Vec2f project(Vec3f p_cam) const {
    return {fx * p_cam.x / p_cam.z + cx, fy * p_cam.y / p_cam.z + cy};
  }
  /// Camera-frame point at depth z (metres) seen at pixel (u, v).
  PERCH2_HD Vec3f backproject(float u, float v, float z) const {
    return {(u - cx) / fx * z, (v - cy) / fy * z, z};
  }
  /// Ray direction with z = 1 through pixel (u, v). Multiplies by 1/f (hoisted out of pixel loops) rather
  /// than dividing: every ray in perch2 comes from here, so renders stay bit-identical across strides and
  /// backends.
  PERCH2_HD Vec3f ray(float u, float v) const { return {(u - cx) * (1.f / fx), (v - cy) * (1.f / fy), 1.f}; }
  PERCH2_HD int num_pixels() const { return width * height; }

  /// The stride grid: full-resolution pixels (s*i, s*j). Its intrinsics are K/s, so projecting with them
  /// gives grid coordinates; it has ceil(W/s) x ceil(H/s) samples.
  PERCH2_HD int grid_width(int stride) const { return (width + stride - 1) / stride; }
  PERCH2_HD int grid_height(int stride) const { return (height + stride - 1) / stride; }
  Intrinsics at_stride(int stride) const {
    return {fx / stride, fy / stride, cx / stride, cy / stride, grid_width(stride), grid_height(stride)};
  }

  /// Throws InvalidInput unless focal lengths are positive and finite and the image is non-empty.
  void validate(const std::string& name = "camera intrinsics") const {
    if (!(std::isfinite(fx) && std::isfinite(fy) && fx > 0 && fy > 0))
      throw InvalidInput(name, "focal lengths must be positive and finite");
    if (!(std::isfinite(cx) && std::isfinite(cy))) throw InvalidInput(name, "principal point must be finite");
    if (width <= 0 || height <= 0) throw InvalidInput(name, "image size must be positive");
  }
};

}  // namespace perch2
