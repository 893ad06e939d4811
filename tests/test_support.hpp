// Shared helpers for the test suites: backend lists, real-data lookup, temporary files.
#pragma once

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/cpu/backend.hpp"
#include "perch2/cuda/backend.hpp"

/// Every backend the tests compare; cross-backend tests are parametrised over it with TEST_CASE_TEMPLATE.
/// Test binaries linked with perch2::cuda (an nvcc build, PERCH2_HAVE_CUDA) include it too; without a
/// visible device its instances are skipped with the reason (doctest_main.cpp), so a GPU machine runs the
/// whole comparison with `./run.sh gpu`.
#ifdef PERCH2_HAVE_CUDA
#define PERCH2_TEST_BACKENDS perch2::cpu::Backend, perch2::thrust_omp::Backend, perch2::cuda::Backend
#else
#define PERCH2_TEST_BACKENDS perch2::cpu::Backend, perch2::thrust_omp::Backend
#endif
/// The name the test files use (from when only CPU backends were instantiated): the same list.
#define PERCH2_CPU_RUNNABLE_BACKENDS PERCH2_TEST_BACKENDS

namespace perch2::test {

/// ADD-S (mean distance to the closest model point), metres, over the mesh's vertices (brute force).
inline double adds_vertices(const Pose& est, const Pose& gt, const Mesh& mesh) {
  std::vector<Eigen::Vector3f> g;
  for (const auto& p : mesh.vertices) g.push_back(gt * p);
  double sum = 0;
  for (const auto& p : mesh.vertices) {
    const Eigen::Vector3f e = est * p;
    float best = INFINITY;
    for (const auto& q : g) best = std::min(best, (e - q).squaredNorm());
    sum += std::sqrt(double(best));
  }
  return sum / double(mesh.vertices.size());
}

/// Path of a file under ../shared/data, or "" (with a printed notice) if this checkout has no shared data.
inline std::string shared_data(const std::string& relative) {
  const std::filesystem::path p = std::filesystem::path(PERCH2_SHARED_DATA_DIR) / relative;
  if (std::filesystem::exists(p)) return p.string();
  MESSAGE("SKIPPED: " << p.string()
                      << " not found (real data lives in ../shared/data beside the repository)");
  return "";
}

/// A fresh path in the test build's temporary folder: $PERCH2_TEST_TMP_DIR (ctest sets it to the build's
/// tests/tmp; an environment variable, not a compile definition, so that builds in other folders compile
/// the same test sources to the same objects and share a compiler cache), else the system's temp folder.
inline std::string temp_path(const std::string& name) {
  const char* env = std::getenv("PERCH2_TEST_TMP_DIR");
  const std::filesystem::path dir =
      env && *env ? std::filesystem::path(env) : std::filesystem::temp_directory_path() / "perch2_tests";
  std::filesystem::create_directories(dir);
  return (dir / name).string();
}

inline void write_file(const std::string& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary);
  f.write(bytes.data(), std::streamsize(bytes.size()));
}

inline std::string read_file(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
}

}  // namespace perch2::test

/// Skip the rest of a test case (with a clear message) when a shared data file is missing.
#define PERCH2_REQUIRE_SHARED_DATA(var, relative)              \
  const std::string var = perch2::test::shared_data(relative); \
  if (var.empty()) return
