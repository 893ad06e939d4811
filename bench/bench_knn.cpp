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
#include <filesystem>
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
#include "perch2/knn/knn.hpp"

#ifdef PERCH2_HAVE_NANOFLANN
#include <nanoflann.hpp>
#endif

using namespace perch2;

namespace {

std::vector<Vec3f> read_ascii_ply_vertices(const std::string& path) {
  std::ifstream f(path);
  std::string line;
  std::size_t n = 0;
  while (std::getline(f, line) && line.rfind("end_header", 0) != 0) {
    std::istringstream ls(line);
    std::string a, b;
    ls >> a >> b;
    if (a == "element" && b == "vertex") ls >> n;
  }
  std::vector<Vec3f> v;
  for (std::size_t i = 0; i < n && std::getline(f, line); ++i) {
    std::istringstream ls(line);
    Vec3f p;
    ls >> p.x >> p.y >> p.z;
    v.push_back(0.001f * p);  // millimetres -> metres
  }
  return v;
}

/// Fallback model without the shared data: a 6 cm x 4 cm x 8 cm box surface.
std::vector<Vec3f> box_model(std::mt19937& rng, int n) {
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  std::uniform_int_distribution<int> face(0, 5);
  const float h[3] = {0.03f, 0.02f, 0.04f};
  std::vector<Vec3f> p;
  for (int i = 0; i < n; ++i) {
    float c[3] = {h[0] * u(rng), h[1] * u(rng), h[2] * u(rng)};
    const int f = face(rng);
    c[f / 2] = f % 2 ? h[f / 2] : -h[f / 2];
    p.push_back({c[0], c[1], c[2]});
  }
  return p;
}

Rigid3f rotation(Vec3f axis, float angle, Vec3f t) {
  const float n = std::sqrt(squared_norm(axis));
  const Vec3f a = (1.f / n) * axis;
  const float c = std::cos(angle), s = std::sin(angle), C = 1 - c;
  return {{{c + a.x * a.x * C, a.x * a.y * C - a.z * s, a.x * a.z * C + a.y * s, a.y * a.x * C + a.z * s,
            c + a.y * a.y * C, a.y * a.z * C - a.x * s, a.z * a.x * C - a.y * s, a.z * a.y * C + a.x * s,
            c + a.z * a.z * C}},
          t};
}

void append(CloudBatch& b, const std::vector<Vec3f>& pts) {
  for (const Vec3f& p : pts) {
    b.x.push_back(p.x), b.y.push_back(p.y), b.z.push_back(p.z);
    b.rgb.push_back(0), b.pixel.push_back(-1), b.cloud.push_back(std::int32_t(b.num_clouds()));
  }
  b.offsets.push_back(std::int64_t(b.x.size()));
}

std::vector<Vec3f> sample(std::mt19937& rng, const std::vector<Vec3f>& pts, std::size_t n) {
  std::uniform_int_distribution<std::size_t> pick(0, pts.size() - 1);
  std::vector<Vec3f> out(n);
  for (auto& p : out) p = pts[pick(rng)];
  return out;
}

std::vector<Vec3f> transformed(const std::vector<Vec3f>& pts, const Rigid3f& T, std::mt19937& rng,
                               float noise_m) {
  std::normal_distribution<float> g(0.f, noise_m);
  std::vector<Vec3f> out;
  for (const Vec3f& p : pts) out.push_back(T * p + Vec3f{g(rng), g(rng), g(rng)});
  return out;
}

struct Scene {
  std::string name;
  CloudBatch targets, queries;
  std::vector<std::int32_t> segment;
};

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
  const std::string data_dir =
      argc > 1 ? argv[1] : (std::filesystem::path(__FILE__).parent_path() / "../../shared/data").string();
  const int runs = argc > 2 ? std::max(1, std::atoi(argv[2])) : 5;
  const bool grid_only = argc > 3 && std::string(argv[3]) == "grid";  // skip the slow scanning methods
  std::mt19937 rng(42);
  std::vector<Vec3f> model = read_ascii_ply_vertices(data_dir + "/models/linemod_obj_06/obj_06.ply");
  const bool real = !model.empty();
  if (!real) model = box_model(rng, 15000);
  // Centre the model at its bounding-box centre.
  Vec3f lo = model[0], hi = model[0];
  for (const Vec3f& p : model)
    lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)},
    hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
  const Vec3f centre = 0.5f * (lo + hi);
  for (Vec3f& p : model) p = p - centre;
  std::printf("model: %s, %zu vertices; OpenMP threads: %d; runs: %d (medians)\n",
              real ? "LINEMOD obj_06 (cat)" : "synthetic box (no shared data)", model.size(),
              omp_get_max_threads(), runs);
