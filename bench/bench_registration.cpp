// Many-to-one registration benchmark: N rendered hypotheses (~300 points each) of the LINEMOD cat near its
// true pose, aligned to one ~5,000-point rendered view, per backend, next to PCL's
// GeneralizedIterativeClosestPoint looping over the same pairs in the same run (OpenMP over pairs, one GICP
// object per thread, target covariances computed once per thread). Every method's result is scored with the
// same metrics: RMS nearest-neighbour distance of the aligned source to the target and the mean point
// displacement from the ideal correction (the hypotheses' perturbations are known).
// Each method runs in a fresh process (this program with --method): its time is the median of --runs runs,
// its memory the peak RSS while it ran (VmHWM reset after building the problem; getrusage ru_maxrss) and the
// growth over the RSS it started with.
//
// small_gicp 1.0.1 (header-only; `./run.sh bench` unpacks its PyPI source package for this benchmark only) is
// the peer a user would pick today: target kd-tree and covariances built once, OpenMP over sources, one
// serial registration per source with the same k, cap, iterations and tolerances.
//
//   bench_registration [--sources 2400] [--runs 3] [--model path/to/obj_06.ply] [--no-pcl]
//                      [--scale S] [--translation-eps M] [--rotation-eps RAD] [--load N]
#include <sys/resource.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "perch2/cpu/backend.hpp"
#include "perch2/cpu/knn.hpp"
#include "perch2/cpu/registration.hpp"
#include "perch2/cpu/render.hpp"
#include "perch2/cuda/backend.hpp"
#ifdef PERCH2_HAVE_CUDA
#include "perch2/cuda/device.hpp"
#endif
#include "perch2/io/mesh_io.hpp"

#include <omp.h>

#include "bench_support.hpp"

#ifdef PERCH2_HAVE_SMALL_GICP
#include <small_gicp/ann/kdtree_omp.hpp>
#include <small_gicp/factors/gicp_factor.hpp>
#include <small_gicp/points/point_cloud.hpp>
#include <small_gicp/registration/reduction.hpp>
#include <small_gicp/registration/registration.hpp>
#include <small_gicp/util/normal_estimation.hpp>
#include <small_gicp/util/normal_estimation_omp.hpp>
#endif

#ifdef PERCH2_HAVE_SMALL_GICP
namespace {
/// small_gicp's reduction, counting its correspondence passes (linearisations) on the calling thread:
/// RegistrationResult::iterations is the last iteration's 0-based index, one less than the passes.
struct CountingReduction : small_gicp::SerialReduction {
  static inline thread_local int passes = 0;
  template <class... A>
  auto linearize(A&&... a) const {
    ++passes;
    return small_gicp::SerialReduction::linearize(std::forward<A>(a)...);
  }
};
}  // namespace
#endif

#ifdef PERCH2_HAVE_PCL
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/gicp.h>
#endif

using namespace perch2;

namespace {

constexpr float kDeg = 3.14159265f / 180.f;

double now_s() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

long current_rss_kb() {
  long pages = 0, resident = 0;
  if (FILE* f = std::fopen("/proc/self/statm", "r")) {
    if (std::fscanf(f, "%ld %ld", &pages, &resident) != 2) resident = 0;
    std::fclose(f);
  }
  return resident * (sysconf(_SC_PAGESIZE) / 1024);
}

long peak_rss_kb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss;
}

struct Problem {
  CloudBatch target;
  CloudBatch sources;
  std::vector<std::int32_t> segment;
  std::vector<Pose> ideal;  ///< the exact correction of each hypothesis: T_true * T_hyp^-1
};

/// What one method returns (fixed-size so a child can send it through a pipe).
struct Measured {
  double median_s = 0, min_s = 0;
  double quiet_median_s = 0;  ///< with --load: the quiet runs alternating with the loaded ones
  long peak_kb = 0, growth_kb = 0;
};

struct Scores {
  double median_rms_mm = 0, mean_rms_mm = 0, median_disp_mm = 0;
  double within_1mm = 0;  ///< fraction of hypotheses whose mean displacement from the ideal is < 1 mm
  double converged = 0;
  double mean_passes = -1;  ///< correspondence passes per source (time is about proportional); -1: unknown
};

