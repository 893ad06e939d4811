// Batched nearest-neighbour search: every method on every CPU-runnable backend equals exact search.
//
// The reference here is a brute-force scan in the test, ordered by (squared distance, index). The Thrust
// backend breaks ties by the smaller index, so it must equal the reference bit for bit (indices and
// distances). FLANN (the cpu backend) may order exact ties differently: its distances must equal the
// reference exactly and its indices wherever the distance at that rank is unique. Distances are compared
// exactly because every path computes dx*dx + dy*dy + dz*dz in the same order in float, without FMA
// contraction (no tolerance needed; Backend::bitwise_reproducible, see perch2/cuda/system.hpp).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <future>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <type_traits>
#include <vector>

#include "perch2/cuda/launch_plan.hpp"
#include "perch2/io/mesh_io.hpp"
#include "perch2/knn/grid.hpp"
#include "perch2/knn/knn.hpp"
#include "test_support.hpp"

using perch2::CloudBatch;
using perch2::KnnMethod;
using perch2::KnnResult;
using perch2::KnnSettings;
using perch2::RadiusResult;
using perch2::Vec3f;

namespace {

static_assert(perch2::cpu::Backend::bitwise_reproducible &&
              perch2::thrust_omp::Backend::bitwise_reproducible);

constexpr float kInf = std::numeric_limits<float>::infinity();
const KnnMethod kMethods[] = {KnnMethod::Auto, KnnMethod::BruteForce, KnnMethod::PerQuery, KnnMethod::Grid};

CloudBatch make_batch(const std::vector<std::vector<Vec3f>>& clouds) {
  CloudBatch b;
  for (std::size_t c = 0; c < clouds.size(); ++c) {
    for (const Vec3f& p : clouds[c]) {
      b.x.push_back(p.x), b.y.push_back(p.y), b.z.push_back(p.z);
      b.rgb.push_back(0), b.pixel.push_back(-1), b.cloud.push_back(std::int32_t(c));
    }
    b.offsets.push_back(std::int64_t(b.x.size()));
  }
  return b;
}

std::vector<Vec3f> random_box(std::mt19937& rng, int n, Vec3f lo, Vec3f hi) {
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::vector<Vec3f> p(static_cast<std::size_t>(n));
  for (auto& v : p)
    v = {lo.x + (hi.x - lo.x) * u(rng), lo.y + (hi.y - lo.y) * u(rng), lo.z + (hi.z - lo.z) * u(rng)};
  return p;
}

/// Points on a sphere surface (centre c, radius r).
std::vector<Vec3f> sphere_surface(std::mt19937& rng, int n, Vec3f c, float r) {
  std::normal_distribution<float> g(0.f, 1.f);
  std::vector<Vec3f> p(static_cast<std::size_t>(n));
  for (auto& v : p) {
    Vec3f d{g(rng), g(rng), g(rng)};
    const float s = r / std::sqrt(perch2::squared_norm(d));
    v = c + s * d;
  }
  return p;
}

/// Points on the surface of an axis-aligned box [lo, hi].
std::vector<Vec3f> box_surface(std::mt19937& rng, int n, Vec3f lo, Vec3f hi) {
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::uniform_int_distribution<int> face(0, 5);
  std::vector<Vec3f> p(static_cast<std::size_t>(n));
  for (auto& v : p) {
    v = {lo.x + (hi.x - lo.x) * u(rng), lo.y + (hi.y - lo.y) * u(rng), lo.z + (hi.z - lo.z) * u(rng)};
    const int f = face(rng);
    float* axis[3] = {&v.x, &v.y, &v.z};
    const float lo_a[3] = {lo.x, lo.y, lo.z}, hi_a[3] = {hi.x, hi.y, hi.z};
    *axis[f / 2] = (f % 2) ? hi_a[f / 2] : lo_a[f / 2];
  }
  return p;
}

/// A query cloud: points of `src` (a random subset) moved by a small rigid motion and noise, like a rendered
/// hypothesis near the observed surface.
std::vector<Vec3f> perturbed(std::mt19937& rng, const std::vector<Vec3f>& src, int n, float shift_m,
                             float noise_m) {
  std::uniform_int_distribution<std::size_t> pick(0, src.size() - 1);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  std::normal_distribution<float> g(0.f, noise_m);
  const float yaw = 0.2f * u(rng), cy = std::cos(yaw), sy = std::sin(yaw);
  const Vec3f t{shift_m * u(rng), shift_m * u(rng), shift_m * u(rng)};
  std::vector<Vec3f> out(static_cast<std::size_t>(n));
  for (auto& q : out) {
    const Vec3f p = src[pick(rng)];
    q = {cy * p.x - sy * p.y + t.x + g(rng), sy * p.x + cy * p.y + t.y + g(rng), p.z + t.z + g(rng)};
  }
  return out;
}

struct Reference {
  int k = 0;
  std::vector<std::int32_t> index;  // (k + 1) per query: one extra rank to detect ties at the boundary
  std::vector<float> d2;
};

/// Brute force, ordered by (d2, index), k + 1 ranks, within max_distance_m.
Reference brute_force(const CloudBatch& targets, const CloudBatch& queries,
                      const std::vector<std::int32_t>& seg, int k, float max_distance_m) {
  Reference r;
  r.k = k;
  const std::size_t kk = std::size_t(k) + 1;
  r.index.assign(queries.size() * kk, -1);
  r.d2.assign(queries.size() * kk, kInf);
  const float max_d2 = max_distance_m * max_distance_m;
  std::vector<std::pair<float, std::int32_t>> cand;
  for (std::size_t c = 0; c < queries.num_clouds(); ++c) {
    const std::size_t s = std::size_t(seg[c]);
    for (std::int64_t i = queries.offsets[c]; i < queries.offsets[c + 1]; ++i) {
      cand.clear();
      for (std::int64_t j = targets.offsets[s]; j < targets.offsets[s + 1]; ++j) {
        const float d = perch2::knn_sq_distance(targets.point(std::size_t(j)), queries.point(std::size_t(i)));
        if (d <= max_d2) cand.push_back({d, std::int32_t(j)});
      }
      const std::size_t m = std::min(kk, cand.size());
      std::partial_sort(cand.begin(), cand.begin() + std::ptrdiff_t(m), cand.end());
      for (std::size_t j = 0; j < m; ++j) {
        r.d2[std::size_t(i) * kk + j] = cand[j].first;
        r.index[std::size_t(i) * kk + j] = cand[j].second;
      }
    }
  }
  return r;
}

/// Checks a result against the reference; exact_ties: indices must match even where distances tie.
void check_equal(const KnnResult& got, const Reference& ref, bool exact_ties, const std::string& what) {
  INFO(what);
  const std::size_t k = std::size_t(ref.k), kk = k + 1;
  REQUIRE(got.k == ref.k);
  const std::size_t nq = ref.index.size() / kk;
  REQUIRE(got.index.size() == nq * k);
  REQUIRE(got.sq_distance_m2.size() == nq * k);
  std::size_t bad_d = 0, bad_i = 0;
  for (std::size_t q = 0; q < nq; ++q)
    for (std::size_t j = 0; j < k; ++j) {
      const float rd = ref.d2[q * kk + j];
      const float gd = got.sq_distance_m2[q * k + j];
      if (!(gd == rd)) ++bad_d;
      const bool unique = (j == 0 || ref.d2[q * kk + j - 1] != rd) && ref.d2[q * kk + j + 1] != rd;
      if ((exact_ties || unique || rd == kInf) && got.index[q * k + j] != ref.index[q * kk + j]) ++bad_i;
    }
  CHECK(bad_d == 0);
  CHECK(bad_i == 0);
}

/// Every reported index lies inside the searched segment (or is -1).
void check_segments(const KnnResult& got, const CloudBatch& targets, const CloudBatch& queries,
                    const std::vector<std::int32_t>& seg) {
  std::size_t outside = 0;
  for (std::size_t c = 0; c < queries.num_clouds(); ++c) {
    const std::size_t s = std::size_t(seg[c]);
    for (std::int64_t i = queries.offsets[c]; i < queries.offsets[c + 1]; ++i)
      for (int j = 0; j < got.k; ++j) {
        const std::int32_t t = got.index[std::size_t(i) * std::size_t(got.k) + std::size_t(j)];
        if (t != -1 && (t < targets.offsets[s] || t >= targets.offsets[s + 1])) ++outside;
      }
  }
  CHECK(outside == 0);
}

template <class Backend>
constexpr bool breaks_ties_by_index() {
  return !std::is_same_v<Backend, perch2::cpu::Backend>;  // FLANN orders exact ties its own way
}

/// Runs every method and k on one (targets, queries) pair and compares with the brute force.
template <class Backend>
void check_all_methods(const CloudBatch& targets, const CloudBatch& queries,
                       const std::vector<std::int32_t>& seg, const std::vector<int>& ks,
                       const std::vector<float>& max_distances, std::size_t small_budget = 0,
                       const perch2::KnnIndexSettings& index_settings = {}) {
  const typename Backend::KnnIndex index(targets, index_settings);
  for (int k : ks)
    for (float md : max_distances) {
      const Reference ref = brute_force(targets, queries, seg, k, md);
      for (KnnMethod m : kMethods) {
        KnnSettings s;
        s.k = k;
        s.max_distance_m = md;
        s.method = m;
        const std::string what = std::string(Backend::name) + " " + perch2::to_string(m) +
                                 " k=" + std::to_string(k) + " max_distance_m=" + std::to_string(md);
        const KnnResult r = index.knn(queries, seg, s);
        check_equal(r, ref, breaks_ties_by_index<Backend>(), what);
        check_segments(r, targets, queries, seg);
        if (m == KnnMethod::BruteForce && small_budget && k == ks[0] && md == max_distances[0]) {
          // Tiles narrower than a segment: one query row, several column blocks per segment. Only the first
          // query clouds (the tiny tiles make many small launches).
          CloudBatch few;
          few.offsets.clear();
          for (std::size_t c = 0; c < 4; ++c) few.offsets.push_back(queries.offsets[c]);
          const std::size_t n = std::size_t(few.offsets.back());
          few.x.assign(queries.x.begin(), queries.x.begin() + std::ptrdiff_t(n));
          few.y.assign(queries.y.begin(), queries.y.begin() + std::ptrdiff_t(n));
          few.z.assign(queries.z.begin(), queries.z.begin() + std::ptrdiff_t(n));
          const std::vector<std::int32_t> few_seg(seg.begin(), seg.begin() + 3);
          s.memory_budget_bytes = small_budget;
          check_equal(index.knn(few, few_seg, s), brute_force(targets, few, few_seg, k, md),
                      breaks_ties_by_index<Backend>(), what + " small tiles");
        }
      }
    }
}

/// The vertices of a PLY model in millimetres (LINEMOD), as metres (perch2's PLY reader).
std::vector<Vec3f> ply_vertices_mm(const std::string& path) {
  std::vector<Vec3f> v;
  for (const auto& p : perch2::io::load_ply(path, {0.001f}).vertices) v.push_back(Vec3f{p.x(), p.y(), p.z()});
  return v;
}

/// Runs fn on its own thread and returns whether it finished within `seconds` (rethrowing its exception).
/// fn must own everything it touches: a call that hangs is left running, detached, so the test fails fast
/// instead of hanging the suite (each doctest case is its own ctest process, which then exits).
template <class Fn>
bool finishes_within(double seconds, Fn fn) {
  auto done = std::make_shared<std::promise<void>>();
  std::future<void> finished = done->get_future();
  std::thread([done, fn = std::move(fn)]() mutable {
    try {
      fn();
      done->set_value();
    } catch (...) {
      done->set_exception(std::current_exception());
    }
  }).detach();
  if (finished.wait_for(std::chrono::duration<double>(seconds)) != std::future_status::ready) return false;
  finished.get();
  return true;
}

}  // namespace

