// kNN throughput: queries/s per method and backend next to FLANN (the cpu backend's kd-trees) on the same
// queries in the same run. Medians of N runs (default 5). Two scenes at the sizes:
//   6dof: 2,400 query clouds x 300 points (the LINEMOD cat under pose perturbations up to 15 deg / 3 cm)
//         against one 5,000-point segment (the observed object);
//   3dof: 2,400 query clouds x 300 points (the cat on a 3-DoF grid of table positions and yaws)
//         against one ~20,000-point observed scene (table plane + the object).
// Scanning methods (kNN I, kNN II) are timed on the first 240 query clouds (10 %): their cost is linear in
// the number of queries, so queries/s is comparable; the full set would take minutes per run.
// Optional peer (built in when CMake finds libnanoflann-dev): nanoflann's KDTreeSingleIndexAdaptor, one tree
// per target segment (leaf size 10 like FLANN's), OpenMP over query clouds like the FLANN reference, on the
// same queries and targets as the FLANN row.
//
// Usage: bench_knn [data_dir=<repo>/../shared/data] [runs=5] [grid: time only FLANN, auto and grid]
#include <omp.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <functional>
#include <limits>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "perch2/cpu/knn.hpp"
#include "perch2/cuda/knn.hpp"
#ifdef PERCH2_HAVE_CUDA
#include "perch2/cuda/device.hpp"
#endif
#include "knn_scenes.hpp"
#include "perch2/knn/knn.hpp"

#ifdef PERCH2_HAVE_NANOFLANN
#include <nanoflann.hpp>
#endif

using namespace perch2;

namespace {

CloudBatch first_clouds(const CloudBatch& b, std::size_t n) {
  CloudBatch out;
  out.offsets.assign(b.offsets.begin(), b.offsets.begin() + std::ptrdiff_t(n) + 1);
  const std::size_t m = std::size_t(out.offsets.back());
  out.x.assign(b.x.begin(), b.x.begin() + std::ptrdiff_t(m));
  out.y.assign(b.y.begin(), b.y.begin() + std::ptrdiff_t(m));
  out.z.assign(b.z.begin(), b.z.begin() + std::ptrdiff_t(m));
  return out;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

struct Timing {
  double wall_s, cpu_s;  ///< medians over runs: wall-clock and process CPU time (all threads)
};

double process_cpu_s() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
}

/// Medians of `runs` calls. The CPU time shows the work done when other processes share the cores.
Timing time_median(int runs, const std::function<void()>& f) {
  std::vector<double> wall, cpu;
  for (int r = 0; r < runs; ++r) {
    const double c0 = process_cpu_s();
    const auto t0 = std::chrono::steady_clock::now();
    f();
    wall.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    cpu.push_back(process_cpu_s() - c0);
  }
  return {median(wall), median(cpu)};
}

#ifdef PERCH2_HAVE_NANOFLANN
/// nanoflann's dataset adaptor: one target segment as row-major x y z (the layout FLANN is given too).
struct NanoflannCloud {
  std::vector<float> rows;
  std::size_t kdtree_get_point_count() const { return rows.size() / 3; }
  float kdtree_get_pt(std::uint32_t i, std::size_t d) const { return rows[3 * std::size_t(i) + d]; }
  template <class BBox>
  bool kdtree_get_bbox(BBox&) const {
    return false;  // let nanoflann compute the bounding box
  }
};
using NanoflannTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, NanoflannCloud>,
                                                          NanoflannCloud, 3>;

/// The peer index: one nanoflann kd-tree per target segment, searched like cpu::KnnIndex searches FLANN's.
class NanoflannIndex {
 public:
  explicit NanoflannIndex(const CloudBatch& targets, std::size_t leaf_max_size = 10)
      : offsets_(targets.offsets), clouds_(targets.num_clouds()), trees_(targets.num_clouds()) {
#pragma omp parallel for schedule(dynamic, 1)
    for (std::int64_t s = 0; s < std::int64_t(clouds_.size()); ++s) {
      const std::int64_t b = offsets_[std::size_t(s)], e = offsets_[std::size_t(s) + 1];
      if (e == b) continue;
      auto cloud = std::make_unique<NanoflannCloud>();
      cloud->rows.resize(std::size_t(e - b) * 3);
      for (std::int64_t i = b; i < e; ++i) {
        float* r = &cloud->rows[std::size_t(i - b) * 3];
        r[0] = targets.x[std::size_t(i)], r[1] = targets.y[std::size_t(i)], r[2] = targets.z[std::size_t(i)];
      }
      trees_[std::size_t(s)] = std::make_unique<NanoflannTree>(  // builds the tree
          3, *cloud, nanoflann::KDTreeSingleIndexAdaptorParams(leaf_max_size));
      clouds_[std::size_t(s)] = std::move(cloud);
    }
  }