std::string find_model(const std::string& given) {
  if (!given.empty()) return given;
#ifdef PERCH2_SHARED_DATA_DIR
  if (std::filesystem::exists(PERCH2_SHARED_DATA_DIR "/models/linemod_obj_06/obj_06.ply"))
    return PERCH2_SHARED_DATA_DIR "/models/linemod_obj_06/obj_06.ply";
#endif
  for (const char* c : {"../shared/data/models/linemod_obj_06/obj_06.ply",
                        "../../shared/data/models/linemod_obj_06/obj_06.ply",
                        "../../../shared/data/models/linemod_obj_06/obj_06.ply",
                        "/work/shared/data/models/linemod_obj_06/obj_06.ply"})
    if (std::filesystem::exists(c)) return c;
  return "";
}

Problem make_problem(const Mesh& mesh, int num_sources, std::mt19937& rng) {
  const Intrinsics K{615.f, 615.f, 319.5f, 239.5f, 640, 480};
  Pose T_true = Pose::Identity();
  T_true.linear() = (Eigen::AngleAxisf(35 * kDeg, Eigen::Vector3f::UnitX()) *
                     Eigen::AngleAxisf(-40 * kDeg, Eigen::Vector3f::UnitY()))
                        .toRotationMatrix();
  T_true.translation() = Eigen::Vector3f(0.02f, -0.01f, 0.75f);
  cpu::Renderer r({mesh});
  RenderSettings target_settings;
  target_settings.stride = 1;
  Problem p;
  p.target = r.render({Hypothesis{0, T_true}}, K, target_settings);
  // Hypotheses: up to 10 degrees about a random axis through the object and up to 2 cm away.
  std::normal_distribution<float> g(0.f, 1.f);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  const Eigen::Vector3f c = T_true.translation();
  std::vector<Hypothesis> hyps;
  for (int k = 0; k < num_sources; ++k) {
    Pose D = Pose::Identity();
    D.linear() = Eigen::AngleAxisf(10 * kDeg * u(rng), Eigen::Vector3f{g(rng), g(rng), g(rng)}.normalized())
                     .toRotationMatrix();
    D.translation() =
        c - D.linear() * c + 0.02f * u(rng) * Eigen::Vector3f{g(rng), g(rng), g(rng)}.normalized();
    hyps.push_back(Hypothesis{0, D * T_true});
    p.ideal.push_back(D.inverse());
  }
  RenderSettings source_settings;
  source_settings.stride = 4;
  p.sources = r.render(hyps, K, source_settings);
  p.segment.assign(p.sources.num_clouds(), 0);
  return p;
}

float model_scale = 0.001f;                           // --scale: model units to metres (LINEMOD PLY: mm)
float translation_eps_m = -1, rotation_eps_rad = -1;  // --translation-eps / --rotation-eps; < 0: defaults

GicpSettings bench_gicp_settings() {
  GicpSettings gs;  // library defaults (k = 10, epsilon 1e-3, 30 iterations) but a 5 cm cap
  gs.max_correspondence_distance_m = 0.05f;
  if (translation_eps_m >= 0) gs.translation_epsilon_m = translation_eps_m;
  if (rotation_eps_rad >= 0) gs.rotation_epsilon_rad = rotation_eps_rad;
  return gs;
}

IcpSettings bench_icp_settings() {
  IcpSettings is;
  is.max_correspondence_distance_m = 0.05f;
  if (translation_eps_m >= 0) is.translation_epsilon_m = translation_eps_m;
  if (rotation_eps_rad >= 0) is.rotation_epsilon_rad = rotation_eps_rad;
  return is;
}