TEST_CASE_TEMPLATE("kNN equals brute force on random clouds with several segments", Backend,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  std::mt19937 rng(7);
  // Segments overlap in space, so isolation is exercised: a query must not see a nearer point of another
  // segment. Sizes include fewer points than k (3) and an empty segment.
  const CloudBatch targets = make_batch({random_box(rng, 700, {-0.2f, -0.2f, 0.5f}, {0.2f, 0.2f, 0.9f}),
                                         random_box(rng, 3, {-0.1f, -0.1f, 0.6f}, {0.1f, 0.1f, 0.7f}),
                                         {},
                                         random_box(rng, 1500, {-0.1f, -0.3f, 0.4f}, {0.3f, 0.1f, 1.0f})});
  std::vector<std::vector<Vec3f>> qc;
  std::vector<std::int32_t> seg;
  std::uniform_int_distribution<int> size(0, 50), which(0, 3);
  for (int c = 0; c < 30; ++c) {
    qc.push_back(random_box(rng,
                            c == 0       ? 40
                            : c % 7 == 3 ? 0
                                         : size(rng),
                            {-0.3f, -0.3f, 0.3f}, {0.3f, 0.3f, 1.1f}));
    seg.push_back(c == 0 ? 3 : which(rng));  // cloud 0: the 1,500-point segment (column tiling below)
  }
  const CloudBatch queries = make_batch(qc);
  check_all_methods<Backend>(targets, queries, seg, {1, 4, 16}, {kInf, 0.03f}, 4000);
  // An index built without cell representatives (as the cost stage's): the grid falls back to rings.
  perch2::KnnIndexSettings no_reps;
  no_reps.grid.cell_representatives = false;
  check_all_methods<Backend>(targets, queries, seg, {1, 16}, {kInf, 0.03f}, 0, no_reps);
}