#ifdef PERCH2_HAVE_NANOFLANN
  std::printf("peer: nanoflann, NANOFLANN_VERSION 0x%x (KDTreeSingleIndexAdaptor, leaf size 10)\n",
              unsigned(NANOFLANN_VERSION));
#else
  std::printf("peer: nanoflann not built in (libnanoflann-dev not found at configure time)\n");
#endif

  std::vector<Scene> scenes;
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  const Rigid3f T_cam_obj = rotation({1, 0.3f, 0.1f}, 2.2f, {0.02f, -0.05f, 0.75f});
  {  // 6-DoF: one object segment of 5,000 points, hypotheses perturbed around the true pose.
    Scene s;
    s.name = "6dof: 2400 x 300 queries -> 1 segment of 5000";
    append(s.targets, transformed(sample(rng, model, 5000), T_cam_obj, rng, 0.001f));
    for (int h = 0; h < 2400; ++h) {
      const Vec3f axis{u(rng), u(rng), u(rng)};  // drawn in sequence: argument order is unspecified
      const float angle = 0.26f * u(rng);
      const Rigid3f dT = rotation(axis, angle, {0.03f * u(rng), 0.03f * u(rng), 0.03f * u(rng)});
      Rigid3f T = T_cam_obj;
      std::vector<Vec3f> pts = transformed(sample(rng, model, 300), T, rng, 0.f);
      for (Vec3f& p : pts) p = dT * (p - T_cam_obj.t) + T_cam_obj.t;
      append(s.queries, pts);
      s.segment.push_back(0);
    }
    scenes.push_back(std::move(s));
  }
  {  // 3-DoF: table plane (1 m x 0.8 m, ~17,000 points) + the object (3,000), hypotheses on a table grid.
    Scene s;
    s.name = "3dof: 2400 x 300 queries -> 1 scene of 20000";
    const Rigid3f T_cam_table = rotation({1, 0, 0}, -2.2f, {0.f, 0.1f, 0.9f});  // table z up, seen from above
    std::vector<Vec3f> scene;
    std::uniform_real_distribution<float> tx(-0.5f, 0.5f), ty(-0.4f, 0.4f);
    for (int i = 0; i < 17000; ++i) scene.push_back(T_cam_table * Vec3f{tx(rng), ty(rng), 0.f});
    const float half_h = 0.5f * (hi.z - lo.z);
    const Rigid3f T_table_obj = rotation({0, 0, 1}, 0.7f, {0.1f, -0.05f, half_h});
    for (const Vec3f& p : sample(rng, model, 3000)) scene.push_back(T_cam_table * (T_table_obj * p));
    append(s.targets, transformed(scene, rotation({0, 0, 1}, 0.f, {0, 0, 0}), rng, 0.001f));
    // 3-DoF grid: x, y every 8 cm over the table (13 x 10), yaw in 22.5 deg steps (16) -> 2,080; pad to
    // 2,400.
    std::vector<Rigid3f> hyps;
    for (int i = 0; i < 13; ++i)
      for (int j = 0; j < 10; ++j)
        for (int y = 0; y < 16; ++y)
          hyps.push_back(rotation({0, 0, 1}, 0.3927f * float(y),
                                  {-0.48f + 0.08f * float(i), -0.36f + 0.08f * float(j), half_h}));
    while (hyps.size() < 2400) hyps.push_back(hyps[hyps.size() % 2080]);
    for (const Rigid3f& T : hyps) {
      std::vector<Vec3f> pts = sample(rng, model, 300);
      for (Vec3f& p : pts) p = T_cam_table * (T * p);
      append(s.queries, pts);
      s.segment.push_back(0);
    }
    scenes.push_back(std::move(s));
  }

  for (const Scene& s : scenes) {
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