Scores score(const Problem& p, const std::vector<Pose>& T, const std::vector<std::uint8_t>& converged,
             const std::vector<int>& passes) {
  CloudBatch moved = p.sources;
  for (std::size_t h = 0; h < p.sources.num_clouds(); ++h)
    for (auto i = p.sources.offsets[h]; i < p.sources.offsets[h + 1]; ++i) {
      const Eigen::Vector3f q = T[h] * Eigen::Vector3f(moved.x[i], moved.y[i], moved.z[i]);
      moved.x[i] = q.x(), moved.y[i] = q.y(), moved.z[i] = q.z();
    }
  cpu::KnnIndex index(p.target);
  KnnSettings ks;
  ks.k = 1;
  const KnnResult nn = index.knn(moved, p.segment, ks);
  std::vector<double> rms, disp;
  Scores s;
  for (std::size_t h = 0; h < p.sources.num_clouds(); ++h) {
    double sq = 0, d = 0;
    const auto b = p.sources.offsets[h], e = p.sources.offsets[h + 1];
    for (auto i = b; i < e; ++i) {
      sq += nn.sq_distance_m2[std::size_t(i)];
      const Eigen::Vector3f x(p.sources.x[i], p.sources.y[i], p.sources.z[i]);
      d += (T[h] * x - p.ideal[h] * x).norm();
    }
    const double n = double(std::max<std::int64_t>(e - b, 1));
    rms.push_back(std::sqrt(sq / n) * 1e3);
    disp.push_back(d / n * 1e3);
    s.within_1mm += disp.back() < 1.0;
    s.converged += converged[h] ? 1 : 0;
  }
  const double N = double(rms.size());
  for (double x : rms) s.mean_rms_mm += x / N;
  s.within_1mm /= N;
  if (!passes.empty()) {
    s.mean_passes = 0;
    for (int n : passes) s.mean_passes += double(n) / N;
  }
  s.converged /= N;
  std::nth_element(rms.begin(), rms.begin() + rms.size() / 2, rms.end());
  std::nth_element(disp.begin(), disp.begin() + disp.size() / 2, disp.end());
  s.median_rms_mm = rms[rms.size() / 2];
  s.median_disp_mm = disp[disp.size() / 2];
  return s;
}

/// Resets the kernel's peak-RSS mark (VmHWM, also what getrusage ru_maxrss reports) to the current RSS.
void reset_peak_rss() {
  if (FILE* f = std::fopen("/proc/self/clear_refs", "w")) {
    std::fputs("5", f);
    std::fclose(f);
  }
}

/// --load N: the busy processes of this method's process; quiet and loaded runs then alternate.
const bench::CompetingLoad* competing = nullptr;

/// Runs `job` `runs` times in this process (a fresh one per method, see main); memory is measured from the
/// RSS after the problem was built. With --load, `runs` quiet runs alternate with `runs` loaded ones
/// (bench::CompetingLoad::pause/resume) and median_s is the loaded median.
Measured measure(int runs, const std::function<void(std::vector<Pose>&, std::vector<std::uint8_t>&)>& job,
                 std::vector<Pose>& T, std::vector<std::uint8_t>& conv) {
  reset_peak_rss();
  const long base = current_rss_kb();
  const auto timed = [&] { job(T, conv); };
  std::vector<double> t, quiet;
  if (competing) {
    auto both = bench::seconds_quiet_loaded(runs, *competing, timed);
    quiet = std::move(both[0]), t = std::move(both[1]);
  } else {
    for (int r = 0; r < runs; ++r) {
      const double t0 = now_s();
      timed();
      t.push_back(now_s() - t0);
    }
  }
  Measured m{bench::median(t), *std::min_element(t.begin(), t.end()), 0, peak_rss_kb(),
             std::max(0L, peak_rss_kb() - base)};
  m.quiet_median_s = quiet.empty() ? m.median_s : bench::median(quiet);
  return m;
}

void row(const char* name, const Measured& m, const Scores& s, std::size_t num, double ref_rate) {
  const double rate = double(num) / m.median_s;
  std::printf("| %-28s | %8.3f | %9.0f | %6.2fx |", name, m.median_s, rate,
              ref_rate > 0 ? rate / ref_rate : 1.0);
  if (competing)
    std::printf(" %9.0f | %4.0f%% |", double(num) / m.quiet_median_s, 100 * m.quiet_median_s / m.median_s);
  std::printf(" %8.1f | %8.1f | %8.3f | %8.3f | %8.3f | %5.1f%% | %5.1f%% | %6.2f |\n",
              double(m.peak_kb) / 1024, double(m.growth_kb) / 1024, s.median_rms_mm, s.mean_rms_mm,
              s.median_disp_mm, 100 * s.within_1mm, 100 * s.converged, s.mean_passes);
  std::fflush(stdout);
}

}  // namespace