TEST_CASE_TEMPLATE("kNN equals brute force on surface clouds (sphere, box)", Backend,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  std::mt19937 rng(11);
  const auto sphere = sphere_surface(rng, 3000, {0.05f, -0.02f, 0.8f}, 0.06f);
  const auto box = box_surface(rng, 2000, {-0.1f, 0.0f, 0.7f}, {0.02f, 0.05f, 0.75f});
  const CloudBatch targets = make_batch({sphere, box});
  std::vector<std::vector<Vec3f>> qc;
  std::vector<std::int32_t> seg;
  for (int c = 0; c < 24; ++c) {
    const bool on_sphere = c % 2 == 0;
    // Near hypotheses (1 cm) and far ones (10 cm, partly outside the target's bounding box).
    qc.push_back(perturbed(rng, on_sphere ? sphere : box, 60, c < 12 ? 0.01f : 0.1f, 0.001f));
    seg.push_back(on_sphere ? 0 : 1);
  }
  const CloudBatch queries = make_batch(qc);
  check_all_methods<Backend>(targets, queries, seg, {1, 10}, {kInf, 0.0075f});
}

TEST_CASE_TEMPLATE("kNN equals brute force on the LINEMOD cat model", Backend, PERCH2_CPU_RUNNABLE_BACKENDS) {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/linemod_obj_06/obj_06.ply");
  const std::vector<Vec3f> cat = ply_vertices_mm(path);
  REQUIRE(cat.size() == 15736);
  std::mt19937 rng(3);
  // Targets: a 5,000-point subset of the scanned vertices (the benchmark's observed-object size).
  std::vector<Vec3f> sub = cat;
  std::shuffle(sub.begin(), sub.end(), rng);
  sub.resize(5000);
  const CloudBatch targets = make_batch({sub});
  std::vector<std::vector<Vec3f>> qc;
  for (int c = 0; c < 16; ++c) qc.push_back(perturbed(rng, cat, 100, 0.02f, 0.0005f));
  const CloudBatch queries = make_batch(qc);
  check_all_methods<Backend>(targets, queries, std::vector<std::int32_t>(qc.size(), 0), {1, 10}, {kInf});
}

TEST_CASE_TEMPLATE("kNN with exact ties on a lattice", Backend, PERCH2_CPU_RUNNABLE_BACKENDS) {
  // Lattice points and lattice-aligned queries: many neighbours at exactly equal distances.
  std::vector<Vec3f> lattice;
  for (int i = 0; i < 8; ++i)
    for (int j = 0; j < 8; ++j)
      for (int l = 0; l < 4; ++l)
        lattice.push_back({0.01f * float(i), 0.01f * float(j), 0.5f + 0.01f * float(l)});
  std::vector<Vec3f> q;
  for (int i = 0; i < 15; ++i)
    for (int j = 0; j < 15; ++j) q.push_back({0.005f * float(i), 0.005f * float(j), 0.515f});
  const CloudBatch targets = make_batch({lattice});
  const CloudBatch queries = make_batch({q});
  check_all_methods<Backend>(targets, queries, {0}, {1, 6}, {kInf});
}

TEST_CASE_TEMPLATE("kNN terminates with knn_ball_cells = 0 when queries are cell representatives", Backend,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  // A cloud searched against itself (as normal estimation does): queries equal to their cell's
  // representative start the ball search at radius 0, which with knn_ball_cells = 0 never grew (a hung
  // kernel on a GPU). The search must finish (well within the guard; it takes milliseconds) and be exact.
  std::mt19937 rng(29);
  auto targets =
      std::make_shared<const CloudBatch>(make_batch({sphere_surface(rng, 2000, {0, 0, 0.8f}, 0.05f)}));
  perch2::KnnIndexSettings is;
  is.grid.knn_ball_cells = 0.f;
  for (int k : {2, 5}) {
    INFO("k = " << k);
    auto got = std::make_shared<KnnResult>();
    auto host_grid = std::make_shared<KnnResult>();
    const bool finished = finishes_within(20.0, [targets, is, k, got, host_grid] {
      const typename Backend::KnnIndex index(*targets, is);
      KnnSettings s;
      s.k = k;
      s.method = KnnMethod::Grid;
      *got = index.knn(*targets, {0}, s);
      // The kernel itself, on a host grid (the cpu backend searches with FLANN, not the grid).
      const perch2::HostGrid grid(*targets, is.grid);
      host_grid->k = k;
      host_grid->index.resize(targets->size() * std::size_t(k));
      host_grid->sq_distance_m2.resize(targets->size() * std::size_t(k));
      for (std::size_t i = 0; i < targets->size(); ++i)
        perch2::grid_knn(grid.view(), 0, targets->point(i), k, kInf, &host_grid->index[i * std::size_t(k)],
                         &host_grid->sq_distance_m2[i * std::size_t(k)]);
    });
    REQUIRE_MESSAGE(finished, "grid kNN did not finish within 20 s (the ball search loops forever)");
    const Reference ref = brute_force(*targets, *targets, {0}, k, kInf);
    check_equal(*got, ref, breaks_ties_by_index<Backend>(), std::string(Backend::name));
    check_equal(*host_grid, ref, true, "grid_knn on a host grid");
  }
}

