// Thrust registration (compiled by registration.cu with nvcc and by registration_omp.cpp with g++).
// Algorithm: perch2/registration/registration.hpp. Per call: upload the sources, estimate source normals
// (GICP), then max_iterations x { pass over blocks of points (correspondence by grid_knn, per-point normal
// equations summed per block), step over hypotheses (sum the hypothesis' blocks in a fixed order, LM accept/
// reject, damped LDL^T solve, pose update, convergence flag) }. Converged or stopped hypotheses skip both.
// The host only launches passes: the one device->host copy is the final per-hypothesis state.
// CPU systems (System::registration_whole_clouds) run the same functors per source cloud instead: one
// parallel region per call whose work items pull whole clouds (all their iterations) from a counter.
// The targets live in the kNN stage's KnnIndex<System>: correspondences and target normals are grid_knn ball
// searches started from its per-cell representatives (exact, within the correspondence distance cap); from
// the second pass on, a correspondence is first looked up in the previous one's neighbour list and source
// normals use per-cloud stripes (both exact: perch2/registration/neighbours.hpp).
#include <thrust/copy.h>
#include <thrust/device_vector.h>
#include <thrust/execution_policy.h>
#include <thrust/fill.h>
#include <thrust/for_each.h>
#include <thrust/iterator/counting_iterator.h>
#include <cuda/atomic>

#include <cmath>
#include <limits>
#include <map>
#include <mutex>

#include "perch2/core/segments.hpp"
#include "perch2/cuda/knn.hpp"
#include "perch2/cuda/registration.hpp"
#include "perch2/knn/grid.hpp"
#include "perch2/knn/scan.hpp"
#include "perch2/registration/device_math.hpp"
#include "perch2/registration/neighbours.hpp"
#include "thrust_util.hpp"

namespace perch2::thrust_backend {
namespace reg_detail {

// Points per block of the per-iteration pass (System::registration_points_per_item): one thread handles
// one block of one hypothesis and writes one partial sum. Affects only throughput and float summation
// order, not the algorithm.

/// Every this many iterations the host asks whether any hypothesis is still active (one count and a
/// 4-byte read back) and stops when none is; in between, passes over finished hypotheses return at once.
constexpr int kActiveCheckInterval = 4;

/// Partial sums of one block: upper triangle of H (21), g (6), costs, squared distances, inliers.
struct Accum {
  float H[21];
  float g[6];
  float cost_new, cost_old, sq;
  int inliers;
};

/// Per-hypothesis LM state (device memory).
struct HypState {
  Rigid3f T_acc, T_cand;
  float H[21];
  float g[6];
  float cost_acc, sq_acc, lambda;
  int inliers, iterations;
  int buf;  ///< which correspondence buffer (0/1) holds the accepted pose's correspondences
  std::uint8_t have_acc, active, converged;
};

/// Sets *any_active to 1 if hypothesis h is still iterating. A plain flag rather than thrust::count_if: the
/// OpenMP system's reduce binds its result through a null policy reference (UBSan reports it), and a flag is
/// all the early stop needs (4 bytes back to the host).
struct FlagActive {
  const HypState* state;
  std::int32_t* any_active;
  PERCH2_HD void operator()(int h) const {
    if (state[h].active == 0) return;
    cuda::atomic_ref<std::int32_t, cuda::thread_scope_device> flag(*any_active);
    flag.store(1, cuda::memory_order_relaxed);
  }
};

/// Per-call constants (POD copy of the settings).
struct Params {
  int gicp, table, min_inliers, max_iterations;
  float eps, max_dist, trans_eps, rot_eps;
  Vec3f up, e1, e2, origin;
  float lambda_initial, lambda_up, lambda_down, lambda_min, lambda_max, floor;
};

/// Surface normal of a neighbourhood given as indices into `points` (offsets taken relative to `ref`, which
/// keeps float sums well conditioned); zero with fewer than 3 points.
PERCH2_HD inline Vec3f neighbourhood_normal(const Vec3f* points, const std::int32_t* idx, int n, Vec3f ref) {
  if (n < 3) return {0.f, 0.f, 0.f};
  Vec3f s1{0.f, 0.f, 0.f};
  reg::Sym3 s2{0, 0, 0, 0, 0, 0};
  for (int j = 0; j < n; ++j) {
    const Vec3f d = points[idx[j]] - ref;
    s1 = s1 + d;
    s2 = reg::sym3_add(s2, {d.x * d.x, d.x * d.y, d.x * d.z, d.y * d.y, d.y * d.z, d.z * d.z});
  }
  const float inv = 1.f / float(n);
  const Vec3f m = inv * s1;
  const reg::Sym3 C{s2.xx * inv - m.x * m.x, s2.xy * inv - m.x * m.y, s2.xz * inv - m.x * m.z,
                    s2.yy * inv - m.y * m.y, s2.yz * inv - m.y * m.z, s2.zz * inv - m.z * m.z};
  return reg::smallest_eigenvector(C);
}

/// Target normals: k nearest neighbours of each target point within its own segment (grid search).
struct TargetNormals {
  GridView grid;
  const Vec3f* points;
  const std::int64_t* offsets;
  int num_segments, k;
  Vec3f* normals;
  PERCH2_HD void operator()(std::int64_t i) const {
    const int seg = find_segment(offsets, num_segments, i);
    std::int32_t idx[kMaxCovarianceNeighbors];
    float d2[kMaxCovarianceNeighbors];
    const int n = grid_knn(grid, seg, points[i], k, INFINITY, idx, d2);
    normals[i] = neighbourhood_normal(points, idx, n, points[i]);
  }
};

/// Heap sort of n (key, index) pairs by key, then index (device-callable, no extra memory).
template <class K>
PERCH2_HD inline void heap_sort_pairs(K* key, std::int32_t* idx, std::int64_t n) {
  auto less = [&](std::int64_t a, std::int64_t b) {
    return key[a] < key[b] || (key[a] == key[b] && idx[a] < idx[b]);
  };
  auto swap = [&](std::int64_t a, std::int64_t b) {
    const K tk = key[a];
    key[a] = key[b];
    key[b] = tk;
    const std::int32_t ti = idx[a];
    idx[a] = idx[b];
    idx[b] = ti;
  };
  heap_sort(n, less, swap);
}

static_assert(reg::kMaxSourceNeighbours >= kMaxCovarianceNeighbors);

/// Sort keys of source points for pixel neighbourhoods: the pixel index, and the identity order.
struct SortKeys {
  const std::int32_t* pixel;
  std::int32_t* key_pixel;
  std::int32_t* order;
  PERCH2_HD void operator()(std::int64_t i) const {
    key_pixel[i] = pixel[i];
    order[i] = std::int32_t(i);
  }
};

/// Sorts each source cloud's points, one cloud per thread (clouds are small): by pixel, or (kNN mode,
/// `stripes` set) into x-sorted stripes (perch2/registration/neighbours.hpp).
struct SortClouds {
  const Vec3f* points;
  const std::int64_t* offsets;
  int k;
  float* key_x;
  std::int32_t* key_pixel;  // the pixel, or the stripe
  std::int32_t* order;
  reg::SourceStripes* stripes;  // null: pixel mode
  PERCH2_HD void operator()(int c) const {
    const std::int64_t b = offsets[c], n = offsets[c + 1] - b;
    if (!stripes) return heap_sort_pairs(key_pixel + b, order + b, n);
    stripes[c] =
        reg::source_stripes_sort(points + b, n, k, std::int32_t(b), key_x + b, key_pixel + b, order + b);
  }
};

/// Scatters the sorted points and each point's sorted position.
struct ScatterSorted {
  const Vec3f* points;
  const std::int32_t* order;
  Vec3f* sorted;
  std::int32_t* position;
  PERCH2_HD void operator()(std::int64_t s) const {
    sorted[s] = points[order[s]];
    position[order[s]] = std::int32_t(s);
  }
};

/// Source normals from the k nearest neighbours within the same source cloud (reg::source_knn).
struct SourceKnnNormals {
  const Vec3f* sorted;  // points sorted by (cloud, stripe, x)
  const float* sorted_x;
  const std::int32_t* sorted_stripe;
  const std::int32_t* position;
  const std::int64_t* offsets;
  const reg::SourceStripes* stripes;
  int num_clouds, k;
  Vec3f* normals;
  PERCH2_HD void operator()(std::int64_t i) const { normal(i, find_segment(offsets, num_clouds, i)); }

