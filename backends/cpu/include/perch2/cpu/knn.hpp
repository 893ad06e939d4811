// Reference nearest-neighbour search: one exact FLANN kd-tree (KDTreeSingleIndex) per target segment, built
// once in the constructor; OpenMP over query clouds. KnnSettings::method is ignored: this IS the reference.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "perch2/core/export.hpp"
#include "perch2/knn/knn.hpp"

namespace perch2::cpu {

class PERCH2_API KnnIndex {
 public:
  /// Validates the targets (each cloud is one segment, metres) and builds one kd-tree per non-empty segment.
  /// Throws InvalidInput on mismatched arrays, bad offsets or non-finite coordinates.
  explicit KnnIndex(CloudBatch targets, const KnnIndexSettings& settings = {});
  ~KnnIndex();
  KnnIndex(KnnIndex&&) noexcept;
  KnnIndex& operator=(KnnIndex&&) noexcept;

  /// k nearest neighbours of every query point within its cloud's segment query_segment[c]
  /// (settings.method ignored). Empty segments or segments with fewer than k points give -1 entries.
  KnnResult knn(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
                const KnnSettings& settings) const;

  /// All neighbours within radius_m (inclusive) in the query cloud's segment, sorted by distance; with
  /// max_neighbors > 0 only the nearest max_neighbors. `method` is ignored (FLANN).
  RadiusResult radius(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
                      float radius_m, int max_neighbors = 0, KnnMethod method = KnnMethod::Auto) const;

  std::size_t num_segments() const;
  const CloudBatch& targets() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace perch2::cpu