/// Runs one method in this process and prints its table row and "rate=<alignments/s>".
int run_method(const std::string& method, int num_sources, int runs, const std::string& model,
               double peer_rate) {
  io::MeshLoadOptions opt;
  opt.scale = model_scale;
  const Mesh mesh = io::load_mesh(model, opt);
  std::mt19937 rng(2020);
  const Problem p = make_problem(mesh, num_sources, rng);
  const std::size_t num = p.sources.num_clouds();
  if (method == "info") {
    std::printf(
        "%zu sources (%.0f points each on average) -> one target of %zu points; %d runs, median; "
        "%d OpenMP threads; model %s\n",
        num, double(p.sources.size()) / double(num), p.target.size(), runs, omp_get_max_threads(),
        model.c_str());
    return 0;
  }
  const GicpSettings gs = bench_gicp_settings();
  const IcpSettings is = bench_icp_settings();
  std::vector<Pose> T;
  std::vector<std::uint8_t> conv;
  std::vector<int> passes;  // filled by the methods that report it
  Measured m;
  const char* name = "";
  if (method == "small_gicp") {
#ifdef PERCH2_HAVE_SMALL_GICP
    name = "small_gicp 1.0.1 GICP";
    using small_gicp::PointCloud;
    auto to_cloud = [](const CloudBatch& b, std::size_t c) {
      std::vector<Eigen::Vector4d> pts;
      for (auto i = b.offsets[c]; i < b.offsets[c + 1]; ++i) pts.emplace_back(b.x[i], b.y[i], b.z[i], 1.0);
      return std::make_shared<PointCloud>(pts);
    };
    m = measure(
        runs,
        [&](std::vector<Pose>& Tout, std::vector<std::uint8_t>& cout) {
          Tout.assign(num, Pose::Identity());
          cout.assign(num, 0);
          passes.assign(num, 0);
          const int threads = omp_get_max_threads();
          const auto target = to_cloud(p.target, 0);  // target structures once, as perch2 does
          const small_gicp::KdTree<PointCloud> tree(target, small_gicp::KdTreeBuilderOMP(threads));
          small_gicp::estimate_covariances_omp(*target, tree, gs.k_neighbors, threads);
          small_gicp::Registration<small_gicp::GICPFactor, CountingReduction> reg;
          reg.rejector.max_dist_sq =
              double(gs.max_correspondence_distance_m) * gs.max_correspondence_distance_m;
          reg.criteria.translation_eps = gs.translation_epsilon_m;
          reg.criteria.rotation_eps = gs.rotation_epsilon_rad;
          reg.optimizer.max_iterations = gs.max_iterations;
#pragma omp parallel for schedule(dynamic)
          for (std::ptrdiff_t h = 0; h < std::ptrdiff_t(num); ++h) {
            const auto source = to_cloud(p.sources, std::size_t(h));
            const small_gicp::KdTree<PointCloud> source_tree(source);
            small_gicp::estimate_covariances(*source, source_tree, gs.k_neighbors);
            CountingReduction::passes = 0;
            const auto r = reg.align(*target, *source, tree);
            Tout[std::size_t(h)] = Pose(r.T_target_source.cast<float>().matrix());
            cout[std::size_t(h)] = r.converged ? 1 : 0;
            passes[std::size_t(h)] = CountingReduction::passes;
          }
        },
        T, conv);
#else
    std::printf("| small_gicp                   | not built: run ./run.sh bench (unpacks its headers) |\n");
    return 0;
#endif
  } else if (method == "pcl") {
#ifdef PERCH2_HAVE_PCL
    name = "PCL GICP (OpenMP over pairs)";
    using Cloud = pcl::PointCloud<pcl::PointXYZ>;
    auto to_pcl = [](const CloudBatch& b, std::size_t c) {
      Cloud::Ptr out(new Cloud);
      for (auto i = b.offsets[c]; i < b.offsets[c + 1]; ++i)
        out->push_back(pcl::PointXYZ(b.x[i], b.y[i], b.z[i]));
      return out;
    };
    m = measure(
        runs,
        [&](std::vector<Pose>& Tout, std::vector<std::uint8_t>& cout) {
          Tout.assign(num, Pose::Identity());
          cout.assign(num, 0);
          const Cloud::Ptr target = to_pcl(p.target, 0);
#pragma omp parallel
          {
            pcl::GeneralizedIterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> gicp;
            gicp.setInputTarget(target);
            gicp.setCorrespondenceRandomness(gs.k_neighbors);
            gicp.setMaxCorrespondenceDistance(gs.max_correspondence_distance_m);
            gicp.setMaximumIterations(gs.max_iterations);
            gicp.setTransformationEpsilon(gs.translation_epsilon_m);
            gicp.setRotationEpsilon(gs.rotation_epsilon_rad);
            Cloud aligned;
#pragma omp for schedule(dynamic)
            for (std::ptrdiff_t h = 0; h < std::ptrdiff_t(num); ++h) {
              gicp.setInputSource(to_pcl(p.sources, std::size_t(h)));
              gicp.align(aligned);
              Tout[std::size_t(h)].matrix() = gicp.getFinalTransformation();
              cout[std::size_t(h)] = gicp.hasConverged() ? 1 : 0;
            }
          }
        },
        T, conv);
#else
    std::printf(
        "| PCL GICP                     | not built: PCL (registration) not found at configure time |\n");
    return 0;
#endif
  } else {
    auto ours = [&](auto tag, bool gicp) {
      using Reg = typename decltype(tag)::Registration;
      return measure(
          runs,
          [&](std::vector<Pose>& Tout, std::vector<std::uint8_t>& cout) {
            const Reg reg(p.target);  // includes the target index (and, for GICP, target covariances)
            const RegistrationResult r =
                gicp ? reg.gicp(p.sources, p.segment, gs) : reg.icp(p.sources, p.segment, is);
            Tout = r.T_corr;
            cout = r.converged;
            passes = r.iterations;
          },
          T, conv);
    };
    if (method == "cpu_gicp")
      name = "perch2 cpu GICP", m = ours(cpu::Backend{}, true);
    else if (method == "omp_gicp")
      name = "perch2 thrust_omp GICP", m = ours(thrust_omp::Backend{}, true);
    else if (method == "cpu_icp")
      name = "perch2 cpu ICP", m = ours(cpu::Backend{}, false);
    else if (method == "omp_icp")
      name = "perch2 thrust_omp ICP", m = ours(thrust_omp::Backend{}, false);
#ifdef PERCH2_HAVE_CUDA
    else if (method == "cuda_gicp" || method == "cuda_icp") {
      const bool gicp = method == "cuda_gicp";
      name = gicp ? "perch2 cuda GICP" : "perch2 cuda ICP";
      if (cuda::device_count() == 0) {
        std::printf("| %-28s | skipped: %s |\n", name, cuda::device_summary().c_str());
        return 0;
      }
      m = ours(cuda::Backend{}, gicp);
    }
#endif
    else {
      std::fprintf(stderr, "unknown method %s\n", method.c_str());
      return 2;
    }
  }
  row(name, m, score(p, T, conv, passes), num, peer_rate);
  std::printf("rate=%.6g\n", double(num) / m.median_s);
  return 0;
}