  /// Point i of cloud c.
  PERCH2_HD void normal(std::int64_t i, int c) const {
    const std::int64_t b = offsets[c];
    std::int32_t idx[kMaxCovarianceNeighbors];
    const int n =
        reg::source_knn(sorted + b, sorted_x + b, sorted_stripe + b, stripes[c], position[i] - b, k, idx);
    normals[i] = neighbourhood_normal(sorted + b, idx, n, sorted[position[i]]);
  }
};

/// Source normals from the render's pixel neighbourhood: each cloud's pixels sorted, with `order`.
struct SourcePixelNormals {
  const Vec3f* points;
  const std::int64_t* offsets;
  const std::int32_t* pixel;
  const std::int32_t* sorted_keys;
  const std::int32_t* order;
  int num_clouds, width, radius;
  float max_d2;
  Vec3f* normals;

  PERCH2_HD std::int64_t lower_bound(std::int64_t b, std::int64_t e, std::int32_t key) const {
    while (b < e) {
      const std::int64_t m = (b + e) / 2;
      if (sorted_keys[m] < key)
        b = m + 1;
      else
        e = m;
    }
    return b;
  }

  PERCH2_HD void operator()(std::int64_t i) const { normal(i, find_segment(offsets, num_clouds, i)); }

  /// Point i of cloud c.
  PERCH2_HD void normal(std::int64_t i, int c) const {
    const Vec3f p = points[i];
    const int u = pixel[i] % width, v = pixel[i] / width;
    Vec3f s1{0.f, 0.f, 0.f};
    reg::Sym3 s2{0, 0, 0, 0, 0, 0};
    int n = 0;
    for (int vv = max_int(0, v - radius); vv <= v + radius; ++vv) {
      const std::int32_t lo = vv * width + max_int(0, u - radius);
      const std::int32_t hi = vv * width + min_int(width - 1, u + radius);
      for (std::int64_t s = lower_bound(offsets[c], offsets[c + 1], lo);
           s < offsets[c + 1] && sorted_keys[s] <= hi; ++s) {
        const Vec3f d = points[order[s]] - p;
        if (!(dot(d, d) <= max_d2)) continue;
        s1 = s1 + d;
        s2 = reg::sym3_add(s2, {d.x * d.x, d.x * d.y, d.x * d.z, d.y * d.y, d.y * d.z, d.z * d.z});
        ++n;
      }
    }
    if (n < 3) {
      normals[i] = {0.f, 0.f, 0.f};
      return;
    }
    const float inv = 1.f / float(n);
    const Vec3f m = inv * s1;
    const reg::Sym3 C{s2.xx * inv - m.x * m.x, s2.xy * inv - m.x * m.y, s2.xz * inv - m.x * m.z,
                      s2.yy * inv - m.y * m.y, s2.yz * inv - m.y * m.z, s2.zz * inv - m.z * m.z};
    normals[i] = reg::smallest_eigenvector(C);
  }
};

/// Initial state and source centroid of each hypothesis.
struct InitState {
  const Vec3f* points;
  const std::int64_t* offsets;
  float lambda_initial;
  Vec3f* centroid;
  HypState* state;
  PERCH2_HD void operator()(int h) const {
    Vec3f s{0.f, 0.f, 0.f};
    const std::int64_t b = offsets[h], e = offsets[h + 1];
    for (std::int64_t i = b; i < e; ++i) s = s + (points[i] - points[b]);
    centroid[h] = e > b ? points[b] + (1.f / float(e - b)) * s : Vec3f{0.f, 0.f, 0.f};
    HypState st{};
    st.T_acc.R = reg::mat3_identity();
    st.T_acc.t = {0.f, 0.f, 0.f};
    st.T_cand = st.T_acc;
    st.lambda = lambda_initial;
    st.active = 1;
    state[h] = st;
  }
};

/// The correspondence weight W = (C_t + R C_s R^T)^-1 = (2 I - s (u u^T + v v^T))^-1 of plane covariances
/// (s = 1 - epsilon; u the target normal, v the rotated source normal, each unit or zero for "no normal");
/// the identity for ICP. By the Woodbury identity W = (I + U G^-1 U^T) / 2 with U = [u v] and the 2x2
/// G = (2 / s) I - U^T U, i.e. W = (I + a_uu u u^T + a_vv v v^T + a_uv (u v^T + v u^T)) / 2: no 3x3
/// inverse, and d^T W d needs only u.d and v.d.
struct Weight {
  Vec3f u{0.f, 0.f, 0.f}, v{0.f, 0.f, 0.f};
  float a_uu = 0.f, a_vv = 0.f, a_uv = 0.f;
  float half = 1.f;  ///< 1/2 for GICP; 1 with a_* = 0 gives ICP's identity

