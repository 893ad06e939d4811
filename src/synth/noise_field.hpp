// Smooth random fields for blotchy dropouts and wobbly mask boundaries (internal to perch2::synth).
#pragma once

#include <opencv2/core.hpp>

#include "perch2/synth/random.hpp"

namespace perch2::synth::detail {

/// A width x height CV_32F field in [0, 1): uniform values on a grid `cell_px` apart, bicubically
/// interpolated (so blobs are about cell_px wide).
cv::Mat smooth_noise(int width, int height, int cell_px, Rng& rng);

}  // namespace perch2::synth::detail
