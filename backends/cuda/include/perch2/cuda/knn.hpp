// Thrust nearest-neighbour search over a device-resident index: kNN I (tiled all-pairs), kNN II (one query
// per thread) and a uniform grid per segment, all over the device-callable kernels of perch2/knn/.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "perch2/cuda/system.hpp"
#include "perch2/knn/knn.hpp"

namespace perch2::thrust_backend {

template <class System>
class PERCH2_API KnnIndex {
 public:
  /// Validates the targets (each cloud is one segment, metres), uploads them once and builds the grid
  /// (cell keys sorted on the device). Throws InvalidInput on bad arrays, offsets, coordinates or settings.
  explicit KnnIndex(CloudBatch targets, const KnnIndexSettings& settings = {});
  ~KnnIndex();
  KnnIndex(KnnIndex&&) noexcept;
  KnnIndex& operator=(KnnIndex&&) noexcept;

  /// k nearest neighbours of every query point within its cloud's segment query_segment[c], by
  /// settings.method (Auto: see KnnSettings::auto_scan_max_points). Missing neighbours are -1 / +inf.
  KnnResult knn(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
                const KnnSettings& settings) const;

  /// All neighbours within radius_m (inclusive), sorted by (distance, index); with max_neighbors > 0 only
  /// the nearest max_neighbors. Methods: Grid visits the cells the ball overlaps; PerQuery and BruteForce
  /// scan the whole segment (the output size is data-dependent, so kNN I has no tile form here);
  /// Auto as for knn().
  RadiusResult radius(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
                      float radius_m, int max_neighbors = 0, KnnMethod method = KnnMethod::Auto) const;

  /// Device pointers for functors searching this index (grid_knn(view().grid, ...), knn_scan(view().points,
  /// ...)). Valid while the index lives.
  KnnView view() const;

  /// Passes, work items and device (and pinned host) allocations of the last knn()/radius() call, or of
  /// the build before any call (see LaunchShape). A repeated call of the same size allocates nothing.
  LaunchShape last_launch_shape() const;

  std::size_t num_segments() const;
  std::size_t num_points() const;
  const std::vector<std::int64_t>& segment_offsets() const;  ///< host copy, num_segments() + 1

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

extern template class KnnIndex<CudaSystem>;
extern template class KnnIndex<OmpSystem>;
extern template class KnnIndex<OmpPassesSystem>;

}  // namespace perch2::thrust_backend
