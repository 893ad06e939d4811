// Thrust nearest-neighbour search. Included by knn.cu (nvcc, CUDA system) and knn_omp.cpp (g++, OpenMP
// system); the algorithm text lives here once, over the PERCH2_HD kernels of perch2/knn/.
#include <thrust/binary_search.h>
#include <thrust/copy.h>
#include <thrust/device_vector.h>
#include <thrust/execution_policy.h>
#include <thrust/fill.h>
#include <thrust/gather.h>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/scan.h>
#include <thrust/sequence.h>
#include <thrust/sort.h>
#include <thrust/transform.h>
#include <cuda/atomic>

#include <algorithm>
#include <limits>
#include <mutex>
#include <string>

#include "perch2/core/segments.hpp"
#include "perch2/cuda/knn.hpp"
#include "perch2/knn/grid.hpp"
#include "perch2/knn/scan.hpp"
#include "segmented_sort.hpp"
#include "thrust_util.hpp"

namespace perch2::thrust_backend {

namespace knn_detail {

inline std::vector<Vec3f> to_aos(const CloudBatch& b) {
  std::vector<Vec3f> p(b.size());
  for (std::size_t i = 0; i < b.size(); ++i) p[i] = {b.x[i], b.y[i], b.z[i]};
  return p;
}

/// Grid cell key of target point i: cell_base of its segment + local cell id.
struct CellKey {
  const Vec3f* points;
  const std::int32_t* segment_of_point;
  const GridSegment* segments;
  PERCH2_HD std::int64_t operator()(std::int64_t i) const {
    const GridSegment& s = segments[segment_of_point[i]];
    return s.cell_base + grid_local_cell(s, points[i]);
  }
};

/// Counting sort of target points by cell, pass 1: rank of point i within its cell (atomic counter).
struct CountCells {
  const std::int64_t* keys;
  std::int32_t* cell_count;
  std::int32_t* rank;
  PERCH2_HD void operator()(std::int64_t i) const {
    cuda::atomic_ref<std::int32_t, cuda::thread_scope_device> c(cell_count[keys[i]]);
    rank[i] = c.fetch_add(1, cuda::memory_order_relaxed);
  }
};

/// Pass 2: place point i at cell_start[key] + rank.
struct PlaceInCells {
  const std::int64_t* keys;
  const std::int32_t* rank;
  const std::int32_t* cell_start;
  const Vec3f* points;
  Vec3f* sorted_points;
  std::int32_t* sorted_index;
  PERCH2_HD void operator()(std::int64_t i) const {
    const std::int64_t pos = cell_start[keys[i]] + rank[i];
    sorted_points[pos] = points[i];
    sorted_index[pos] = std::int32_t(i);
  }
};

/// Pass 3 (segmented_sort over cells): order each cell's points by index, so the layout does not depend on
/// the order of the atomic increments.
struct IndexLess {
  PERCH2_HD bool operator()(std::int32_t ia, const Vec3f&, std::int32_t ib, const Vec3f&) const {
    return ia < ib;
  }
};

/// Radius results of one query, ordered by (distance, index) (segmented_sort over queries).
struct PairLess {
  PERCH2_HD bool operator()(float da, std::int32_t ia, float db, std::int32_t ib) const {
    return knn_less(da, ia, db, ib);
  }
};

/// Segment of global cell c (segments are few: a linear scan over their cell bases).
PERCH2_HD inline int segment_of_cell(const GridSegment* segments, int num_segments, std::int64_t c) {
  int s = 0;
  while (s + 1 < num_segments && segments[s + 1].cell_base <= c) ++s;
  return s;
}

/// Jump flooding (cell representatives for grid_knn) over the cells of all segments at once: the initial
/// pass and one step. Steps larger than a segment's grid find no neighbours there (harmless).
struct RepInit {
  GridView grid;
  std::int32_t* rep;
  PERCH2_HD void operator()(std::int64_t c) const {
    const GridSegment& s = grid.segments[segment_of_cell(grid.segments, grid.num_segments, c)];
    rep[c] = grid_rep_init(grid, s, c - s.cell_base);
  }
};
struct JfaStep {
  const GridSegment* segments;
  int num_segments;
  const Vec3f* points;
  const std::int32_t* rep_in;
  std::int32_t* rep_out;
  int step;
  PERCH2_HD void operator()(std::int64_t c) const {
    const GridSegment& s = segments[segment_of_cell(segments, num_segments, c)];
    rep_out[c] = grid_jfa_step(s, points, rep_in, c - s.cell_base, step);
  }
};

/// Query point i -> the target segment its cloud searches.
struct QuerySegment {
  const std::int32_t* segment_of_cloud;
  PERCH2_HD std::int32_t operator()(std::int32_t c) const { return segment_of_cloud[c]; }
};

struct ClearLists {
  int k;
  std::int32_t* idx;
  float* d2;
  PERCH2_HD void operator()(std::int64_t i) const { knn_clear(k, idx + i * k, d2 + i * k); }
};

/// kNN II: one query point per thread scans its whole segment.
struct PerQueryKnn {
  const Vec3f* points;
  const std::int64_t* segment_offsets;
  const Vec3f* queries;
  const std::int32_t* query_segment;
  int k;
  float max_d2;
  std::int32_t* idx;
  float* d2;
  PERCH2_HD void operator()(std::int64_t i) const {
    const std::int32_t s = query_segment[i];
    knn_clear(k, idx + i * k, d2 + i * k);
    knn_scan(points, segment_offsets[s], segment_offsets[s + 1], queries[i], k, max_d2, idx + i * k,
             d2 + i * k);
  }
};

/// Grid search, one query point per thread.
struct GridKnn {
  GridView grid;
  const Vec3f* queries;
  const std::int32_t* query_segment;
  int k;
  float max_distance_m;
  std::int32_t* idx;
  float* d2;
  PERCH2_HD void operator()(std::int64_t i) const {
    grid_knn(grid, query_segment[i], queries[i], k, max_distance_m, idx + i * k, d2 + i * k);
  }
};

/// kNN I step 1: entry e of a tile of `rows` query points (from row0) x `width` target columns (from col0).
struct TileDistances {
  const Vec3f* points;
  const std::int64_t* segment_offsets;
  const Vec3f* queries;
  const std::int32_t* query_segment;
  std::int64_t row0, col0, width;
  float* tile;
  PERCH2_HD void operator()(std::int64_t e) const {
    const std::int64_t r = e / width, j = e - r * width, q = row0 + r;
    const std::int32_t s = query_segment[q];
    tile[e] = knn_tile_distance(points, segment_offsets[s], segment_offsets[s + 1], col0, j, queries[q]);
  }
};

/// kNN I step 2: one query point merges its tile row into its sorted list.
struct TileSelect {
  const std::int64_t* segment_offsets;
  const std::int32_t* query_segment;
  const float* tile;
  std::int64_t row0, col0, width;
  int k;
  float max_d2;
  std::int32_t* idx;
  float* d2;
  PERCH2_HD void operator()(std::int64_t r) const {
    const std::int64_t q = row0 + r;
    const std::int32_t s = query_segment[q];
    const std::int64_t b = segment_offsets[s], n = segment_offsets[s + 1] - b - col0;
    if (n <= 0) return;
    const std::int64_t w = n < width ? n : width;
    knn_tile_select(tile + r * width, w, b + col0, k, max_d2, idx + q * k, d2 + q * k);
  }
};

/// Radius search visitors: count, then write (in visiting order; a segmented sort orders them after).
struct CountVisit {
  std::int64_t n = 0;
  PERCH2_HD void operator()(std::int32_t, float) { ++n; }
};
struct WriteVisit {
  std::int32_t* idx;
  float* d2;
  std::int64_t n = 0;
  PERCH2_HD void operator()(std::int32_t i, float d) {
    idx[n] = i;
    d2[n] = d;
    ++n;
  }
};

struct RadiusCount {
  const Vec3f* points;
  const std::int64_t* segment_offsets;
  GridView grid;
  bool use_grid;
  const Vec3f* queries;
  const std::int32_t* query_segment;
  float radius_m;
  PERCH2_HD std::int64_t operator()(std::int64_t i) const {
    CountVisit v;
    const std::int32_t s = query_segment[i];
    if (use_grid)
      grid_radius_visit(grid, s, queries[i], radius_m, v);
    else
      radius_scan(points, segment_offsets[s], segment_offsets[s + 1], queries[i], radius_m * radius_m, v);
    return v.n;
  }
};

struct RadiusFill {
  const Vec3f* points;
  const std::int64_t* segment_offsets;
  GridView grid;
  bool use_grid;
  const Vec3f* queries;
  const std::int32_t* query_segment;
  float radius_m;
  const std::int64_t* out_offsets;
  std::int32_t* idx;
  float* d2;
  PERCH2_HD void operator()(std::int64_t i) const {
    const std::int64_t o = out_offsets[i];
    WriteVisit v{idx + o, d2 + o, 0};
    const std::int32_t s = query_segment[i];
    if (use_grid)
      grid_radius_visit(grid, s, queries[i], radius_m, v);
    else
      radius_scan(points, segment_offsets[s], segment_offsets[s + 1], queries[i], radius_m * radius_m, v);
  }
};

/// Number of found neighbours of a sorted list (missing entries are last).
struct ListCount {
  const std::int32_t* idx;
  int k;
  PERCH2_HD std::int64_t operator()(std::int64_t i) const {
    std::int64_t n = 0;
    while (n < k && idx[i * k + n] >= 0) ++n;
    return n;
  }
};

/// Copies query i's found entries (the list's prefix) to its slice of the compacted radius result.
struct CompactLists {
  const std::int32_t* list_idx;
  const float* list_d2;
  int k;
  const std::int64_t* offsets;
  std::int32_t* idx;
  float* d2;
  PERCH2_HD void operator()(std::int64_t i) const {
    const std::int64_t o = offsets[i], n = offsets[i + 1] - o;
    for (std::int64_t j = 0; j < n; ++j) idx[o + j] = list_idx[i * k + j], d2[o + j] = list_d2[i * k + j];
  }
};

}  // namespace knn_detail

template <class System>
struct KnnIndex<System>::Impl {
  std::vector<std::int64_t> segment_offsets_host;
  std::size_t num_points = 0;
  thrust::device_vector<Vec3f> points;                  // batch order
  thrust::device_vector<std::int64_t> segment_offsets;  // num_segments + 1
  thrust::device_vector<GridSegment> grid_segments;
  thrust::device_vector<std::int32_t> cell_start;
  thrust::device_vector<Vec3f> grid_points;  // sorted by global cell id
  thrust::device_vector<std::int32_t> grid_index;
  thrust::device_vector<std::int32_t> cell_rep;  // per cell: a point near its centre