int main(int argc, char** argv) {
  int num_sources = 2400, runs = 3;
  std::string model, method;
  double peer_rate = 0;
  bool use_pcl = true;
  int load = 0;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--sources" && i + 1 < argc)
      num_sources = std::atoi(argv[++i]);
    else if (a == "--runs" && i + 1 < argc)
      runs = std::max(1, std::atoi(argv[++i]));
    else if (a == "--model" && i + 1 < argc)
      model = argv[++i];
    else if (a == "--method" && i + 1 < argc)
      method = argv[++i];
    else if (a == "--peer-rate" && i + 1 < argc)
      peer_rate = std::atof(argv[++i]);
    else if (a == "--no-pcl")
      use_pcl = false;
    else if (a == "--translation-eps" && i + 1 < argc)
      translation_eps_m = float(std::atof(argv[++i]));
    else if (a == "--rotation-eps" && i + 1 < argc)
      rotation_eps_rad = float(std::atof(argv[++i]));
    else if (a == "--scale" && i + 1 < argc)
      model_scale = float(std::atof(argv[++i]));
    else if (a == "--load" && i + 1 < argc)
      load = std::atoi(argv[++i]);
    else {
      std::fprintf(stderr, "usage: %s [--sources N] [--runs R] [--model obj_06.ply] [--no-pcl]\n", argv[0]);
      return 2;
    }
  }
  model = find_model(model);
  if (model.empty()) {
    std::fprintf(stderr, "LINEMOD cat model not found: pass --model path/to/obj_06.ply\n");
    return 2;
  }
  if (!method.empty()) {
    const bench::CompetingLoad load_processes(load);
    if (load > 0) competing = &load_processes;
    return run_method(method, num_sources, runs, model, peer_rate);
  }

  // One fresh process per method: separate peak-memory figures, and no OpenMP state shared across methods.
  auto run = [&](const std::string& m) {
    const std::string cmd = std::string(argv[0]) + " --method " + m + " --sources " +
                            std::to_string(num_sources) + " --runs " + std::to_string(runs) + " --model '" +
                            model + "' --peer-rate " + std::to_string(peer_rate) + " --translation-eps " +
                            bench::format("%g", translation_eps_m) + " --rotation-eps " +
                            bench::format("%g", rotation_eps_rad) + " --scale " +
                            bench::format("%g", model_scale) + " --load " + std::to_string(load);
    FILE* f = popen(cmd.c_str(), "r");
    if (!f) return;
    char line[1024];
    while (std::fgets(line, sizeof line, f)) {
      if (std::strncmp(line, "rate=", 5) == 0) {
        if (peer_rate == 0 && (m == "small_gicp" || m == "pcl")) peer_rate = std::atof(line + 5);
      } else {
        std::fputs(line, stdout);
      }
    }
    pclose(f);
    std::fflush(stdout);
  };
  std::printf("bench_registration: ");
  std::fflush(stdout);
  run("info");
  const GicpSettings gs = bench_gicp_settings();
  std::printf(
      "settings: max_correspondence_distance %.3f m, max_iterations %d, epsilons %.0e m / %.0e rad, "
      "k %d, covariance epsilon %.0e (small_gicp and PCL GICP get the same values); %d competing busy "
      "processes%s\n\n",
      gs.max_correspondence_distance_m, gs.max_iterations, gs.translation_epsilon_m, gs.rotation_epsilon_rad,
      gs.k_neighbors, gs.covariance_epsilon, load,
      load > 0 ? " (median s, aligns/s, vs peer: loaded runs; quiet aligns/s: the quiet runs alternating "
                 "with them; kept: loaded / quiet)"
               : "");
  std::printf(
      "| method                       | median s | aligns/s | vs peer |%s peak MB  | growth MB| med RMS mm| "
      "mean RMS mm| med disp mm| <1mm  | conv   | passes |\n",
      load > 0 ? " quiet aligns/s | kept |" : "");
  std::printf("|---|---|---|---|%s---|---|---|---|---|---|---|---|\n", load > 0 ? "---|---|" : "");
  run("small_gicp");  // the peer the ratio column refers to (PCL when small_gicp is not built)
  if (use_pcl) run("pcl");
  for (const char* m : {"cpu_gicp", "omp_gicp", "cpu_icp", "omp_icp"}) run(m);
#ifdef PERCH2_HAVE_CUDA
  for (const char* m : {"cuda_gicp", "cuda_icp"}) run(m);
#endif
  std::printf(
      "\nRMS: nearest-neighbour distance of the aligned source to the target; disp: mean distance of the\n"
      "aligned source points from their ideal positions (the known perturbation undone); <1mm: share of\n"
      "hypotheses with disp < 1 mm; conv: share reported converged; passes: correspondence passes per "
      "source\n"
      "(-1: not reported). peak: the method's peak RSS (reset\n"
      "after the problem was built); growth: that peak minus the RSS before the method ran.\n");
  return 0;
}
