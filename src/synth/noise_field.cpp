#include "noise_field.hpp"

#include <algorithm>
#include <opencv2/imgproc.hpp>

namespace perch2::synth::detail {

cv::Mat smooth_noise(int width, int height, int cell_px, Rng& rng) {
  cell_px = std::max(1, cell_px);
  cv::Mat coarse(height / cell_px + 2, width / cell_px + 2, CV_32F);
  for (int y = 0; y < coarse.rows; ++y)
    for (int x = 0; x < coarse.cols; ++x) coarse.at<float>(y, x) = float(rng.uniform());
  cv::Mat fine;
  cv::resize(coarse, fine, {coarse.cols * cell_px, coarse.rows * cell_px}, 0, 0, cv::INTER_CUBIC);
  cv::Mat out = fine(cv::Rect(cell_px / 2, cell_px / 2, width, height)).clone();
  cv::min(cv::max(out, 0.f), 0.99999f, out);
  return out;
}

}  // namespace perch2::synth::detail