TEST_CASE("thrust_omp KnnIndex over 400,000 coincident points builds without quadratic work") {
  // All points fall in one grid cell, placed in the order of the threads' atomic increments. Ordering the
  // cell by insertion sort was O(m^2) in one thread: ~13 s here for 200,000 points on 2 threads, ~4x that
  // for 400,000; a heap sort took ~0.5 s; the segmented sort (runs of 16, then 15 merge passes spread over
  // all threads) 0.4 s of CPU (2.4 s wall on a loaded machine).
  auto targets =
      std::make_shared<CloudBatch>(make_batch({std::vector<Vec3f>(400000, Vec3f{0.1f, 0.2f, 0.9f})}));
  auto result = std::make_shared<KnnResult>();
  const bool finished = finishes_within(20.0, [targets, result] {
    const perch2::thrust_omp::Backend::KnnIndex index(*targets);
    KnnSettings s;
    s.k = 3;
    s.method = KnnMethod::Grid;
    *result = index.knn(make_batch({{{0.1f, 0.2f, 0.9f}, {0.1f, 0.2f, 1.0f}}}), {0}, s);
  });
  REQUIRE_MESSAGE(finished, "building the grid over coincident points took over 20 s");
  // Exact ties at distance 0 (and 0.1 m) break by the smaller index: the first three points.
  CHECK(result->index == std::vector<std::int32_t>{0, 1, 2, 0, 1, 2});
  CHECK(result->sq_distance_m2[0] == 0.f);
}

TEST_CASE_TEMPLATE("kNN edge cases: empty queries, empty segments, fewer than k points", Backend,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  const CloudBatch targets = make_batch({{}, {{0, 0, 1}, {0, 0, 1.1f}}});
  const typename Backend::KnnIndex index(targets);
  for (KnnMethod m : kMethods) {
    INFO(perch2::to_string(m));
    KnnSettings s;
    s.k = 3;
    s.method = m;
    // No query clouds at all, and only empty query clouds: empty results of the right shape.
    const KnnResult none = index.knn(make_batch({}), {}, s);
    CHECK(none.k == 3);
    CHECK(none.index.empty());
    const KnnResult empty = index.knn(make_batch({{}, {}}), {0, 1}, s);
    CHECK(empty.index.empty());
    // Query cloud 0 searches the empty segment, cloud 1 the 2-point segment (fewer than k = 3).
    const KnnResult r = index.knn(make_batch({{{0, 0, 0}}, {}, {{0, 0, 1.04f}}}), {0, 0, 1}, s);
    REQUIRE(r.index.size() == 6);
    CHECK(r.index == std::vector<std::int32_t>{-1, -1, -1, 0, 1, -1});
    CHECK(r.sq_distance_m2[0] == kInf);
    CHECK(r.sq_distance_m2[3] == doctest::Approx(0.04f * 0.04f).epsilon(1e-4));
    CHECK(r.sq_distance_m2[4] == doctest::Approx(0.06f * 0.06f).epsilon(1e-4));
    CHECK(r.sq_distance_m2[5] == kInf);
  }
}

TEST_CASE_TEMPLATE("kNN segment isolation: a nearer point of another segment is never returned", Backend,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  // Segment 0 holds a point exactly at the query; the query searches segment 1, 1 m away.
  const CloudBatch targets = make_batch({{{0, 0, 1}}, {{1, 0, 1}, {1.5f, 0, 1}}, {{0, 0, 1.001f}}});
  const typename Backend::KnnIndex index(targets);
  for (KnnMethod m : kMethods) {
    INFO(perch2::to_string(m));
    KnnSettings s;
    s.k = 3;
    s.method = m;
    const KnnResult r = index.knn(make_batch({{{0, 0, 1}}}), {1}, s);
    CHECK(r.index == std::vector<std::int32_t>{1, 2, -1});
    // With a 0.5 m cap the query finds nothing: it must not fall back to another segment.
    s.max_distance_m = 0.5f;
    CHECK(index.knn(make_batch({{{0, 0, 1}}}), {1}, s).index == std::vector<std::int32_t>{-1, -1, -1});
  }
}

TEST_CASE_TEMPLATE("kNN max_distance_m is inclusive and drops farther neighbours", Backend,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  // Distances 0.25, 0.5 and 1 (exact binary fractions, so d^2 is exact and equals max_distance^2).
  const CloudBatch targets = make_batch({{{0.25f, 0, 0}, {0.5f, 0, 0}, {1, 0, 0}}});
  const typename Backend::KnnIndex index(targets);
  for (KnnMethod m : kMethods) {
    INFO(perch2::to_string(m));
    KnnSettings s;
    s.k = 3;
    s.method = m;
    s.max_distance_m = 0.5f;
    const KnnResult r = index.knn(make_batch({{{0, 0, 0}}}), {0}, s);
    CHECK(r.index == std::vector<std::int32_t>{0, 1, -1});
    CHECK(r.sq_distance_m2 == std::vector<float>{0.0625f, 0.25f, kInf});
    s.max_distance_m = 0.f;  // only coincident points
    CHECK(index.knn(make_batch({{{0.5f, 0, 0}}}), {0}, s).index == std::vector<std::int32_t>{1, -1, -1});
  }
}

