// Device-callable neighbour searches of the registration stage, beside the kNN stage's grid
// (perch2/knn/grid.hpp). Each returns exactly what a brute-force scan returns, from fewer distances:
//
// Source stripes (GICP source normals, SourceCovariance::FromKnn): the k nearest neighbours of every point of
//   one small source cloud. The cloud's finite points are cut into stripes along y, each sorted by x. A query
//   sweeps its own stripe outwards in x, then the neighbouring stripes nearest first, until the x gap (within
//   a stripe) or the y gap (to a stripe) alone exceeds its k-th distance. On bench_registration's rendered
//   clouds (313 points, k = 10) that is 42 distances per query instead of 99 for one sweep over the whole
//   cloud sorted by x.
//
// Target neighbour lists (the correspondence search's shortcut): each target point's kTargetListSize nearest
//   points of its segment, with the radius they cover. A source point's nearest target point within the
//   radius lies no farther than r0, its distance to the previous correspondence j0 (radius <= r0), so within
//   2 r0 of j0: when j0's list covers that, the list holds the answer. It is scanned in distance from j0 only
//   while |t - t_j0| - r0 could still beat the best so far. Near convergence ~5 distances instead of the
//   grid's ~55 and no cell walk; a list too short for r0 (early iterations) leaves the search to the grid.
//
// Neighbours are ordered by (squared distance, index), as everywhere in perch2/knn.
#pragma once

#include <cstdint>

#include "perch2/core/device.hpp"
#include "perch2/core/segments.hpp"
#include "perch2/knn/grid.hpp"
#include "perch2/knn/scan.hpp"

