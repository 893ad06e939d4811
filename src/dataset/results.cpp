#include "perch2/dataset/results.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
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

namespace {

/// One line of a results file: a row, nothing (a header or blank line), or what is wrong with it.
struct ParsedLine {
  bool row = false;
  PoseEstimate estimate;
  std::string error;
};

ParsedLine parse_line(std::string_view line, int line_no) {
  ParsedLine out;
  const std::string_view l = trim(line);
  if (l.empty() || l == kBopResultsHeader) return out;
  auto fail = [&](const std::string& why) {
    out.error = why;
    return out;
  };
  std::vector<std::string_view> fields;
  std::size_t start = 0;
  for (std::size_t p = 0; p <= l.size(); ++p)
    if (p == l.size() || l[p] == ',') fields.push_back(l.substr(start, p - start)), start = p + 1;
  if (fields.size() != 7)
    return fail("expected 7 comma-separated fields (" + std::string(kBopResultsHeader) + "), got " +
                std::to_string(fields.size()));
  PoseEstimate& e = out.estimate;
  std::vector<double> values;
  e.line = line_no;
  if (!parse_id(fields[0], e.scene_id)) return fail("scene_id is not a non-negative integer");
  if (!parse_id(fields[1], e.im_id)) return fail("im_id is not a non-negative integer");
  if (!parse_id(fields[2], e.obj_id)) return fail("obj_id is not a non-negative integer");
  if (!parse_numbers(fields[3], values) || values.size() != 1) return fail("score is not a finite number");
  e.score = values[0];
  if (!parse_numbers(fields[4], values) || values.size() != 9)
    return fail("R must be 9 finite numbers separated by spaces");
  Eigen::Matrix3d R;
  R << values[0], values[1], values[2], values[3], values[4], values[5], values[6], values[7], values[8];
  if (!detail::orthonormalise(R)) return fail("R is not a rotation matrix");
  if (!parse_numbers(fields[5], values) || values.size() != 3)
    return fail("t must be 3 finite numbers (millimetres) separated by spaces");
  e.T_cam_obj.linear() = R.cast<float>();
  e.T_cam_obj.translation() = (Eigen::Vector3d(values[0], values[1], values[2]) * 1e-3).cast<float>();
  if (!parse_numbers(fields[6], values) || values.size() != 1) return fail("time is not a finite number");
  e.time_s = values[0];
  out.row = true;
  return out;
}

/// The file's lines without their '\n'; `last_complete` = the file is empty or ends with '\n'.
std::vector<std::string> read_lines(const std::string& path, bool& last_complete) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw FileError(path, "cannot open (missing or unreadable)");
  const std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  if (f.bad()) throw FileError(path, "read error");
  std::vector<std::string> lines;
  std::size_t start = 0;
  for (std::size_t p; (p = text.find('\n', start)) != std::string::npos; start = p + 1)
    lines.push_back(text.substr(start, p - start));
  last_complete = start == text.size();
  if (!last_complete) lines.push_back(text.substr(start));
  return lines;
}

const char* kTorn = "torn last line (no newline at the end: the process writing it stopped?): ";

/// The rows of a results file with the index of the line each came from; a torn last line is dropped
/// (its number in *torn_line) or thrown.
std::vector<std::pair<PoseEstimate, std::size_t>> parse_results(const std::string& path,
                                                                const std::vector<std::string>& lines,
                                                                bool last_complete, bool drop_torn,
                                                                int* torn_line) {
  std::vector<std::pair<PoseEstimate, std::size_t>> out;
  if (torn_line) *torn_line = 0;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    const int line_no = int(i) + 1;
    ParsedLine p = parse_line(lines[i], line_no);
    if (!p.error.empty()) {
      const std::string where = path + ":" + std::to_string(line_no);
      if (i + 1 < lines.size() || last_complete) throw FileError(where, p.error);
      if (!drop_torn) throw FileError(where, kTorn + p.error);
      if (torn_line) *torn_line = line_no;
      break;
    }
    if (p.row) out.emplace_back(p.estimate, i);
  }
  return out;
}

using ImageKey = std::pair<int, int>;

/// PATH.done: "scene_id,im_id,rows" per finished image after a header; a torn last line is dropped.
std::map<ImageKey, int> read_done(const std::string& path, std::vector<std::string>* notes = nullptr) {
  bool last_complete = true;
  const std::vector<std::string> lines = read_lines(path, last_complete);
  std::map<ImageKey, int> out;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    const std::string_view l = trim(lines[i]);
    if (l.empty() || l == "scene_id,im_id,rows") continue;
    const std::string where = path + ":" + std::to_string(i + 1);
    int v[3] = {0, 0, 0};
    std::size_t start = 0, n = 0;
    bool ok = true;
    for (std::size_t p = 0; p <= l.size() && ok; ++p)
      if (p == l.size() || l[p] == ',') {
        ok = n < 3 && parse_id(l.substr(start, p - start), v[n]);
        ++n, start = p + 1;
      }
    if (!ok || n != 3) {
      if (i + 1 == lines.size() && !last_complete) {
        if (notes) notes->push_back(where + ": dropped: " + kTorn + "'" + std::string(l) + "'");
        break;
      }
      throw FileError(where, "expected scene_id,im_id,rows (3 non-negative integers)");
    }
    out[{v[0], v[1]}] = v[2];
  }
  return out;
}

std::map<ImageKey, int> count_rows(const std::vector<std::pair<PoseEstimate, std::size_t>>& rows) {
  std::map<ImageKey, int> out;
  for (const auto& [e, line] : rows) ++out[{e.scene_id, e.im_id}];
  return out;
}