TEST_CASE_TEMPLATE("radius search equals brute force, sorted, with and without a cap", Backend,
                   PERCH2_CPU_RUNNABLE_BACKENDS) {
  std::mt19937 rng(5);
  const auto sphere = sphere_surface(rng, 1500, {0, 0, 0.8f}, 0.05f);
  const CloudBatch targets =
      make_batch({sphere, {}, random_box(rng, 400, {-0.05f, -0.05f, 0.75f}, {0.05f, 0.05f, 0.85f})});
  std::vector<std::vector<Vec3f>> qc;
  for (int c = 0; c < 12; ++c)
    qc.push_back(c == 5 ? std::vector<Vec3f>{} : perturbed(rng, sphere, 40, 0.01f, 0.002f));
  const std::vector<std::int32_t> seg{0, 2, 1, 0, 2, 0, 0, 2, 0, 1, 0, 2};
  const CloudBatch queries = make_batch(qc);
  const typename Backend::KnnIndex index(targets);
  const float radius_m = 0.012f;
  for (int cap : {0, 5}) {
    // Reference: brute force to a large k, cut to the radius (and cap).
    const Reference ref = brute_force(targets, queries, seg, 2000, radius_m);
    for (KnnMethod m : kMethods) {
      INFO(perch2::to_string(m) << " cap " << cap);
      const RadiusResult r = index.radius(queries, seg, radius_m, cap, m);
      REQUIRE(r.num_queries() == queries.size());
      std::size_t bad_count = 0, bad_d = 0, bad_i = 0, total = 0;
      for (std::size_t q = 0; q < queries.size(); ++q) {
        std::size_t n = 0;
        while (n < 2000 && ref.index[q * 2001 + n] >= 0) ++n;
        if (cap > 0) n = std::min<std::size_t>(n, std::size_t(cap));
        if (std::size_t(r.offsets[q + 1] - r.offsets[q]) != n) {
          ++bad_count;
          continue;
        }
        total += n;
        for (std::size_t j = 0; j < n; ++j) {
          const std::size_t o = std::size_t(r.offsets[q]) + j;
          if (r.sq_distance_m2[o] != ref.d2[q * 2001 + j]) ++bad_d;
          // Random float coordinates: exact distance ties have probability ~0, indices must match.
          if (r.index[o] != ref.index[q * 2001 + j]) ++bad_i;
        }
      }
      CHECK(bad_count == 0);
      CHECK(bad_d == 0);
      CHECK(bad_i == 0);
      CHECK(total > 100);  // the radius actually finds neighbours
    }
  }
}

/// Collects every visited neighbour; with `nearest`, shrinks the bound to the nearest so far; with
/// `stop_after` > 0, ends the search after that many visits.
struct Collect final : perch2::cpu::KnnIndex::RadiusVisitor {
  float r2;
  bool nearest = false;
  int stop_after = 0;
  std::vector<std::pair<float, std::int32_t>> seen;
  explicit Collect(float r) : r2(r * r) {}
  void visit(std::int32_t i, float d2) override { seen.emplace_back(d2, i); }
  float bound_m2() const override {
    if (stop_after > 0 && int(seen.size()) >= stop_after) return -1.f;
    if (!nearest || seen.empty()) return r2;
    return std::min_element(seen.begin(), seen.end())->first;
  }
};

float flann_d2(const CloudBatch& t, std::size_t i, Vec3f q) {
  const float dx = q.x - t.x[i], dy = q.y - t.y[i], dz = q.z - t.z[i];
  return dx * dx + dy * dy + dz * dz;
}

TEST_CASE("cpu radius_visit visits exactly the points within the bound (brute force), and stops early") {
  std::mt19937 rng(19);
  const auto sphere = sphere_surface(rng, 1500, {0, 0, 0.8f}, 0.05f);
  // Segment 1: a lattice of 0.25 m steps (exact in binary) so that points lie exactly on the radius.
  std::vector<Vec3f> lattice;
  for (int i = -3; i <= 3; ++i)
    for (int j = -3; j <= 3; ++j) lattice.push_back({0.25f * float(i), 0.25f * float(j), 0.f});
  const CloudBatch targets = make_batch({sphere, lattice, {}});
  const perch2::cpu::KnnIndex index(targets);
  const auto queries = perturbed(rng, sphere, 200, 0.01f, 0.002f);
  std::size_t total = 0, bad_sets = 0, bad_nearest = 0;
  for (const Vec3f& q : queries) {
    const float p[3] = {q.x, q.y, q.z};
    Collect all(0.012f);
    index.radius_visit(p, 0, all);
    std::vector<std::pair<float, std::int32_t>> ref;
    for (std::size_t i = 0; i < 1500; ++i)
      if (flann_d2(targets, i, q) <= all.r2) ref.emplace_back(flann_d2(targets, i, q), std::int32_t(i));
    std::sort(all.seen.begin(), all.seen.end());
    std::sort(ref.begin(), ref.end());
    bad_sets += all.seen != ref;
    total += ref.size();
    Collect near(0.012f);
    near.nearest = true;
    index.radius_visit(p, 0, near);
    // The nearest must be among the visits; visits are never beyond the bound at the time.
    const bool ok = ref.empty() ? near.seen.empty()
                                : !near.seen.empty() &&
                                      *std::min_element(near.seen.begin(), near.seen.end()) == ref.front();
    bad_nearest += !ok;
  }
  CHECK(bad_sets == 0);
  CHECK(bad_nearest == 0);
  CHECK(total > 1000);  // the radius finds neighbours

  SUBCASE("the bound is inclusive: points exactly on the radius are visited") {
    const float origin[3] = {0.f, 0.f, 0.f};
    Collect c(0.5f);  // d2 = 0.25 exactly for (+-0.5, 0), (0, +-0.5)
    index.radius_visit(origin, 1, c);
    CHECK(c.seen.size() == 13);  // 1 + 4 + 4 (diagonal 0.125) + 4 on the radius
  }
  SUBCASE("a negative bound ends the search, empty segments visit nothing, bad segment throws") {
    const float p[3] = {0.f, 0.f, 0.75f};
    Collect c(0.1f);
    c.stop_after = 1;
    index.radius_visit(p, 0, c);
    Collect all(0.1f);
    index.radius_visit(p, 0, all);
    CHECK(all.seen.size() > 50);
    CHECK(c.seen.size() >= 1);
    CHECK(c.seen.size() <= 16);  // at most the rest of the leaf being scanned (FLANN leaves here: <= 10)
    Collect none(1.f);
    index.radius_visit(p, 2, none);
    CHECK(none.seen.empty());
    CHECK_THROWS_AS(index.radius_visit(p, 3, none), std::out_of_range);
  }
}