  PERCH2_HD Weight(const Params& P, Vec3f nt, Vec3f m) {
    if (!P.gicp) return;
    const float two_over_s = 2.f / (1.f - P.eps);
    const float g_uu = two_over_s - dot(nt, nt), g_vv = two_over_s - dot(m, m), c = dot(nt, m);
    // det > 0 for unit or zero normals (g_uu > 1 >= |u|^2, c^2 <= |u|^2 |v|^2); NaN normals: identity.
    const float det = g_uu * g_vv - c * c;
    if (!(det > 0.f)) return;
    const float inv = 1.f / det;
    u = nt, v = m, a_uu = g_vv * inv, a_vv = g_uu * inv, a_uv = c * inv, half = 0.5f;
  }

  /// d^T W d.
  PERCH2_HD float quadratic(Vec3f d) const {
    const float ud = dot(u, d), vd = dot(v, d);
    return half * (dot(d, d) + a_uu * ud * ud + a_vv * vd * vd + 2.f * a_uv * ud * vd);
  }

  /// W itself.
  PERCH2_HD reg::Sym3 matrix() const {
    const Vec3f au = a_uu * u + a_uv * v, av = a_vv * v + a_uv * u;  // W = half (I + au u^T + av v^T)
    return {half * (1.f + au.x * u.x + av.x * v.x), half * (au.x * u.y + av.x * v.y),
            half * (au.x * u.z + av.x * v.z),       half * (1.f + au.y * u.y + av.y * v.y),
            half * (au.y * u.z + av.y * v.z),       half * (1.f + au.z * u.z + av.z * v.z)};
  }
};

/// Adds one correspondence's J^T W J, J^T W d and d^T W d to `a`, with J = [S, -I], S = [r]x, r = p - c.
/// Written out block by block (H_ww = S^T W S, H_wv = -S^T W, H_vv = W; g_w = S^T W d, g_v = -W d) since
/// S^T a = a x r: about 50 multiplications instead of the ~270 of dense 3x6 products (the zeros of J
/// cannot be folded without -ffast-math).
PERCH2_HD inline void accumulate_normal_equations(Accum& a, const reg::Sym3& W, Vec3f r, Vec3f d) {
  const Vec3f w0{W.xx, W.xy, W.xz}, w1{W.xy, W.yy, W.yz}, w2{W.xz, W.yz, W.zz};  // columns of W
  // Columns of W S.
  const Vec3f a0 = r.z * w1 - r.y * w2, a1 = r.x * w2 - r.z * w0, a2 = r.y * w0 - r.x * w1;
  const Vec3f h0 = cross(a0, r), h1 = cross(a1, r), h2 = cross(a2, r);  // columns of S^T W S
  const Vec3f Wd = reg::sym3_mul(W, d);
  const Vec3f gw = cross(Wd, r);
  const float H[21] = {h0.x, h1.x,  h2.x,  -a0.x, -a0.y, -a0.z, h1.y, h2.y, -a1.x, -a1.y, -a1.z,
                       h2.z, -a2.x, -a2.y, -a2.z, W.xx,  W.xy,  W.xz, W.yy, W.yz,  W.zz};
  for (int k = 0; k < 21; ++k) a.H[k] += H[k];
  a.g[0] += gw.x, a.g[1] += gw.y, a.g[2] += gw.z;
  a.g[3] -= Wd.x, a.g[4] -= Wd.y, a.g[5] -= Wd.z;
  a.cost_new += dot(d, Wd);
}

/// The target neighbour lists of one Registration (reg::target_list_nearest), built on first use: a state
/// flag per target point claimed atomically; a thread finding a list being built searches the grid.
struct TargetLists {
  GridView grid;
  const Vec3f* points;
  std::int32_t* state;      // per target point: 0 none, 1 being built, 2 built
  float* reach;             // per target point: the list holds every point nearer than this (metres)
  reg::ListEntry* entries;  // reg::kTargetListSize per target point

