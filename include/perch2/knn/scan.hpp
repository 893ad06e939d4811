// Device-callable nearest-neighbour building blocks shared by every backend (the algorithm text lives once):
// the sorted small-k list, the per-query scan of kNN II, the tile kernels of kNN I and a sort for radius
// results. Everything here is PERCH2_HD over raw pointers: no std:: containers, no exceptions.
//
// Ordering. Neighbours are ordered by (squared distance, index), lexicographically. Every method therefore
// returns exactly the same list, ties included: the k smallest (distance, index) pairs, whatever the order
// in which candidates were visited. An empty slot holds (+inf, -1); -1 compares as the largest index.
#pragma once

#include <cstdint>

#include "perch2/core/device.hpp"

namespace perch2 {

/// Squared Euclidean distance, in this exact operation order on every backend (results compare bit-exactly
/// with FLANN's L2_Simple on the host).
PERCH2_HD inline float knn_sq_distance(Vec3f a, Vec3f b) {
  const float dx = a.x - b.x, dy = a.y - b.y, dz = a.z - b.z;
  return dx * dx + dy * dy + dz * dz;
}

/// (d2a, ia) < (d2b, ib) lexicographically, with index -1 (empty) ordered last.
PERCH2_HD inline bool knn_less(float d2a, std::int32_t ia, float d2b, std::int32_t ib) {
  return d2a < d2b || (d2a == d2b && std::uint32_t(ia) < std::uint32_t(ib));
}

/// Empties a list of k slots: (+inf, -1).
PERCH2_HD inline void knn_clear(int k, std::int32_t* idx, float* d2) {
  for (int j = 0; j < k; ++j) {
    idx[j] = -1;
    d2[j] = INFINITY;
  }
}

/// The largest squared distance a candidate may have to enter a full list (or any list, given max_d2):
/// min(d2[k-1], max_d2). A cheap first filter; knn_push() does the exact test. d2[k-1] is never NaN (knn_push
/// only stores distances <= max_d2), so a NaN max_d2 yields d2[k-1] (and knn_push rejects every candidate).
PERCH2_HD inline float knn_bound(int k, const float* d2, float max_d2) {
  return min_f(max_d2, d2[k - 1]);
}

/// Inserts candidate (cand_d2, cand) into the sorted list if it beats the last slot and is within max_d2.
/// Returns true if it was inserted. O(k) worst case, O(1) for the common rejected candidate.
PERCH2_HD inline bool knn_push(int k, std::int32_t* idx, float* d2, float max_d2, float cand_d2,
                               std::int32_t cand) {
  if (!(cand_d2 <= max_d2) || !knn_less(cand_d2, cand, d2[k - 1], idx[k - 1])) return false;
  int j = k - 1;
  while (j > 0 && knn_less(cand_d2, cand, d2[j - 1], idx[j - 1])) {
    d2[j] = d2[j - 1];
    idx[j] = idx[j - 1];
    --j;
  }
  d2[j] = cand_d2;
  idx[j] = cand;
  return true;
}

/// kNN II: one query against points [begin, end) of `points` (global indices), merged into the sorted list
/// (idx, d2) of k slots, which the caller has cleared (or filled by earlier calls). max_d2 = max distance^2.
PERCH2_HD inline void knn_scan(const Vec3f* points, std::int64_t begin, std::int64_t end, Vec3f q, int k,
                               float max_d2, std::int32_t* idx, float* d2) {
  float bound = knn_bound(k, d2, max_d2);
  for (std::int64_t i = begin; i < end; ++i) {
    const float c = knn_sq_distance(points[i], q);
    if (c <= bound && knn_push(k, idx, d2, max_d2, c, std::int32_t(i))) bound = knn_bound(k, d2, max_d2);
  }
}

/// Radius search by scanning: calls visit(index, d2) for every point of [begin, end) within sqrt(max_d2).
template <class Visit>
PERCH2_HD inline void radius_scan(const Vec3f* points, std::int64_t begin, std::int64_t end, Vec3f q,
                                  float max_d2, Visit& visit) {
  for (std::int64_t i = begin; i < end; ++i) {
    const float c = knn_sq_distance(points[i], q);
    if (c <= max_d2) visit(std::int32_t(i), c);
  }
}

/// kNN I, step 1 (one thread per entry): the distance between a query and one target of a tile. The tile is
/// `rows` queries x `width` target columns; column j of row r is target point seg_begin[r] + col0 + j, or
/// +inf past the end of the query's segment (seg_end[r]).
PERCH2_HD inline float knn_tile_distance(const Vec3f* points, std::int64_t seg_begin, std::int64_t seg_end,
                                         std::int64_t col0, std::int64_t j, Vec3f q) {
  const std::int64_t i = seg_begin + col0 + j;
  return i < seg_end ? knn_sq_distance(points[i], q) : INFINITY;
}

/// kNN I, step 2 (one thread per query): merges one row of a distance tile into the query's sorted list.
/// Entry j of `row` is the distance to target point first_index + j.
PERCH2_HD inline void knn_tile_select(const float* row, std::int64_t width, std::int64_t first_index, int k,
                                      float max_d2, std::int32_t* idx, float* d2) {
  float bound = knn_bound(k, d2, max_d2);
  for (std::int64_t j = 0; j < width; ++j) {
    const float c = row[j];
    if (c <= bound && knn_push(k, idx, d2, max_d2, c, std::int32_t(first_index + j)))
      bound = knn_bound(k, d2, max_d2);
  }
}

PERCH2_HD inline void knn_swap_pairs(float* d2, std::int32_t* idx, std::int64_t a, std::int64_t b) {
  const float td = d2[a];
  d2[a] = d2[b];
  d2[b] = td;
  const std::int32_t ti = idx[a];
  idx[a] = idx[b];
  idx[b] = ti;
}

PERCH2_HD inline void knn_sift_down(float* d2, std::int32_t* idx, std::int64_t root, std::int64_t size) {
  while (true) {
    std::int64_t child = 2 * root + 1;
    if (child >= size) return;
    if (child + 1 < size && knn_less(d2[child], idx[child], d2[child + 1], idx[child + 1])) ++child;
    if (!knn_less(d2[root], idx[root], d2[child], idx[child])) return;
    knn_swap_pairs(d2, idx, root, child);
    root = child;
  }
}

/// Sorts n (d2, idx) pairs in place by knn_less (heap sort: O(n log n), no extra memory, device-callable).
PERCH2_HD inline void knn_sort_pairs(float* d2, std::int32_t* idx, std::int64_t n) {
  for (std::int64_t s = n / 2 - 1; s >= 0; --s) knn_sift_down(d2, idx, s, n);
  for (std::int64_t end = n - 1; end > 0; --end) {
    knn_swap_pairs(d2, idx, 0, end);
    knn_sift_down(d2, idx, 0, end);
  }
}

}  // namespace perch2
