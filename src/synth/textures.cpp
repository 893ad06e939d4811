#include "textures.hpp"

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "perch2/synth/random.hpp"

namespace perch2::synth::detail {

ColorImage to_color_image(const cv::Mat& rgb) {
  ColorImage out(rgb.cols, rgb.rows);
  for (int y = 0; y < rgb.rows; ++y)
    for (int x = 0; x < rgb.cols; ++x) {
      const cv::Vec3b c = rgb.at<cv::Vec3b>(y, x);
      out(x, y) = {c[0], c[1], c[2]};
    }
  return out;
}

namespace {

/// Text centred at (cx, cy), scaled to `width_px` wide.
void centred_text(cv::Mat& img, const std::string& text, int cx, int cy, int width_px, cv::Scalar colour,
                  int font = cv::FONT_HERSHEY_DUPLEX, int thickness = 2) {
  int base = 0;
  const cv::Size unit = cv::getTextSize(text, font, 1.0, thickness, &base);
  const double scale = double(width_px) / unit.width;
  const cv::Size sz = cv::getTextSize(text, font, scale, thickness, &base);
  cv::putText(img, text, {cx - sz.width / 2, cy + sz.height / 2}, font, scale, colour,
              std::max(1, int(thickness * scale * 0.6)), cv::LINE_AA);
}

/// A barcode block: deterministic bar widths from the text.
void barcode(cv::Mat& img, cv::Rect r, unsigned seed) {
  cv::rectangle(img, r, {245, 245, 245}, cv::FILLED);
  Rng rng(seed);
  for (int x = r.x + 4; x < r.x + r.width - 4;) {
    const int w = rng.integer(1, 3);
    if (rng.chance(0.5f)) cv::rectangle(img, {x, r.y + 3, w, r.height - 12}, {10, 10, 10}, cv::FILLED);
    x += w + 1;
  }
}

}  // namespace

ColorImage lathe_texture(int width, int height, float label_v0, float label_v1, const LabelDesign& d,
                         cv::Scalar body, cv::Scalar cap, float cap_v0) {
  cv::Mat img(height, width, CV_8UC3, body);
  auto row = [&](float v) { return int(std::lround((1.f - v) * height)); };  // v = 0 at the bottom
  // Caps and body: concentric rings (v runs along the radius on the lids).
  for (int y = 0; y < height; ++y) {
    const float v = 1.f - (y + 0.5f) / height;
    const cv::Scalar base = v >= cap_v0 ? cap : body;
    const double ring = 0.9 + 0.1 * std::cos(v * 260.0);
    cv::line(img, {0, y}, {width - 1, y}, base * ring, 1);
  }
  const int y0 = row(label_v1), y1 = row(label_v0), h = y1 - y0;
  cv::rectangle(img, {0, y0, width, h}, d.background, cv::FILLED);
  // Stripes around the can.
  if (d.stripe_style == 0) {
    for (int x = 0; x < width; ++x) {
      const int yc = y0 + int(h * (0.72 + 0.08 * std::sin(2 * CV_PI * 2 * x / width)));
      cv::line(img, {x, yc - h / 18}, {x, yc + h / 18}, d.stripe, 1);
    }
  } else if (d.stripe_style == 1) {
    for (int k = 0; k < 8; ++k) {
      const int x = k * width / 8;
      std::vector<cv::Point> band{
          {x, y1}, {x + width / 16, y1}, {x + width / 16 + h / 3, y1 - h / 3}, {x + h / 3, y1 - h / 3}};
      cv::fillConvexPoly(img, band, d.stripe, cv::LINE_AA);
    }
  } else {
    for (int k = 0; k < 3; ++k)
      cv::rectangle(img, {0, y0 + h / 10 + k * h / 14, width, h / 28}, d.stripe, -1);
  }
  // Front: brand and a logo; back: slogan and a barcode (so every yaw looks different).
  centred_text(img, d.brand, width / 4, y0 + int(0.45 * h), int(0.34 * width), d.text_colour);
  cv::circle(img, {width / 4 - int(0.2 * width), y0 + int(0.22 * h)}, h / 10, d.accent, cv::FILLED,
             cv::LINE_AA);
  cv::circle(img, {width / 4 - int(0.2 * width), y0 + int(0.22 * h)}, h / 16, d.background, cv::FILLED,
             cv::LINE_AA);
  centred_text(img, d.slogan, 3 * width / 4, y0 + int(0.3 * h), int(0.3 * width), d.text_colour,
               cv::FONT_HERSHEY_SIMPLEX, 1);
  barcode(img, {int(0.62 * width), y0 + int(0.45 * h), int(0.12 * width), int(0.22 * h)},
          unsigned(d.brand[0]) * 31u + unsigned(d.slogan[0]));
  cv::rectangle(img, {int(0.78 * width), y0 + int(0.45 * h), int(0.14 * width), int(0.2 * h)}, d.accent, 2);
  return to_color_image(img);
}

ColorImage wood_texture(int size, unsigned seed) {
  cv::Mat img(size, size, CV_8UC3);
  Rng rng(seed);
  // Fine streaks along the grain (x): a smoothed random value per row, periodic so the texture tiles.
  std::vector<float> streak(size);
  for (float& v : streak) v = float(rng.uniform());
  std::vector<float> smooth(size);
  for (int y = 0; y < size; ++y) {
    float acc = 0;
    for (int k = -2; k <= 2; ++k) acc += streak[(y + k + size) % size];
    smooth[y] = acc / 5;
  }
  const float phase[3] = {rng.uniform(0.f, 6.28f), rng.uniform(0.f, 6.28f), rng.uniform(0.f, 6.28f)};
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) {
      const double fx = 2 * CV_PI * x / size, fy = 2 * CV_PI * y / size;
      // Growth rings: bands across y, bent slowly along x.
      const double warp = 0.5 * std::sin(fx + phase[0]) + 0.2 * std::sin(3 * fx + phase[1]);
      const double rings = 0.5 + 0.5 * std::sin(11 * fy + 1.2 * warp + 0.4 * std::sin(2 * fy + phase[2]));
      const double t = 0.4 * std::pow(rings, 4.0) + 0.6 * smooth[y];
      img.at<cv::Vec3b>(y, x) = {cv::saturate_cast<uchar>(150 - 55 * t),
                                 cv::saturate_cast<uchar>(108 - 45 * t),
                                 cv::saturate_cast<uchar>(72 - 32 * t)};
    }
  return to_color_image(img);
}