  /// True if the list of target point j (segment seg) is built, building it now if nobody has started to.
  PERCH2_HD bool ready(int seg, std::int32_t j) const {
    cuda::atomic_ref<std::int32_t, cuda::thread_scope_device> flag(state[j]);
    const std::int32_t s = flag.load(cuda::memory_order_acquire);
    if (s != 0) return s == 2;
    std::int32_t expected = 0;
    if (!flag.compare_exchange_strong(expected, 1, cuda::memory_order_acq_rel)) return expected == 2;
    reach[j] = reg::target_list_build(grid, seg, points, j, entries + std::int64_t(j) * reg::kTargetListSize);
    flag.store(2, cuda::memory_order_release);
    return true;
  }

  /// grid_knn(grid, seg, q, 1, radius, &j, &d2) given target point j0 at distance r0 >= radius / (1 + 1e-5).
  PERCH2_HD int nearest(int seg, std::int32_t j0, float r0, Vec3f q, float radius, std::int32_t& j,
                        float& d2) const {
    if (r0 < INFINITY && ready(seg, j0)) {
      const int found = reg::target_list_nearest(entries + std::int64_t(j0) * reg::kTargetListSize, reach[j0],
                                                 points, r0, q, radius, j, d2);
      if (found >= 0) return found;
    }
    return grid_knn(grid, seg, q, 1, radius, &j, &d2);
  }
};

/// The per-iteration pass over one block of one hypothesis' points, at its candidate pose.
struct LinearizeBlock {
  Params P;
  GridView grid;
  const Vec3f* target_points;
  const Vec3f* target_normals;  // null for ICP
  const Vec3f* points;
  const Vec3f* normals;  // null for ICP
  const std::int32_t* segment;
  const Vec3f* centroid;
  const int* block_hyp;
  const std::int64_t* block_begin;
  const HypState* state;
  std::int32_t* corr;  // 2 x num_points
  std::int64_t num_points;
  Accum* blocks;
  TargetLists lists;

  PERCH2_HD void operator()(std::int64_t b) const {
    const int h = block_hyp[b];
    const HypState& st = state[h];
    if (!st.active) return;
    Accum a;
    for (int k = 0; k < 21; ++k) a.H[k] = 0.f;
    for (int k = 0; k < 6; ++k) a.g[k] = 0.f;
    a.cost_new = a.cost_old = a.sq = 0.f;
    a.inliers = 0;
    const Rigid3f T = st.T_cand;
    const Vec3f c = P.table ? P.origin : T * centroid[h];
    const int seg = segment[h];
    const std::int32_t* corr_old = corr + std::int64_t(st.buf) * num_points;
    std::int32_t* corr_new = corr + std::int64_t(1 - st.buf) * num_points;
    const std::int64_t end = block_begin[b + 1];
    for (std::int64_t i = block_begin[b]; i < end; ++i) {
      const Vec3f p = T * points[i];
      const Vec3f m = P.gicp ? T.R * normals[i] : Vec3f{0.f, 0.f, 0.f};
      // The accepted pose's correspondence, moved by the step: its cost term, and its distance bounds the
      // nearest-neighbour search (the true nearest is at most that far; the 1e-5 margin covers rounding).
      float radius = P.max_dist, r0 = INFINITY;
      const std::int32_t jo = st.have_acc ? corr_old[i] : -1;
      if (jo >= 0) {
        const Vec3f d = target_points[jo] - p;
        // Weights frozen at the accepted linearisation: the cost the step minimised.
        const Vec3f m_acc = P.gicp ? st.T_acc.R * normals[i] : Vec3f{0.f, 0.f, 0.f};
        a.cost_old += Weight(P, P.gicp ? target_normals[jo] : Vec3f{0, 0, 0}, m_acc).quadratic(d);
        r0 = sqrtf(knn_sq_distance(target_points[jo], p));
        radius = min_f(radius, r0 * (1.f + 1e-5f));
      }
      std::int32_t j;
      float d2;
      const int found =
          jo >= 0 ? lists.nearest(seg, jo, r0, p, radius, j, d2) : grid_knn(grid, seg, p, 1, radius, &j, &d2);
      corr_new[i] = found ? j : -1;
      if (found) {
        const Vec3f d = target_points[j] - p;
        const reg::Sym3 W = Weight(P, P.gicp ? target_normals[j] : Vec3f{0, 0, 0}, m).matrix();
        accumulate_normal_equations(a, W, p - c, d);
        a.sq += dot(d, d);
        ++a.inliers;
      }
    }
    blocks[b] = a;
  }
};

/// The per-iteration step of one hypothesis: sum its blocks, accept/reject, solve, update, converge.
struct StepHypothesis {
  Params P;
  const Vec3f* centroid;
  const std::int64_t* hyp_blocks;  // blocks [hyp_blocks[h], hyp_blocks[h + 1]) belong to h
  const Accum* blocks;
  HypState* state;