  /// Per-call arrays of knn() and radius(), reused across calls (they grow only; calls hold the mutex).
  struct Workspace {
    std::vector<Vec3f> host_queries;
    thrust::device_vector<Vec3f> queries;
    thrust::device_vector<std::int64_t> query_offsets, offsets, scalar;
    thrust::device_vector<std::int32_t> segment_of_cloud, cloud, query_segment, idx, list_idx, sort_idx;
    thrust::device_vector<float> d2, list_d2, sort_d2, tile;
    TempAllocator temp;
    HostBuffer<System, unsigned char> staging;  // device -> host copies (pinned on CUDA)
    std::size_t bytes() const {
      return queries.capacity() * sizeof(Vec3f) +
             (query_offsets.capacity() + offsets.capacity() + scalar.capacity()) * 8 +
             (segment_of_cloud.capacity() + cloud.capacity() + query_segment.capacity() + idx.capacity() +
              list_idx.capacity() + sort_idx.capacity() + d2.capacity() + list_d2.capacity() +
              sort_d2.capacity() + tile.capacity()) *
                 4 +
             temp.bytes();
    }
  };
  mutable std::mutex mutex;
  mutable Workspace ws;
  mutable LaunchShape shape;  // the last call's (after construction: the build's)

  GridView grid_view() const {
    return {ptr(grid_segments), int(grid_segments.size()), ptr(cell_start),
            ptr(grid_points),   ptr(grid_index),           cell_rep.empty() ? nullptr : ptr(cell_rep)};
  }

