// Uniform spatial grid for exact nearest-neighbour search, one dense grid per target segment.
//
// Layout (GridView, raw pointers to host or device memory owned by a backend):
//   segment s has its own origin, cell size and dims (nx, ny, nz); local cell id (z * ny + y) * nx + x;
//   global cell id = segments[s].cell_base + local id; points are sorted by global cell id (so each segment
//   stays contiguous) and cell c holds sorted points [cell_start[c], cell_start[c + 1]).
//   A row of cells (fixed y, z) is one contiguous range of sorted points: the search scans rows, not cells.
//
// Search (grid_knn), exact: the k smallest (distance, index) pairs within max_distance_m.
//   Ball search (default): every cell stores a representative target point near its centre (cell_rep, built
//   once by jump flooding). The query's distance to its cell's representative is an upper bound R on its
//   nearest-neighbour distance, so all cells overlapping the ball of radius R are scanned, rows nearest the
//   query first; rows farther than the current k-th distance are skipped and each row's x range is cut to
//   the ball. For k > 1 the ball starts at R + ball_step_m * sqrt(k) and doubles until it holds
//   k points (or reaches max_distance_m / the whole segment). Far queries thus cost about as much as near
//   ones: the ball's radius is the true distance plus ~2 cells.
//   Ring search (fallback when cell_rep is null): rings of cells r = 0, 1, 2... around the query's clamped
//   cell until the k-th distance is below the distance to every unvisited cell.
// Cell boxes are widened by a per-segment slack covering float rounding of the cell assignment.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <string>
#include <vector>

#include "perch2/core/cloud.hpp"
#include "perch2/core/device.hpp"
#include "perch2/core/error.hpp"
#include "perch2/knn/scan.hpp"

