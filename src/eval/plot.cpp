// The report's curves as a PNG, drawn with OpenCV: precision against recall for detection, accuracy against
// the error threshold (ADD(-S), 0 to auc_max_m) for localization; one line per object and a thick one for
// all.
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cstdio>

#include "perch2/core/error.hpp"
#include "perch2/eval/evaluator.hpp"

namespace perch2::eval {

namespace {

struct Curve {
  std::string label;
  std::vector<double> x, y;  // in [0, 1]
  bool total = false;
};

// Plot area inside a 760 x 520 canvas: axes on the left, legend on the right.
constexpr int kW = 760, kH = 520, kLeft = 70, kTop = 40, kPlotW = 440, kPlotH = 400;

cv::Point to_px(double x, double y) {
  return {kLeft + int(x * kPlotW + 0.5), kTop + kPlotH - int(y * kPlotH + 0.5)};
}

cv::Scalar colour(std::size_t k) {  // a qualitative palette (BGR), repeated beyond ten objects
  static const cv::Scalar p[] = {{180, 119, 31},  {14, 127, 255}, {44, 160, 44},   {40, 39, 214},
                                 {189, 103, 148}, {75, 86, 140},  {194, 119, 227}, {127, 127, 127},
                                 {34, 189, 188},  {207, 190, 23}};
  return p[k % 10];
}

void draw(const std::vector<Curve>& curves, const std::string& title, const std::string& x_label,
          double x_max, const std::string& x_unit, const std::string& y_label, const std::string& path) {
  cv::Mat img(kH, kW, CV_8UC3, cv::Scalar(255, 255, 255));
  const auto font = cv::FONT_HERSHEY_SIMPLEX;
  const cv::Scalar ink(40, 40, 40), grid(225, 225, 225);
  for (int k = 0; k <= 4; ++k) {
    const double f = k / 4.0;
    cv::line(img, to_px(f, 0), to_px(f, 1), grid, 1);
    cv::line(img, to_px(0, f), to_px(1, f), grid, 1);
    char t[32];
    std::snprintf(t, sizeof t, "%.2g", f * x_max);
    cv::putText(img, t, to_px(f, 0) + cv::Point(-10, 20), font, 0.45, ink, 1, cv::LINE_AA);
    std::snprintf(t, sizeof t, "%.2g", f);
    cv::putText(img, t, to_px(0, f) + cv::Point(-40, 5), font, 0.45, ink, 1, cv::LINE_AA);
  }
  cv::rectangle(img, to_px(0, 1), to_px(1, 0), ink, 1);
  cv::putText(img, title, {kLeft, 18}, font, 0.55, ink, 1, cv::LINE_AA);
  cv::putText(img, x_label + (x_unit.empty() ? "" : " (" + x_unit + ")"), {kLeft + kPlotW / 2 - 60, kH - 30},
              font, 0.5, ink, 1, cv::LINE_AA);
  cv::putText(img, y_label, {8, kTop - 6}, font, 0.5, ink, 1, cv::LINE_AA);
  int legend_y = kTop + 10;
  for (std::size_t c = 0; c < curves.size(); ++c) {
    const Curve& curve = curves[c];
    const cv::Scalar col = curve.total ? cv::Scalar(0, 0, 0) : colour(c);
    std::vector<cv::Point> pts;
    for (std::size_t i = 0; i < curve.x.size(); ++i) pts.push_back(to_px(curve.x[i], curve.y[i]));
    cv::polylines(img, pts, false, col, curve.total ? 3 : 1, cv::LINE_AA);
    if (legend_y < kH - 20) {
      cv::line(img, {kLeft + kPlotW + 20, legend_y - 4}, {kLeft + kPlotW + 45, legend_y - 4}, col,
               curve.total ? 3 : 2, cv::LINE_AA);
      cv::putText(img, curve.label, {kLeft + kPlotW + 52, legend_y}, font, 0.42, ink, 1, cv::LINE_AA);
      legend_y += 18;
    }
  }
  bool written = false;
  try {
    written = cv::imwrite(path, img);
  } catch (const cv::Exception& e) {
    throw FileError(path, std::string("cannot be written: ") + e.what());
  }
  if (!written) throw FileError(path, "cannot be written (a .png path in an existing folder?)");
}

std::string label(const std::string& name, const char* metric, double value) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "%s (%s %.1f)", name.c_str(), metric, 100 * value);
  return buf;
}

/// Fraction of errors below each threshold t = max_m * k / 200 (the curve whose area is the AUC).
Curve accuracy_curve(std::vector<double> errors_m, double max_m, std::string name) {
  std::sort(errors_m.begin(), errors_m.end());
  Curve c;
  c.label = std::move(name);
  for (int k = 0; k <= 200; ++k) {
    const double t = max_m * k / 200;
    const auto below = std::lower_bound(errors_m.begin(), errors_m.end(), t) - errors_m.begin();
    c.x.push_back(k / 200.0);
    c.y.push_back(errors_m.empty() ? 0 : double(below) / double(errors_m.size()));
  }
  return c;
}

}  // namespace

void plot_report(const EvalReport& r, const EvalSettings& s, const std::string& png_path) {
  std::vector<Curve> curves;
  if (r.detection_computed) {
    auto add = [&](const std::string& name, const DetectionScores& d, bool total) {
      Curve c;
      c.label = label(name, "AP", d.ap), c.total = total;
      for (std::size_t k = 0; k < d.precision_at_recall.size(); ++k)
        c.x.push_back(double(k) / double(d.precision_at_recall.size() - 1)),
            c.y.push_back(d.precision_at_recall[k]);
      curves.push_back(std::move(c));
    };
    for (const auto& [obj, d] : r.detection.per_object) add("obj " + std::to_string(obj), d, false);
    add("all", r.detection.overall, true);
    draw(curves, "6D detection: interpolated precision, mean over MSSD and MSPD thresholds", "recall", 1.0,
         "", "precision", png_path);
    return;
  }
  std::map<int, std::vector<double>> errors;
  std::vector<double> all;
  for (const auto& i : r.instances)
    errors[i.obj_id].push_back(i.add_or_adds_m), all.push_back(i.add_or_adds_m);
  for (const auto& [obj, e] : errors) {
    curves.push_back(accuracy_curve(e, s.auc_max_m, ""));
    curves.back().label = label("obj " + std::to_string(obj), "AUC", r.per_object.at(obj).auc_add_or_adds);
  }
  curves.push_back(accuracy_curve(all, s.auc_max_m, label("all", "AUC", r.overall.auc_add_or_adds)));
  curves.back().total = true;
  draw(curves, "Accuracy: fraction of instances with ADD(-S) below the threshold", "ADD(-S) threshold",
       s.auc_max_m * 100, "cm", "accuracy", png_path);
}

}  // namespace perch2::eval
