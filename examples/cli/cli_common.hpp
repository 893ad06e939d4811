// Helpers shared by the perch2 command-line tool's commands and the benchmarks (library target
// perch2_cli_common, built with the examples): per-stage time tables, progress, overlays. The estimation
// itself is the library's (perch2/dataset/runner.hpp).
#pragma once

#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include "perch2/core/image.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"

namespace perch2::cli {

/// Per-stage wall-clock seconds summed over images, stages in the order first seen ("total" last).
struct StageTimes {
  std::vector<std::pair<std::string, double>> sum;
  int images = 0;
  void add(const std::vector<std::pair<std::string, double>>& stages);
  /// One line per stage: total seconds, mean per image and share of the "total" stage.
  void print(std::FILE* out, const char* indent = "  ") const;
};

/// The RGB image with the given models drawn at their poses (rendered at full resolution by perch2's CPU
/// renderer): each object's visible surface tinted in its own colour and outlined. `model_of_pose[i]`
/// indexes `meshes`.
ColorImage draw_overlay(const ColorImage& rgb, const Intrinsics& camera, const std::vector<Mesh>& meshes,
                        const std::vector<int>& model_of_pose, const std::vector<Pose>& T_cam_obj);

/// A distinct colour for overlay index i (also printed as a legend).
Rgb8 overlay_color(int i);
const char* overlay_color_name(int i);

/// Progress on one line of `out`: "[#####.....] 3/10 images  2.1 s/image (last 1.9 s)".
void print_progress(std::FILE* out, int done, int total, double mean_s, double last_s);

/// Bad usage of `perch2 COMMAND`: "perch2 COMMAND: MESSAGE" and the usage text on stderr; returns 2 (the
/// exit status of bad usage).
int usage_error(const char* command, const char* usage, const std::string& message);

/// "A-B" or "A" (--scenes: scene ids, A <= B) as {A, B}; InvalidInput naming --scenes otherwise.
std::pair<int, int> parse_scene_range(const std::string& s);

}  // namespace perch2::cli