  PERCH2_HD void operator()(int h) const {
    HypState st = state[h];
    if (!st.active) return;
    Accum a;
    for (int k = 0; k < 21; ++k) a.H[k] = 0.f;
    for (int k = 0; k < 6; ++k) a.g[k] = 0.f;
    a.cost_new = a.cost_old = a.sq = 0.f;
    a.inliers = 0;
    for (std::int64_t b = hyp_blocks[h]; b < hyp_blocks[h + 1]; ++b) {
      const Accum& x = blocks[b];
      for (int k = 0; k < 21; ++k) a.H[k] += x.H[k];
      for (int k = 0; k < 6; ++k) a.g[k] += x.g[k];
      a.cost_new += x.cost_new;
      a.cost_old += x.cost_old;
      a.sq += x.sq;
      a.inliers += x.inliers;
    }
    ++st.iterations;
    const bool accept = !st.have_acc || a.cost_old <= st.cost_acc;
    if (accept) {
      if (st.have_acc) st.lambda = max_f(st.lambda * P.lambda_down, P.lambda_min);
      st.T_acc = st.T_cand;
      st.buf = 1 - st.buf;
      for (int k = 0; k < 21; ++k) st.H[k] = a.H[k];
      for (int k = 0; k < 6; ++k) st.g[k] = a.g[k];
      st.cost_acc = a.cost_new;
      st.sq_acc = a.sq;
      st.inliers = a.inliers;
      st.have_acc = 1;
    } else {
      st.lambda *= P.lambda_up;
      if (st.lambda > P.lambda_max) return finish(h, st);
    }
    if (st.inliers < P.min_inliers) return finish(h, st);

    Vec3f w, v;
    if (P.table) {
      // Reduced system B^T H B, B = [[up, 0, 0], [0, e1, e2]] (6x3).
      float B[6][3] = {{P.up.x, 0, 0},      {P.up.y, 0, 0},      {P.up.z, 0, 0},
                       {0, P.e1.x, P.e2.x}, {0, P.e1.y, P.e2.y}, {0, P.e1.z, P.e2.z}};
      float A[9], rhs[3], z[3];
      for (int i = 0; i < 3; ++i) {
        float gi = 0.f;
        for (int r = 0; r < 6; ++r) gi += B[r][i] * st.g[r];
        rhs[i] = -gi;
        for (int j = 0; j < 3; ++j) {
          float s = 0.f;
          for (int r = 0; r < 6; ++r)
            for (int c = 0; c < 6; ++c)
              s += B[r][i] * st.H[r <= c ? reg::sym6_index(r, c) : reg::sym6_index(c, r)] * B[c][j];
          A[3 * i + j] = s;
        }
      }
      for (int i = 0; i < 3; ++i) A[4 * i] += st.lambda * (A[4 * i] + P.floor);
      if (!reg::ldlt_solve<3>(A, rhs, z)) return finish(h, st);
      w = z[0] * P.up;
      v = z[1] * P.e1 + z[2] * P.e2;
    } else {
      float A[36], rhs[6], x[6];
      for (int r = 0; r < 6; ++r) {
        rhs[r] = -st.g[r];
        for (int c = 0; c < 6; ++c)
          A[6 * r + c] = st.H[r <= c ? reg::sym6_index(r, c) : reg::sym6_index(c, r)];
      }
      for (int r = 0; r < 6; ++r) A[7 * r] += st.lambda * (A[7 * r] + P.floor);
      if (!reg::ldlt_solve<6>(A, rhs, x)) return finish(h, st);
      w = {x[0], x[1], x[2]};
      v = {x[3], x[4], x[5]};
    }
    if (!(reg::is_finite(w) && reg::is_finite(v))) return finish(h, st);
    if (accept && sqrtf(dot(w, w)) < P.rot_eps && sqrtf(dot(v, v)) < P.trans_eps) {
      st.converged = 1;
      return finish(h, st);
    }
    const Vec3f c = P.table ? P.origin : st.T_acc * centroid[h];
    st.T_cand = reg::apply_increment(st.T_acc, w, v, c);
    if (st.iterations >= P.max_iterations) return finish(h, st);
    state[h] = st;
  }

  PERCH2_HD void finish(int h, HypState& st) const {
    st.active = 0;
    state[h] = st;
  }
};

/// Registers whole source clouds per work item (CPU systems, System::registration_whole_clouds): each of
/// the `workers` items pulls clouds from the shared counter `next` and runs every stage of one cloud in
/// order, the same functors the passes launch: clear its correspondences, sort its points and estimate its
/// normals (GICP), initialise, then per iteration linearise its blocks and step, until it stops. The same
/// functions of the same values in the same order: results equal the passes' bit for bit, in one parallel
/// region per call, and no thread waits at a barrier for a descheduled one.
struct RegisterClouds {
  int num_clouds;
  const std::int64_t* offsets;     // per cloud: its points
  const std::int64_t* hyp_blocks;  // per cloud: its blocks of the linearisation pass
  std::int32_t* corr;              // 2 x num_points
  std::int64_t num_points;
  int normals;  // 0: none (ICP), 1: k nearest neighbours (x-sorted sweep), 2: pixel neighbourhoods
  SortKeys sort_keys;
  SortClouds sort_clouds;
  ScatterSorted scatter_sorted;
  SourceKnnNormals knn_normals;
  SourcePixelNormals pixel_normals;
  InitState init;
  LinearizeBlock pass;
  StepHypothesis step;
  int* next;