  /// k nearest neighbours (global target indices, squared distances), OpenMP over query clouds.
  KnnResult knn(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment, int k) const {
    KnnResult out;
    out.k = k;
    out.index.assign(queries.size() * std::size_t(k), -1);
    out.sq_distance_m2.assign(queries.size() * std::size_t(k), std::numeric_limits<float>::infinity());
#pragma omp parallel
    {
      std::vector<std::uint32_t> idx(static_cast<std::size_t>(k));
      std::vector<float> d2(static_cast<std::size_t>(k));
#pragma omp for schedule(dynamic, 4)
      for (std::int64_t c = 0; c < std::int64_t(queries.num_clouds()); ++c) {
        const std::int64_t qb = queries.offsets[std::size_t(c)], qe = queries.offsets[std::size_t(c) + 1];
        const std::size_t s = std::size_t(query_segment[std::size_t(c)]);
        const NanoflannTree* tree = trees_[s].get();
        if (qe == qb || !tree) continue;
        const std::int64_t seg_begin = offsets_[s];
        for (std::int64_t q = qb; q < qe; ++q) {
          const float p[3] = {queries.x[std::size_t(q)], queries.y[std::size_t(q)],
                              queries.z[std::size_t(q)]};
          const std::size_t n = tree->knnSearch(p, std::size_t(k), idx.data(), d2.data());
          for (std::size_t j = 0; j < n; ++j) {
            const std::size_t o = std::size_t(q) * std::size_t(k) + j;
            out.index[o] = std::int32_t(seg_begin + std::int64_t(idx[j]));
            out.sq_distance_m2[o] = d2[j];
          }
        }
      }
    }
    return out;
  }

 private:
  std::vector<std::int64_t> offsets_;
  std::vector<std::unique_ptr<NanoflannCloud>> clouds_;  // per segment, kept alive for the trees
  std::vector<std::unique_ptr<NanoflannTree>> trees_;    // null for empty segments
};
#endif

}  // namespace

