// Render throughput and peak memory: 2,000 poses of a ~10k-triangle mesh, 640x480, strides 1/4/8, per
// backend.
//   bench_render [--runs N] [--poses N] [--stride S] [--backend embree|cpu|thrust_omp|cuda]
//                [--model FILE --scale S] [--load N] [--budget-mib M]
// --load N runs N busy processes alongside (a shared CPU): each row then alternates quiet and loaded runs
// (the busy processes stopped and continued) and reports the loaded rate and the share of the quiet rate it
// kept, both from the same run. Embree (libembree-dev) is the peer when found.
// Default mesh: a procedural 10,224-triangle lumpy sphere with vertex colours (always available); with
// ../shared/data present the YCB banana (15,728 triangles, 4096^2 texture) is measured too.
#include <omp.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
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

template <class Renderer>
void measure(const char* backend, Mesh& mesh, const std::vector<Hypothesis>& hyps, int runs,
             double reference_rate[3]) {
  const Intrinsics K{615.f, 615.f, 319.5f, 239.5f, 640, 480};
  for (std::size_t k = 0; k < strides.size(); ++k) {
    RenderSettings s;
    s.stride = strides[k];
    s.memory_budget_bytes = budget_bytes;
    const auto [seconds, quiet_seconds, points, peak_mib] = bench::in_child([&] {
      // The child's copy-on-write image of the mesh is handed over as a user hands over a loaded model.
      std::vector<Mesh> models(1);
      models[0] = std::move(mesh);
      const Renderer renderer(std::move(models));
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
    std::printf("| %-10s | %6d | %12.0f | %8.2fx |", backend, strides[k], rate, rate / reference_rate[k]);
    if (competing)
      std::printf(" %11.0f | %4.0f%% |", double(hyps.size()) / quiet_seconds, 100 * quiet_seconds / seconds);
    std::printf(" %10.0f | %9.0f |\n", double(points) / double(hyps.size()), peak_mib);
    std::fflush(stdout);
  }
}

void run(Mesh mesh, int num_poses, int runs) {
  const auto hyps = poses(num_poses, mesh);
  std::printf("\n%s: %zu triangles, %s, %d poses, 640x480, median of %d runs\n\n", mesh.name.c_str(),
              mesh.triangles.size(), mesh.has_texture() ? "textured" : "vertex colours", num_poses, runs);
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
    measure<bench::EmbreeRenderer>("Embree 3", mesh, hyps, runs, reference);
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
  run(test::lumpy_sphere(0.06f, 71, 72), num_poses, runs);
  const std::string banana =
      model.empty() ? std::string(PERCH2_SHARED_DATA_DIR) + "/models/ycb_011_banana/textured_simple.obj"
                    : model;
  if (std::filesystem::exists(banana)) {
    io::MeshLoadOptions options;
    options.scale = scale;
    run(io::load_mesh(banana, options), num_poses, runs);
  } else {
    std::printf("\n(%s not found: real-mesh rows skipped)\n", banana.c_str());
  }
  return 0;
}