  std::size_t index_bytes() const {
    return (points.capacity() + grid_points.capacity()) * sizeof(Vec3f) + segment_offsets.capacity() * 8 +
           grid_segments.capacity() * sizeof(GridSegment) +
           (cell_start.capacity() + grid_index.capacity() + cell_rep.capacity()) * 4;
  }

  /// Starts a call: clears the launch shape and the allocation counters.
  std::int64_t& begin_call() const {
    shape = LaunchShape{};
    ws.temp.allocations = 0;
    return shape.device_allocations;
  }
  void end_call() const {
    shape.device_allocations += ws.temp.allocations;
    shape.workspace_bytes = ws.bytes();
  }

  /// Uploads query points and, per point, the segment its cloud searches, into the workspace.
  void upload_queries(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
                      std::int64_t& allocs) const {
    using namespace knn_detail;
    Workspace& w = ws;
    w.host_queries.resize(queries.size());
    for (std::size_t i = 0; i < queries.size(); ++i) w.host_queries[i] = queries.point(i);
    upload(w.queries, w.host_queries, allocs);
    const std::int64_t* offsets = upload(w.query_offsets, queries.offsets, allocs);
    const std::int32_t* seg_of_cloud = upload(w.segment_of_cloud, query_segment, allocs);
    const std::int64_t nq = std::int64_t(queries.size());
    std::int32_t* cloud = reuse(w.cloud, std::size_t(nq), allocs);
    thrust::upper_bound(thrust::device(w.temp), offsets + 1, offsets + queries.offsets.size(),
                        thrust::counting_iterator<std::int64_t>(0),
                        thrust::counting_iterator<std::int64_t>(nq), cloud);
    thrust::transform(thrust::device, cloud, cloud + nq, reuse(w.query_segment, std::size_t(nq), allocs),
                      QuerySegment{seg_of_cloud});
    shape.launch("query_segment", 1, nq);
  }

