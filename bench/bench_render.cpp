// Render throughput and peak memory: 2,000 poses of a ~10k-triangle mesh, 640x480, strides 1/4/8, per
// backend.
//   bench_render [--runs N] [--poses N] [--stride S] [--backend embree|cpu|thrust_omp|cuda]
//                [--model FILE --scale S] [--load N] [--budget-mib M]
//                [--embree-trace 1|1M|8|16|all] [--embree-quality low|medium|high|all] [--interleave 1]
// --load N runs N busy processes alongside (a shared CPU): each row then alternates quiet and loaded runs
// (the busy processes stopped and continued) and reports the loaded rate and the share of the quiet rate it
// kept, both from the same run. Embree (libembree-dev) is the peer when found: --embree-trace and
// --embree-quality choose how it traces and builds (`all`: one row per choice, the first one the reference);
// before the rows, the peer's clouds are compared with perch2's (points per hypothesis, pixels, colours).
// --interleave 1: instead of the table, the peer configurations, cpu and thrust_omp timed in turns in one
// process, for ratios that hold on a machine whose speed drifts (no peak memory); with --load N each turn
// renders once quiet and once beside the busy processes, and both tables come from the same rounds.
// Default mesh: a procedural 10,224-triangle lumpy sphere with vertex colours (always available); with
// ../shared/data present the YCB banana (15,728 triangles, 4096^2 texture) is measured too.
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <random>
#include <string>

#include "bench_support.hpp"
#include "perch2/cpu/backend.hpp"
#include "perch2/cuda/backend.hpp"
#ifdef PERCH2_HAVE_CUDA
#include "perch2/cuda/device.hpp"
#endif
#include "perch2/io/io.hpp"
#include "render_fixtures.hpp"
#ifdef PERCH2_HAVE_EMBREE
#include "embree_peer.hpp"
#endif

using namespace perch2;