TEST_CASE_TEMPLATE("kNN rejects bad input with a clear error", Backend, PERCH2_CPU_RUNNABLE_BACKENDS) {
  using Index = typename Backend::KnnIndex;
  const CloudBatch targets = make_batch({{{0, 0, 1}}, {{1, 0, 1}}});
  const Index index(targets);
  const CloudBatch q = make_batch({{{0, 0, 1}}});
  KnnSettings s;
  CHECK_THROWS_WITH_AS(index.knn(q, {2}, s),
                       doctest::Contains("segment index 2 of query cloud 0 out of range"),
                       perch2::InvalidInput);
  CHECK_THROWS_WITH_AS(index.knn(q, {-1}, s), doctest::Contains("out of range"), perch2::InvalidInput);
  CHECK_THROWS_WITH_AS(index.knn(q, {0, 1}, s), doctest::Contains("query_segment: has 2 entries for 1"),
                       perch2::InvalidInput);
  CHECK_THROWS_WITH_AS(index.radius(q, {5}, 0.1f), doctest::Contains("out of range"), perch2::InvalidInput);
  s.k = 0;
  CHECK_THROWS_WITH_AS(index.knn(q, {0}, s), doctest::Contains("KnnSettings::k"), perch2::InvalidInput);
  s = {};
  s.max_distance_m = -1.f;
  CHECK_THROWS_WITH_AS(index.knn(q, {0}, s), doctest::Contains("max_distance_m"), perch2::InvalidInput);
  s.max_distance_m = std::nanf("");
  CHECK_THROWS_WITH_AS(index.knn(q, {0}, s), doctest::Contains("max_distance_m"), perch2::InvalidInput);
  s = {};
  s.memory_budget_bytes = 8;
  CHECK_THROWS_WITH_AS(index.knn(q, {0}, s), doctest::Contains("memory_budget_bytes"), perch2::InvalidInput);
  CHECK_THROWS_WITH_AS(index.radius(q, {0}, -0.1f), doctest::Contains("radius_m"), perch2::InvalidInput);
  CHECK_THROWS_WITH_AS(index.radius(q, {0}, 0.1f, -2), doctest::Contains("max_neighbors"),
                       perch2::InvalidInput);

  CloudBatch nan_q = q;
  nan_q.y[0] = std::nanf("");
  CHECK_THROWS_WITH_AS(index.knn(nan_q, {0}, {}), doctest::Contains("kNN queries: point 0 has a non-finite"),
                       perch2::InvalidInput);
  CloudBatch bad_offsets = q;
  bad_offsets.offsets = {0, 2};
  CHECK_THROWS_WITH_AS(index.knn(bad_offsets, {0}, {}), doctest::Contains("offsets"), perch2::InvalidInput);
  CloudBatch short_y = q;
  short_y.y.clear();
  CHECK_THROWS_WITH_AS(index.knn(short_y, {0}, {}), doctest::Contains("different lengths"),
                       perch2::InvalidInput);

  CloudBatch inf_t = targets;
  inf_t.z[1] = kInf;
  CHECK_THROWS_WITH_AS(Index{inf_t}, doctest::Contains("kNN targets: point 1 has a non-finite"),
                       perch2::InvalidInput);
  perch2::KnnIndexSettings is;
  is.grid.points_per_cell = 0.f;
  CHECK_THROWS_WITH_AS(Index(targets, is), doctest::Contains("points_per_cell"), perch2::InvalidInput);
}

