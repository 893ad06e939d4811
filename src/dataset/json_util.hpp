// JSON helpers shared by the perch2::dataset sources (not installed): every error names the file and key.
#pragma once

#include <cmath>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/pose.hpp"

namespace perch2::dataset::detail {

using nlohmann::json;

/// Parses a whole JSON file; FileError if it is missing or malformed (with nlohmann's byte position).
json read_json(const std::string& path);

/// Writes JSON (indented by `indent`, -1 = compact); FileError if the file cannot be written.
void write_json(const std::string& path, const json& value, int indent = 2);

/// j[key] or FileError "<path>: <where>: missing key".
const json& member(const json& j, const char* key, const std::string& path, const std::string& where);

/// A finite number, or FileError naming the file and where.
double number(const json& j, const std::string& path, const std::string& where);

/// An integer (a JSON integer, or a float with no fractional part), or FileError.
int integer(const json& j, const std::string& path, const std::string& where);

/// An array of exactly n finite numbers, or FileError.
std::vector<double> numbers(const json& j, std::size_t n, const std::string& path, const std::string& where);

/// An object key that is an integer id ("42" or "000042"), or FileError.
int key_id(const std::string& key, const std::string& path, const std::string& where);

/// Rotation (9 numbers, row-major) and translation (3 numbers, millimetres) -> Pose in metres.
/// FileError unless R is a rotation to within 1e-2 (then it is re-orthonormalised).
Pose pose_from_bop(const json& R, const json& t_mm, const std::string& path, const std::string& where);

/// Nearest rotation matrix (SVD); false if R is farther than tol from a rotation (any entry of RR^T - I or
/// |det - 1|) or non-finite.
bool orthonormalise(Eigen::Matrix3d& R, double tol = 1e-2);

}  // namespace perch2::dataset::detail
