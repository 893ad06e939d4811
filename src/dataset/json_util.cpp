#include "json_util.hpp"

#include <Eigen/SVD>
#include <fstream>
#include <sstream>

namespace perch2::dataset::detail {

json read_json(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw FileError(path, "cannot open (missing or unreadable)");
  try {
    return json::parse(f);
  } catch (const json::exception& e) {
    throw FileError(path, std::string("malformed JSON: ") + e.what());
  }
}

void write_json(const std::string& path, const json& value, int indent) {
  std::ofstream f(path, std::ios::binary);
  if (!f) throw FileError(path, "cannot be written");
  f << value.dump(indent) << "\n";
  if (!f) throw FileError(path, "write failed");
}

const json& member(const json& j, const char* key, const std::string& path, const std::string& where) {
  if (!j.is_object()) throw FileError(path, where + ": expected a JSON object");
  const auto it = j.find(key);
  if (it == j.end()) throw FileError(path, where + ": missing key \"" + key + "\"");
  return *it;
}

double number(const json& j, const std::string& path, const std::string& where) {
  if (!j.is_number()) throw FileError(path, where + ": expected a number, got " + j.dump());
  const double v = j.get<double>();
  if (!std::isfinite(v)) throw FileError(path, where + ": number is not finite");
  return v;
}

int integer(const json& j, const std::string& path, const std::string& where) {
  const double v = number(j, path, where);
  if (v != std::floor(v) || std::abs(v) > 2e9)
    throw FileError(path, where + ": expected an integer, got " + j.dump());
  return int(v);
}

std::vector<double> numbers(const json& j, std::size_t n, const std::string& path, const std::string& where) {
  if (!j.is_array() || j.size() != n)
    throw FileError(path, where + ": expected an array of " + std::to_string(n) + " numbers");
  std::vector<double> out(n);
  for (std::size_t k = 0; k < n; ++k) out[k] = number(j[k], path, where + "[" + std::to_string(k) + "]");
  return out;
}

int key_id(const std::string& key, const std::string& path, const std::string& where) {
  std::size_t end = 0;
  int id = -1;
  try {
    id = std::stoi(key, &end);
  } catch (const std::exception&) {
    end = 0;
  }
  if (key.empty() || end != key.size() || id < 0)
    throw FileError(path, where + ": key \"" + key + "\" is not a non-negative integer id");
  return id;
}

bool orthonormalise(Eigen::Matrix3d& R, double tol) {
  if (!R.allFinite()) return false;
  if ((R * R.transpose() - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > tol ||
      std::abs(R.determinant() - 1.0) > tol)
    return false;
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
  R = svd.matrixU() * svd.matrixV().transpose();
  return true;
}

Pose pose_from_bop(const json& R, const json& t_mm, const std::string& path, const std::string& where) {
  const auto r = numbers(R, 9, path, where);
  const auto t = numbers(t_mm, 3, path, where);
  Eigen::Matrix3d Rd;
  Rd << r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8];
  if (!orthonormalise(Rd)) throw FileError(path, where + ": the 3x3 matrix is not a rotation");
  Pose T = Pose::Identity();
  T.linear() = Rd.cast<float>();
  T.translation() = Eigen::Vector3f(float(t[0] * 1e-3), float(t[1] * 1e-3), float(t[2] * 1e-3));
  return T;
}

}  // namespace perch2::dataset::detail