ColorImage wall_texture(int size, cv::Scalar paint, unsigned seed) {
  cv::Mat img(size, size, CV_8UC3, paint);
  Rng rng(seed);
  for (int k = 0; k < 40; ++k) {
    const cv::Point c{rng.integer(0, size - 1), rng.integer(0, size - 1)};
    const double shade = rng.uniform(0.93f, 1.05f);
    cv::circle(img, c, rng.integer(size / 20, size / 6), paint * shade, cv::FILLED, cv::LINE_AA);
  }
  cv::GaussianBlur(img, img, {0, 0}, size / 40.0);
  // A framed poster so the wall is not blank.
  cv::rectangle(img, {size / 5, size / 6, size / 3, size / 4}, {40, 70, 120}, cv::FILLED);
  cv::rectangle(img, {size / 5, size / 6, size / 3, size / 4}, {30, 30, 30}, 4);
  cv::circle(img, {size / 5 + size / 6, size / 6 + size / 8}, size / 14, {230, 190, 60}, cv::FILLED,
             cv::LINE_AA);
  return to_color_image(img);
}

ColorImage floor_texture(int size, cv::Scalar a, cv::Scalar b) {
  cv::Mat img(size, size, CV_8UC3, a);
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 4; ++x)
      if ((x + y) % 2) cv::rectangle(img, {x * size / 4, y * size / 4, size / 4, size / 4}, b, cv::FILLED);
  for (int k = 0; k <= 4; ++k) {
    cv::line(img, {k * size / 4, 0}, {k * size / 4, size}, {90, 90, 90}, 2);
    cv::line(img, {0, k * size / 4}, {size, k * size / 4}, {90, 90, 90}, 2);
  }
  return to_color_image(img);
}

}  // namespace perch2::synth::detail