TEST_CASE("grid_knn is exact for far queries, degenerate segments and capped grids") {
  std::mt19937 rng(13);
  std::vector<Vec3f> plane =
      random_box(rng, 800, {-0.2f, -0.2f, 0.7f}, {0.2f, 0.2f, 0.7f});             // flat: z extent 0
  const std::vector<Vec3f> same(20, Vec3f{0.1f, 0.2f, 0.3f});                     // one repeated point
  const std::vector<Vec3f> line = random_box(rng, 300, {0, 0, 1}, {0.5f, 0, 1});  // a segment of a line
  const CloudBatch targets = make_batch({plane, same, line});
  // Queries near, inside and far outside each segment's bounding box (up to 2 m away).
  std::vector<std::vector<Vec3f>> qc;
  for (int s = 0; s < 3; ++s) {
    qc.push_back(random_box(rng, 60, {-0.3f, -0.3f, 0.6f}, {0.6f, 0.3f, 1.1f}));
    qc.push_back(random_box(rng, 20, {-2.f, -2.f, -1.f}, {2.f, 2.f, 3.f}));
  }
  const CloudBatch queries = make_batch(qc);
  const std::vector<std::int32_t> seg{0, 0, 1, 1, 2, 2};
  for (float cell : {0.f, 0.0005f, 0.3f}) {  // automatic, very fine (hits the cell cap), coarse
    perch2::GridSettings gs;
    gs.cell_size_m = cell;
    const perch2::HostGrid grid(targets, gs);
    for (int s = 0; s < 3; ++s) {
      const auto& g = grid.segments[std::size_t(s)];
      // The cap holds: at most max_cells_per_point * points + 64 cells.
      CHECK(double(g.nx) * g.ny * g.nz <=
            gs.max_cells_per_point * double(targets.cloud_size(std::size_t(s))) + 64);
    }
    for (bool rings : {false, true})  // ball search (with cell representatives) and the ring-search fallback
      for (int k : {1, 7})
        for (float md : {kInf, 0.05f}) {
          perch2::GridView view = grid.view();
          REQUIRE(view.cell_rep != nullptr);
          if (rings) view.cell_rep = nullptr;
          const Reference ref = brute_force(targets, queries, seg, k, md);
          KnnResult got;
          got.k = k;
          got.index.resize(queries.size() * std::size_t(k));
          got.sq_distance_m2.resize(queries.size() * std::size_t(k));
          for (std::size_t c = 0; c < queries.num_clouds(); ++c)
            for (std::int64_t i = queries.offsets[c]; i < queries.offsets[c + 1]; ++i) {
              const std::size_t o = std::size_t(i) * std::size_t(k);
              const int found = perch2::grid_knn(view, seg[c], queries.point(std::size_t(i)), k, md,
                                                 &got.index[o], &got.sq_distance_m2[o]);
              CHECK(found == int(std::count_if(got.index.begin() + std::ptrdiff_t(o),
                                               got.index.begin() + std::ptrdiff_t(o) + k,
                                               [](int v) { return v >= 0; })));
            }
          check_equal(
              got, ref, true,
              "cell " + std::to_string(cell) + " k " + std::to_string(k) + (rings ? " rings" : " ball"));
          // A NaN or infinite query (e.g. a point moved by a diverged pose in device code) finds nothing.
          for (const Vec3f bad : {Vec3f{std::nanf(""), 0, 1}, Vec3f{0, kInf, 1}}) {
            CHECK(perch2::grid_knn(view, 0, bad, k, md, got.index.data(), got.sq_distance_m2.data()) == 0);
            CHECK(got.index[0] == -1);
          }
        }
  }
}

TEST_CASE("thrust_omp KnnIndex::view() searches the index from device-callable code") {
  // The registration stage calls grid_knn / knn_scan on view() inside its functors; on the OpenMP system
  // the device pointers are host memory, so the kernels can be called here directly.
  std::mt19937 rng(17);
  const auto sphere = sphere_surface(rng, 2000, {0, 0, 0.8f}, 0.05f);
  const CloudBatch targets = make_batch({random_box(rng, 50, {1, 1, 1}, {2, 2, 2}), sphere});
  const perch2::thrust_omp::Backend::KnnIndex index(targets);
  const perch2::KnnView v = index.view();
  REQUIRE(v.num_segments == 2);
  CHECK(v.segment_offsets[1] == 50);
  CHECK(v.points[60].x == targets.x[60]);
  const CloudBatch queries = make_batch({perturbed(rng, sphere, 200, 0.01f, 0.001f)});
  const Reference ref = brute_force(targets, queries, {1}, 10, kInf);
  KnnResult grid, scan;
  grid.k = scan.k = 10;
  grid.index.resize(2000), grid.sq_distance_m2.resize(2000), scan.index.resize(2000),
      scan.sq_distance_m2.resize(2000);
  for (std::size_t i = 0; i < queries.size(); ++i) {
    perch2::grid_knn(v.grid, 1, queries.point(i), 10, kInf, &grid.index[i * 10],
                     &grid.sq_distance_m2[i * 10]);
    perch2::knn_clear(10, &scan.index[i * 10], &scan.sq_distance_m2[i * 10]);
    perch2::knn_scan(v.points, v.segment_offsets[1], v.segment_offsets[2], queries.point(i), 10, kInf,
                     &scan.index[i * 10], &scan.sq_distance_m2[i * 10]);
  }
  check_equal(grid, ref, true, "grid_knn on view()");
  check_equal(scan, ref, true, "knn_scan on view()");
}

