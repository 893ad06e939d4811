#include "cli_common.hpp"

#include <algorithm>
#include <cmath>
#include <iostream>
#include <stdexcept>
#include <string>

#include "perch2/cpu/backend.hpp"

namespace perch2::cli {

void StageTimes::add(const std::vector<std::pair<std::string, double>>& stages) {
  for (const auto& [name, s] : stages) {
    auto it = std::find_if(sum.begin(), sum.end(), [&](const auto& e) { return e.first == name; });
    if (it == sum.end()) it = sum.insert(sum.end(), {name, 0.0});
    it->second += s;
  }
  ++images;
}

void StageTimes::print(std::FILE* out, const char* indent) const {
  const double n = std::max(images, 1);
  double total = 0;
  for (const auto& [name, s] : sum)
    if (name == "total") total = s;
  std::fprintf(out, "%s%-11s %10s %12s %7s\n", indent, "stage", "total s", "s / image", "share");
  for (const auto& [name, s] : sum)
    std::fprintf(out, "%s%-11s %10.3f %12.3f %6.1f%%\n", indent, name.c_str(), s, s / n,
                 total > 0 ? 100 * s / total : 0.0);
}

Rgb8 overlay_color(int i) {
  static const Rgb8 colors[] = {{255, 40, 40}, {40, 230, 40}, {60, 110, 255}, {255, 220, 0},
                                {255, 0, 255}, {0, 230, 230}, {255, 140, 0},  {255, 255, 255}};
  return colors[i % 8];
}

const char* overlay_color_name(int i) {
  static const char* names[] = {"red", "green", "blue", "yellow", "magenta", "cyan", "orange", "white"};
  return names[i % 8];
}

ColorImage draw_overlay(const ColorImage& rgb, const Intrinsics& camera, const std::vector<Mesh>& meshes,
                        const std::vector<int>& model_of_pose, const std::vector<Pose>& T_cam_obj) {
  if (rgb.empty()) throw InvalidInput("overlay", "no colour image to draw on");
  ColorImage out = rgb;
  if (T_cam_obj.empty()) return out;
  std::vector<Hypothesis> hyps;
  for (std::size_t i = 0; i < T_cam_obj.size(); ++i) hyps.push_back({model_of_pose[i], T_cam_obj[i]});
  RenderSettings full;
  full.stride = 1;
  const CloudBatch c = cpu::Renderer(meshes).render(hyps, camera, full);
  // Nearest pose per pixel, then tint it and outline where the label changes.
  const int w = camera.width, h = camera.height;
  std::vector<float> z(std::size_t(w) * h, INFINITY);
  std::vector<int> label(std::size_t(w) * h, -1);
  for (std::size_t i = 0; i < c.size(); ++i)
    if (c.z[i] < z[c.pixel[i]]) z[c.pixel[i]] = c.z[i], label[c.pixel[i]] = int(c.cloud[i]);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const int l = label[std::size_t(v) * w + u];
      bool edge = false;
      for (int dv = -1; dv <= 1 && !edge; ++dv)
        for (int du = -1; du <= 1 && !edge; ++du) {
          const int uu = std::clamp(u + du, 0, w - 1), vv = std::clamp(v + dv, 0, h - 1);
          edge = label[std::size_t(vv) * w + uu] != l && (l >= 0 || label[std::size_t(vv) * w + uu] >= 0);
        }
      const int owner = l >= 0 ? l : -1;
      if (edge) {
        int k = owner;
        for (int dv = -1; dv <= 1 && k < 0; ++dv)
          for (int du = -1; du <= 1 && k < 0; ++du)
            k = label[std::size_t(std::clamp(v + dv, 0, h - 1)) * w + std::clamp(u + du, 0, w - 1)];
        out(u, v) = overlay_color(k);
      } else if (owner >= 0) {
        const Rgb8 a = rgb(u, v), b = overlay_color(owner);
        out(u, v) = {std::uint8_t((a.r * 3 + b.r * 2) / 5), std::uint8_t((a.g * 3 + b.g * 2) / 5),
                     std::uint8_t((a.b * 3 + b.b * 2) / 5)};
      }
    }
  return out;
}

void print_progress(std::FILE* out, int done, int total, double mean_s, double last_s) {
  const int width = 30, filled = total > 0 ? width * done / total : width;
  std::fprintf(out, "\r  [%s%s] %d/%d images  %.2f s/image (last %.2f s)", std::string(filled, '#').c_str(),
               std::string(width - filled, '.').c_str(), done, total, mean_s, last_s);
  if (done == total) std::fprintf(out, "\n");
  std::fflush(out);
}

int usage_error(const char* command, const char* usage, const std::string& message) {
  std::cerr << "perch2 " << command << ": " << message << "\n\n" << usage;
  return 2;
}

std::pair<int, int> parse_scene_range(const std::string& s) {
  try {
    const auto dash = s.find('-');
    std::size_t used = 0;
    const int a = std::stoi(s.substr(0, dash), &used);
    if (used != (dash == std::string::npos ? s.size() : dash)) throw std::invalid_argument(s);
    if (dash == std::string::npos) return {a, a};
    const std::string rest = s.substr(dash + 1);
    const int b = std::stoi(rest, &used);
    if (used != rest.size() || b < a) throw std::invalid_argument(s);
    return {a, b};
  } catch (const std::logic_error&) {
    throw InvalidInput("--scenes", "'" + s + "' is not A-B or A (scene ids, A <= B)");
  }
}

}  // namespace perch2::cli
