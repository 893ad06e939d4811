// BOP results CSV (https://bop.felk.cvut.cz/challenges/, format of bop_toolkit_lib/inout.py
// save/load_bop_results):
//   scene_id,im_id,obj_id,score,R,t,time
//   1,3,5,0.93,r11 r12 r13 r21 r22 r23 r31 r32 r33,t1 t2 t3,0.51
// R row-major rotation model -> camera, t in millimetres, time = seconds for the whole image (the same on
// every row of an image). Shards of one dataset concatenate into one valid file: the reader skips a header
// line wherever it appears, and the appending writer writes the header only into an empty file.
//
// Runs that lose nothing: ResultsWriter appends each image's rows as soon as the image is done, so a run
// that stops (killed, crashed, interrupted) leaves a valid file of every finished image, at most its last
// line torn, and resumes where it stopped.
#pragma once

#include <iosfwd>
#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "perch2/core/pose.hpp"

namespace perch2::dataset {

struct PoseEstimate {
  int scene_id = 0, im_id = 0, obj_id = 0;
  double score = 1;
  Pose T_cam_obj = Pose::Identity();  ///< model -> camera, metres
  double time_s = -1;                 ///< seconds for the whole image; -1 = not measured
  int line = 0;                       ///< 1-based line in the file it was read from (0 if not read)
};

inline constexpr const char* kBopResultsHeader = "scene_id,im_id,obj_id,score,R,t,time";

/// Writes rows (and the header line first if `header`). R is written with 9 significant digits, t (mm) with 7
/// (float precision).
void write_results_csv(std::ostream& out, const std::vector<PoseEstimate>& estimates, bool header = true);

/// Writes a results file; with append = true adds rows to an existing file (header only if it is empty or
/// new), so shards written by different runs concatenate. FileError if it cannot be written.
void save_results_csv(const std::string& path, const std::vector<PoseEstimate>& estimates,
                      bool append = false);

/// Reads a results file (or several concatenated). Header lines and blank lines are skipped. Any other
/// problem -- not 7 comma-separated fields, an unparsable or non-finite number, R that is not 9 numbers of a
/// rotation (to 1e-2; re-orthonormalised), t that is not 3 numbers, negative ids -- raises FileError
/// "PATH:LINE: reason". A bad last line without its newline is a torn line (the writer was stopped while
/// writing it): FileError "PATH:LINE: torn last line ..." unless `drop_torn_last_line`, which drops it and
/// sets `*torn_line` (if given) to its line number (0 when there was none).
std::vector<PoseEstimate> load_results_csv(const std::string& path, bool drop_torn_last_line = false,
                                           int* torn_line = nullptr);

/// The images a results file holds in full, with their row counts: those ResultsWriter recorded in
/// PATH.done (see there) whose rows are all in PATH; without PATH.done (a file from another tool, or
/// concatenated shards) every image with rows in PATH, a torn last line dropped. An image with zero rows
/// counts only when PATH.done lists it.
std::map<std::pair<int, int>, int> completed_images(const std::string& path);

/// Appends each finished image's rows to a BOP results CSV at once (one write(2) of the image's lines, then
/// one of its done record), so that a process that stops at any point leaves a valid CSV of every finished
/// image, at most its last line torn. Beside RESULTS.csv it keeps RESULTS.csv.done: the header
/// "scene_id,im_id,rows" and one line per finished image, written after the image's rows. An image is
/// complete when its done line is there and its rows are all in the CSV -- also an image with no rows (every
/// instance unusable, nothing found), which the CSV alone cannot show. Not thread-safe: one writer (the
/// process, or the distributed driver) owns the file.
class ResultsWriter {
 public:
  struct Options {
    /// false: start a new file (an existing one is replaced). true: keep the images complete in an
    /// existing file (completed_images) and append after them; rows of unfinished images and a torn last
    /// line are dropped first (the file is rewritten through a temporary file and renamed over it).
    bool resume = false;
    /// fsync(2) both files after each image: survives an operating-system crash or power loss, not only a
    /// killed process (costs a disk flush per image).
    bool fsync = false;
  };

  /// Opens (creates) PATH and PATH.done; FileError if they cannot be read, written or (resume) parsed.
  explicit ResultsWriter(std::string path, Options options);
  ResultsWriter(std::string path) : ResultsWriter(std::move(path), Options{}) {}
  ~ResultsWriter();
  ResultsWriter(const ResultsWriter&) = delete;
  ResultsWriter& operator=(const ResultsWriter&) = delete;

  /// Appends one image's rows (all of that image; possibly none) and records it done. InvalidInput if a
  /// row is of another image or the image is done already (each image is written exactly once); FileError if
  /// a write fails (e.g. a full disk).
  void write_image(int scene_id, int im_id, const std::vector<PoseEstimate>& rows);

  bool is_done(int scene_id, int im_id) const { return done_.count({scene_id, im_id}) != 0; }
  /// Every complete image with its row count (those kept on resume, then those written).
  const std::map<std::pair<int, int>, int>& done() const { return done_; }
  /// What resume found: kept images, dropped lines (each "PATH:LINE: why"). Empty without resume.
  const std::vector<std::string>& resume_notes() const { return notes_; }

  const std::string& path() const { return path_; }
  std::string done_path() const { return path_ + ".done"; }

 private:
  void append(int fd, const std::string& path, const std::string& bytes) const;
  std::string path_;
  Options options_;
  int csv_fd_ = -1, done_fd_ = -1;
  std::map<std::pair<int, int>, int> done_;
  std::vector<std::string> notes_;
};

}  // namespace perch2::dataset