namespace perch2::reg {

// ---- Source stripes ----

constexpr int kMaxSourceStripes = 32;
constexpr int kMaxSourceNeighbours = 32;  ///< source_knn's largest k

/// Stripe width relative to sqrt(k * bounding area / points), i.e. ~1.3x the radius of k neighbours spread
/// over the cloud's x-y box: the fastest of 0.5 / 0.75 / 1 / 1.5 on bench_registration's rendered clouds.
constexpr float kStripeWidthFactor = 0.75f;

/// One cloud's stripes: stripe t holds y in [y0 + t w, y0 + (t + 1) w] (widened by slack for the rounding
/// of the assignment) at sorted positions [start[t], start[t + 1]); non-finite points follow start[count].
struct SourceStripes {
  float y0, w, inv_w, slack;
  int count;
  std::int32_t start[kMaxSourceStripes + 1];
};

/// The stripe of point p; kMaxSourceStripes for a non-finite point.
PERCH2_HD inline int source_stripe_of(const SourceStripes& st, Vec3f p) {
  return knn_sq_distance(p, p) == 0.f ? grid_coord(p.y, st.y0, st.inv_w, st.count) : kMaxSourceStripes;
}

/// Sorts positions [b, e) by (x, order): insertion sort for the usual short stripe, heap sort (O(n log n))
/// for a long one.
PERCH2_HD inline void source_sort_by_x(float* key_x, std::int32_t* order, std::int64_t b, std::int64_t e) {
  if (e - b > 32) {
    float* x = key_x + b;
    std::int32_t* o = order + b;
    heap_sort(
        e - b, [&](std::int64_t u, std::int64_t v) { return x[u] < x[v] || (x[u] == x[v] && o[u] < o[v]); },
        [&](std::int64_t u, std::int64_t v) {
          const float tx = x[u];
          x[u] = x[v], x[v] = tx;
          const std::int32_t to = o[u];
          o[u] = o[v], o[v] = to;
        });
    return;
  }
  for (std::int64_t i = b + 1; i < e; ++i) {  // stable: equal x keep the point order
    const float x = key_x[i];
    const std::int32_t o = order[i];
    std::int64_t j = i;
    for (; j > b && key_x[j - 1] > x; --j) key_x[j] = key_x[j - 1], order[j] = order[j - 1];
    key_x[j] = x, order[j] = o;
  }
}

/// Sorts the n points of one cloud into stripes sized for k neighbours: fills, per sorted position s, the
/// point (order[s] = first_index + its position in `points`), its stripe and its x, and returns the stripes
/// (positions relative to the cloud).
PERCH2_HD inline SourceStripes source_stripes_sort(const Vec3f* points, std::int64_t n, int k,
                                                   std::int32_t first_index, float* key_x,
                                                   std::int32_t* key_stripe, std::int32_t* order) {
  float x0 = INFINITY, x1 = -INFINITY, y0 = INFINITY, y1 = -INFINITY;
  std::int64_t finite = 0;
  for (std::int64_t i = 0; i < n; ++i) {
    const Vec3f p = points[i];
    if (!(knn_sq_distance(p, p) == 0.f)) continue;
    x0 = min_f(x0, p.x), x1 = max_f(x1, p.x), y0 = min_f(y0, p.y), y1 = max_f(y1, p.y);
    ++finite;
  }
  SourceStripes st{};
  st.count = 1;
  st.y0 = finite > 0 ? y0 : 0.f;
  const float ext_y = finite > 0 ? y1 - y0 : 0.f;
  const float w = kStripeWidthFactor * sqrtf(float(k) * (x1 - x0) * ext_y / float(finite > 0 ? finite : 1));
  if (w > 0.f && ext_y > 0.f) st.count = min_int(kMaxSourceStripes, max_int(1, int(ext_y / w)));
  st.w = ext_y / float(st.count);
  st.inv_w = st.w > 0.f ? 1.f / st.w : 0.f;
  st.slack = 1e-5f * (ext_y + fabsf(st.y0) + st.w);
  // Counting sort into the stripes (in point order), then each stripe by x (then point order). Stripes
  // count..kMaxSourceStripes - 1 stay empty: start[count] is where the non-finite points begin.
  std::int32_t cursor[kMaxSourceStripes + 2] = {};
  for (std::int64_t i = 0; i < n; ++i) ++cursor[source_stripe_of(st, points[i]) + 1];
  for (int t = 0; t <= kMaxSourceStripes; ++t) cursor[t + 1] += cursor[t];
  for (int t = 0; t <= st.count; ++t) st.start[t] = cursor[t];
  for (std::int64_t i = 0; i < n; ++i) {
    const Vec3f p = points[i];
    const int t = source_stripe_of(st, p);
    const std::int32_t s = cursor[t]++;
    key_stripe[s] = t, key_x[s] = t < kMaxSourceStripes ? p.x : 0.f, order[s] = first_index + std::int32_t(i);
  }
  for (int t = 0; t < st.count; ++t) source_sort_by_x(key_x, order, st.start[t], st.start[t + 1]);
  return st;
}

namespace detail {

constexpr std::uint64_t kNoKey = ~std::uint64_t(0);

/// Inserts (d, s) into the sorted list of k pair_keys if it belongs there (one integer compare and move per
/// step); keeps `bound` at the k-th distance once the list is full.
PERCH2_HD inline void source_push(int k, std::uint64_t* list, float d, std::int64_t s, float& bound) {
  const std::uint64_t key = pair_key(d, std::int32_t(s));
  if (!(d <= bound) || key >= list[k - 1]) return;
  int j = k - 1;
  for (; j > 0 && key < list[j - 1]; --j) list[j] = list[j - 1];
  list[j] = key;
  if (list[k - 1] != kNoKey) bound = bits_float(std::uint32_t(list[k - 1] >> 32));
}

/// Merges sorted positions [b, e) (one stripe, sorted by x) into the list, outwards from position m until
/// the x gap exceeds the k-th distance.
PERCH2_HD inline void source_sweep(const Vec3f* sorted, const float* sorted_x, Vec3f q, int k, std::int64_t m,
                                   std::int64_t b, std::int64_t e, std::uint64_t* list, float& bound) {
  for (std::int64_t s = m; s < e; ++s) {
    const float dx = sorted_x[s] - q.x;
    if (dx * dx > bound) break;
    source_push(k, list, knn_sq_distance(sorted[s], q), s, bound);
  }
  for (std::int64_t s = m - 1; s >= b; --s) {
    const float dx = sorted_x[s] - q.x;
    if (dx * dx > bound) break;
    source_push(k, list, knn_sq_distance(sorted[s], q), s, bound);
  }
}

}  // namespace detail

/// The k (<= kMaxSourceNeighbours) nearest neighbours of the point at sorted position s0 of one cloud
/// sorted by source_stripes_sort (sorted: its points in sorted order; sorted_x, sorted_stripe: its keys), the
/// point itself included: sorted positions by (squared distance, position) into idx; returns how many (fewer
/// than k only in a cloud of fewer finite points; none for a non-finite query).
PERCH2_HD inline int source_knn(const Vec3f* sorted, const float* sorted_x, const std::int32_t* sorted_stripe,
                                const SourceStripes& st, std::int64_t s0, int k, std::int32_t* idx) {
  const int t0 = sorted_stripe[s0];
  if (t0 >= st.count) return 0;  // a non-finite point
  const Vec3f q = sorted[s0];
  std::uint64_t list[kMaxSourceNeighbours];
  for (int j = 0; j < k; ++j) list[j] = detail::kNoKey;
  float bound = INFINITY;
  detail::source_sweep(sorted, sorted_x, q, k, s0, st.start[t0], st.start[t0 + 1], list, bound);
  for (int o = 1;; ++o) {
    bool nearer = false;  // a stripe at offset o may hold nearer points; none can at larger offsets then
    for (int t = t0 - o; t <= t0 + o; t += 2 * o) {
      if (t < 0 || t >= st.count || grid_cells_gap2(q.y, st.y0, st.w, t, t, st.slack) > bound) continue;
      nearer = true;
      std::int64_t lo = st.start[t], hi = st.start[t + 1];
      while (lo < hi) {  // first position with x >= q.x
        const std::int64_t m = (lo + hi) / 2;
        if (sorted_x[m] < q.x)
          lo = m + 1;
        else
          hi = m;
      }
      detail::source_sweep(sorted, sorted_x, q, k, lo, st.start[t], st.start[t + 1], list, bound);
    }
    if (!nearer) break;
  }
  int n = 0;
  for (; n < k && list[n] != detail::kNoKey; ++n) idx[n] = std::int32_t(std::uint32_t(list[n]));
  return n;
}

// ---- Target neighbour lists ----

constexpr int kTargetListSize = 16;  ///< 8 / 24 / 32 were no faster on bench_registration

struct ListEntry {
  float dist;        ///< metres from the list's point; +inf past the segment's end
  std::int32_t idx;  ///< global target index; -1 past the segment's end
};

/// Fills the list of target point j (global index, in segment seg of the grid; points in batch order) and
/// returns its reach: the list holds every point of the segment nearer to j than that.
PERCH2_HD inline float target_list_build(const GridView& grid, int seg, const Vec3f* points, std::int32_t j,
                                         ListEntry* list) {
  std::int32_t idx[kTargetListSize];
  float d2[kTargetListSize];
  grid_knn(grid, seg, points[j], kTargetListSize, INFINITY, idx, d2);
  for (int e = 0; e < kTargetListSize; ++e) list[e] = {sqrtf(d2[e]), idx[e]};
  return list[kTargetListSize - 1].dist;
}

/// grid_knn(grid, seg, q, 1, radius, &j, &d2), bit for bit, from the list (and reach) of a target point j0
/// at distance r0 = sqrtf(knn_sq_distance(points[j0], q)) from q, where radius <= r0 (1 + 1e-5); -1 if the
/// list does not reach far enough to decide (or r0 is not finite). The 1e-4 relative and 1 nm absolute
/// margins cover the float rounding of the distances.
PERCH2_HD inline int target_list_nearest(const ListEntry* list, float reach, const Vec3f* points, float r0,
                                         Vec3f q, float radius, std::int32_t& j, float& d2) {
  const float margin = 1.f + 1e-4f, floor = 1e-9f;
  float within = (r0 + radius) * margin + floor;  // every candidate is this close to point j0
  if (!(within < reach)) return -1;
  const float max_d2 = radius * radius;
  j = -1;
  d2 = INFINITY;
  for (int e = 0; e < kTargetListSize && list[e].dist <= within; ++e) {
    const std::int32_t t = list[e].idx;
    const float d = knn_sq_distance(points[t], q);
    if (d <= max_d2 && knn_less(d, t, d2, j)) {
      d2 = d, j = t;
      within = (r0 + sqrtf(d)) * margin + floor;  // a list point farther than this cannot beat t
    }
  }
  return j >= 0 ? 1 : 0;
}

}  // namespace perch2::reg
