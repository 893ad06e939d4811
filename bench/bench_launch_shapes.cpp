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
// kNN rows (KnnIndex build, knn(), radius()) use bench_knn's problems (knn_scenes.hpp). Every kNN pass has
// one query, target point or grid cell per work item on every System (no System constant applies), so
// the cuda plan repeats the measured passes; on CUDA the cold call also allocates its pinned staging
// buffer and CUB's scan temporaries, both kept by the index (warm calls: 0 allocations).
//
//   bench_launch_shapes [--poses 2000] [--sources 2400] [--data <repo>/../shared/data]
#include <omp.h>

#include <algorithm>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "bench_support.hpp"
#include "knn_scenes.hpp"
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
  for (const auto& p : omp.passes) print_pass("thrust_omp", "gicp (whole clouds)", p);
  // CUDA runs the pass structure, measured on OpenMP as OmpPassesSystem; only the per-iteration pass's
  // items depend on the System.
  const thrust_backend::Registration<thrust_backend::OmpPassesSystem> passes_reg(target);
  passes_reg.gicp(sources, seg, s);
  const LaunchShape passes = passes_reg.last_launch_shape();
  for (const auto& p : passes.passes) print_pass("omp passes", "gicp", p);
  const LaunchShape::Pass* lin = passes.find("linearize");
  LaunchShape::Pass cuda_lin = *lin;
  cuda_lin.elements_per_item = CudaSystem::registration_points_per_item;
  cuda_lin.max_items = thrust_backend::registration_items(sources.offsets, cuda_lin.elements_per_item);
  cuda_lin.items = cuda_lin.max_items * cuda_lin.launches;
  print_pass("cuda (plan)", "gicp (iterations as omp)", cuda_lin);
  const int most = *std::max_element(r.iterations.begin(), r.iterations.end());
  std::printf(
      "\nIterations: most %d of max_iterations %d (passes stop once no hypothesis is active, checked "
      "every 4); parallel launches per gicp() call: thrust_omp %lld, passes %lld; device allocations per "
      "gicp() call (thrust_omp): cold %lld, warm %lld\n",
      most, s.max_iterations, (long long)launches(omp), (long long)launches(passes), (long long)cold,
      (long long)omp.device_allocations);
}

/// The kNN stage's launches for a System: one query, point or cell per work item on every System, so the
/// plan is the measured pass list (see the file comment).
template <class System>
LaunchShape planned_knn(const LaunchShape& measured) {
  LaunchShape shape;
  for (const auto& p : measured.passes)
    for (std::int64_t l = 0; l < p.launches; ++l) shape.launch(p.name, p.elements_per_item, p.max_items);
  return shape;
}

void print_knn(const std::string& problem, const LaunchShape& omp) {
  for (const auto& p : omp.passes) print_pass("thrust_omp", problem, p);
  for (const auto& p : planned_knn<CudaSystem>(omp).passes) print_pass("cuda (plan)", problem, p);
}

void knn_shapes(const std::string& data_dir) {
  const bench::KnnScenes problems = bench::knn_scenes(data_dir);
  const float radius_m = 0.0075f;  // the 3-DoF cost's delta (paper default)
  std::printf(
      "\nkNN: bench_knn's problems (%s model), Auto method (grid at these sizes), radius %.4f m "
      "without a cap\n\n",
      problems.model_name.c_str(), double(radius_m));
  print_header();
  std::vector<std::string> memory;
  auto row = [&](const std::string& problem, long long cold, const std::string& warm, std::size_t bytes,
                 const std::string& found = "") {
    char line[256];
    std::snprintf(line, sizeof line, "| %-26s | %11lld | %11s | %8.1f | %-26s |", problem.c_str(), cold,
                  warm.c_str(), double(bytes) / (1 << 20), found.c_str());
    memory.push_back(line);
  };
  for (const bench::Scene& sc : problems.scenes) {
    const std::string tag = sc.name.substr(0, 4);  // 6dof / 3dof
    const thrust_omp::Backend::KnnIndex index(sc.targets);
    const LaunchShape build = index.last_launch_shape();
    print_knn(tag + " build", build);
    row(tag + " build", (long long)build.device_allocations, "(new index)", build.workspace_bytes);
    for (int k : {1, 10}) {
      KnnSettings s;
      s.k = k;
      const std::string problem = tag + " knn k=" + std::to_string(k);
      index.knn(sc.queries, sc.segment, s);
      const std::int64_t cold = index.last_launch_shape().device_allocations;
      index.knn(sc.queries, sc.segment, s);
      const LaunchShape warm = index.last_launch_shape();
      print_knn(problem, warm);
      row(problem, (long long)cold, std::to_string(warm.device_allocations), warm.workspace_bytes);
    }
    const std::string problem = tag + " radius";
    const RadiusResult r = index.radius(sc.queries, sc.segment, radius_m);
    const std::int64_t cold = index.last_launch_shape().device_allocations;
    index.radius(sc.queries, sc.segment, radius_m);
    const LaunchShape warm = index.last_launch_shape();
    print_knn(problem, warm);
    std::int64_t most = 0;
    for (std::size_t q = 0; q < r.num_queries(); ++q) most = std::max(most, r.offsets[q + 1] - r.offsets[q]);
    row(problem, (long long)cold, std::to_string(warm.device_allocations), warm.workspace_bytes,
        std::to_string(r.index.size()) + " (<= " + std::to_string(most) + " per query)");
  }
  std::printf(
      "\nDevice allocations per call (thrust_omp measured; cold: the first call of that size on the index, "
      "so k = 10 after k = 1 only grows the result lists; build: the index's arrays and temporaries) and the "
      "device memory the index keeps (build: the index; calls: the reusable workspace):\n\n");
  std::printf(
      "| problem                    | allocs cold | allocs warm | kept MiB | radius results             |\n");
  std::printf(
      "|----------------------------|-------------|-------------|----------|----------------------------|\n");
  for (const auto& l : memory) std::printf("%s\n", l.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  int num_poses = 2000, num_sources = 2400;
  std::string data_dir = PERCH2_SHARED_DATA_DIR;  // set by bench/CMakeLists.txt
  for (int k = 1; k + 1 < argc; k += 2) {
    const std::string a = argv[k];
    if (a == "--poses") num_poses = std::stoi(argv[k + 1]);
    if (a == "--sources") num_sources = std::stoi(argv[k + 1]);
    if (a == "--data") data_dir = argv[k + 1];
  }
  std::printf("bench_launch_shapes on %s, %d threads (counts, not timings)\n", bench::cpu_model().c_str(),
              omp_get_max_threads());
  std::printf(
      "el/it: elements (vertices, triangles, samples, points) per work item; items/launch: largest "
      "launch of the pass, i.e. the threads a GPU would run at once\n");
  render_shapes(num_poses);
  registration_shapes(num_sources);
  knn_shapes(data_dir);
  return 0;
}
