// Structure-of-arrays point clouds: many clouds (one per hypothesis) in one batch.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "perch2/core/device.hpp"
#include "perch2/core/error.hpp"

namespace perch2 {

/// Cloud c holds points [offsets[c], offsets[c+1]). Points are in the camera frame, metres.
struct CloudBatch {
  std::vector<float> x, y, z;
  std::vector<std::uint32_t> rgb;        ///< 0xRRGGBB sRGB
  std::vector<std::int32_t> pixel;       ///< full-resolution pixel index v * width + u, or -1 if none
  std::vector<std::int32_t> cloud;       ///< index of the cloud (hypothesis) the point belongs to
  std::vector<std::int64_t> offsets{0};  ///< size num_clouds() + 1

  std::size_t size() const { return x.size(); }
  std::size_t num_clouds() const { return offsets.size() - 1; }
  std::size_t cloud_size(std::size_t c) const { return std::size_t(offsets[c + 1] - offsets[c]); }
  Vec3f point(std::size_t i) const { return {x[i], y[i], z[i]}; }

  void resize(std::size_t n) {
    x.resize(n), y.resize(n), z.resize(n), rgb.resize(n), pixel.resize(n), cloud.resize(n);
  }

  /// Throws InvalidInput if the arrays and offsets disagree.
  void validate(const std::string& name = "cloud batch") const {
    const std::size_t n = x.size();
    if (y.size() != n || z.size() != n || rgb.size() != n || pixel.size() != n || cloud.size() != n)
      throw InvalidInput(name, "arrays have different lengths");
    if (offsets.empty() || offsets.front() != 0 || std::size_t(offsets.back()) != n)
      throw InvalidInput(name, "offsets must start at 0 and end at the point count");
    for (std::size_t c = 0; c + 1 < offsets.size(); ++c)
      if (offsets[c + 1] < offsets[c]) throw InvalidInput(name, "offsets must not decrease");
  }
};

}  // namespace perch2