  PERCH2_HD void cloud(int h) const {
    const std::int64_t b = offsets[h], e = offsets[h + 1];
    for (std::int64_t i = b; i < e; ++i) corr[i] = corr[num_points + i] = -1;
    if (normals != 0) {
      if (normals == 2)
        for (std::int64_t i = b; i < e; ++i) sort_keys(i);
      sort_clouds(h);
      if (normals == 1) {
        for (std::int64_t i = b; i < e; ++i) scatter_sorted(i);
        for (std::int64_t i = b; i < e; ++i) knn_normals.normal(i, h);
      } else {
        for (std::int64_t i = b; i < e; ++i) pixel_normals.normal(i, h);
      }
    }
    init(h);
    // StepHypothesis deactivates the cloud at max_iterations at the latest.
    while (step.state[h].active) {
      for (std::int64_t k = hyp_blocks[h]; k < hyp_blocks[h + 1]; ++k) pass(k);
      step(h);
    }
  }

  PERCH2_HD void operator()(std::int64_t) const {
    cuda::atomic_ref<int, cuda::thread_scope_device> counter(*next);
    for (int h = counter.fetch_add(1, cuda::memory_order_relaxed); h < num_clouds;
         h = counter.fetch_add(1, cuda::memory_order_relaxed))
      cloud(h);
  }
};

}  // namespace reg_detail

template <class System>
struct Registration<System>::Impl {
  /// The kNN stage's index over the targets: points in batch order, segment offsets and the uniform grid
  /// with its cell representatives (grid_knn's ball search), all on the device. Built once.
  KnnIndex<System> index;
  mutable std::mutex mutex;
  mutable std::map<int, thrust::device_vector<Vec3f>> target_normals;  // by k_neighbors
  /// Neighbour lists of the target points (reg_detail::TargetLists), allocated by the first call and filled
  /// on demand by the calls.
  mutable thrust::device_vector<std::int32_t> list_state;
  mutable thrust::device_vector<float> list_reach;
  mutable thrust::device_vector<reg::ListEntry> list_entries;

  /// Per-call arrays, reused across calls (they grow only; run() holds run_mutex).
  struct Workspace {
    thrust::device_vector<Vec3f> points, centroid, normals, sorted;
    thrust::device_vector<std::int64_t> offsets, block_begin, hyp_blocks;
    thrust::device_vector<std::int32_t> segment, block_hyp, corr, key_pixel, order, pixel, position;
    thrust::device_vector<std::int32_t> any_active{1};
    thrust::device_vector<float> key_x;
    thrust::device_vector<reg_detail::HypState> state;
    thrust::device_vector<reg::SourceStripes> stripes;
    thrust::device_vector<reg_detail::Accum> blocks;
    TempAllocator temp;
  };
  mutable std::mutex run_mutex;
  mutable Workspace ws;
  mutable LaunchShape shape;

  explicit Impl(const CloudBatch& targets) : index(targets) {}

  GridView grid() const { return index.view().grid; }
  const Vec3f* target_points() const { return index.view().points; }
  std::size_t num_segments() const { return index.num_segments(); }

  const thrust::device_vector<Vec3f>& normals(int k) const {
    std::lock_guard<std::mutex> lock(mutex);
    auto it = target_normals.find(k);
    if (it != target_normals.end()) return it->second;
    const KnnView v = index.view();
    const std::int64_t num_points = std::int64_t(index.num_points());
    thrust::device_vector<Vec3f> n(static_cast<std::size_t>(num_points));
    thrust::for_each(
        thrust::device, thrust::counting_iterator<std::int64_t>(0),
        thrust::counting_iterator<std::int64_t>(num_points),
        reg_detail::TargetNormals{v.grid, v.points, v.segment_offsets, v.num_segments, k, ptr(n)});
    return target_normals.emplace(k, std::move(n)).first->second;
  }