namespace {

using bench::poses;

std::vector<int> strides = {1, 4, 8};
std::string only_backend;
std::size_t budget_bytes = 0;  // --budget-mib: RenderSettings::memory_budget_bytes (0: the backend default)
const bench::CompetingLoad* competing = nullptr;  // --load: quiet and loaded runs alternate per row
#ifdef PERCH2_HAVE_EMBREE
std::vector<bench::EmbreeTrace> embree_traces = {bench::EmbreeSettings{}.trace};
std::vector<RTCBuildQuality> embree_qualities = {bench::EmbreeSettings{}.quality};
#endif

template <class Renderer, class... Options>
void measure(const std::string& backend, Mesh& mesh, const std::vector<Hypothesis>& hyps, int runs,
             double reference_rate[3], const Options&... options) {
  const Intrinsics K{615.f, 615.f, 319.5f, 239.5f, 640, 480};
  for (std::size_t k = 0; k < strides.size(); ++k) {
    RenderSettings s;
    s.stride = strides[k];
    s.memory_budget_bytes = budget_bytes;
    const auto [seconds, quiet_seconds, points, peak_mib] = bench::in_child([&] {
      // The child's copy-on-write image of the mesh is handed over as a user hands over a loaded model.
      std::vector<Mesh> models(1);
      models[0] = std::move(mesh);
      const Renderer renderer(std::move(models), options...);
      std::size_t n = 0;
      const auto render = [&] { n = renderer.render(hyps, K, s).size(); };
      if (!competing) {
        const double t = bench::median_seconds(runs, render);
        return std::array<double, 3>{t, t, double(n)};
      }
      const auto [quiet, loaded] = bench::median_seconds_quiet_loaded(runs, *competing, render);
      return std::array<double, 3>{loaded, quiet, double(n)};
    });
    const double rate = double(hyps.size()) / seconds;
    if (reference_rate[k] == 0) reference_rate[k] = rate;
    std::printf("| %-10s | %6d | %12.0f | %8.2fx |", backend.c_str(), strides[k], rate,
                rate / reference_rate[k]);
    if (competing)
      std::printf(" %11.0f | %4.0f%% |", double(hyps.size()) / quiet_seconds, 100 * quiet_seconds / seconds);
    std::printf(" %10.0f | %9.0f |\n", double(points) / double(hyps.size()), peak_mib);
    std::fflush(stdout);
  }
}

#ifdef PERCH2_HAVE_EMBREE
/// The peer's clouds against perch2's (`cpu`) for the same poses, per stride: hypotheses whose point counts
/// differ, and of the samples at the same pixel, how many have another colour or depth.
void compare_with_peer(Mesh& mesh, const std::vector<Hypothesis>& hyps) {
  const Intrinsics K{615.f, 615.f, 319.5f, 239.5f, 640, 480};
  for (const int stride : strides) {
    const auto r = bench::in_child([&] {
      RenderSettings s;
      s.stride = stride;
      const CloudBatch ours = cpu::Renderer({mesh}).render(hyps, K, s);
      const CloudBatch peer =
          bench::EmbreeRenderer({mesh}, {embree_traces[0], embree_qualities[0]}).render(hyps, K, s);
      double count_differs = 0, same_pixel = 0, colour_differs = 0, depth_differs = 0;
      for (std::size_t h = 0; h < hyps.size(); ++h) {
        const std::int64_t a0 = ours.offsets[h], a1 = ours.offsets[h + 1];
        const std::int64_t b0 = peer.offsets[h], b1 = peer.offsets[h + 1];
        count_differs += (a1 - a0) != (b1 - b0);
        for (std::int64_t a = a0, b = b0; a < a1 && b < b1;) {  // both in raster order
          if (ours.pixel[a] < peer.pixel[b]) {
            ++a;
          } else if (peer.pixel[b] < ours.pixel[a]) {
            ++b;
          } else {
            ++same_pixel;
            colour_differs += ours.rgb[a] != peer.rgb[b];
            depth_differs += std::abs(ours.z[a] - peer.z[b]) > 1e-4f * ours.z[a];
            ++a, ++b;
          }
        }
      }
      return std::array<double, 6>{count_differs, double(ours.size()), double(peer.size()),
                                   same_pixel,    colour_differs,      depth_differs};
    });
    std::printf(
        "stride %d, Embree (%s, %s build) against cpu: %.0f of %zu hypotheses with another point count; "
        "points %.0f / %.0f; of %.0f samples at the same pixel %.0f have another colour, %.0f a depth off by "
        "> 1e-4 x depth\n",
        stride, bench::trace_name(embree_traces[0]), bench::quality_name(embree_qualities[0]), r[0],
        hyps.size(), r[2], r[1], r[3], r[4], r[5]);
  }
}
#endif

#ifdef PERCH2_HAVE_EMBREE
/// --interleave: every peer configuration asked for (--embree-trace, --embree-quality), cpu and thrust_omp
/// built in one process and timed in turns, one render each per round (the order rotated), so a host whose
/// speed drifts with other sessions' load slows them all alike; each one's rate is the median over the
/// rounds, its ratio to the first peer the median of the per-round ratios. With --load, each turn is a
/// quiet render (the busy processes stopped) then one beside them; kept = quiet / loaded median time.
void interleaved(Mesh& mesh, const std::vector<Hypothesis>& hyps, int runs) {
  const Intrinsics K{615.f, 615.f, 319.5f, 239.5f, 640, 480};
  std::vector<std::unique_ptr<bench::EmbreeRenderer>> peers;
  std::vector<std::string> names;
  for (const bench::EmbreeTrace trace : embree_traces)
    for (const RTCBuildQuality quality : embree_qualities) {
      peers.push_back(std::make_unique<bench::EmbreeRenderer>(std::vector<Mesh>{mesh},
                                                              bench::EmbreeSettings{trace, quality}));
      names.push_back(std::string("Embree 3 ") + bench::trace_name(trace) + " " +
                      bench::quality_name(quality));
    }
  const cpu::Renderer ours_cpu({mesh});
  const thrust_omp::Backend::Renderer ours_thrust({mesh});
  names.push_back("cpu");
  names.push_back("thrust_omp");
  const std::size_t n = names.size();
  for (const int stride : strides) {
    RenderSettings s;
    s.stride = stride;
    std::vector<std::function<void()>> render;
    for (const auto& peer : peers) render.push_back([&, p = peer.get()] { p->render(hyps, K, s); });
    render.push_back([&] { ours_cpu.render(hyps, K, s); });
    render.push_back([&] { ours_thrust.render(hyps, K, s); });
    for (const auto& f : render) f();  // warm-up
    // Pass 0: quiet; pass 1 (with --load): beside the busy processes.
    const int passes = competing ? 2 : 1;
    std::vector<std::vector<double>> seconds[2], ratio[2];
    for (int pass = 0; pass < passes; ++pass) seconds[pass].resize(n), ratio[pass].resize(n);
    for (int r = 0; r < runs; ++r) {
      std::vector<double> t[2] = {std::vector<double>(n), std::vector<double>(n)};
      for (std::size_t k = 0; k < n; ++k) {
        const std::size_t b = (std::size_t(r) + k) % n;
        for (int pass = 0; pass < passes; ++pass) {
          if (competing) pass ? competing->resume() : competing->pause();
          const auto t0 = std::chrono::steady_clock::now();
          render[b]();
          t[pass][b] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        }
      }
      for (int pass = 0; pass < passes; ++pass)
        for (std::size_t b = 0; b < n; ++b)
          seconds[pass][b].push_back(t[pass][b]), ratio[pass][b].push_back(t[pass][0] / t[pass][b]);
    }
    if (competing) competing->resume();
    for (std::size_t b = 0; b < n; ++b) {
      std::printf("| %-30s | %6d |", names[b].c_str(), stride);
      for (int pass = 0; pass < passes; ++pass) {
        const auto [lo, hi] = std::minmax_element(ratio[pass][b].begin(), ratio[pass][b].end());
        std::printf(" %12.0f | %8.2fx | %.2f-%.2fx |", double(hyps.size()) / bench::median(seconds[pass][b]),
                    bench::median(ratio[pass][b]), *lo, *hi);
      }
      if (competing)
        std::printf(" %4.0f%% |", 100 * bench::median(seconds[0][b]) / bench::median(seconds[1][b]));
      std::printf("\n");
    }
    std::fflush(stdout);
  }
}
#endif

void run(Mesh mesh, int num_poses, int runs, bool interleave) {
  const auto hyps = poses(num_poses, mesh);
  std::printf("\n%s: %zu triangles, %s, %d poses, 640x480, median of %d runs\n\n", mesh.name.c_str(),
              mesh.triangles.size(), mesh.has_texture() ? "textured" : "vertex colours", num_poses, runs);
#ifdef PERCH2_HAVE_EMBREE
  if (only_backend.empty() || only_backend == "embree") {
    compare_with_peer(mesh, hyps);
    std::printf("\n");
  }
#endif
#ifdef PERCH2_HAVE_EMBREE
  if (interleave) {
    if (competing) {
      std::printf(
          "| backend | stride | quiet: hypotheses/s | vs first (median of rounds) | range | beside the busy "
          "processes: hypotheses/s | vs first | range | kept |\n");
      std::printf("|---|---|---|---|---|---|---|---|---|\n");
    } else {
      std::printf("| backend | stride | hypotheses/s | vs first (median of rounds) | range |\n");
      std::printf("|---|---|---|---|---|\n");
    }
    // In a child, as every measurement: OpenMP and Embree threads started here would hang later forks.
    std::fflush(stdout);  // or the child prints what this process buffered too
    bench::in_child([&] {
      interleaved(mesh, hyps, runs);
      return std::array<double, 0>{};
    });
    return;
  }
#endif
  if (competing) {
    std::printf(
        "| backend    | stride | hypotheses/s | vs first | quiet hyp/s | kept | points/hyp | peak MiB* |\n");
    std::printf(
        "|------------|--------|--------------|----------|-------------|------|------------|-----------|\n");
  } else {
    std::printf("| backend    | stride | hypotheses/s | vs first | points/hyp | peak MiB* |\n");
    std::printf("|------------|--------|--------------|----------|------------|-----------|\n");
  }
  double reference[3] = {0, 0, 0};  // the first row measured: Embree when built with it, else cpu
#ifdef PERCH2_HAVE_EMBREE
  if (only_backend.empty() || only_backend == "embree")
    for (const bench::EmbreeTrace trace : embree_traces)
      for (const RTCBuildQuality quality : embree_qualities) {
        const bench::EmbreeSettings settings{trace, quality};
        const std::string name =
            embree_traces.size() * embree_qualities.size() == 1
                ? std::string("Embree 3")
                : std::string("Embree 3 ") + bench::trace_name(trace) + " " + bench::quality_name(quality);
        measure<bench::EmbreeRenderer>(name, mesh, hyps, runs, reference, settings);
      }
#else
  std::printf("| Embree 3   | (not built: install libembree-dev and reconfigure) |\n");
#endif
  if (only_backend.empty() || only_backend == "cpu")
    measure<cpu::Renderer>("cpu", mesh, hyps, runs, reference);
  if (only_backend.empty() || only_backend == "thrust_omp")
    measure<thrust_omp::Backend::Renderer>("thrust_omp", mesh, hyps, runs, reference);
#ifdef PERCH2_HAVE_CUDA
  if (only_backend.empty() || only_backend == "cuda") {
    // Asked in a child: CUDA must not be initialised in this process before measure() forks a child using it.
    if (bench::in_child([] { return std::array<double, 1>{double(cuda::device_count())}; })[0] > 0)
      measure<cuda::Backend::Renderer>("cuda", mesh, hyps, runs, reference);
    else
      std::printf("| cuda       | skipped: %s |\n", cuda::device_summary().c_str());
  }
#endif
}

}  // namespace

