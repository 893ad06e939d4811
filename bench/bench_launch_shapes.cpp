// Launch shapes of the Thrust stages, per System, on the benchmark problems: how many work items each pass
// launches (the parallelism a GPU would see), how a render batch is chunked under the memory budget, and how
// many device allocations a call makes (cold, then warm). Not a timing: the figures depend only on the
// System's work-item sizes and budgets (perch2/cuda/system.hpp, launch_plan.hpp), so a GPU user can read the
// CUDA shapes on a machine without a GPU.
//   thrust_omp rows are measured: the stage runs and reports last_launch_shape().
//   cuda rows are planned with CudaSystem's constants by the same planning code the stage launches from
//   (the CUDA build runs the same source; it adds only CUB's scan/count temporaries, cached per stage
//   object).
//
//   bench_launch_shapes [--poses 2000] [--sources 2400]
#include <omp.h>

#include <algorithm>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "bench_support.hpp"
#include "perch2/cuda/backend.hpp"
#include "perch2/cuda/launch_plan.hpp"
#include "perch2/render/mesh_arrays.hpp"
#include "render_fixtures.hpp"

using namespace perch2;
using thrust_backend::CudaSystem;
using thrust_backend::LaunchShape;
using thrust_backend::OmpSystem;

namespace {

const Intrinsics kCamera{615.f, 615.f, 319.5f, 239.5f, 640, 480};

void print_pass(const char* system, const std::string& problem, const LaunchShape::Pass& p) {
  std::printf("| %-11s | %-26s | %-18s | %5d | %8lld | %12lld | %13lld |\n", system, problem.c_str(),
              p.name.c_str(), p.elements_per_item, (long long)p.launches, (long long)p.max_items,
              (long long)p.items);
}

/// Parallel launches of a call (on OpenMP each is a parallel region ending in a barrier).
std::int64_t launches(const LaunchShape& shape) {
  std::int64_t n = 0;
  for (const auto& p : shape.passes) n += p.launches;
  return n;
}

void print_header() {
  std::printf(
      "| system      | problem                    | pass               | el/it | launches | items/launch |"
      " items (total) |\n");
  std::printf(
      "|-------------|----------------------------|--------------------|-------|----------|--------------|"
      "---------------|\n");
}

/// The renderer's launches for a System's work-item size and budget, from the same plan render() uses.
template <class System>
LaunchShape planned_render(const MeshArrays& mesh, const std::vector<Hypothesis>& hyps, int stride) {
  const MeshView view = mesh.host_view();
  const int n = int(hyps.size());
  std::vector<std::int64_t> vertices(n, std::int64_t(mesh.vertices.size())),
      triangles(n, std::int64_t(mesh.triangles.size() / 3)), samples(n);
  RenderSettings s;
  for (int k = 0; k < n; ++k)
    samples[k] = model_roi(view, to_rigid(hyps[k].T_cam_obj), kCamera, stride, s.near_m).size();
  const int block = System::render_elements_per_item;
  LaunchShape shape;
  shape.launch("roi", 1, n);
  for (const auto& ch :
       thrust_backend::plan_render_chunks(vertices, triangles, samples, System::default_chunk_bytes, block)) {
    shape.launch("transform_vertices", block, ch.vertices.blocks.back());
    shape.launch("rasterize", block, ch.triangles.blocks.back());
    shape.launch("resolve", block, ch.pixels.blocks.back());
    shape.launch("scatter", block, ch.pixels.blocks.back());
    ++shape.chunks;
    shape.peak_chunk_bytes = std::max(shape.peak_chunk_bytes, ch.arena_bytes());
  }
  return shape;
}

void render_shapes(int num_poses) {
  Mesh mesh = test::lumpy_sphere(0.06f, 71, 72);
  const auto hyps = bench::poses(num_poses, mesh);
  std::printf(
      "\nRenderer: %s, %zu triangles, %d poses, 640x480, default chunk budgets (thrust_omp %zu MiB, "
      "cuda %zu MiB)\n\n",
      mesh.name.c_str(), mesh.triangles.size(), num_poses, OmpSystem::default_chunk_bytes >> 20,
      CudaSystem::default_chunk_bytes >> 20);
  const MeshArrays arrays{Mesh(mesh)};
  const thrust_omp::Backend::Renderer renderer({mesh});
  std::vector<std::string> memory;
  print_header();
  for (int stride : {1, 4, 8}) {
    RenderSettings s;
    s.stride = stride;
    const std::string problem = "render stride " + std::to_string(stride);
    renderer.render(hyps, kCamera, s);
    const std::int64_t cold = renderer.last_launch_shape().device_allocations;
    renderer.render(hyps, kCamera, s);
    const LaunchShape omp = renderer.last_launch_shape();
    for (const auto& p : omp.passes) print_pass("thrust_omp", problem, p);
    const LaunchShape cuda = planned_render<CudaSystem>(arrays, hyps, stride);
    for (const auto& p : cuda.passes) print_pass("cuda (plan)", problem, p);
    char line[256];
    std::snprintf(line, sizeof line, "| %-26s | %13.1f | %10d | %12lld | %11lld | %11lld | %14.1f | %13lld |",
                  problem.c_str(), double(omp.peak_chunk_bytes) / (1 << 20), int(omp.chunks),
                  (long long)launches(omp), (long long)cold, (long long)omp.device_allocations,
                  double(cuda.peak_chunk_bytes) / (1 << 20), (long long)launches(cuda));
    memory.push_back(line);
  }
  std::printf(
      "\nDevice memory, allocations and parallel launches per render() call (thrust_omp measured: whole "
      "hypotheses per work item; cuda planned: passes):\n\n");
  std::printf(
      "| problem                    | omp chunk MiB | omp chunks | omp launches | allocs cold | allocs warm "
      "| "
      "cuda chunk MiB | cuda launches |\n");
  std::printf(
      "|----------------------------|---------------|------------|--------------|-------------|-------------|"
      "-"
      "---------------|---------------|\n");
  for (const auto& l : memory) std::printf("%s\n", l.c_str());
}

void registration_shapes(int num_sources) {
  // The registration benchmark's shape: many ~300-point rendered views aligned to one ~5,000-point view.
  Mesh mesh = test::lumpy_sphere(0.06f, 71, 72);
  const thrust_omp::Backend::Renderer renderer({mesh});
  RenderSettings target_settings;
  target_settings.stride = 1;
  const Eigen::Vector3f centre = mesh.bounds().center();
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3f{0.f, 0.f, 0.7f} - centre;
  const CloudBatch target = renderer.render({{0, T}}, kCamera, target_settings);
  std::mt19937 rng(7);
  std::normal_distribution<float> g(0.f, 1.f);
  std::vector<Hypothesis> views;
  for (int k = 0; k < num_sources; ++k) {
    Pose D = Pose::Identity();
    D.linear() = Eigen::AngleAxisf(0.05f * g(rng), Eigen::Vector3f{g(rng), g(rng), g(rng)}.normalized())
                     .toRotationMatrix();
    D.translation() = 0.005f * Eigen::Vector3f{g(rng), g(rng), g(rng)};
    views.push_back({0, D * T});
  }
  RenderSettings source_settings;
  source_settings.stride = 5;
  const CloudBatch sources = renderer.render(views, kCamera, source_settings);
  const std::vector<std::int32_t> seg(sources.num_clouds(), 0);
  std::printf(
      "\nRegistration: %zu sources (%.0f points each on average) -> one target of %zu points, GICP "
      "(default settings, max_correspondence_distance_m 0.05)\n\n",
      sources.num_clouds(), double(sources.size()) / double(sources.num_clouds()), target.size());
  const thrust_omp::Backend::Registration reg(target);
  GicpSettings s;
  s.max_correspondence_distance_m = 0.05f;
  reg.gicp(sources, seg, s);
  const std::int64_t cold = reg.last_launch_shape().device_allocations;
  const RegistrationResult r = reg.gicp(sources, seg, s);
  const LaunchShape omp = reg.last_launch_shape();
  print_header();
  for (const auto& p : omp.passes) print_pass("thrust_omp", "gicp", p);
  // CUDA: the same passes; only the per-iteration pass's items depend on the System.
  const LaunchShape::Pass* lin = omp.find("linearize");
  LaunchShape::Pass cuda_lin = *lin;
  cuda_lin.elements_per_item = CudaSystem::registration_points_per_item;
  cuda_lin.max_items = thrust_backend::registration_items(sources.offsets, cuda_lin.elements_per_item);
  cuda_lin.items = cuda_lin.max_items * cuda_lin.launches;
  print_pass("cuda (plan)", "gicp (iterations as omp)", cuda_lin);
  const int most = *std::max_element(r.iterations.begin(), r.iterations.end());
  std::printf(
      "\nIterations: most %d of max_iterations %d (passes stop once no hypothesis is active, checked "
      "every 4); device allocations per gicp() call: cold %lld, warm %lld\n",
      most, s.max_iterations, (long long)cold, (long long)omp.device_allocations);
}

}  // namespace

int main(int argc, char** argv) {
  int num_poses = 2000, num_sources = 2400;
  for (int k = 1; k + 1 < argc; k += 2) {
    const std::string a = argv[k];
    if (a == "--poses") num_poses = std::stoi(argv[k + 1]);
    if (a == "--sources") num_sources = std::stoi(argv[k + 1]);
  }
  std::printf("bench_launch_shapes on %s, %d threads (counts, not timings)\n", bench::cpu_model().c_str(),
              omp_get_max_threads());
  std::printf(
      "el/it: elements (vertices, triangles, samples, points) per work item; items/launch: largest "
      "launch of the pass, i.e. the threads a GPU would run at once\n");
  render_shapes(num_poses);
  registration_shapes(num_sources);
  return 0;
}