  RegistrationResult run(const CloudBatch& src, const std::vector<std::int32_t>& seg, reg_detail::Params P,
                         const GicpSettings* gs) const {
    std::lock_guard<std::mutex> lock(run_mutex);
    shape = LaunchShape{};
    Workspace& w = ws;
    w.temp.allocations = 0;
    std::int64_t& allocs = shape.device_allocations;
    const std::int64_t per_item = System::registration_points_per_item;
    const int num = int(src.num_clouds());
    const std::int64_t n = std::int64_t(src.size());
    const std::size_t un = src.size(), unum = src.num_clouds();
    // Upload the sources and the block layout (host work proportional to the input, once per call).
    std::vector<Vec3f> host_points(un);
    for (std::int64_t i = 0; i < n; ++i) host_points[std::size_t(i)] = src.point(std::size_t(i));
    std::vector<int> host_block_hyp;
    std::vector<std::int64_t> host_block_begin, host_hyp_blocks(unum + 1, 0);
    for (int h = 0; h < num; ++h) {
      for (std::int64_t b = src.offsets[h]; b < src.offsets[h + 1]; b += per_item) {
        host_block_hyp.push_back(h);
        host_block_begin.push_back(b);
      }
      host_hyp_blocks[std::size_t(h) + 1] = std::int64_t(host_block_hyp.size());
    }
    host_block_begin.push_back(n);
    const std::int64_t num_blocks = std::int64_t(host_block_hyp.size());
    Vec3f* points = upload(w.points, host_points, allocs);
    const std::int64_t* offsets = upload(w.offsets, src.offsets, allocs);
    const std::int32_t* segment = upload(w.segment, seg, allocs);
    const int* block_hyp = upload(w.block_hyp, host_block_hyp, allocs);
    const std::int64_t* block_begin = upload(w.block_begin, host_block_begin, allocs);
    const std::int64_t* hyp_blocks = upload(w.hyp_blocks, host_hyp_blocks, allocs);
    Vec3f* centroid = reuse(w.centroid, unum, allocs);
    reg_detail::HypState* state = reuse(w.state, unum, allocs);
    std::int32_t* corr = reuse(w.corr, 2 * un, allocs);
    reg_detail::Accum* blocks = reuse(w.blocks, std::size_t(num_blocks), allocs);
    const auto pts = thrust::counting_iterator<std::int64_t>(0);
    const auto hyps = thrust::counting_iterator<int>(0);
    // Source normals (GICP): each cloud's points sorted (into x-sorted stripes for the kNN search, by pixel
    // for pixel neighbourhoods) with one device-callable heap sort per cloud.
    const int normal_mode = !gs                                                                 ? 0
                            : gs->source_covariance == SourceCovariance::FromPixelNeighbourhood ? 2
                                                                                                : 1;
    const Vec3f* tn = gs ? ptr(normals_for(gs->k_neighbors)) : nullptr;
    Vec3f* normals = gs ? reuse(w.normals, un, allocs) : nullptr;
    float* kx = normal_mode == 1 ? reuse(w.key_x, un, allocs) : nullptr;
    std::int32_t* kp = gs ? reuse(w.key_pixel, un, allocs) : nullptr;  // pixel or stripe keys
    std::int32_t* order = gs ? reuse(w.order, un, allocs) : nullptr;
    const std::int32_t* pixel = normal_mode == 2 ? upload(w.pixel, src.pixel, allocs) : nullptr;
    std::int32_t* position = normal_mode == 1 ? reuse(w.position, un, allocs) : nullptr;
    Vec3f* sorted = normal_mode == 1 ? reuse(w.sorted, un, allocs) : nullptr;
    reg::SourceStripes* stripes = normal_mode == 1 ? reuse(w.stripes, unum, allocs) : nullptr;
    const float md = gs ? gs->pixel_neighbour_max_distance_m : 0.f;
    const int k = gs ? gs->k_neighbors : 0;
    const reg_detail::SortKeys sort_keys{pixel, kp, order};
    const reg_detail::SortClouds sort_clouds{points, offsets, k, kx, kp, order, stripes};
    const reg_detail::ScatterSorted scatter_sorted{points, order, sorted, position};
    const reg_detail::SourceKnnNormals knn_normals{sorted,  kx,  kp, position, offsets,
                                                   stripes, num, k,  normals};
    const reg_detail::SourcePixelNormals pixel_normals{
        points,  offsets, pixel, kp, order, num, gs ? gs->image_width_px : 0, gs ? gs->pixel_radius_px : 0,
        md * md, normals};
    const reg_detail::InitState init{points, offsets, P.lambda_initial, centroid, state};
    const std::size_t nt = index.num_points();
    if (list_state.size() != nt) {  // the first call with targets allocates the lists
      thrust::device_vector<std::int32_t>(nt, 0).swap(list_state);
      list_reach.resize(nt);
      list_entries.resize(nt * reg::kTargetListSize);
      allocs += 3;
    }
    const reg_detail::TargetLists lists{grid(), target_points(), ptr(list_state), ptr(list_reach),
                                        ptr(list_entries)};
    const reg_detail::LinearizeBlock pass{
        P,         grid(),      target_points(), tn,   points, normals, segment, centroid,
        block_hyp, block_begin, state,           corr, n,      blocks,  lists};
    const reg_detail::StepHypothesis step{P, centroid, hyp_blocks, blocks, state};

    if constexpr (System::registration_whole_clouds) {
      const int workers = cpu_system_workers();
      write_at(w.any_active, 0, std::int32_t(0));  // the clouds' shared counter
      thrust::for_each(thrust::device, pts, pts + workers,
                       reg_detail::RegisterClouds{num, offsets, hyp_blocks, corr, n, normal_mode, sort_keys,
                                                  sort_clouds, scatter_sorted, knn_normals, pixel_normals,
                                                  init, pass, step, ptr(w.any_active)});
      shape.launch("register_clouds", 1, workers);
    } else {
      thrust::fill_n(thrust::device, corr, std::int64_t(2 * un), std::int32_t(-1));
      if (gs) {
        if (normal_mode == 2) {
          thrust::for_each(thrust::device, pts, pts + n, sort_keys);
          shape.launch("source_sort_keys", 1, n);
        }
        thrust::for_each(thrust::device, hyps, hyps + num, sort_clouds);
        shape.launch("source_sort_clouds", 1, num);
        if (normal_mode == 1) {
          thrust::for_each(thrust::device, pts, pts + n, scatter_sorted);
          thrust::for_each(thrust::device, pts, pts + n, knn_normals);
        } else {
          thrust::for_each(thrust::device, pts, pts + n, pixel_normals);
        }
        shape.launch("source_normals", 1, n);
      }
      thrust::for_each(thrust::device, hyps, hyps + num, init);
      shape.launch("init", 1, num);
      for (int it = 0; it < P.max_iterations; ++it) {
        if (it > 0 && it % reg_detail::kActiveCheckInterval == 0) {
          shape.launch("active_check", 1, num);
          write_at(w.any_active, 0, std::int32_t(0));
          thrust::for_each(thrust::device, hyps, hyps + num,
                           reg_detail::FlagActive{state, ptr(w.any_active)});
          if (read_at(w.any_active, 0) == 0) break;
        }
        thrust::for_each(nosync(), pts, pts + num_blocks, pass);  // no host wait per iteration
        thrust::for_each(nosync(), hyps, hyps + num, step);
        shape.launch("linearize", int(per_item), num_blocks);
        shape.launch("step", 1, num);
      }
    }

    std::vector<reg_detail::HypState> host_state;
    append_to_host(host_state, state, unum);
    allocs += w.temp.allocations;
    shape.workspace_bytes = w.temp.bytes();
    RegistrationResult res;
    for (const auto& st : host_state) {
      res.T_corr.push_back(to_pose(st.T_acc));
      res.iterations.push_back(st.iterations);
      res.inliers.push_back(st.inliers);
      res.final_error.push_back(st.inliers > 0 ? std::sqrt(st.sq_acc / float(st.inliers))
                                               : std::numeric_limits<float>::infinity());
      res.converged.push_back(st.converged);
    }
    return res;
  }