int main(int argc, char** argv) {
  int runs = 5, num_poses = 2000, load = 0;
  bool interleave = false;
  std::string model;
  float scale = 1.f;
  for (int k = 1; k + 1 < argc; k += 2) {
    const std::string a = argv[k];
    if (a == "--runs")
      runs = std::stoi(argv[k + 1]);
    else if (a == "--poses")
      num_poses = std::stoi(argv[k + 1]);
    else if (a == "--stride")
      strides = {std::stoi(argv[k + 1])};
    else if (a == "--backend")
      only_backend = argv[k + 1];
    else if (a == "--model")
      model = argv[k + 1];
    else if (a == "--scale")
      scale = std::stof(argv[k + 1]);
    else if (a == "--budget-mib")
      budget_bytes = std::size_t(std::stod(argv[k + 1]) * 1024 * 1024);
    else if (a == "--load")
      load = std::stoi(argv[k + 1]);
    else if (a == "--interleave")
      interleave = std::stoi(argv[k + 1]) != 0;
#ifdef PERCH2_HAVE_EMBREE
    else if (a == "--embree-trace")
      embree_traces =
          std::string(argv[k + 1]) == "all"
              ? std::vector<bench::EmbreeTrace>{bench::EmbreeTrace::One, bench::EmbreeTrace::Stream,
                                                bench::EmbreeTrace::Packet8, bench::EmbreeTrace::Packet16}
              : std::vector<bench::EmbreeTrace>{bench::parse_trace(argv[k + 1])};
    else if (a == "--embree-quality")
      embree_qualities = std::string(argv[k + 1]) == "all"
                             ? std::vector<RTCBuildQuality>{RTC_BUILD_QUALITY_LOW, RTC_BUILD_QUALITY_MEDIUM,
                                                            RTC_BUILD_QUALITY_HIGH}
                             : std::vector<RTCBuildQuality>{bench::parse_quality(argv[k + 1])};
#endif
  }
  std::printf("bench_render on %s, %d threads, %d competing busy processes%s\n", bench::cpu_model().c_str(),
              omp_get_max_threads(), load,
              load > 0 ? " (hypotheses/s and vs first: loaded runs; quiet hyp/s: the quiet runs in between; "
                         "kept: loaded / quiet)"
                       : "");
  const bench::CompetingLoad load_processes(load);
  if (load > 0) competing = &load_processes;
  std::printf(
      "* peak MiB: peak resident memory of a process that holds the loaded mesh, builds the renderer and "
      "renders the batch (one process per row)\n");
  run(test::lumpy_sphere(0.06f, 71, 72), num_poses, runs, interleave);
  const std::string banana =
      model.empty() ? std::string(PERCH2_SHARED_DATA_DIR) + "/models/ycb_011_banana/textured_simple.obj"
                    : model;
  if (std::filesystem::exists(banana)) {
    io::MeshLoadOptions options;
    options.scale = scale;
    run(io::load_mesh(banana, options), num_poses, runs, interleave);
  } else {
    std::printf("\n(%s not found: real-mesh rows skipped)\n", banana.c_str());
  }
  return 0;
}