TEST_CASE("thrust_omp KnnIndex reuses its workspace: warm knn() and radius() calls allocate nothing") {
  // Every per-call array (queries, per-point segments, result lists, kNN I tiles, radius offsets and
  // sort buffers, scan temporaries) lives in the index's workspace and only grows: the second identical
  // call makes no device allocation, and a smaller call none either. Results are unchanged by reuse.
  std::mt19937 rng(61);
  const auto sphere = sphere_surface(rng, 3000, {0, 0, 0.8f}, 0.05f);
  const CloudBatch targets = make_batch({sphere, random_box(rng, 500, {-0.05f, -0.05f, 0.7f}, {0, 0, 0.8f})});
  std::vector<std::vector<Vec3f>> qc;
  for (int c = 0; c < 20; ++c) qc.push_back(perturbed(rng, sphere, 50, 0.01f, 0.001f));
  const CloudBatch queries = make_batch(qc);
  const std::vector<std::int32_t> seg(qc.size(), 0);
  const CloudBatch fewer = make_batch({qc[0], qc[1]});
  const perch2::thrust_omp::Backend::KnnIndex index(targets);
  const perch2::thrust_backend::LaunchShape build = index.last_launch_shape();
  CHECK(build.device_allocations > 0);
  REQUIRE(build.find("place_in_cells") != nullptr);
  CHECK(build.find("place_in_cells")->items == std::int64_t(targets.size()));
  CHECK(build.find("cell_sort_runs") != nullptr);  // cells of more than one point are ordered by index
  {  // ... so the layout does not depend on the order of the build's atomic increments
    const perch2::GridView g = index.view().grid;
    const perch2::GridSegment& last = g.segments[g.num_segments - 1];
    const std::int64_t cells = last.cell_base + std::int64_t(last.nx) * last.ny * last.nz;
    std::int64_t unordered = 0, largest = 0;
    for (std::int64_t c = 0; c < cells; ++c) {
      largest = std::max<std::int64_t>(largest, g.cell_start[c + 1] - g.cell_start[c]);
      for (std::int32_t i = g.cell_start[c] + 1; i < g.cell_start[c + 1]; ++i)
        unordered += g.point_index[i - 1] > g.point_index[i];
    }
    CHECK(unordered == 0);
    CHECK(largest > perch2::thrust_backend::segmented_sort_run);  // the merge passes ran
    CHECK(build.find("cell_sort_merge") != nullptr);
  }
  for (KnnMethod m : kMethods) {
    INFO(perch2::to_string(m));
    KnnSettings s;
    s.k = 8;
    s.method = m;
    s.memory_budget_bytes = 1 << 20;  // kNN I: several tiles (1,000 queries x 3,000 targets)
    const KnnResult cold = index.knn(queries, seg, s);
    // The first call builds the workspace; kNN I adds its tile.
    if (m == KnnMethod::Auto || m == KnnMethod::BruteForce)
      CHECK(index.last_launch_shape().device_allocations > 0);
    const KnnResult warm = index.knn(queries, seg, s);
    const perch2::thrust_backend::LaunchShape shape = index.last_launch_shape();
    CHECK(shape.device_allocations == 0);
    CHECK(warm.index == cold.index);
    CHECK(warm.sq_distance_m2 == cold.sq_distance_m2);
    REQUIRE(shape.find("query_segment") != nullptr);
    CHECK(shape.find("query_segment")->items == std::int64_t(queries.size()));
    if (m == KnnMethod::Grid) CHECK(shape.find("grid_knn")->items == std::int64_t(queries.size()));
    if (m == KnnMethod::BruteForce) CHECK(shape.find("tile_select")->launches > 1);
    index.knn(fewer, {0, 0}, s);
    CHECK(index.last_launch_shape().device_allocations == 0);
  }
  for (int cap : {0, 6}) {
    INFO("cap " << cap);
    const RadiusResult cold = index.radius(queries, seg, 0.01f, cap);
    CHECK(index.last_launch_shape().device_allocations > 0);  // offsets (and lists or sort buffers)
    const RadiusResult warm = index.radius(queries, seg, 0.01f, cap);
    CHECK(index.last_launch_shape().device_allocations == 0);
    CHECK(warm.offsets == cold.offsets);
    CHECK(warm.index == cold.index);
    CHECK(warm.sq_distance_m2 == cold.sq_distance_m2);
    index.radius(fewer, {0, 0}, 0.01f, cap);
    CHECK(index.last_launch_shape().device_allocations == 0);
  }
}

TEST_CASE_TEMPLATE("kNN and radius search over 20,000 coincident points finish and sort in bounded passes",
                   Backend, PERCH2_TEST_BACKENDS) {
  // Worst case for per-item serial work: every target point in one grid cell and within every query's
  // radius. The Thrust backend orders the cell by index and each query's 20,000 radius results by
  // (distance, index) with a segmented sort (runs of 16, then merge passes: one binary search per element),
  // never one thread sorting a whole segment; the guard catches a hang.
  auto targets =
      std::make_shared<CloudBatch>(make_batch({std::vector<Vec3f>(20000, Vec3f{0.1f, 0.2f, 0.9f})}));
  std::vector<Vec3f> q(40, Vec3f{0.1f, 0.2f, 0.9f});
  q[1] = {0.1f, 0.2f, 0.91f};  // 1 cm away: every point at the same distance, still index order
  auto queries = std::make_shared<CloudBatch>(make_batch({q}));
  auto knn = std::make_shared<KnnResult>();
  auto radius = std::make_shared<RadiusResult>();
  auto shape = std::make_shared<perch2::thrust_backend::LaunchShape>();
  const bool finished = finishes_within(60.0, [targets, queries, knn, radius, shape] {
    const typename Backend::KnnIndex index(*targets);
    KnnSettings s;
    s.k = 10;
    s.method = KnnMethod::Grid;
    *knn = index.knn(*queries, {0}, s);
    *radius = index.radius(*queries, {0}, 0.02f);
    if constexpr (!std::is_same_v<Backend, perch2::cpu::Backend>) *shape = index.last_launch_shape();
  });
  REQUIRE_MESSAGE(finished, "searching 20,000 coincident points took over 60 s");
  std::vector<std::int32_t> first10(10);
  for (int j = 0; j < 10; ++j) first10[std::size_t(j)] = j;
  for (std::size_t i = 0; i < q.size(); ++i) {
    std::vector<std::int32_t> got(knn->index.begin() + std::ptrdiff_t(i * 10),
                                  knn->index.begin() + std::ptrdiff_t(i * 10 + 10));
    // Exact ties break by the smaller index (FLANN returns some 10 distinct points of the tie).
    if (breaks_ties_by_index<Backend>()) {
      CHECK(got == first10);
    } else {
      std::sort(got.begin(), got.end());
      CHECK(std::unique(got.begin(), got.end()) == got.end());
      CHECK(got.front() >= 0);
      CHECK(got.back() < 20000);
    }
    CHECK(knn->sq_distance_m2[i * 10 + 9] == knn->sq_distance_m2[i * 10]);  // all tied
  }
  REQUIRE(radius->offsets.size() == q.size() + 1);
  std::size_t unsorted = 0;
  for (std::size_t i = 0; i < q.size(); ++i) {
    REQUIRE(radius->offsets[i + 1] - radius->offsets[i] == 20000);
    for (std::int64_t j = 0; j < 20000; ++j)
      unsorted += radius->index[std::size_t(radius->offsets[i] + j)] != std::int32_t(j);
  }
  CHECK(unsorted == 0);
  if constexpr (!std::is_same_v<Backend, perch2::cpu::Backend>) {
    // 20,000 = 16 x 1,250 <= 16 x 2^11: runs of 16 then 11 merge passes, each one item per result.
    const auto* runs = shape->find("radius_sort_runs");
    const auto* merge = shape->find("radius_sort_merge");
    REQUIRE(runs != nullptr);
    REQUIRE(merge != nullptr);
    CHECK(runs->items == 40 * 20000);
    CHECK(merge->launches == 11);
    CHECK(merge->max_items == 40 * 20000);
  }
}