  const thrust::device_vector<Vec3f>& normals_for(int k) const { return normals(k); }
};

namespace reg_detail {
template <class S>
Params make_params(const S& s, bool gicp, float eps) {
  Params P{};
  P.gicp = gicp ? 1 : 0;
  P.table = s.dof == Dof::TableXYYaw ? 1 : 0;
  P.min_inliers = s.min_inliers;
  P.max_iterations = s.max_iterations;
  P.eps = eps;
  P.max_dist = s.max_correspondence_distance_m;
  P.trans_eps = s.translation_epsilon_m;
  P.rot_eps = s.rotation_epsilon_rad;
  if (P.table) {
    const Eigen::Vector3f u = s.up_cam.normalized();
    Eigen::Vector3f e1, e2;
    plane_basis(u, e1, e2);
    P.up = to_vec3(u), P.e1 = to_vec3(e1), P.e2 = to_vec3(e2), P.origin = to_vec3(s.origin_cam);
  } else {
    P.up = P.e1 = P.e2 = P.origin = {0.f, 0.f, 0.f};
  }
  P.lambda_initial = s.lm.lambda_initial;
  P.lambda_up = s.lm.lambda_up;
  P.lambda_down = s.lm.lambda_down;
  P.lambda_min = s.lm.lambda_min;
  P.lambda_max = s.lm.lambda_max;
  P.floor = s.lm.diagonal_floor;
  return P;
}
}  // namespace reg_detail

template <class System>
Registration<System>::Registration(const CloudBatch& targets) {
  validate_registration_targets(targets);
  // The kNN stage's index: uploads the targets once and builds the grid and its cell representatives on the
  // device (counting sort and jump flooding, perch2/knn/grid.hpp).
  impl_ = std::make_unique<Impl>(targets);
}

template <class System>
Registration<System>::~Registration() = default;
template <class System>
Registration<System>::Registration(Registration&&) noexcept = default;
template <class System>
Registration<System>& Registration<System>::operator=(Registration&&) noexcept = default;

template <class System>
std::size_t Registration<System>::num_segments() const {
  return impl_->num_segments();
}

template <class System>
LaunchShape Registration<System>::last_launch_shape() const {
  std::lock_guard<std::mutex> lock(impl_->run_mutex);
  return impl_->shape;
}

template <class System>
RegistrationResult Registration<System>::icp(const CloudBatch& sources,
                                             const std::vector<std::int32_t>& source_segment,
                                             const IcpSettings& settings) const {
  validate(settings);
  validate_registration_sources(sources, source_segment, impl_->num_segments());
  return impl_->run(sources, source_segment, reg_detail::make_params(settings, false, 1.f), nullptr);
}

template <class System>
RegistrationResult Registration<System>::gicp(const CloudBatch& sources,
                                              const std::vector<std::int32_t>& source_segment,
                                              const GicpSettings& settings) const {
  validate(settings);
  validate_registration_sources(sources, source_segment, impl_->num_segments(),
                                settings.source_covariance == SourceCovariance::FromPixelNeighbourhood);
  auto run_gicp = [&](const CloudBatch& c, const GicpSettings& s) {
    return impl_->run(c, source_segment, reg_detail::make_params(s, true, s.covariance_epsilon), &s);
  };
  if (settings.icp_warmup_iterations > 0)
    return gicp_after_icp_warmup(
        sources, settings,
        [&](const CloudBatch& c, const IcpSettings& s) {
          return impl_->run(c, source_segment, reg_detail::make_params(s, false, 1.f), nullptr);
        },
        run_gicp);
  return run_gicp(sources, settings);
}

}  // namespace perch2::thrust_backend