  /// Searches the uploaded queries into idx/d2 (nq * k each, preallocated). max_seg: largest searched
  /// segment (kNN I tile width).
  void run_knn(int k, float max_distance_m, KnnMethod method, std::size_t memory_budget_bytes,
               std::int64_t max_seg, std::int32_t* idx, float* d2, std::int64_t& allocs) const {
    using namespace knn_detail;
    Workspace& w = ws;
    const Vec3f* q = ptr(w.queries);
    const std::int32_t* qseg = ptr(w.query_segment);
    const std::int64_t nq = std::int64_t(w.query_segment.size());
    const float max_d2 = max_distance_m * max_distance_m;
    const thrust::counting_iterator<std::int64_t> first(0);

    if (method == KnnMethod::Grid) {
      thrust::for_each(thrust::device, first, first + nq,
                       GridKnn{grid_view(), q, qseg, k, max_distance_m, idx, d2});
      shape.launch("grid_knn", 1, nq);
    } else if (method == KnnMethod::PerQuery) {
      thrust::for_each(thrust::device, first, first + nq,
                       PerQueryKnn{ptr(points), ptr(segment_offsets), q, qseg, k, max_d2, idx, d2});
      shape.launch("per_query_knn", 1, nq);
    } else {  // kNN I: tiles of (query rows x target columns) under the memory budget
      thrust::for_each(thrust::device, first, first + nq, ClearLists{k, idx, d2});
      shape.launch("clear_lists", 1, nq);
      if (max_seg > 0) {
        const KnnTiles t = plan_knn_tiles(nq, max_seg, memory_budget_bytes);
        float* tile = reuse(w.tile, std::size_t(t.rows * t.width), allocs);
        for (std::int64_t row0 = 0; row0 < nq; row0 += t.rows) {
          const std::int64_t nr = std::min(t.rows, nq - row0);
          for (std::int64_t col0 = 0; col0 < max_seg; col0 += t.width) {
            thrust::for_each(
                thrust::device, first, first + nr * t.width,
                TileDistances{ptr(points), ptr(segment_offsets), q, qseg, row0, col0, t.width, tile});
            thrust::for_each(
                thrust::device, first, first + nr,
                TileSelect{ptr(segment_offsets), qseg, tile, row0, col0, t.width, k, max_d2, idx, d2});
            shape.launch("tile_distances", 1, nr * t.width);
            shape.launch("tile_select", 1, nr);
          }
        }
      }
    }
  }

