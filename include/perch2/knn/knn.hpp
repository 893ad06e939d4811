// The batched nearest-neighbour stage: many query clouds (one per hypothesis) against the segments of one
// target batch (the observed cloud as one segment, or one segment per label in 6-DoF).
//
// Backends implement `KnnIndex` with this interface (see perch2/cpu/knn.hpp, perch2/cuda/knn.hpp):
//   explicit KnnIndex(CloudBatch targets, const KnnIndexSettings& = {});   // index built once, reused
//   KnnResult knn(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
//                 const KnnSettings&) const;
//   RadiusResult radius(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
//                       float radius_m, int max_neighbors = 0, KnnMethod method = KnnMethod::Auto) const;
// Query cloud c searches only target segment query_segment[c], never another segment's points.
// Results are exact and identical across methods and backends: the k smallest (squared distance, index)
// pairs, ties broken by the smaller target index (FLANN, the reference, may order exact ties differently).
// Device code (e.g. registration functors) searches through the device-callable kernels directly:
// grid_knn() in perch2/knn/grid.hpp and knn_scan() in perch2/knn/scan.hpp, on a backend's view().
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "perch2/core/cloud.hpp"
#include "perch2/core/error.hpp"
#include "perch2/knn/grid.hpp"
#include "perch2/knn/scan.hpp"

namespace perch2 {

enum class KnnMethod {
  Auto,        ///< PerQuery for small segments, else Grid (see KnnSettings::auto_scan_max_points)
  BruteForce,  ///< kNN I: all pairwise distances of a tile of queries, tiled under memory_budget_bytes
  PerQuery,    ///< kNN II: one query per thread scanning its segment with a small-k sorted insertion
  Grid,        ///< uniform spatial grid per segment, ball search from per-cell representatives (exact)
};

inline const char* to_string(KnnMethod m) {
  switch (m) {
    case KnnMethod::Auto:
      return "auto";
    case KnnMethod::BruteForce:
      return "brute_force";
    case KnnMethod::PerQuery:
      return "per_query";
    case KnnMethod::Grid:
      return "grid";
  }
  return "?";
}

/// Per-call search parameters.
struct KnnSettings {
  int k = 1;  ///< neighbours per query point, >= 1
  /// Neighbours farther than this (metres) are reported missing (-1); +inf = unlimited. A finite value also
  /// makes the grid search cheaper (it stops at this radius).
  float max_distance_m = std::numeric_limits<float>::infinity();
  KnnMethod method = KnnMethod::Auto;
  /// kNN I working memory: the distance tile (4 bytes per query-target pair) stays under this, bytes.
  std::size_t memory_budget_bytes = std::size_t(64) << 20;
  /// Auto picks PerQuery (kNN II) when every searched segment has at most this many points, else Grid.
  /// Measured single-threaded (bench scenes, cat model): the plain scan is faster up to ~64 points
  /// (k = 1: 0.11 vs 0.15 us/query; k = 10: 0.54 vs 0.58), even at 128 and slower beyond (256 points:
  /// 0.28 vs 0.19, k = 10: 1.05 vs 0.79). kNN I (BruteForce) is never faster on CPUs (it writes every
  /// distance to memory before selecting) and is never picked automatically.
  std::size_t auto_scan_max_points = 96;
};

/// Build parameters of an index (the CPU reference backend uses only flann_leaf_max_size).
struct KnnIndexSettings {
  GridSettings grid;             ///< uniform-grid geometry (Thrust backend)
  int flann_leaf_max_size = 10;  ///< FLANN KDTreeSingleIndex leaf size (CPU reference backend)
};

/// k nearest neighbours of every query point (queries in batch order).
struct KnnResult {
  int k = 0;
  /// num_query_points * k global point indices into the target CloudBatch, per query sorted by distance,
  /// -1 where fewer than k neighbours exist within max_distance_m.
  std::vector<std::int32_t> index;
  std::vector<float> sq_distance_m2;  ///< num_query_points * k squared distances, m^2; +inf where index = -1

  std::size_t num_queries() const { return k > 0 ? index.size() / std::size_t(k) : 0; }
};

/// All neighbours within a radius of every query point.
struct RadiusResult {
  std::vector<std::int64_t> offsets{0};  ///< per query point: neighbours [offsets[i], offsets[i + 1])
  std::vector<std::int32_t> index;       ///< global target indices, per query sorted by distance
  std::vector<float> sq_distance_m2;     ///< squared distances, m^2

