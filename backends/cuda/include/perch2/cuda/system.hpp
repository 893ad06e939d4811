// The Thrust backend is one source compiled for two Thrust device systems. Each stage is a class template
// over a system tag, explicitly instantiated in the library built for that system:
//   perch2::cuda        nvcc, THRUST_DEVICE_SYSTEM_CUDA (production, GPUs)
//   perch2::thrust_omp  g++,  THRUST_DEVICE_SYSTEM_OMP  (checked against the reference on every CI run)
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "perch2/core/export.hpp"

// Floating-point contract: by default every backend rounds each product and sum as written (no fused
// multiply-add: nvcc --fmad=false, g++/clang -ffp-contract=off), so results are bitwise equal across
// perch2::cpu, perch2::thrust_omp and perch2::cuda. A CUDA build configured with PERCH2_CUDA_FMA=ON fuses
// them (faster); its results then differ in the last bits, and PERCH2_CUDA_FMA is 1 for its consumers.
#ifndef PERCH2_CUDA_FMA
#define PERCH2_CUDA_FMA 0
#endif

namespace perch2::thrust_backend {

// Work-item sizes (elements one thread handles in a pass) are a property of the system: a GPU wants ~10^5
// threads in flight (one triangle, sample or a few points each), a CPU a few long items per core (amortising
// each item's search for its hypothesis). They change throughput and, for registration, the order of float
// sums (hence results in the last bits between systems; each system is deterministic).
struct PERCH2_API CudaSystem {
  static constexpr const char* name = "cuda";
  static constexpr std::size_t default_chunk_bytes = std::size_t(256) << 20;  ///< fills a GPU
  /// Renderer: vertices, triangles or ROI samples per work item (one per thread, the classic mapping).
  static constexpr int render_elements_per_item = 1;
  /// Renderer: false: one pass per stage per chunk (pose, rasterise, resolve, compact), each over many small
  /// work items; true: one pass per chunk whose work items render whole hypotheses (see OmpSystem).
  static constexpr bool render_whole_hypotheses = false;
  /// Registration: source points per work item (each writes a 124-byte partial sum of the normal
  /// equations; 8 gives ~90k threads for 2,400 hypotheses x 300 points and ~40 partial sums per hypothesis).
  static constexpr int registration_points_per_item = 8;
  /// Registration: false: per iteration one pass over blocks of points and one over hypotheses; true: one
  /// pass per call whose work items register whole source clouds (see OmpSystem).
  static constexpr bool registration_whole_clouds = false;
  /// Cost: false: J_r as one work item per rendered point, each finding the pair record of a volume point it
  /// meets by binary search in its hypothesis' sorted keys; true: work items classify whole hypotheses'
  /// rendered points, finding those records through a per-item dense slot array (see OmpSystem).
  static constexpr bool cost_whole_hypotheses = false;
  /// Results equal the reference backend's bit for bit (false only in a PERCH2_CUDA_FMA=ON build).
  static constexpr bool bitwise_reproducible = PERCH2_CUDA_FMA == 0;
  /// Device -> host copies of stage results land in a page-locked (pinned) staging buffer the stage object
  /// keeps: one DMA at full bus bandwidth instead of the driver's chunked copy through its own pinned
  /// bounce buffer (HostBuffer in the backend's thrust_util.hpp).
  static constexpr bool pinned_host_buffers = true;
};
struct PERCH2_API OmpSystem {
  static constexpr const char* name = "thrust_omp";
  /// Per chunk: the outputs only (each thread's working set of one hypothesis stays in cache whatever the
  /// chunk size), so chunks are large and parallel regions few: ~1 chunk for 2,000 hypotheses at stride 4.
  static constexpr std::size_t default_chunk_bytes = std::size_t(64) << 20;
  static constexpr int render_elements_per_item = 64;  ///< when rendering in passes (OmpPassesSystem)
  /// A CPU renders each hypothesis start to end in one thread, hypotheses pulled from a shared counter: two
  /// parallel regions per chunk instead of ~9, and no thread waits at a barrier for a descheduled one
  /// holding a fixed share of the work (with libgomp's default spinning waits, the pass structure ran 6x
  /// slower than the reference backend beside one busy process).
  static constexpr bool render_whole_hypotheses = true;
  static constexpr int registration_points_per_item = 64;  ///< as measured in the README's tables
  /// A CPU registers each source cloud start to end (all its iterations) in one thread, clouds pulled from a
  /// shared counter: one parallel region per call instead of ~2 per iteration, each a barrier waiting for
  /// the slowest (or a descheduled) thread.
  static constexpr bool registration_whole_clouds = true;
  /// A CPU classifies each hypothesis' rendered points in one thread, hypotheses pulled from a shared
  /// counter: the pair records of its volume points are found with one load from the thread's slot array
  /// (the binary search per visited pair was ~20% of the stage), as the reference backend does.
  static constexpr bool cost_whole_hypotheses = true;
  static constexpr bool bitwise_reproducible = true;
  static constexpr bool pinned_host_buffers = false;  ///< host memory is device memory: copy directly
};
/// The CUDA renderer's, registration's and cost's pass structure run on OpenMP: not faster, but it runs the
/// GPU path's passes (the same functors and launch plan) against the reference on every CI run.
struct PERCH2_API OmpPassesSystem : OmpSystem {
  static constexpr const char* name = "thrust_omp_passes";
  static constexpr std::size_t default_chunk_bytes = std::size_t(4) << 20;  ///< stays in cache
  static constexpr bool render_whole_hypotheses = false;
  static constexpr bool registration_whole_clouds = false;
  static constexpr bool cost_whole_hypotheses = false;
};

/// What the last call of a stage object launched and allocated: lets a GPU user see the launch shapes and
/// the memory a batch needs on any machine (the figures depend on the system's work-item sizes, not on the
/// hardware).
struct LaunchShape {
  struct Pass {
    std::string name;
    int elements_per_item = 1;   ///< elements (triangles, samples, points, ...) one work item handles
    std::int64_t launches = 0;   ///< parallel launches of this pass in the call
    std::int64_t items = 0;      ///< work items over all launches
    std::int64_t max_items = 0;  ///< work items of the largest launch (the parallelism a GPU sees)
  };
  std::vector<Pass> passes;
  std::int64_t chunks = 0;  ///< chunks the batch was split into (renderer)
  /// Device (and pinned host) allocations the call made (0 once workspaces are warm).
  std::int64_t device_allocations = 0;
  std::size_t peak_chunk_bytes = 0;  ///< largest chunk working memory (renderer: within memory_budget_bytes)
  std::size_t workspace_bytes = 0;   ///< device memory the stage object keeps between calls

  void launch(const std::string& pass, int elements_per_item, std::int64_t items) {
    for (Pass& p : passes)
      if (p.name == pass) {
        ++p.launches, p.items += items, p.max_items = items > p.max_items ? items : p.max_items;
        return;
      }
    passes.push_back({pass, elements_per_item, 1, items, items});
  }
  const Pass* find(const std::string& pass) const {
    for (const Pass& p : passes)
      if (p.name == pass) return &p;
    return nullptr;
  }
};

}  // namespace perch2::thrust_backend