  /// Inclusive scan of the per-query counts in offsets[1..nq] and the offsets to the host.
  void scan_offsets(std::int64_t nq, std::vector<std::int64_t>& host, std::int64_t& allocs) const {
    std::int64_t* offsets = ptr(ws.offsets);
    thrust::inclusive_scan(thrust::device(ws.temp), offsets + 1, offsets + nq + 1, offsets + 1);
    shape.launch("offsets_scan", 1, nq);
    download<System>(static_cast<const std::int64_t*>(offsets), std::size_t(nq) + 1, host, ws.staging,
                     allocs);
  }
};

template <class System>
KnnIndex<System>::KnnIndex(CloudBatch targets, const KnnIndexSettings& settings)
    : impl_(std::make_unique<Impl>()) {
  using namespace knn_detail;
  validate_knn_cloud(targets, "kNN targets");
  validate_knn_index_settings(settings);
  Impl& m = *impl_;
  std::int64_t& allocs = m.begin_call();
  m.segment_offsets_host = targets.offsets;
  m.num_points = targets.size();
  upload(m.points, to_aos(targets), allocs);
  upload(m.segment_offsets, targets.offsets, allocs);

  // Grid: geometry planned on the host (bounding boxes, cell size), keys and order on the device.
  std::vector<GridSegment> segs;
  const std::int64_t total_cells = plan_grid(targets, settings.grid, segs);
  upload(m.grid_segments, segs, allocs);
  const std::int64_t n = std::int64_t(m.num_points);
  const std::size_t un = m.num_points, cells = static_cast<std::size_t>(total_cells);
  thrust::device_vector<std::int32_t> seg_of_point, cell_count, rank, sort_index, next;
  thrust::device_vector<std::int64_t> keys;
  thrust::device_vector<Vec3f> sort_points;
  // All algorithms run on raw pointers with an explicit policy: Thrust's OpenMP algorithms read
  // device_vector iterators through device_reference, which binds a reference through a null policy
  // pointer (UBSan reports it). Points are bucketed by a counting sort (atomics + scan), not thrust::sort,
  // whose OpenMP version does the same internally.
  thrust::upper_bound(thrust::device(m.ws.temp), ptr(m.segment_offsets) + 1,
                      ptr(m.segment_offsets) + m.segment_offsets.size(),
                      thrust::counting_iterator<std::int64_t>(0), thrust::counting_iterator<std::int64_t>(n),
                      reuse(seg_of_point, un, allocs));
  thrust::transform(thrust::device, thrust::counting_iterator<std::int64_t>(0),
                    thrust::counting_iterator<std::int64_t>(n), reuse(keys, un, allocs),
                    CellKey{ptr(m.points), ptr(seg_of_point), ptr(m.grid_segments)});
  m.shape.launch("point_segment", 1, n);
  m.shape.launch("cell_keys", 1, n);
  thrust::fill_n(thrust::device, reuse(cell_count, cells + 1, allocs), total_cells + 1, 0);
  const thrust::counting_iterator<std::int64_t> first(0);
  thrust::for_each(thrust::device, first, first + n,
                   CountCells{ptr(keys), ptr(cell_count), reuse(rank, un, allocs)});
  m.shape.launch("count_cells", 1, n);
  thrust::exclusive_scan(thrust::device(m.ws.temp), ptr(cell_count), ptr(cell_count) + total_cells + 1,
                         reuse(m.cell_start, cells + 1, allocs));
  m.shape.launch("cell_scan", 1, total_cells + 1);
  thrust::for_each(thrust::device, first, first + n,
                   PlaceInCells{ptr(keys), ptr(rank), ptr(m.cell_start), ptr(m.points),
                                reuse(m.grid_points, un, allocs), reuse(m.grid_index, un, allocs)});
  m.shape.launch("place_in_cells", 1, n);
  // Cells hold ~points_per_cell points, but a dense cluster or coincident points make one cell large.
  const std::int64_t max_cell =
      max_segment_size(ptr(m.cell_start), total_cells, reuse(m.ws.scalar, 1, allocs), m.shape, "cell_max");
  if (max_cell > 1)
    segmented_sort(ptr(m.cell_start), int(total_cells), n, max_cell, ptr(m.grid_index), ptr(m.grid_points),
                   reuse(sort_index, un, allocs), reuse(sort_points, un, allocs), IndexLess{}, m.shape,
                   "cell_sort");
  if (!settings.grid.cell_representatives) {
    m.end_call();
    m.shape.workspace_bytes = m.index_bytes();
    return;
  }
  // Cell representatives by jump flooding: one pass per step for all segments (steps of the largest grid).
  thrust::for_each(thrust::device, first, first + total_cells,
                   RepInit{m.grid_view(), reuse(m.cell_rep, cells, allocs)});
  m.shape.launch("rep_init", 1, total_cells);
  reuse(next, cells, allocs);
  GridSegment largest;
  for (const GridSegment& s : segs)
    if (std::max({s.nx, s.ny, s.nz}) > std::max({largest.nx, largest.ny, largest.nz})) largest = s;
  for (int step : grid_jfa_steps(largest)) {
    thrust::for_each(thrust::device, first, first + total_cells,
                     JfaStep{ptr(m.grid_segments), int(segs.size()), ptr(m.grid_points), ptr(m.cell_rep),
                             ptr(next), step});
    m.shape.launch("jump_flood", 1, total_cells);
    m.cell_rep.swap(next);
  }
  m.end_call();
  m.shape.workspace_bytes = m.index_bytes();
}

template <class System>
KnnIndex<System>::~KnnIndex() = default;
template <class System>
KnnIndex<System>::KnnIndex(KnnIndex&&) noexcept = default;
template <class System>
KnnIndex<System>& KnnIndex<System>::operator=(KnnIndex&&) noexcept = default;

template <class System>
std::size_t KnnIndex<System>::num_segments() const {
  return impl_->segment_offsets_host.size() - 1;
}
template <class System>
std::size_t KnnIndex<System>::num_points() const {
  return impl_->num_points;
}
template <class System>
const std::vector<std::int64_t>& KnnIndex<System>::segment_offsets() const {
  return impl_->segment_offsets_host;
}

template <class System>
KnnView KnnIndex<System>::view() const {
  const Impl& m = *impl_;
  return {ptr(m.points), ptr(m.segment_offsets), int(num_segments()), m.grid_view()};
}

template <class System>
LaunchShape KnnIndex<System>::last_launch_shape() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->shape;
}

