// Procedural textures for the built-in models, drawn with OpenCV (internal to perch2::synth).
#pragma once

#include <opencv2/core.hpp>

#include "perch2/core/image.hpp"

namespace perch2::synth::detail {

/// cv::Mat (8UC3, channels in R, G, B order) -> ColorImage.
ColorImage to_color_image(const cv::Mat& rgb);

/// One label design for a can or bottle: colours and words.
struct LabelDesign {
  cv::Scalar background, stripe, text_colour, accent;
  const char* brand;
  const char* slogan;
  int stripe_style;  ///< 0 waves, 1 diagonal bands, 2 thin rings
};

/// Texture of a lathe whose profile is mapped by arc length (v = 0 at the bottom pole): rows of `lathe_v`
/// in [label_v0, label_v1] carry the label, the rest is `body` (metal, glass or plastic) with rings.
ColorImage lathe_texture(int width, int height, float label_v0, float label_v1, const LabelDesign& d,
                         cv::Scalar body, cv::Scalar cap, float cap_v0);

/// Wood grain for the table top (repeating).
ColorImage wood_texture(int size, unsigned seed);
/// Painted wall with faint blotches; floor tiles.
ColorImage wall_texture(int size, cv::Scalar paint, unsigned seed);
ColorImage floor_texture(int size, cv::Scalar a, cv::Scalar b);

}  // namespace perch2::synth::detail