/// The done images whose rows are all in the CSV (exactly as many as recorded).
std::map<ImageKey, int> complete_of(const std::map<ImageKey, int>& done,
                                    const std::map<ImageKey, int>& rows) {
  std::map<ImageKey, int> out;
  for (const auto& [key, n] : done) {
    const auto it = rows.find(key);
    if ((it == rows.end() ? 0 : it->second) == n) out[key] = n;
  }
  return out;
}

std::string image_name(const ImageKey& k) {
  return "scene " + std::to_string(k.first) + " image " + std::to_string(k.second);
}

/// Replaces `path` by `text` atomically (a temporary file beside it, renamed over it).
void replace_file(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) throw FileError(path, "cannot be written (through " + tmp + ")");
    f << text;
    f.flush();
    if (!f) throw FileError(path, "write failed (through " + tmp + ")");
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) throw FileError(path, "cannot be replaced by " + tmp + " (" + ec.message() + ")");
}

std::string done_text(const std::map<ImageKey, int>& done) {
  std::string out = "scene_id,im_id,rows\n";
  for (const auto& [k, n] : done)
    out += std::to_string(k.first) + "," + std::to_string(k.second) + "," + std::to_string(n) + "\n";
  return out;
}

int open_append(const std::string& path) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0)
    throw FileError(path, std::string("cannot be opened for writing (") + std::strerror(errno) + ")");
  return fd;
}

}  // namespace

std::vector<PoseEstimate> load_results_csv(const std::string& path, bool drop_torn_last_line,
                                           int* torn_line) {
  bool last_complete = true;
  const auto lines = read_lines(path, last_complete);
  std::vector<PoseEstimate> out;
  for (auto& [e, line] : parse_results(path, lines, last_complete, drop_torn_last_line, torn_line))
    out.push_back(e);
  return out;
}

std::map<std::pair<int, int>, int> completed_images(const std::string& path) {
  bool last_complete = true;
  const auto lines = read_lines(path, last_complete);
  const auto rows = count_rows(parse_results(path, lines, last_complete, true, nullptr));
  const std::string done = path + ".done";
  if (!std::filesystem::exists(done)) return rows;
  return complete_of(read_done(done), rows);
}

ResultsWriter::ResultsWriter(std::string path, Options options) : path_(std::move(path)), options_(options) {
  namespace fs = std::filesystem;
  std::string csv = std::string(kBopResultsHeader) + "\n";
  if (options_.resume && fs::exists(path_)) {
    bool last_complete = true;
    const auto lines = read_lines(path_, last_complete);
    int torn = 0;
    const auto rows = parse_results(path_, lines, last_complete, true, &torn);
    if (torn)
      notes_.push_back(path_ + ":" + std::to_string(torn) + ": dropped: " + kTorn + "'" +
                       lines[std::size_t(torn - 1)] + "'");
    const auto counts = count_rows(rows);
    if (fs::exists(done_path())) {
      done_ = complete_of(read_done(done_path(), &notes_), counts);
    } else {
      done_ = counts;
      notes_.push_back(done_path() + " not found: every image with rows in " + path_ + " counts as done");
    }
    std::size_t kept_rows = 0;
    for (const auto& [e, line] : rows) {
      if (done_.count({e.scene_id, e.im_id})) {
        csv += lines[line] + "\n", ++kept_rows;
      } else {
        notes_.push_back(path_ + ":" + std::to_string(line + 1) + ": dropped: a row of " +
                         image_name({e.scene_id, e.im_id}) + ", which is not recorded complete");
      }
    }
    notes_.insert(notes_.begin(), "resuming " + path_ + ": " + std::to_string(done_.size()) +
                                      " complete images (" + std::to_string(kept_rows) + " rows) kept");
  }
  // Both files are rewritten whole (a fresh run, or a resumed one without its dropped lines), then appended.
  replace_file(path_, csv);
  replace_file(done_path(), done_text(done_));
  csv_fd_ = open_append(path_);
  done_fd_ = open_append(done_path());
}

ResultsWriter::~ResultsWriter() {
  if (csv_fd_ >= 0) ::close(csv_fd_);
  if (done_fd_ >= 0) ::close(done_fd_);
}

void ResultsWriter::append(int fd, const std::string& path, const std::string& bytes) const {
  for (std::size_t written = 0; written < bytes.size();) {
    const ssize_t n = ::write(fd, bytes.data() + written, bytes.size() - written);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) throw FileError(path, std::string("write failed (") + std::strerror(errno) + ")");
    written += std::size_t(n);
  }
  if (options_.fsync && ::fsync(fd) != 0)
    throw FileError(path, std::string("fsync failed (") + std::strerror(errno) + ")");
}

void ResultsWriter::write_image(int scene_id, int im_id, const std::vector<PoseEstimate>& rows) {
  const ImageKey key{scene_id, im_id};
  if (done_.count(key))
    throw InvalidInput(image_name(key), "is already in " + path_ + " (written once only)");
  for (const auto& e : rows)
    if (e.scene_id != scene_id || e.im_id != im_id)
      throw InvalidInput(image_name(key), "given a row of " + image_name({e.scene_id, e.im_id}));
  std::ostringstream text;
  write_results_csv(text, rows, false);
  append(csv_fd_, path_, text.str());
  append(done_fd_, done_path(),
         std::to_string(scene_id) + "," + std::to_string(im_id) + "," + std::to_string(rows.size()) + "\n");
  done_[key] = int(rows.size());
}

}  // namespace perch2::dataset