  std::size_t num_queries() const { return offsets.size() - 1; }
};

/// What a device functor needs to search an index (pointers into one backend's memory, valid while the
/// index lives; knn()/radius() calls do not change them).
struct KnnView {
  const Vec3f* points = nullptr;                  ///< targets in batch order (global index)
  const std::int64_t* segment_offsets = nullptr;  ///< num_segments + 1
  int num_segments = 0;
  GridView grid;  ///< empty (null pointers) on backends without a grid
};

/// Checks a cloud batch used by the kNN stage: x, y, z lengths, offsets, finite coordinates.
/// (rgb, pixel and cloud are not needed and may be empty.)
inline void validate_knn_cloud(const CloudBatch& b, const std::string& name) {
  const std::size_t n = b.x.size();
  if (b.y.size() != n || b.z.size() != n) throw InvalidInput(name, "x, y and z have different lengths");
  if (b.offsets.empty() || b.offsets.front() != 0 || b.offsets.back() != std::int64_t(n))
    throw InvalidInput(name, "offsets must start at 0 and end at the point count " + std::to_string(n));
  for (std::size_t c = 0; c + 1 < b.offsets.size(); ++c)
    if (b.offsets[c + 1] < b.offsets[c])
      throw InvalidInput(name, "offsets must not decrease (cloud " + std::to_string(c) + ")");
  if (n > std::size_t(std::numeric_limits<std::int32_t>::max()))
    throw InvalidInput(name, "more than 2^31 - 1 points");
  for (std::size_t i = 0; i < n; ++i)
    if (!std::isfinite(b.x[i]) || !std::isfinite(b.y[i]) || !std::isfinite(b.z[i]))
      throw InvalidInput(name, "point " + std::to_string(i) + " has a non-finite coordinate");
}

/// Checks a search request; shared by every backend so all reject the same inputs with the same message.
inline void validate_knn_queries(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
                                 std::size_t num_segments) {
  validate_knn_cloud(queries, "kNN queries");
  if (query_segment.size() != queries.num_clouds())
    throw InvalidInput("query_segment", "has " + std::to_string(query_segment.size()) + " entries for " +
                                            std::to_string(queries.num_clouds()) + " query clouds");
  for (std::size_t c = 0; c < query_segment.size(); ++c)
    if (query_segment[c] < 0 || std::size_t(query_segment[c]) >= num_segments)
      throw InvalidInput("query_segment", "segment index " + std::to_string(query_segment[c]) +
                                              " of query cloud " + std::to_string(c) + " out of range (" +
                                              std::to_string(num_segments) + " target segments)");
}

inline void validate_knn_settings(const KnnSettings& s) {
  if (s.k < 1) throw InvalidInput("KnnSettings::k", "must be >= 1, got " + std::to_string(s.k));
  if (!(s.max_distance_m >= 0)) throw InvalidInput("KnnSettings::max_distance_m", "must be >= 0 (or +inf)");
  if (s.memory_budget_bytes < 16 * sizeof(float))
    throw InvalidInput("KnnSettings::memory_budget_bytes", "must hold at least 16 distances (64 bytes)");
  if (s.method != KnnMethod::Auto && s.method != KnnMethod::BruteForce && s.method != KnnMethod::PerQuery &&
      s.method != KnnMethod::Grid)
    throw InvalidInput("KnnSettings::method", "unknown method");
}

inline void validate_radius_request(float radius_m, int max_neighbors) {
  if (!(radius_m >= 0)) throw InvalidInput("radius_m", "must be >= 0 (or +inf)");
  if (max_neighbors < 0) throw InvalidInput("max_neighbors", "must be >= 0 (0 = all)");
}

inline void validate_knn_index_settings(const KnnIndexSettings& s) {
  if (!(s.grid.cell_size_m >= 0) || !std::isfinite(s.grid.cell_size_m))
    throw InvalidInput("GridSettings::cell_size_m", "must be finite and >= 0 (0 = automatic)");
  if (!(s.grid.points_per_cell > 0) || !std::isfinite(s.grid.points_per_cell))
    throw InvalidInput("GridSettings::points_per_cell", "must be finite and > 0");
  if (!(s.grid.max_cells_per_point > 0) || !std::isfinite(s.grid.max_cells_per_point))
    throw InvalidInput("GridSettings::max_cells_per_point", "must be finite and > 0");
  if (!(s.grid.knn_ball_cells >= 0) || !std::isfinite(s.grid.knn_ball_cells))
    throw InvalidInput("GridSettings::knn_ball_cells", "must be finite and >= 0");
  if (s.flann_leaf_max_size < 1) throw InvalidInput("KnnIndexSettings::flann_leaf_max_size", "must be >= 1");
}

/// The method Auto resolves to for a request whose largest searched segment has max_segment_points points.
inline KnnMethod resolve_knn_method(const KnnSettings& s, std::size_t max_segment_points) {
  if (s.method != KnnMethod::Auto) return s.method;
  return max_segment_points <= s.auto_scan_max_points ? KnnMethod::PerQuery : KnnMethod::Grid;
}

/// Largest segment among those the query clouds search (segments with no query are ignored).
inline std::size_t max_searched_segment(const std::vector<std::int64_t>& segment_offsets,
                                        const CloudBatch& queries,
                                        const std::vector<std::int32_t>& query_segment) {
  std::vector<char> used(segment_offsets.size() - 1, 0);
  for (std::size_t c = 0; c < query_segment.size(); ++c)
    if (queries.cloud_size(c) > 0) used[std::size_t(query_segment[c])] = 1;
  std::size_t m = 0;
  for (std::size_t s = 0; s < used.size(); ++s)
    if (used[s]) m = std::max(m, std::size_t(segment_offsets[s + 1] - segment_offsets[s]));
  return m;
}

}  // namespace perch2
