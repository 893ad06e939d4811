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

#include "perch2/core/segments.hpp"
#include "perch2/cuda/knn.hpp"
#include "perch2/knn/grid.hpp"
#include "perch2/knn/scan.hpp"

namespace perch2::thrust_backend {

namespace knn_detail {

template <class T>
T* raw(thrust::device_vector<T>& v) {
  return thrust::raw_pointer_cast(v.data());
}
template <class T>
const T* raw(const thrust::device_vector<T>& v) {
  return thrust::raw_pointer_cast(v.data());
}

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

/// Pass 3: order each cell's points by index, so the layout does not depend on the order of the atomic
/// increments. Cells hold ~points_per_cell points (insertion sort); a large cell (coincident points, a
/// dense cluster) is heap sorted: O(m log m) instead of O(m^2) in its one thread.
struct OrderCell {
  const std::int32_t* cell_start;
  Vec3f* points;
  std::int32_t* index;
  PERCH2_HD void operator()(std::int64_t c) const {
    const std::int64_t b = cell_start[c], m = cell_start[c + 1] - b;
    Vec3f* p = points + b;
    std::int32_t* v = index + b;
    if (m > 32) {
      heap_sort(
          m, [v](std::int64_t x, std::int64_t y) { return v[x] < v[y]; },
          [p, v](std::int64_t x, std::int64_t y) {
            const Vec3f tp = p[x];
            p[x] = p[y], p[y] = tp;
            const std::int32_t tv = v[x];
            v[x] = v[y], v[y] = tv;
          });
      return;
    }
    for (std::int64_t i = 1; i < m; ++i) {
      const Vec3f pi = p[i];
      const std::int32_t vi = v[i];
      std::int64_t j = i;
      for (; j > 0 && v[j - 1] > vi; --j) p[j] = p[j - 1], v[j] = v[j - 1];
      p[j] = pi;
      v[j] = vi;
    }
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

/// Radius search visitors: count, then write.
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
    knn_sort_pairs(d2 + o, idx + o, v.n);
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

  GridView grid_view() const {
    return {knn_detail::raw(grid_segments), int(grid_segments.size()),   knn_detail::raw(cell_start),
            knn_detail::raw(grid_points),   knn_detail::raw(grid_index), knn_detail::raw(cell_rep)};
  }

  /// Uploads query points and, per point, the segment its cloud searches.
  void upload_queries(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
                      thrust::device_vector<Vec3f>& q, thrust::device_vector<std::int32_t>& qseg) const {
    using namespace knn_detail;
    const std::vector<Vec3f> host = to_aos(queries);
    q.assign(host.begin(), host.end());
    const thrust::device_vector<std::int64_t> offsets(queries.offsets.begin(), queries.offsets.end());
    const thrust::device_vector<std::int32_t> seg_of_cloud(query_segment.begin(), query_segment.end());
    thrust::device_vector<std::int32_t> cloud(q.size());
    thrust::upper_bound(thrust::device, raw(offsets) + 1, raw(offsets) + offsets.size(),
                        thrust::counting_iterator<std::int64_t>(0),
                        thrust::counting_iterator<std::int64_t>(std::int64_t(q.size())), raw(cloud));
    qseg.resize(q.size());
    thrust::transform(thrust::device, raw(cloud), raw(cloud) + cloud.size(), raw(qseg),
                      QuerySegment{raw(seg_of_cloud)});
  }

  /// Searches uploaded queries (q, per-point segment qseg) into idx/d2 (nq * k each, preallocated).
  /// max_seg: largest searched segment (kNN I tile width).
  void run_knn(const thrust::device_vector<Vec3f>& q, const thrust::device_vector<std::int32_t>& qseg, int k,
               float max_distance_m, KnnMethod method, std::size_t memory_budget_bytes, std::int64_t max_seg,
               thrust::device_vector<std::int32_t>& idx, thrust::device_vector<float>& d2) const {
    using namespace knn_detail;
    const std::int64_t nq = std::int64_t(q.size());
    const float max_d2 = max_distance_m * max_distance_m;
    const thrust::counting_iterator<std::int64_t> first(0);

    if (method == KnnMethod::Grid) {
      thrust::for_each(thrust::device, first, first + nq,
                       GridKnn{grid_view(), raw(q), raw(qseg), k, max_distance_m, raw(idx), raw(d2)});
    } else if (method == KnnMethod::PerQuery) {
      thrust::for_each(
          thrust::device, first, first + nq,
          PerQueryKnn{raw(points), raw(segment_offsets), raw(q), raw(qseg), k, max_d2, raw(idx), raw(d2)});
    } else {  // kNN I: tiles of (query rows x target columns) under the memory budget
      thrust::for_each(thrust::device, first, first + nq, ClearLists{k, raw(idx), raw(d2)});
      if (max_seg > 0) {
        const std::int64_t budget = std::int64_t(memory_budget_bytes / sizeof(float));
        const std::int64_t width = std::min(max_seg, budget);
        const std::int64_t rows = std::min(nq, std::max<std::int64_t>(1, budget / width));
        thrust::device_vector<float> tile(static_cast<std::size_t>(rows * width));
        for (std::int64_t row0 = 0; row0 < nq; row0 += rows) {
          const std::int64_t nr = std::min(rows, nq - row0);
          for (std::int64_t col0 = 0; col0 < max_seg; col0 += width) {
            thrust::for_each(thrust::device, first, first + nr * width,
                             TileDistances{raw(points), raw(segment_offsets), raw(q), raw(qseg), row0, col0,
                                           width, raw(tile)});
            thrust::for_each(thrust::device, first, first + nr,
                             TileSelect{raw(segment_offsets), raw(qseg), raw(tile), row0, col0, width, k,
                                        max_d2, raw(idx), raw(d2)});
          }
        }
      }
    }
  }
};

template <class System>
KnnIndex<System>::KnnIndex(CloudBatch targets, const KnnIndexSettings& settings)
    : impl_(std::make_unique<Impl>()) {
  using namespace knn_detail;
  validate_knn_cloud(targets, "kNN targets");
  validate_knn_index_settings(settings);
  Impl& m = *impl_;
  m.segment_offsets_host = targets.offsets;
  m.num_points = targets.size();
  const std::vector<Vec3f> host = to_aos(targets);
  m.points.assign(host.begin(), host.end());
  m.segment_offsets.assign(targets.offsets.begin(), targets.offsets.end());

  // Grid: geometry planned on the host (bounding boxes, cell size), keys and order on the device.
  std::vector<GridSegment> segs;
  const std::int64_t total_cells = plan_grid(targets, settings.grid, segs);
  m.grid_segments.assign(segs.begin(), segs.end());
  const std::int64_t n = std::int64_t(m.num_points);
  thrust::device_vector<std::int32_t> seg_of_point(static_cast<std::size_t>(n));
  // All algorithms run on raw pointers with an explicit policy: Thrust's OpenMP algorithms read
  // device_vector iterators through device_reference, which binds a reference through a null policy
  // pointer (UBSan reports it). Points are bucketed by a counting sort (atomics + scan), not thrust::sort,
  // whose OpenMP version does the same internally.
  thrust::upper_bound(thrust::device, raw(m.segment_offsets) + 1,
                      raw(m.segment_offsets) + m.segment_offsets.size(),
                      thrust::counting_iterator<std::int64_t>(0), thrust::counting_iterator<std::int64_t>(n),
                      raw(seg_of_point));
  thrust::device_vector<std::int64_t> keys(static_cast<std::size_t>(n));
  thrust::transform(thrust::device, thrust::counting_iterator<std::int64_t>(0),
                    thrust::counting_iterator<std::int64_t>(n), raw(keys),
                    CellKey{raw(m.points), raw(seg_of_point), raw(m.grid_segments)});
  thrust::device_vector<std::int32_t> cell_count(static_cast<std::size_t>(total_cells) + 1, 0),
      rank(seg_of_point.size());
  const thrust::counting_iterator<std::int64_t> first(0);
  thrust::for_each(thrust::device, first, first + n, CountCells{raw(keys), raw(cell_count), raw(rank)});
  m.cell_start.resize(static_cast<std::size_t>(total_cells) + 1);
  thrust::exclusive_scan(thrust::device, raw(cell_count), raw(cell_count) + total_cells + 1,
                         raw(m.cell_start));
  m.grid_points.resize(static_cast<std::size_t>(n));
  m.grid_index.resize(static_cast<std::size_t>(n));
  thrust::for_each(thrust::device, first, first + n,
                   PlaceInCells{raw(keys), raw(rank), raw(m.cell_start), raw(m.points), raw(m.grid_points),
                                raw(m.grid_index)});
  thrust::for_each(thrust::device, first, first + total_cells,
                   OrderCell{raw(m.cell_start), raw(m.grid_points), raw(m.grid_index)});
  // Cell representatives by jump flooding: one pass per step for all segments (steps of the largest grid).
  m.cell_rep.assign(static_cast<std::size_t>(total_cells), -1);
  thrust::device_vector<std::int32_t> next(static_cast<std::size_t>(total_cells), -1);
  thrust::for_each(thrust::device, first, first + total_cells, RepInit{m.grid_view(), raw(m.cell_rep)});
  GridSegment largest;
  for (const GridSegment& s : segs)
    if (std::max({s.nx, s.ny, s.nz}) > std::max({largest.nx, largest.ny, largest.nz})) largest = s;
  for (int step : grid_jfa_steps(largest)) {
    thrust::for_each(thrust::device, first, first + total_cells,
                     JfaStep{raw(m.grid_segments), int(segs.size()), raw(m.grid_points), raw(m.cell_rep),
                             raw(next), step});
    m.cell_rep.swap(next);
  }
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
  return {knn_detail::raw(m.points), knn_detail::raw(m.segment_offsets), int(num_segments()), m.grid_view()};
}

template <class System>
KnnResult KnnIndex<System>::knn(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
                                const KnnSettings& settings) const {
  using namespace knn_detail;
  validate_knn_settings(settings);
  validate_knn_queries(queries, query_segment, num_segments());
  const Impl& m = *impl_;
  const int k = settings.k;
  const std::int64_t nq = std::int64_t(queries.size());
  KnnResult out;
  out.k = k;
  if (nq == 0) return out;
  const KnnMethod method =
      resolve_knn_method(settings, max_searched_segment(m.segment_offsets_host, queries, query_segment));
  thrust::device_vector<Vec3f> q;
  thrust::device_vector<std::int32_t> qseg;
  m.upload_queries(queries, query_segment, q, qseg);
  thrust::device_vector<std::int32_t> idx(static_cast<std::size_t>(nq * k));
  thrust::device_vector<float> d2(static_cast<std::size_t>(nq * k));
  m.run_knn(q, qseg, k, settings.max_distance_m, method, settings.memory_budget_bytes,
            std::int64_t(max_searched_segment(m.segment_offsets_host, queries, query_segment)), idx, d2);
  out.index.resize(std::size_t(nq * k));
  out.sq_distance_m2.resize(std::size_t(nq * k));
  thrust::copy(idx.begin(), idx.end(), out.index.begin());
  thrust::copy(d2.begin(), d2.end(), out.sq_distance_m2.begin());
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
  const std::int64_t nq = std::int64_t(queries.size());
  RadiusResult out;
  out.offsets.assign(std::size_t(nq) + 1, 0);
  if (nq == 0) return out;
  KnnSettings ks;
  ks.method = method;
  const bool use_grid = resolve_knn_method(ks, max_searched_segment(m.segment_offsets_host, queries,
                                                                    query_segment)) == KnnMethod::Grid;
  const thrust::counting_iterator<std::int64_t> first(0);
  thrust::device_vector<std::int64_t> offsets(static_cast<std::size_t>(nq) + 1, 0);
  thrust::device_vector<std::int32_t> idx;
  thrust::device_vector<float> d2;

  if (max_neighbors > 0) {  // the nearest max_neighbors within the radius = kNN with a distance cap
    ks.k = max_neighbors;
    ks.max_distance_m = radius_m;
    ks.method = use_grid ? KnnMethod::Grid : KnnMethod::PerQuery;
    thrust::device_vector<Vec3f> q;
    thrust::device_vector<std::int32_t> qseg;
    m.upload_queries(queries, query_segment, q, qseg);
    thrust::device_vector<std::int32_t> li(std::size_t(nq) * std::size_t(max_neighbors));
    thrust::device_vector<float> ld(li.size());
    m.run_knn(q, qseg, max_neighbors, radius_m, ks.method, ks.memory_budget_bytes, 0, li, ld);
    thrust::transform(thrust::device, first, first + nq, raw(offsets) + 1, ListCount{raw(li), max_neighbors});
    thrust::inclusive_scan(thrust::device, raw(offsets) + 1, raw(offsets) + nq + 1, raw(offsets) + 1);
    // One scalar to the host by copy: reading a device_reference trips UBSan on the OpenMP system.
    std::int64_t total = 0;
    thrust::copy(offsets.end() - 1, offsets.end(), &total);
    idx.resize(std::size_t(total));
    d2.resize(std::size_t(total));
    thrust::for_each(thrust::device, first, first + nq,
                     CompactLists{raw(li), raw(ld), max_neighbors, raw(offsets), raw(idx), raw(d2)});
  } else {
    thrust::device_vector<Vec3f> q;
    thrust::device_vector<std::int32_t> qseg;
    m.upload_queries(queries, query_segment, q, qseg);
    thrust::transform(thrust::device, first, first + nq, raw(offsets) + 1,
                      RadiusCount{raw(m.points), raw(m.segment_offsets), m.grid_view(), use_grid, raw(q),
                                  raw(qseg), radius_m});
    thrust::inclusive_scan(thrust::device, raw(offsets) + 1, raw(offsets) + nq + 1, raw(offsets) + 1);
    // One scalar to the host by copy: reading a device_reference trips UBSan on the OpenMP system.
    std::int64_t total = 0;
    thrust::copy(offsets.end() - 1, offsets.end(), &total);
    idx.resize(std::size_t(total));
    d2.resize(std::size_t(total));
    thrust::for_each(thrust::device, first, first + nq,
                     RadiusFill{raw(m.points), raw(m.segment_offsets), m.grid_view(), use_grid, raw(q),
                                raw(qseg), radius_m, raw(offsets), raw(idx), raw(d2)});
  }
  thrust::copy(offsets.begin(), offsets.end(), out.offsets.begin());
  out.index.resize(idx.size());
  out.sq_distance_m2.resize(d2.size());
  thrust::copy(idx.begin(), idx.end(), out.index.begin());
  thrust::copy(d2.begin(), d2.end(), out.sq_distance_m2.begin());
  return out;
}

}  // namespace perch2::thrust_backend
