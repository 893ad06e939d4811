// Pictures for looking at generated frames: false-colour depth and instance masks over the colour image.
#pragma once

#include "perch2/core/export.hpp"
#include "perch2/core/image.hpp"

namespace perch2::synth {

/// Depth as a turbo-like colour ramp from near_m (red) to far_m (blue); no reading = black.
PERCH2_API ColorImage depth_preview(const DepthImage& depth_m, float near_m, float far_m);

/// The colour image darkened, with each label > 0 tinted in its own colour and outlined; labels < 0
/// (distractors) hatched grey.
PERCH2_API ColorImage label_overlay(const ColorImage& rgb, const LabelImage& labels);

}  // namespace perch2::synth