template <class System>
KnnResult KnnIndex<System>::knn(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
                                const KnnSettings& settings) const {
  using namespace knn_detail;
  validate_knn_settings(settings);
  validate_knn_queries(queries, query_segment, num_segments());
  const Impl& m = *impl_;
  std::lock_guard<std::mutex> lock(m.mutex);
  std::int64_t& allocs = m.begin_call();
  const int k = settings.k;
  const std::int64_t nq = std::int64_t(queries.size());
  KnnResult out;
  out.k = k;
  if (nq == 0) return out;
  const std::int64_t max_seg =
      std::int64_t(max_searched_segment(m.segment_offsets_host, queries, query_segment));
  const KnnMethod method = resolve_knn_method(settings, std::size_t(max_seg));
  m.upload_queries(queries, query_segment, allocs);
  const std::size_t n = std::size_t(nq) * std::size_t(k);
  std::int32_t* idx = reuse(m.ws.idx, n, allocs);
  float* d2 = reuse(m.ws.d2, n, allocs);
  m.run_knn(k, settings.max_distance_m, method, settings.memory_budget_bytes, max_seg, idx, d2, allocs);
  download<System>(static_cast<const std::int32_t*>(idx), n, out.index, m.ws.staging, allocs);
  download<System>(static_cast<const float*>(d2), n, out.sq_distance_m2, m.ws.staging, allocs);
  m.end_call();
  return out;
}