int main(int argc, char** argv) {
  // PERCH2_SHARED_DATA_DIR (bench/CMakeLists.txt): __FILE__ may be relative (ccache's base dir).
  const std::string data_dir = argc > 1 ? argv[1] : PERCH2_SHARED_DATA_DIR;
  const int runs = argc > 2 ? std::max(1, std::atoi(argv[2])) : 5;
  const bool grid_only = argc > 3 && std::string(argv[3]) == "grid";  // skip the slow scanning methods
  const bench::KnnScenes problems = bench::knn_scenes(data_dir);
  std::printf("model: %s, %zu vertices; OpenMP threads: %d; runs: %d (medians)\n",
              problems.model_name.c_str(), problems.model_vertices, omp_get_max_threads(), runs);
#ifdef PERCH2_HAVE_NANOFLANN
  std::printf("peer: nanoflann, NANOFLANN_VERSION 0x%x (KDTreeSingleIndexAdaptor, leaf size 10)\n",
              unsigned(NANOFLANN_VERSION));
#else
  std::printf("peer: nanoflann not built in (libnanoflann-dev not found at configure time)\n");
#endif
  const std::vector<bench::Scene>& scenes = problems.scenes;

  for (const bench::Scene& s : scenes) {
    std::printf("\n## %s (%zu query points)\n\n", s.name.c_str(), s.queries.size());
    std::unique_ptr<cpu::KnnIndex> flann;
    std::unique_ptr<thrust_backend::KnnIndex<thrust_backend::OmpSystem>> thr;
    const double t_flann_build =
        time_median(runs, [&] { flann = std::make_unique<cpu::KnnIndex>(s.targets); }).wall_s;
    const double t_grid_build =
        time_median(runs, [&] {
          thr = std::make_unique<thrust_backend::KnnIndex<thrust_backend::OmpSystem>>(s.targets);
        }).wall_s;
#ifdef PERCH2_HAVE_NANOFLANN
    std::unique_ptr<NanoflannIndex> nano;
    const double t_nano_build =
        time_median(runs, [&] { nano = std::make_unique<NanoflannIndex>(s.targets); }).wall_s;
    std::printf(
        "index build: FLANN kd-tree %.2f ms, nanoflann kd-tree %.2f ms, "
        "thrust_omp (upload + grid) %.2f ms\n\n",
        1e3 * t_flann_build, 1e3 * t_nano_build, 1e3 * t_grid_build);
#else
    std::printf("index build: FLANN kd-tree %.2f ms, thrust_omp (upload + grid) %.2f ms\n\n",
                1e3 * t_flann_build, 1e3 * t_grid_build);
#endif
#ifdef PERCH2_HAVE_CUDA
    std::unique_ptr<thrust_backend::KnnIndex<thrust_backend::CudaSystem>> gpu;
    if (cuda::device_count() > 0) {
      const double t_gpu_build =
          time_median(runs, [&] {
            gpu = std::make_unique<thrust_backend::KnnIndex<thrust_backend::CudaSystem>>(s.targets);
          }).wall_s;
      std::printf("index build: cuda (upload + grid) %.2f ms\n\n", 1e3 * t_gpu_build);
    }
#endif
    std::printf(
        "| k | backend | method | queries timed | wall s | queries/s | vs FLANN | CPU us/query | "
        "max abs(d2 - FLANN d2) |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|\n");
    const CloudBatch subset = first_clouds(s.queries, 240);
    const std::vector<std::int32_t> subset_seg(s.segment.begin(), s.segment.begin() + 240);
    for (int k : {1, 10}) {
      KnnSettings ks;
      ks.k = k;
      KnnResult ref, ref_sub;
      const Timing t_flann = time_median(runs, [&] { ref = flann->knn(s.queries, s.segment, ks); });
      ref_sub = flann->knn(subset, subset_seg, ks);
      const double flann_qps = double(s.queries.size()) / t_flann.wall_s;
      std::printf("| %d | cpu | FLANN kd-tree | %zu | %.4f | %.3g | 1.00 | %.3f | 0 |\n", k, s.queries.size(),
                  t_flann.wall_s, flann_qps, 1e6 * t_flann.cpu_s / double(s.queries.size()));
#ifdef PERCH2_HAVE_NANOFLANN
      {
        KnnResult r;
        const Timing t = time_median(runs, [&] { r = nano->knn(s.queries, s.segment, k); });
        float max_err = 0;
        for (std::size_t i = 0; i < r.sq_distance_m2.size(); ++i)
          max_err = std::max(max_err, std::abs(r.sq_distance_m2[i] - ref.sq_distance_m2[i]));
        const double qps = double(s.queries.size()) / t.wall_s;
        std::printf("| %d | cpu | nanoflann kd-tree | %zu | %.4f | %.3g | %.2f | %.3f | %g |\n", k,
                    s.queries.size(), t.wall_s, qps, qps / flann_qps,
                    1e6 * t.cpu_s / double(s.queries.size()), double(max_err));
      }
#endif
      // One row per method for a Thrust backend's index.
      auto thrust_rows = [&](const auto& index, const char* backend) {
        for (KnnMethod m : {KnnMethod::Auto, KnnMethod::Grid, KnnMethod::PerQuery, KnnMethod::BruteForce}) {
          ks.method = m;
          const bool scan = m == KnnMethod::PerQuery || m == KnnMethod::BruteForce;
          if (scan && grid_only) continue;
          const CloudBatch& q = scan ? subset : s.queries;
          const std::vector<std::int32_t>& seg = scan ? subset_seg : s.segment;
          const KnnResult& r0 = scan ? ref_sub : ref;
          KnnResult r;
          const Timing t = time_median(runs, [&] { r = index.knn(q, seg, ks); });
          float max_err = 0;
          for (std::size_t i = 0; i < r.sq_distance_m2.size(); ++i)
            max_err = std::max(max_err, std::abs(r.sq_distance_m2[i] - r0.sq_distance_m2[i]));
          const double qps = double(q.size()) / t.wall_s;
          const std::string label =
              m == KnnMethod::Auto
                  ? std::string("auto -> ") +
                        to_string(resolve_knn_method(ks, max_searched_segment(s.targets.offsets, q, seg)))
                  : std::string(to_string(m));
          std::printf("| %d | %s | %s | %zu | %.4f | %.3g | %.2f | %.3f | %g |\n", k, backend, label.c_str(),
                      q.size(), t.wall_s, qps, qps / flann_qps, 1e6 * t.cpu_s / double(q.size()),
                      double(max_err));
        }
      };
      thrust_rows(*thr, "thrust_omp");
#ifdef PERCH2_HAVE_CUDA
      if (gpu)
        thrust_rows(*gpu, "cuda");
      else
        std::printf("| %d | cuda | skipped: %s | | | | | | |\n", k, cuda::device_summary().c_str());
#endif
    }
  }
  return 0;
}
