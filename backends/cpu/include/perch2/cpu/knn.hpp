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

  /// Receives the neighbours of one radius_visit() query and steers the search.
  struct RadiusVisitor {
    virtual ~RadiusVisitor() = default;
    /// Called for target points with squared distance d2 <= the current bound (global index into targets()).
    virtual void visit(std::int32_t index, float d2) = 0;
    /// The bound (squared metres, inclusive) a point must not exceed to be visited next: the search
    /// radius squared, which may shrink during the search. A negative value ends the search (once the visitor
    /// has what it needs). Points of a kd-tree leaf being scanned may still be visited after the bound shrank
    /// (compare d2 when it matters).
    virtual float bound_m2() const = 0;
  };
  /// Exact radius search without collecting results: visits every target point of `segment` within the
  /// visitor's bound of p (any order), unless the bound shrinks or ends the search. No allocation per
  /// query; thread-safe (const). Throws std::out_of_range for a bad segment.
  void radius_visit(const float p[3], std::int32_t segment, RadiusVisitor& visitor) const;

  std::size_t num_segments() const;
  const CloudBatch& targets() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace perch2::cpu