namespace perch2 {

/// Build parameters of the grid (the index's, chosen once per target).
struct GridSettings {
  /// Cell edge, metres; 0 = automatic per segment (aiming at points_per_cell points per occupied cell).
  float cell_size_m = 0.f;
  /// Automatic cell size: target mean number of points per occupied cell. With the ball search, coarse
  /// cells win: the bench_knn scenes (5,000- and 20,000-point surface clouds), one thread, ran fastest
  /// at 12-24 (k = 1: 0.40 us/query at 16 vs 0.45 at 8 and 0.75 at 2; k = 10: 1.2 vs 1.23 vs 1.86).
  float points_per_cell = 16.f;
  /// Dense-grid size cap: a segment gets at most max_cells_per_point * points + 64 cells (4 bytes each);
  /// the cell grows until it fits. Bounds memory for sparse clouds spread over a large volume.
  float max_cells_per_point = 8.f;
  /// k > 1 search: the first ball's radius is the representative's distance plus
  /// knn_ball_cells * cell * sqrt(k / points_per_cell); too small a ball is rescanned at twice the radius.
  /// Speed only (results are exact either way): 0.5 visited the fewest points at k = 10 in bench_knn's
  /// scenes (166 distances/query vs 175 at 1 and 216 at 0, where half the queries needed a second pass).
  float knn_ball_cells = 0.5f;
  /// Build the cell representatives of the ball search (jump flooding over every cell: on a sparse scene
  /// of 71k points, ~570k cells, 90% of the index build). Radius searches never use them; an index used
  /// only for radius searches (the cost stage's) skips them. false: k-nearest searches fall back to rings.
  bool cell_representatives = true;
};

/// One segment's grid geometry.
struct GridSegment {
  Vec3f origin{0, 0, 0};  ///< min corner, metres
  float cell_m = 1.f;     ///< cell edge, metres
  float inv_cell = 1.f;   ///< 1 / cell_m
  float slack_m = 0.f;    ///< cell boxes are widened by this (float rounding of the cell assignment)
  int nx = 1, ny = 1, nz = 1;
  float points_per_cell = 1.f;  ///< mean points per occupied cell
  float ball_step_m = 0.f;      ///< k > 1: the first search ball adds ball_step_m * sqrt(k), metres
  std::int64_t cell_base = 0;   ///< first global cell id
  std::int64_t point_begin = 0, point_end = 0;  ///< sorted-point range of the segment
};

struct GridView {
  const GridSegment* segments = nullptr;
  int num_segments = 0;
  const std::int32_t* cell_start = nullptr;   ///< size total cells + 1: sorted-point positions
  const Vec3f* points = nullptr;              ///< target points sorted by global cell id
  const std::int32_t* point_index = nullptr;  ///< global target index of each sorted point
  /// Per cell: sorted position of a target point near the cell centre (jump flooding, see grid_jfa_step),
  /// -1 if none. Optional: without it grid_knn falls back to ring search.
  const std::int32_t* cell_rep = nullptr;
};

/// Cell coordinate of v along one axis, clamped into [0, n - 1] (queries outside the grid get edge cells).
PERCH2_HD inline int grid_coord(float v, float origin, float inv_cell, int n) {
  const float t = (v - origin) * inv_cell;
  if (!(t >= 0.f)) return 0;
  if (t >= float(n)) return n - 1;
  return min_int(int(t), n - 1);
}

/// Local cell id of point p in segment s.
PERCH2_HD inline std::int64_t grid_local_cell(const GridSegment& s, Vec3f p) {
  const int x = grid_coord(p.x, s.origin.x, s.inv_cell, s.nx);
  const int y = grid_coord(p.y, s.origin.y, s.inv_cell, s.ny);
  const int z = grid_coord(p.z, s.origin.z, s.inv_cell, s.nz);
  return (std::int64_t(z) * s.ny + y) * s.nx + x;
}

/// Squared distance from v to the interval [lo - slack, hi + slack].
/// A NaN v gives 0: max_f returns its second argument when the comparison fails.
PERCH2_HD inline float grid_gap2(float v, float lo, float hi, float slack) {
  const float g = max_f(max_f(lo - slack - v, v - hi - slack), 0.f);
  return g * g;
}

/// Squared distance from v to cells [c0, c1] of one axis (inclusive), widened by the slack.
PERCH2_HD inline float grid_cells_gap2(float v, float origin, float cell, int c0, int c1, float slack) {
  return grid_gap2(v, origin + float(c0) * cell, origin + float(c1 + 1) * cell, slack);
}

namespace detail {

/// Scans sorted points [cell_start[first], cell_start[last + 1]) into the list; keeps `bound` current.
PERCH2_HD inline void grid_scan_cells(const GridView& g, std::int64_t first, std::int64_t last, Vec3f q,
                                      int k, float max_d2, std::int32_t* idx, float* d2, float& bound) {
  const std::int64_t b = g.cell_start[first], e = g.cell_start[last + 1];
  for (std::int64_t i = b; i < e; ++i) {
    const float c = knn_sq_distance(g.points[i], q);
    if (c <= bound && knn_push(k, idx, d2, max_d2, c, g.point_index[i])) bound = knn_bound(k, d2, max_d2);
  }
}

}  // namespace detail

/// Number of filled entries of a sorted list.
PERCH2_HD inline int knn_count(int k, const std::int32_t* idx) {
  int found = 0;
  while (found < k && idx[found] >= 0) ++found;
  return found;
}

/// Ring search (see the file comment); grid_knn uses it when the view has no cell representatives.
PERCH2_HD inline int grid_knn_rings(const GridView& g, int segment, Vec3f q, int k, float max_distance_m,
                                    std::int32_t* idx, float* d2) {
  knn_clear(k, idx, d2);
  if (!(knn_sq_distance(q, q) == 0.f)) return 0;  // a non-finite query has no neighbours
  const GridSegment s = g.segments[segment];
  if (s.point_end <= s.point_begin) return 0;
  const float max_d2 = max_distance_m * max_distance_m;
  const int cx = grid_coord(q.x, s.origin.x, s.inv_cell, s.nx);
  const int cy = grid_coord(q.y, s.origin.y, s.inv_cell, s.ny);
  const int cz = grid_coord(q.z, s.origin.z, s.inv_cell, s.nz);
  const float ox = s.origin.x, oy = s.origin.y, oz = s.origin.z, cell = s.cell_m, slack = s.slack_m;
  // Whole-grid gaps per axis, used by the stopping bound.
  const float gx = grid_cells_gap2(q.x, ox, cell, 0, s.nx - 1, slack);
  const float gy = grid_cells_gap2(q.y, oy, cell, 0, s.ny - 1, slack);
  const float gz = grid_cells_gap2(q.z, oz, cell, 0, s.nz - 1, slack);
  if (gx + gy + gz > max_d2) return 0;  // the whole segment lies beyond max_distance_m
  float bound = max_d2;
  for (int r = 0;; ++r) {
    const int z0 = max_int(cz - r, 0), z1 = min_int(cz + r, s.nz - 1);
    const int y0 = max_int(cy - r, 0), y1 = min_int(cy + r, s.ny - 1);
    const int xa = cx - r, xb = cx + r;
    for (int z = z0; z <= z1; ++z) {
      const float dz2 = grid_cells_gap2(q.z, oz, cell, z, z, slack);
      if (dz2 > bound) continue;
      const bool z_face = z == cz - r || z == cz + r;
      for (int y = y0; y <= y1; ++y) {
        const float dyz2 = dz2 + grid_cells_gap2(q.y, oy, cell, y, y, slack);
        if (dyz2 > bound) continue;
        // Cells of this row the current k-th distance ball can reach.
        int xlo = 0, xhi = s.nx - 1;
        if (bound < INFINITY) {
          const float rx = sqrtf(bound - dyz2) + slack;
          xlo = grid_coord(q.x - rx, ox, s.inv_cell, s.nx);
          xhi = grid_coord(q.x + rx, ox, s.inv_cell, s.nx);
        }
        const std::int64_t row = s.cell_base + (std::int64_t(z) * s.ny + y) * s.nx;
        if (z_face || y == cy - r || y == cy + r) {
          const int a = max_int(xa, xlo), b = min_int(xb, xhi);
          if (a <= b) detail::grid_scan_cells(g, row + a, row + b, q, k, max_d2, idx, d2, bound);
        } else {  // inside the ring's y-z square: only its two end cells are new
          if (xa >= xlo && xa <= xhi)
            detail::grid_scan_cells(g, row + xa, row + xa, q, k, max_d2, idx, d2, bound);
          if (xb >= xlo && xb <= xhi)
            detail::grid_scan_cells(g, row + xb, row + xb, q, k, max_d2, idx, d2, bound);
        }
      }
    }
    // Lower bound on the distance to every unvisited cell: the nearest of the (up to) six slabs of the grid
    // outside the visited block [c - r, c + r].
    float lb2 = INFINITY;
    if (cx - r > 0) lb2 = min_f(lb2, grid_cells_gap2(q.x, ox, cell, 0, cx - r - 1, slack) + gy + gz);
    if (cx + r < s.nx - 1)
      lb2 = min_f(lb2, grid_cells_gap2(q.x, ox, cell, cx + r + 1, s.nx - 1, slack) + gy + gz);
    if (cy - r > 0) lb2 = min_f(lb2, gx + grid_cells_gap2(q.y, oy, cell, 0, cy - r - 1, slack) + gz);
    if (cy + r < s.ny - 1)
      lb2 = min_f(lb2, gx + grid_cells_gap2(q.y, oy, cell, cy + r + 1, s.ny - 1, slack) + gz);
    if (cz - r > 0) lb2 = min_f(lb2, gx + gy + grid_cells_gap2(q.z, oz, cell, 0, cz - r - 1, slack));
    if (cz + r < s.nz - 1)
      lb2 = min_f(lb2, gx + gy + grid_cells_gap2(q.z, oz, cell, cz + r + 1, s.nz - 1, slack));
    if (lb2 == INFINITY || lb2 > max_d2 || d2[k - 1] < lb2) break;
  }
  return knn_count(k, idx);
}

/// i-th coordinate of the order c, c + 1, c - 1, c + 2, c - 2, ... (nearest rows first).
PERCH2_HD inline int grid_outward(int c, int i) {
  return (i & 1) ? c + (i + 1) / 2 : c - i / 2;
}

/// Merges every point of segment s within sqrt(limit_d2) of q into the sorted list (which may hold points
/// already; a point is never visited twice within one call). Rows nearest the query are visited first so
/// the k-th distance tightens early; rows and row ends beyond the current k-th distance are skipped.
PERCH2_HD inline void grid_ball_scan(const GridView& g, const GridSegment& s, Vec3f q, int k, float limit_d2,
                                     std::int32_t* idx, float* d2) {
  float bound = knn_bound(k, d2, limit_d2);
  const float cell = s.cell_m, slack = s.slack_m;
  const float reach_z = sqrtf(bound) + slack;
  const int z0 = grid_coord(q.z - reach_z, s.origin.z, s.inv_cell, s.nz);
  const int z1 = grid_coord(q.z + reach_z, s.origin.z, s.inv_cell, s.nz);
  const int cz = grid_coord(q.z, s.origin.z, s.inv_cell, s.nz);
  const int cy = grid_coord(q.y, s.origin.y, s.inv_cell, s.ny);
  const int nzi = 2 * max_int(cz - z0, z1 - cz) + 1;
  for (int iz = 0; iz < nzi; ++iz) {
    const int z = grid_outward(cz, iz);
    if (z < z0 || z > z1) continue;
    const float dz2 = grid_cells_gap2(q.z, s.origin.z, cell, z, z, slack);
    if (dz2 > bound) continue;
    const float reach_y = sqrtf(bound - dz2) + slack;
    const int y0 = grid_coord(q.y - reach_y, s.origin.y, s.inv_cell, s.ny);
    const int y1 = grid_coord(q.y + reach_y, s.origin.y, s.inv_cell, s.ny);
    const int nyi = 2 * max_int(cy - y0, y1 - cy) + 1;
    for (int iy = 0; iy < nyi; ++iy) {
      const int y = grid_outward(cy, iy);
      if (y < y0 || y > y1) continue;
      const float dyz2 = dz2 + grid_cells_gap2(q.y, s.origin.y, cell, y, y, slack);
      if (dyz2 > bound) continue;
      const float reach_x = sqrtf(bound - dyz2) + slack;
      const int x0 = grid_coord(q.x - reach_x, s.origin.x, s.inv_cell, s.nx);
      const int x1 = grid_coord(q.x + reach_x, s.origin.x, s.inv_cell, s.nx);
      const std::int64_t row = s.cell_base + (std::int64_t(z) * s.ny + y) * s.nx;
      detail::grid_scan_cells(g, row + x0, row + x1, q, k, limit_d2, idx, d2, bound);
    }
  }
}

/// Exact k nearest neighbours of q among segment `segment`'s points within max_distance_m (inclusive;
/// +inf = unlimited). Fills idx[0..k) with global target indices and d2[0..k) with squared distances
/// (metres^2), sorted by (distance, index); missing entries are (-1, +inf). Returns the number found.
/// A non-finite q finds nothing (device callers need not filter NaN points first).
PERCH2_HD inline int grid_knn(const GridView& g, int segment, Vec3f q, int k, float max_distance_m,
                              std::int32_t* idx, float* d2) {
  if (!g.cell_rep) return grid_knn_rings(g, segment, q, k, max_distance_m, idx, d2);
  knn_clear(k, idx, d2);
  if (!(knn_sq_distance(q, q) == 0.f)) return 0;  // a non-finite query (q - q is NaN) has no neighbours
  const GridSegment s = g.segments[segment];
  if (s.point_end <= s.point_begin) return 0;
  const float max_d2 = max_distance_m * max_distance_m;
  const float ox = s.origin.x, oy = s.origin.y, oz = s.origin.z, cell = s.cell_m, slack = s.slack_m;
  const int nx = s.nx, ny = s.ny, nz = s.nz;
  // Distances from q to the nearest and the farthest point of the grid box.
  const float gx = grid_cells_gap2(q.x, ox, cell, 0, nx - 1, slack),
              gy = grid_cells_gap2(q.y, oy, cell, 0, ny - 1, slack),
              gz = grid_cells_gap2(q.z, oz, cell, 0, nz - 1, slack);
  if (gx + gy + gz > max_d2) return 0;
  const float fx = max_f(fabsf(q.x - ox), fabsf(q.x - (ox + float(nx) * cell))) + slack;
  const float fy = max_f(fabsf(q.y - oy), fabsf(q.y - (oy + float(ny) * cell))) + slack;
  const float fz = max_f(fabsf(q.z - oz), fabsf(q.z - (oz + float(nz) * cell))) + slack;
  const float far2 = fx * fx + fy * fy + fz * fz;  // every point of the segment lies within this
  const std::int64_t c = s.cell_base + grid_local_cell(s, q);
  const std::int32_t rep = g.cell_rep[c];
  float ball2 = rep >= 0 ? knn_sq_distance(g.points[rep], q) : INFINITY;  // holds >= 1 point
  if (k > 1 && ball2 < INFINITY) {
    const float r = sqrtf(ball2) + s.ball_step_m * sqrtf(float(k));
    ball2 = r * r;
  }
  while (true) {
    const bool last = ball2 >= max_d2 || ball2 >= far2;
    const float limit = min_f(max_d2, ball2);  // ball2 is never NaN (a NaN max_d2 gives ball2)
    knn_clear(k, idx, d2);
    grid_ball_scan(g, s, q, k, limit, idx, d2);
    if (last || idx[k - 1] >= 0) break;  // the ball holds k points: they are the k nearest
    // Fewer than k in the ball: double its radius and rescan. A zero-radius ball (the query is its cell's
    // representative and knn_ball_cells = 0) would stay zero, so it restarts from one cell (or, should
    // cell^2 underflow, from the smallest normal float): the loop always reaches far2.
    ball2 = max_f(4.f * ball2, max_f(cell * cell, 1.17549435e-38f));
  }
  return knn_count(k, idx);
}

namespace grid_detail {
/// visit.done() if the visitor has it (true: it needs no more points), else false.
template <class V>
PERCH2_HD inline auto visitor_done(const V& v, int) -> decltype(bool(v.done())) {
  return v.done();
}
template <class V>
PERCH2_HD inline bool visitor_done(const V&, long) {
  return false;
}
}  // namespace grid_detail

/// Calls visit(index, d2) for every point of segment `segment` within max_distance_m of q (inclusive), in
/// grid order (not sorted), until visit.done() (if the visitor has that member) returns true. Visits only
/// the cells overlapping the query's ball.
template <class Visit>
PERCH2_HD inline void grid_radius_visit(const GridView& g, int segment, Vec3f q, float max_distance_m,
                                        Visit& visit) {
  const GridSegment s = g.segments[segment];
  if (s.point_end <= s.point_begin) return;
  const float max_d2 = max_distance_m * max_distance_m;
  const float reach = max_distance_m + s.slack_m;
  const int x0 = grid_coord(q.x - reach, s.origin.x, s.inv_cell, s.nx);
  const int x1 = grid_coord(q.x + reach, s.origin.x, s.inv_cell, s.nx);
  const int y0 = grid_coord(q.y - reach, s.origin.y, s.inv_cell, s.ny);
  const int y1 = grid_coord(q.y + reach, s.origin.y, s.inv_cell, s.ny);
  const int z0 = grid_coord(q.z - reach, s.origin.z, s.inv_cell, s.nz);
  const int z1 = grid_coord(q.z + reach, s.origin.z, s.inv_cell, s.nz);
  const float gx = grid_cells_gap2(q.x, s.origin.x, s.cell_m, x0, x1, s.slack_m);
  for (int z = z0; z <= z1; ++z) {
    const float dz2 = grid_cells_gap2(q.z, s.origin.z, s.cell_m, z, z, s.slack_m);
    for (int y = y0; y <= y1; ++y) {
      if (gx + dz2 + grid_cells_gap2(q.y, s.origin.y, s.cell_m, y, y, s.slack_m) > max_d2) continue;
      const std::int64_t row = s.cell_base + (std::int64_t(z) * s.ny + y) * s.nx;
      const std::int64_t b = g.cell_start[row + x0], e = g.cell_start[row + x1 + 1];
      for (std::int64_t i = b; i < e; ++i) {
        const float c = knn_sq_distance(g.points[i], q);
        if (c <= max_d2) {
          visit(g.point_index[i], c);
          if (grid_detail::visitor_done(visit, 0)) return;
        }
      }
    }
  }
}

/// Centre of cell (x, y, z) of segment s.
PERCH2_HD inline Vec3f grid_cell_centre(const GridSegment& s, int x, int y, int z) {
  return {s.origin.x + (float(x) + 0.5f) * s.cell_m, s.origin.y + (float(y) + 0.5f) * s.cell_m,
          s.origin.z + (float(z) + 0.5f) * s.cell_m};
}

/// Jump flooding, initial pass: the cell's own point nearest its centre (sorted position), or -1 if empty.
PERCH2_HD inline std::int32_t grid_rep_init(const GridView& g, const GridSegment& s, std::int64_t local) {
  const int x = int(local % s.nx), y = int((local / s.nx) % s.ny),
            z = int(local / (std::int64_t(s.nx) * s.ny));
  const Vec3f centre = grid_cell_centre(s, x, y, z);
  const std::int64_t b = g.cell_start[s.cell_base + local], e = g.cell_start[s.cell_base + local + 1];
  std::int32_t best = -1;
  float best_d2 = INFINITY;
  for (std::int64_t i = b; i < e; ++i) {
    const float d = knn_sq_distance(g.points[i], centre);
    if (d < best_d2) best_d2 = d, best = std::int32_t(i);
  }
  return best;
}

/// Jump flooding, one pass with offset `step` cells (Rong & Tan 2006): the best representative (nearest to
/// this cell's centre) among this cell's and its 26 neighbours' at +-step. rep_in/rep_out are global per
/// cell. Passes with steps 2^m, ..., 2, 1, 1 give every cell a point near its centre (exactness is not
/// needed: any point gives grid_knn a valid bound; a nearer one only makes it faster).
PERCH2_HD inline std::int32_t grid_jfa_step(const GridSegment& s, const Vec3f* points,
                                            const std::int32_t* rep_in, std::int64_t local, int step) {
  const int x = int(local % s.nx), y = int((local / s.nx) % s.ny),
            z = int(local / (std::int64_t(s.nx) * s.ny));
  const Vec3f centre = grid_cell_centre(s, x, y, z);
  std::int32_t best = rep_in[s.cell_base + local];
  float best_d2 = best >= 0 ? knn_sq_distance(points[best], centre) : INFINITY;
  for (int dz = -step; dz <= step; dz += step) {
    const int zz = z + dz;
    if (zz < 0 || zz >= s.nz) continue;
    for (int dy = -step; dy <= step; dy += step) {
      const int yy = y + dy;
      if (yy < 0 || yy >= s.ny) continue;
      for (int dx = -step; dx <= step; dx += step) {
        const int xx = x + dx;
        if (xx < 0 || xx >= s.nx) continue;
        const std::int32_t r = rep_in[s.cell_base + (std::int64_t(zz) * s.ny + yy) * s.nx + xx];
        if (r < 0 || r == best) continue;
        const float d = knn_sq_distance(points[r], centre);
        if (d < best_d2) best_d2 = d, best = r;
      }
    }
  }
  return best;
}

/// The jump-flooding steps for a segment: 2^m (largest power of two below the largest dim), ..., 1, then 1.
inline std::vector<int> grid_jfa_steps(const GridSegment& s) {
  const int n = std::max({s.nx, s.ny, s.nz});
  std::vector<int> steps;
  int p = 1;
  while (2 * p < n) p *= 2;
  for (; p >= 1 && n > 1; p /= 2) steps.push_back(p);
  if (n > 1) steps.push_back(1);
  return steps;
}

// ---- host-side planning and a host-memory grid ---------------------------------------------------------

/// Chooses one segment's geometry from its points [begin, end) (host arrays). cell_base and the point range
/// are left for the caller. Automatic cell size: starting from the volume per point, the cell is rescaled
/// (assuming points on surfaces: occupied cells ~ 1 / cell^2) until occupied cells hold ~points_per_cell.
inline GridSegment plan_grid_segment(const float* x, const float* y, const float* z, std::int64_t begin,
                                     std::int64_t end, const GridSettings& settings) {
  GridSegment s;
  const std::int64_t n = end - begin;
  if (n <= 0) return s;
  float lo[3] = {x[begin], y[begin], z[begin]}, hi[3] = {lo[0], lo[1], lo[2]};
  for (std::int64_t i = begin; i < end; ++i) {
    const float p[3] = {x[i], y[i], z[i]};
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], p[a]), hi[a] = std::max(hi[a], p[a]);
  }
  const double ext[3] = {double(hi[0]) - lo[0], double(hi[1]) - lo[1], double(hi[2]) - lo[2]};
  const double max_ext = std::max({ext[0], ext[1], ext[2]});
  const double max_abs = std::max(
      {std::abs(lo[0]), std::abs(lo[1]), std::abs(lo[2]), std::abs(hi[0]), std::abs(hi[1]), std::abs(hi[2])});
  s.origin = {lo[0], lo[1], lo[2]};
  const double max_cells = double(settings.max_cells_per_point) * double(n) + 64.0;
  auto cells_for = [&](double cell) {
    double c = 1;
    for (int a = 0; a < 3; ++a) c *= std::floor(ext[a] / cell) + 1.0;
    return c;
  };
  double cell;
  if (max_ext <= 0) {
    cell = 1.0;  // all points coincide: one cell
  } else if (settings.cell_size_m > 0) {
    cell = settings.cell_size_m;
  } else {
    const double floor_ext = max_ext * 1e-3;
    const double vol =
        std::max(ext[0], floor_ext) * std::max(ext[1], floor_ext) * std::max(ext[2], floor_ext);
    cell = std::cbrt(vol / double(n));
    std::vector<std::int64_t> keys(std::size_t(n), 0);
    for (int it = 0; it < 6; ++it) {
      while (cells_for(cell) > max_cells) cell *= 1.1;
      const double inv = 1.0 / cell;
      const std::int64_t nx = std::int64_t(std::floor(ext[0] * inv)) + 1,
                         ny = std::int64_t(std::floor(ext[1] * inv)) + 1;
      for (std::int64_t i = begin; i < end; ++i) {
        const std::int64_t cx = std::int64_t((double(x[i]) - lo[0]) * inv),
                           cy = std::int64_t((double(y[i]) - lo[1]) * inv),
                           cz = std::int64_t((double(z[i]) - lo[2]) * inv);
        keys[std::size_t(i - begin)] = (cz * ny + cy) * nx + cx;
      }
      std::sort(keys.begin(), keys.end());
      const double occupied = double(std::unique(keys.begin(), keys.end()) - keys.begin());
      const double ppc = double(n) / occupied;
      const double scale = std::clamp(std::sqrt(double(settings.points_per_cell) / ppc), 0.25, 4.0);
      if (std::abs(scale - 1.0) < 0.05) break;
      cell *= scale;
    }
  }
  while (cells_for(cell) > max_cells) cell *= 1.1;
  s.cell_m = float(cell);
  s.inv_cell = float(1.0 / cell);
  s.nx = int(std::floor(ext[0] / cell)) + 1;
  s.ny = int(std::floor(ext[1] / cell)) + 1;
  s.nz = int(std::floor(ext[2] / cell)) + 1;
  {  // occupancy at the final cell size (as the kernels assign cells)
    std::vector<std::int64_t> keys(static_cast<std::size_t>(n));
    for (std::int64_t i = begin; i < end; ++i)
      keys[std::size_t(i - begin)] = grid_local_cell(s, {x[i], y[i], z[i]});
    std::sort(keys.begin(), keys.end());
    s.points_per_cell = float(double(n) / double(std::unique(keys.begin(), keys.end()) - keys.begin()));
  }
  // k neighbours on a surface lie within ~ cell * sqrt(k / points_per_cell) of each other.
  s.ball_step_m = float(settings.knn_ball_cells * cell / std::sqrt(double(s.points_per_cell)));
  // Rounding of (p - origin) * inv_cell and of origin + c * cell is a few ulps of the coordinates.
  s.slack_m = float(1e-5 * (max_ext + max_abs + cell));
  return s;
}

