// BOP results CSV (https://bop.felk.cvut.cz/challenges/, format of bop_toolkit_lib/inout.py
// save/load_bop_results):
//   scene_id,im_id,obj_id,score,R,t,time
//   1,3,5,0.93,r11 r12 r13 r21 r22 r23 r31 r32 r33,t1 t2 t3,0.51
// R row-major rotation model -> camera, t in millimetres, time = seconds for the whole image (the same on
// every row of an image). Shards of one dataset concatenate into one valid file: the reader skips a header
// line wherever it appears, and the appending writer writes the header only into an empty file.
#pragma once

#include <iosfwd>
#include <string>
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
/// "PATH:LINE: reason".
std::vector<PoseEstimate> load_results_csv(const std::string& path);

}  // namespace perch2::dataset