template <class System>
RadiusResult KnnIndex<System>::radius(const CloudBatch& queries,
                                      const std::vector<std::int32_t>& query_segment, float radius_m,
                                      int max_neighbors, KnnMethod method) const {
  using namespace knn_detail;
  validate_radius_request(radius_m, max_neighbors);
  validate_knn_queries(queries, query_segment, num_segments());
  const Impl& m = *impl_;
  std::lock_guard<std::mutex> lock(m.mutex);
  std::int64_t& allocs = m.begin_call();
  typename Impl::Workspace& w = m.ws;
  const std::int64_t nq = std::int64_t(queries.size());
  RadiusResult out;
  out.offsets.assign(std::size_t(nq) + 1, 0);
  if (nq == 0) return out;
  KnnSettings ks;
  ks.method = method;
  const bool use_grid = resolve_knn_method(ks, max_searched_segment(m.segment_offsets_host, queries,
                                                                    query_segment)) == KnnMethod::Grid;
  const thrust::counting_iterator<std::int64_t> first(0);
  m.upload_queries(queries, query_segment, allocs);
  const Vec3f* q = ptr(w.queries);
  const std::int32_t* qseg = ptr(w.query_segment);
  std::int64_t* offsets = reuse(w.offsets, std::size_t(nq) + 1, allocs);
  thrust::fill_n(thrust::device, offsets, 1, std::int64_t(0));
  std::int32_t* idx = nullptr;
  float* d2 = nullptr;

  if (max_neighbors > 0) {  // the nearest max_neighbors within the radius = kNN with a distance cap
    const std::size_t lists = std::size_t(nq) * std::size_t(max_neighbors);
    std::int32_t* li = reuse(w.list_idx, lists, allocs);
    float* ld = reuse(w.list_d2, lists, allocs);
    m.run_knn(max_neighbors, radius_m, use_grid ? KnnMethod::Grid : KnnMethod::PerQuery,
              ks.memory_budget_bytes, 0, li, ld, allocs);
    thrust::transform(thrust::device, first, first + nq, offsets + 1, ListCount{li, max_neighbors});
    m.shape.launch("list_count", 1, nq);
    m.scan_offsets(nq, out.offsets, allocs);
    const std::size_t total = std::size_t(out.offsets.back());
    idx = reuse(w.idx, total, allocs);
    d2 = reuse(w.d2, total, allocs);
    thrust::for_each(thrust::device, first, first + nq,
                     CompactLists{li, ld, max_neighbors, offsets, idx, d2});
    m.shape.launch("compact_lists", 1, nq);
  } else {  // count, allocate, write in visiting order, then sort each query's results
    thrust::transform(
        thrust::device, first, first + nq, offsets + 1,
        RadiusCount{ptr(m.points), ptr(m.segment_offsets), m.grid_view(), use_grid, q, qseg, radius_m});
    m.shape.launch("radius_count", 1, nq);
    m.scan_offsets(nq, out.offsets, allocs);
    const std::size_t total = std::size_t(out.offsets.back());
    std::int64_t max_found = 0;
    for (std::int64_t i = 0; i < nq; ++i)
      max_found = std::max(max_found, out.offsets[std::size_t(i) + 1] - out.offsets[std::size_t(i)]);
    idx = reuse(w.idx, total, allocs);
    d2 = reuse(w.d2, total, allocs);
    thrust::for_each(thrust::device, first, first + nq,
                     RadiusFill{ptr(m.points), ptr(m.segment_offsets), m.grid_view(), use_grid, q, qseg,
                                radius_m, offsets, idx, d2});
    m.shape.launch("radius_fill", 1, nq);
    if (max_found > 1)
      segmented_sort(static_cast<const std::int64_t*>(offsets), int(nq), std::int64_t(total), max_found, d2,
                     idx, reuse(w.sort_d2, total, allocs), reuse(w.sort_idx, total, allocs), PairLess{},
                     m.shape, "radius_sort");
  }
  const std::size_t total = std::size_t(out.offsets.back());
  download<System>(static_cast<const std::int32_t*>(idx), total, out.index, w.staging, allocs);
  download<System>(static_cast<const float*>(d2), total, out.sq_distance_m2, w.staging, allocs);
  m.end_call();
  return out;
}

}  // namespace perch2::thrust_backend