/// Plans every segment of a batch and assigns cell bases and point ranges; returns the total cell count.
inline std::int64_t plan_grid(const CloudBatch& targets, const GridSettings& settings,
                              std::vector<GridSegment>& segments) {
  segments.resize(targets.num_clouds());
  std::int64_t base = 0;
  for (std::size_t c = 0; c < targets.num_clouds(); ++c) {
    GridSegment& s = segments[c];
    s = plan_grid_segment(targets.x.data(), targets.y.data(), targets.z.data(), targets.offsets[c],
                          targets.offsets[c + 1], settings);
    s.cell_base = base;
    s.point_begin = targets.offsets[c];
    s.point_end = targets.offsets[c + 1];
    base += std::int64_t(s.nx) * s.ny * s.nz;
  }
  return base;
}

/// A grid in host memory (for host code and tests; the Thrust backend builds the same layout on its device).
struct HostGrid {
  std::vector<GridSegment> segments;
  std::vector<std::int32_t> cell_start;
  std::vector<Vec3f> points;
  std::vector<std::int32_t> point_index;
  std::vector<std::int32_t> cell_rep;

  HostGrid() = default;
  HostGrid(const CloudBatch& targets, const GridSettings& settings = {}) {
    const std::int64_t total = plan_grid(targets, settings, segments);
    const std::size_t n = targets.size();
    std::vector<std::int64_t> key(n);
    for (std::size_t c = 0; c < segments.size(); ++c)
      for (std::int64_t i = targets.offsets[c]; i < targets.offsets[c + 1]; ++i)
        key[std::size_t(i)] =
            segments[c].cell_base + grid_local_cell(segments[c], targets.point(std::size_t(i)));
    point_index.resize(n);
    std::iota(point_index.begin(), point_index.end(), 0);
    std::stable_sort(point_index.begin(), point_index.end(), [&](std::int32_t a, std::int32_t b) {
      return key[std::size_t(a)] < key[std::size_t(b)];
    });
    points.resize(n);
    cell_start.assign(std::size_t(total) + 1, 0);
    for (std::size_t i = 0; i < n; ++i) {
      points[i] = targets.point(std::size_t(point_index[i]));
      ++cell_start[std::size_t(key[std::size_t(point_index[i])]) + 1];
    }
    for (std::size_t c = 0; c < std::size_t(total); ++c) cell_start[c + 1] += cell_start[c];
    if (!settings.cell_representatives) return;
    cell_rep.assign(std::size_t(total), -1);
    std::vector<std::int32_t> next(std::size_t(total), -1);
    const GridView g = view();
    for (const GridSegment& s : segments) {
      if (s.point_end <= s.point_begin) continue;
      const std::int64_t cells = std::int64_t(s.nx) * s.ny * s.nz;
      for (std::int64_t l = 0; l < cells; ++l)
        cell_rep[std::size_t(s.cell_base + l)] = grid_rep_init(g, s, l);
      for (int step : grid_jfa_steps(s)) {
        for (std::int64_t l = 0; l < cells; ++l)
          next[std::size_t(s.cell_base + l)] = grid_jfa_step(s, points.data(), cell_rep.data(), l, step);
        std::copy(next.begin() + s.cell_base, next.begin() + s.cell_base + cells,
                  cell_rep.begin() + s.cell_base);
      }
    }
  }

  GridView view() const {
    return {segments.data(), int(segments.size()), cell_start.data(),
            points.data(),   point_index.data(),   cell_rep.empty() ? nullptr : cell_rep.data()};
  }
};

}  // namespace perch2
