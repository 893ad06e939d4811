#include "perch2/dataset/results.hpp"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <ostream>
#include <sstream>
#include <string_view>

#include "json_util.hpp"

namespace perch2::dataset {

namespace {

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) s.remove_suffix(1);
  return s;
}

/// Whitespace-separated numbers of one field; false if any token is not a finite number.
bool parse_numbers(std::string_view field, std::vector<double>& out) {
  out.clear();
  std::size_t p = 0;
  while (true) {
    while (p < field.size() && (field[p] == ' ' || field[p] == '\t')) ++p;
    if (p >= field.size()) break;
    std::size_t e = p;
    while (e < field.size() && field[e] != ' ' && field[e] != '\t') ++e;
    std::string_view tok = field.substr(p, e - p);
    if (tok.front() == '+') tok.remove_prefix(1);
    double v = 0;
    const auto [end, ec] = std::from_chars(tok.data(), tok.data() + tok.size(), v);
    if (ec != std::errc() || end != tok.data() + tok.size() || !std::isfinite(v)) return false;
    out.push_back(v);
    p = e;
  }
  return true;
}

bool parse_id(std::string_view field, int& id) {
  field = trim(field);
  const auto [end, ec] = std::from_chars(field.data(), field.data() + field.size(), id);
  return ec == std::errc() && end == field.data() + field.size() && !field.empty() && id >= 0;
}

}  // namespace

void write_results_csv(std::ostream& out, const std::vector<PoseEstimate>& estimates, bool header) {
  if (header) out << kBopResultsHeader << "\n";
  char buf[512];
  for (const auto& e : estimates) {
    const Eigen::Matrix3f R = e.T_cam_obj.linear();
    // R to 9 significant digits (exact for float); t to 7 (float precision: below 1 um at 10 m).
    const Eigen::Vector3d t_mm = e.T_cam_obj.translation().cast<double>() * 1e3;
    std::snprintf(buf, sizeof buf,
                  "%d,%d,%d,%.9g,%.9g %.9g %.9g %.9g %.9g %.9g %.9g %.9g %.9g,%.7g %.7g %.7g,%.9g\n",
                  e.scene_id, e.im_id, e.obj_id, e.score, R(0, 0), R(0, 1), R(0, 2), R(1, 0), R(1, 1),
                  R(1, 2), R(2, 0), R(2, 1), R(2, 2), t_mm.x(), t_mm.y(), t_mm.z(), e.time_s);
    out << buf;
  }
}

void save_results_csv(const std::string& path, const std::vector<PoseEstimate>& estimates, bool append) {
  std::error_code ec;
  const bool empty = !append || !std::filesystem::exists(path) || std::filesystem::file_size(path, ec) == 0;
  std::ofstream f(path, append ? std::ios::app : std::ios::trunc);
  if (!f) throw FileError(path, "cannot be written");
  write_results_csv(f, estimates, empty);
  if (!f) throw FileError(path, "write failed");
}

std::vector<PoseEstimate> load_results_csv(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw FileError(path, "cannot open (missing or unreadable)");
  std::vector<PoseEstimate> out;
  std::string line;
  std::vector<double> values;
  for (int line_no = 1; std::getline(f, line); ++line_no) {
    const std::string_view l = trim(line);
    if (l.empty() || l == kBopResultsHeader) continue;
    auto fail = [&](const std::string& why) { throw FileError(path + ":" + std::to_string(line_no), why); };
    std::vector<std::string_view> fields;
    std::size_t start = 0;
    for (std::size_t p = 0; p <= l.size(); ++p)
      if (p == l.size() || l[p] == ',') fields.push_back(l.substr(start, p - start)), start = p + 1;
    if (fields.size() != 7)
      fail("expected 7 comma-separated fields (" + std::string(kBopResultsHeader) + "), got " +
           std::to_string(fields.size()));
    PoseEstimate e;
    e.line = line_no;
    if (!parse_id(fields[0], e.scene_id)) fail("scene_id is not a non-negative integer");
    if (!parse_id(fields[1], e.im_id)) fail("im_id is not a non-negative integer");
    if (!parse_id(fields[2], e.obj_id)) fail("obj_id is not a non-negative integer");
    if (!parse_numbers(fields[3], values) || values.size() != 1) fail("score is not a finite number");
    e.score = values[0];
    if (!parse_numbers(fields[4], values) || values.size() != 9)
      fail("R must be 9 finite numbers separated by spaces");
    Eigen::Matrix3d R;
    R << values[0], values[1], values[2], values[3], values[4], values[5], values[6], values[7], values[8];
    if (!detail::orthonormalise(R)) fail("R is not a rotation matrix");
    if (!parse_numbers(fields[5], values) || values.size() != 3)
      fail("t must be 3 finite numbers (millimetres) separated by spaces");
    e.T_cam_obj.linear() = R.cast<float>();
    e.T_cam_obj.translation() = (Eigen::Vector3d(values[0], values[1], values[2]) * 1e-3).cast<float>();
    if (!parse_numbers(fields[6], values) || values.size() != 1) fail("time is not a finite number");
    e.time_s = values[0];
    out.push_back(e);
  }
  return out;
}

}  // namespace perch2::dataset
