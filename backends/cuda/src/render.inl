// Thrust batch renderer (compiled by render.cu with nvcc and by render_omp.cpp with g++).
// In passes (GPU systems): per chunk of hypotheses, transform vertices (hypothesis x vertex), rasterise
// (hypothesis x triangle) into per-hypothesis ROI z-buffers with a packed 64-bit atomic min, resolve
// (hypothesis x ROI sample), then compact the visible samples with a scan.
// Whole hypotheses (CPU systems, System::render_whole_hypotheses): per chunk, one pass whose work items
// each render whole hypotheses (render_hypothesis, the reference backend's code) pulled from a counter, and
// one pass that compacts them. Chunks are sized to RenderSettings::memory_budget_bytes.
#include <thrust/device_vector.h>
#include <thrust/execution_policy.h>
#include <thrust/fill.h>
#include <thrust/for_each.h>
#include <thrust/gather.h>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/scan.h>
#include <thrust/transform.h>

#include <algorithm>
#include <cuda/atomic>
#include <mutex>

#include "perch2/core/segments.hpp"
#include "perch2/cuda/launch_plan.hpp"
#include "perch2/cuda/render.hpp"
#include "perch2/render/mesh_arrays.hpp"
#include "perch2/render/raster.hpp"
#include "thrust_util.hpp"

namespace perch2::thrust_backend {
namespace render_detail {

/// One model's arrays in device memory.
struct DeviceMesh {
  thrust::device_vector<Vec3f> vertices;
  thrust::device_vector<float> vertex_xyz;
  thrust::device_vector<std::int32_t> triangles;
  thrust::device_vector<Rgb8> vertex_colors, texture;
  thrust::device_vector<Vec2f> corner_uvs;
  thrust::device_vector<TriangleCluster> clusters;
  thrust::device_vector<VertexBlockMask> vertex_masks;
  MeshView view;

  explicit DeviceMesh(const MeshArrays& a)
      : vertices(to_device(a.vertices)),
        vertex_xyz(to_device(a.vertex_xyz)),
        triangles(to_device(a.triangles)),
        vertex_colors(to_device(a.vertex_colors)),
        texture(to_device(a.texture)),
        corner_uvs(to_device(a.corner_uvs)),
        clusters(to_device(a.clusters)),
        vertex_masks(to_device(a.vertex_masks)),
        view(a.view(ptr(vertices), ptr(vertex_xyz), ptr(triangles), ptr(vertex_colors), ptr(corner_uvs),
                    ptr(texture), ptr(clusters), ptr(vertex_masks))) {}
};

/// Per-hypothesis inputs of one render call, in device memory.
struct HypothesisArgs {
  const MeshView* views;
  const std::int32_t* model;
  const Rigid3f* T_cam_obj;
  const std::int32_t* label;
};

struct ComputeRoi {
  HypothesisArgs h;
  Intrinsics K;
  int stride;
  float near_m;
  PERCH2_HD GridRoi operator()(int k) const {
    return model_roi(h.views[h.model[k]], h.T_cam_obj[k], K, stride, near_m);
  }
};

/// A segmented domain of the chunk (vertices, triangles or ROI samples): per chunk hypothesis, element
/// offsets (count + 1, address the buffers) and work-item offsets (count + 1, blocks of `block` elements:
/// System::render_elements_per_item).
struct Domain {
  const std::int64_t* elements;
  const std::int64_t* blocks;
};

/// The chunk being rendered: hypotheses [first, first + count) and their segmented work arrays.
struct ChunkArgs {
  int first, count, block;
  const GridRoi* roi;  // per chunk hypothesis
  Domain vertices, triangles, pixels;
  PosedPoint* verts_cam;
  GridSpan* spans;
  DepthTriangle* zbuf;
  PERCH2_HD BlockRange range(const Domain& d, std::int64_t item) const {
    return block_range(d.blocks, d.elements, count, item, block);
  }
  /// Posed vertices of the chunk's hypothesis `segment`.
  PERCH2_HD PosedVertices posed(int segment) const {
    const std::int64_t base = vertices.elements[segment];
    return {verts_cam + base, spans + base};
  }
};

struct TransformVertices {
  HypothesisArgs h;
  ChunkArgs c;
  Intrinsics K;
  int stride;
  float near_m;
  PERCH2_HD void operator()(std::int64_t item) const {
    const BlockRange r = c.range(c.vertices, item);
    const int hyp = c.first + r.segment;
    const std::int64_t base = c.vertices.elements[r.segment];
    pose_vertices(h.views[h.model[hyp]], h.T_cam_obj[hyp], K, stride, near_m, int(r.begin), int(r.end),
                  c.verts_cam + base, c.spans + base);
  }
};

struct Rasterize {
  HypothesisArgs h;
  ChunkArgs c;
  Intrinsics K;
  int stride;
  float near_m;
  bool cull;
  PERCH2_HD void operator()(std::int64_t item) const {
    const BlockRange r = c.range(c.triangles, item);
    const int hyp = c.first + r.segment;
    const GridRoi roi = c.roi[r.segment];
    if (roi.size() == 0) return;
    DepthTriangle* zbuf = c.zbuf + c.pixels.elements[r.segment];
    const PosedVertices posed = c.posed(r.segment);
    const MeshView& m = h.views[h.model[hyp]];
    rasterize_triangles(m, posed, int(r.begin), int(r.end), h.T_cam_obj[hyp], K, stride, near_m, roi, cull,
                        [zbuf](int idx, DepthTriangle w) {
                          auto* word = reinterpret_cast<unsigned long long*>(zbuf + idx);
                          if (w >= *word) return;  // cheap pre-check; the atomic decides
                          cuda::atomic_ref<unsigned long long, cuda::thread_scope_device> ref(*word);
                          ref.fetch_min((unsigned long long)w, cuda::memory_order_relaxed);
                        });
  }
};

struct Resolve {
  HypothesisArgs h;
  ChunkArgs c;
  Intrinsics K;
  int stride;
  OccluderView occ;
  RenderedSample* samples;
  std::int32_t* visible;
  PERCH2_HD void operator()(std::int64_t item) const {
    const BlockRange r = c.range(c.pixels, item);
    const int hyp = c.first + r.segment;
    const GridRoi roi = c.roi[r.segment];
    const std::int64_t base = c.pixels.elements[r.segment];
    const MeshView& m = h.views[h.model[hyp]];
    const PosedVertices verts_cam = c.posed(r.segment);
    const GridRays rays(K, stride);
    for (std::int64_t idx = r.begin; idx < r.end; ++idx) {
      const std::int64_t k = base + idx;
      visible[k] = resolve_sample(m, verts_cam, c.zbuf[k], K, rays, roi.i0 + int(idx % roi.width),
                                  roi.j0 + int(idx / roi.width), occ, h.label[hyp], samples[k]);
    }
  }
};

/// Writes the visible samples of a block to their compacted slots (SoA output of the chunk).
struct Scatter {
  ChunkArgs c;
  const RenderedSample* samples;
  const std::int32_t* visible;
  const std::int64_t* slot;
  float *x, *y, *z;
  std::uint32_t* rgb;
  std::int32_t *pixel, *cloud;
  PERCH2_HD void operator()(std::int64_t item) const {
    const BlockRange r = c.range(c.pixels, item);
    const std::int64_t base = c.pixels.elements[r.segment];
    for (std::int64_t k = base + r.begin; k < base + r.end; ++k) {
      if (!visible[k]) continue;
      const std::int64_t s = slot[k];
      const RenderedSample& p = samples[k];
      x[s] = p.p_cam.x, y[s] = p.p_cam.y, z[s] = p.p_cam.z, rgb[s] = p.rgb, pixel[s] = p.pixel;
      cloud[s] = c.first + r.segment;
    }
  }
};

/// Work item `worker` renders the chunk's hypotheses it pulls from the shared counter `next`, with its own
/// scratch, into the hypothesis' slice of `samples` (its ROI offset); visible[k]: how many it wrote.
struct RenderWhole {
  HypothesisArgs h;
  RenderParams p;
  int first, count;
  const GridRoi* roi;          // per chunk hypothesis
  const std::int64_t* pixels;  // per chunk hypothesis: its first ROI sample (count + 1)
  int* next;
  PosedPoint* p_cam;
  GridSpan* spans;
  DepthTriangle* zbuf;
  std::int32_t* front_clusters;
  std::uint64_t* vertex_blocks;
  std::int64_t max_vertices, max_clusters, max_roi;  // scratch per worker
  RenderedSample* samples;
  std::int64_t* visible;
  PERCH2_HD void operator()(std::int64_t worker) const {
    const HypothesisScratch s{p_cam + worker * max_vertices, spans + worker * max_vertices,
                              zbuf + worker * max_roi, front_clusters + worker * max_clusters,
                              vertex_blocks + worker * vertex_block_words(int(max_vertices))};
    cuda::atomic_ref<int, cuda::thread_scope_device> counter(*next);
    for (int k = counter.fetch_add(1, cuda::memory_order_relaxed); k < count;
         k = counter.fetch_add(1, cuda::memory_order_relaxed)) {
      const int hyp = first + k;
      visible[k] = render_hypothesis(h.views[h.model[hyp]], h.T_cam_obj[hyp], h.label[hyp], roi[k], p, s,
                                     samples + pixels[k]);
    }
  }
};

/// Work item `worker` copies the visible samples of the chunk's hypotheses it pulls from the shared counter
/// `next` to their output slots (SoA output of the chunk): balanced like RenderWhole, so a descheduled thread
/// delays the pass by one hypothesis, not by its fixed half of the copies.
struct ScatterWhole {
  int first, count;
  const std::int64_t *pixels, *visible, *slot;
  const RenderedSample* samples;
  float *x, *y, *z;
  std::uint32_t* rgb;
  std::int32_t *pixel, *cloud;
  int* next;
  PERCH2_HD void operator()(std::int64_t) const {
    cuda::atomic_ref<int, cuda::thread_scope_device> counter(*next);
    for (int k = counter.fetch_add(1, cuda::memory_order_relaxed); k < count;
         k = counter.fetch_add(1, cuda::memory_order_relaxed)) {
      const RenderedSample* in = samples + pixels[k];
      for (std::int64_t i = 0, s = slot[k]; i < visible[k]; ++i, ++s) {
        x[s] = in[i].p_cam.x, y[s] = in[i].p_cam.y, z[s] = in[i].p_cam.z, rgb[s] = in[i].rgb;
        pixel[s] = in[i].pixel, cloud[s] = first + k;
      }
    }
  }
};

/// Host -> device copy of a host vector into arena memory.
template <class T>
void copy_to(T* device, const std::vector<T>& host) {
  if (!host.empty()) thrust::copy(host.begin(), host.end(), thrust::device_pointer_cast(device));
}

/// Renders the batch in whole-hypothesis chunks (CPU systems): per chunk two parallel passes, RenderWhole
/// and ScatterWhole, and plain copies. Appends the clouds to `batch` and records the launches in `shape`.
/// The scatter writes the batch's host arrays directly (on CPU systems host memory is device memory): no
/// serial copy of the chunk's output.
template <class System>
void render_whole_chunks(const HypothesisArgs& args, const GridRoi* d_roi, const RenderParams& params,
                         const std::vector<std::int64_t>& hyp_vertices,
                         const std::vector<std::int64_t>& hyp_clusters,
                         const std::vector<std::int64_t>& roi_samples, std::size_t budget, DeviceArena& arena,
                         LaunchShape& shape, CloudBatch& batch) {
  static_assert(!System::pinned_host_buffers,
                "whole-hypothesis rendering needs host-accessible device memory");
  using Items = thrust::counting_iterator<std::int64_t>;
  const int workers = cpu_system_workers();
  const std::vector<WholeRenderChunk> chunks =
      plan_whole_render_chunks(hyp_vertices, hyp_clusters, roi_samples, budget, workers);
  std::size_t arena_bytes = 0;
  for (const WholeRenderChunk& ch : chunks) arena_bytes = std::max(arena_bytes, ch.arena_bytes());
  if (arena.reserve(arena_bytes, budget)) ++shape.device_allocations;
  std::vector<std::int64_t> visible_host, slot_host;
  for (const WholeRenderChunk& ch : chunks) {
    const std::size_t V = std::size_t(ch.max_vertices), R = std::size_t(ch.max_roi), W = std::size_t(workers),
                      H = std::size_t(ch.count) + 1, P = std::size_t(ch.pixels.elements.back());
    arena.rewind();  // carve in the order of WholeRenderChunk::bytes
    PosedPoint* p_cam = arena.take<PosedPoint>(W * V);
    GridSpan* spans = arena.take<GridSpan>(W * V);
    DepthTriangle* zbuf = arena.take<DepthTriangle>(W * R);
    std::int32_t* front_clusters = arena.take<std::int32_t>(W * std::size_t(ch.max_clusters));
    std::uint64_t* vertex_blocks = arena.take<std::uint64_t>(W * std::size_t(vertex_block_words(int(V))));
    int* next = reinterpret_cast<int*>(arena.take<std::int64_t>(1));  // two counters: render, scatter
    std::int64_t *pixels = arena.take<std::int64_t>(H), *visible = arena.take<std::int64_t>(H),
                 *slot = arena.take<std::int64_t>(H);
    RenderedSample* samples = arena.take<RenderedSample>(P);
    copy_to(pixels, ch.pixels.elements);
    copy_to(next, std::vector<int>{0, 0});
    thrust::for_each(thrust::device, Items(0), Items(workers),
                     RenderWhole{args, params, ch.first, ch.count, d_roi + ch.first, pixels, next, p_cam,
                                 spans, zbuf, front_clusters, vertex_blocks, std::int64_t(V), ch.max_clusters,
                                 std::int64_t(R), samples, visible});
    // Output slots on the host: the per-hypothesis counts come back anyway to set the batch offsets.
    visible_host.clear(), slot_host.assign(1, 0);
    append_to_host(visible_host, visible, std::size_t(ch.count));
    for (int k = 0; k < ch.count; ++k) slot_host.push_back(slot_host.back() + visible_host[std::size_t(k)]);
    copy_to(slot, slot_host);
    const std::size_t at = batch.size();
    batch.resize(at + std::size_t(slot_host.back()));
    thrust::for_each(thrust::device, Items(0), Items(workers),
                     ScatterWhole{ch.first, ch.count, pixels, visible, slot, samples, batch.x.data() + at,
                                  batch.y.data() + at, batch.z.data() + at, batch.rgb.data() + at,
                                  batch.pixel.data() + at, batch.cloud.data() + at, next + 1});
    for (int k = 1; k <= ch.count; ++k)
      batch.offsets[std::size_t(ch.first + k)] = std::int64_t(at) + slot_host[std::size_t(k)];
    shape.launch("render_hypotheses", 1, workers);
    shape.launch("scatter", 1, workers);
    ++shape.chunks;
    shape.peak_chunk_bytes = std::max(shape.peak_chunk_bytes, arena.bytes());
  }
}

/// A domain's offsets copied into the arena.
inline Domain upload_domain(DeviceArena& arena, const HostDomain& d) {
  std::int64_t* e = arena.take<std::int64_t>(d.elements.size());
  std::int64_t* b = arena.take<std::int64_t>(d.blocks.size());
  thrust::copy(d.elements.begin(), d.elements.end(), thrust::device_pointer_cast(e));
  thrust::copy(d.blocks.begin(), d.blocks.end(), thrust::device_pointer_cast(b));
  return {e, b};
}

}  // namespace render_detail

template <class System>
struct Renderer<System>::Impl {
  struct Sizes {
    std::size_t vertices, triangles, clusters;
  };
  std::vector<Sizes> host;  // the arrays themselves live on the device only
  std::vector<std::unique_ptr<render_detail::DeviceMesh>> device;
  thrust::device_vector<MeshView> views;
  // Workspace reused across chunks and calls (render() holds the mutex): per-call inputs grow only; the
  // chunk arena is resized to the largest chunk (released when a later call's budget is smaller).
  mutable std::mutex mutex;
  mutable thrust::device_vector<std::int32_t> model, label, occ_labels;
  mutable thrust::device_vector<Rigid3f> T_cam_obj;
  mutable thrust::device_vector<GridRoi> roi;
  mutable thrust::device_vector<float> occ_depth;
  mutable DeviceArena arena;
  mutable TempAllocator temp;
  mutable LaunchShape shape;
};

/// Device memory a renderer keeps between calls.
template <class Impl>
std::size_t workspace_bytes(const Impl& w) {
  return w.arena.bytes() + w.temp.bytes() +
         (w.model.capacity() + w.label.capacity() + w.occ_labels.capacity()) * 4 +
         w.occ_depth.capacity() * 4 + w.T_cam_obj.capacity() * sizeof(Rigid3f) +
         w.roi.capacity() * sizeof(GridRoi);
}

template <class System>
Renderer<System>::Renderer(std::vector<Mesh> models) : impl_(std::make_unique<Impl>()) {
  validate_models(models);
  std::vector<MeshView> views;
  for (auto& mesh : models) {
    const MeshArrays arrays(std::move(mesh));
    impl_->host.push_back({arrays.vertices.size(), arrays.triangles.size() / 3, arrays.clusters.size()});
    impl_->device.push_back(std::make_unique<render_detail::DeviceMesh>(arrays));
    views.push_back(impl_->device.back()->view);
  }
  impl_->views = to_device(views);
}
template <class System>
Renderer<System>::~Renderer() = default;
template <class System>
Renderer<System>::Renderer(Renderer&&) noexcept = default;
template <class System>
Renderer<System>& Renderer<System>::operator=(Renderer&&) noexcept = default;
template <class System>
std::size_t Renderer<System>::num_models() const {
  return impl_->host.size();
}

template <class System>
LaunchShape Renderer<System>::last_launch_shape() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->shape;
}

template <class System>
CloudBatch Renderer<System>::render(const std::vector<Hypothesis>& hypotheses, const Intrinsics& camera,
                                    const RenderSettings& s, const Occluders* occluders) const {
  using namespace render_detail;
  validate_render_request(hypotheses, impl_->host.size(), camera, s, occluders);
  Impl& w = *impl_;
  std::lock_guard<std::mutex> lock(w.mutex);
  w.shape = LaunchShape{};
  w.temp.allocations = 0;
  std::int64_t& allocations = w.shape.device_allocations;
  const int n = int(hypotheses.size());
  const int block = System::render_elements_per_item;

  // Hypotheses and occluders to the device.
  std::vector<std::int32_t> model(n), label(n);
  std::vector<Rigid3f> T(n);
  for (int k = 0; k < n; ++k)
    model[k] = hypotheses[k].model, label[k] = hypotheses[k].label, T[k] = to_rigid(hypotheses[k].T_cam_obj);
  OccluderView occ;
  if (occluders) {
    occ.depth_m = upload(w.occ_depth, occluders->depth_m.data, allocations);
    occ.labels =
        occluders->labels.empty() ? nullptr : upload(w.occ_labels, occluders->labels.data, allocations);
    occ.margin_m = s.occlusion_margin_m;
  }
  const HypothesisArgs args{ptr(w.views), upload(w.model, model, allocations),
                            upload(w.T_cam_obj, T, allocations), upload(w.label, label, allocations)};

  // ROIs on the device; their sizes come back once to plan the chunks.
  GridRoi* d_roi = reuse(w.roi, std::size_t(n), allocations);
  thrust::transform(thrust::device, thrust::counting_iterator<int>(0), thrust::counting_iterator<int>(n),
                    d_roi, ComputeRoi{args, camera, s.stride, s.near_m});
  w.shape.launch("roi", 1, n);
  const std::vector<GridRoi> roi = to_host(w.roi);

  CloudBatch batch;
  batch.offsets.assign(std::size_t(n) + 1, 0);
  using Items = thrust::counting_iterator<std::int64_t>;
  const std::size_t budget = s.memory_budget_bytes ? s.memory_budget_bytes : System::default_chunk_bytes;
  // Plan the chunks (perch2/cuda/launch_plan.hpp): all of a chunk's device memory fits the budget.
  std::vector<std::int64_t> hyp_vertices(n), hyp_triangles(n), hyp_clusters(n), roi_samples(n);
  for (int k = 0; k < n; ++k) {
    hyp_vertices[k] = std::int64_t(impl_->host[model[k]].vertices);
    hyp_triangles[k] = std::int64_t(impl_->host[model[k]].triangles);
    hyp_clusters[k] = std::int64_t(impl_->host[model[k]].clusters);
    roi_samples[k] = roi[k].size();
  }
  if constexpr (System::render_whole_hypotheses) {
    const RenderParams params{camera, s.stride, s.near_m, s.cull_back_faces, occ};
    render_whole_chunks<System>(args, d_roi, params, hyp_vertices, hyp_clusters, roi_samples, budget, w.arena,
                                w.shape, batch);
    w.shape.workspace_bytes = workspace_bytes(w);
    return batch;
  }
  const std::vector<RenderChunk> chunks =
      plan_render_chunks(hyp_vertices, hyp_triangles, roi_samples, budget, block);
  std::size_t arena_bytes = 0;
  for (const RenderChunk& ch : chunks) arena_bytes = std::max(arena_bytes, ch.arena_bytes());
  DeviceArena& arena = w.arena;
  if (arena.reserve(arena_bytes, budget)) ++allocations;

  for (const RenderChunk& ch : chunks) {
    const int first = ch.first, count = ch.count;
    const HostDomain &vertices = ch.vertices, &triangles = ch.triangles, &pixels = ch.pixels;
    const std::int64_t num_vertices = vertices.elements.back(), num_pixels = pixels.elements.back();
    const std::size_t V = std::size_t(num_vertices), P = std::size_t(num_pixels);
    arena.rewind();  // carve the chunk's arrays in the order of render_chunk_arena_bytes
    PosedPoint* verts_cam = arena.take<PosedPoint>(V);
    GridSpan* spans = arena.take<GridSpan>(V);
    const Domain d_vertices = upload_domain(arena, vertices), d_triangles = upload_domain(arena, triangles),
                 d_pixels = upload_domain(arena, pixels);
    DepthTriangle* zbuf = arena.take<DepthTriangle>(P);
    RenderedSample* samples = arena.take<RenderedSample>(P);
    std::int32_t* visible = arena.take<std::int32_t>(P);
    std::int64_t* slot = arena.take<std::int64_t>(P + 1);
    float *x = arena.take<float>(P), *y = arena.take<float>(P), *z = arena.take<float>(P);
    std::uint32_t* rgb = arena.take<std::uint32_t>(P);
    std::int32_t *pixel = arena.take<std::int32_t>(P), *cloud = arena.take<std::int32_t>(P);
    std::int64_t* starts = arena.take<std::int64_t>(std::size_t(count) + 1);
    const ChunkArgs c{first,       count,    block,     d_roi + first, d_vertices,
                      d_triangles, d_pixels, verts_cam, spans,         zbuf};

    // Passes up to the scan need no host wait (nosync); reading the chunk total waits for them.
    thrust::fill_n(nosync(), zbuf, num_pixels, kEmptyPixel);
    thrust::for_each(nosync(), Items(0), Items(vertices.blocks.back()),
                     TransformVertices{args, c, camera, s.stride, s.near_m});
    thrust::for_each(nosync(), Items(0), Items(triangles.blocks.back()),
                     Rasterize{args, c, camera, s.stride, s.near_m, s.cull_back_faces});
    thrust::for_each(nosync(), Items(0), Items(pixels.blocks.back()),
                     Resolve{args, c, camera, s.stride, occ, samples, visible});

    // Compact: slot[k] = number of visible samples before k; slot[num_pixels] = chunk total.
    thrust::fill_n(nosync(), slot, 1, std::int64_t(0));
    // Raw pointers with an explicit policy: Thrust's OpenMP scan is sequential over device_reference
    // iterators, whose reads bind a reference through a null policy pointer (UBSan reports it).
    thrust::inclusive_scan(thrust::device(w.temp), visible, visible + num_pixels, slot + 1,
                           thrust::plus<std::int64_t>());
    std::int64_t total = 0;
    thrust::copy_n(thrust::device_pointer_cast(slot + num_pixels), 1, &total);
    thrust::for_each(thrust::device, Items(0), Items(pixels.blocks.back()),
                     Scatter{c, samples, visible, slot, x, y, z, rgb, pixel, cloud});

    // Per-hypothesis offsets: the slot at the start of each ROI.
    thrust::gather(thrust::device, d_pixels.elements, d_pixels.elements + count + 1, slot, starts);
    std::vector<std::int64_t> host_starts;
    append_to_host(host_starts, starts, std::size_t(count) + 1);
    const std::int64_t at = std::int64_t(batch.size());
    for (int k = 1; k <= count; ++k) batch.offsets[first + k] = at + host_starts[k];

    const std::size_t m = std::size_t(total);
    append_to_host(batch.x, x, m), append_to_host(batch.y, y, m), append_to_host(batch.z, z, m);
    append_to_host(batch.rgb, rgb, m), append_to_host(batch.pixel, pixel, m),
        append_to_host(batch.cloud, cloud, m);

    ++w.shape.chunks;
    w.shape.launch("transform_vertices", block, vertices.blocks.back());
    w.shape.launch("rasterize", block, triangles.blocks.back());
    w.shape.launch("resolve", block, pixels.blocks.back());
    w.shape.launch("scatter", block, pixels.blocks.back());
    // Device memory actually held for chunks: the arena (sized to the largest chunk) and scan temporaries.
    w.shape.peak_chunk_bytes = std::max(w.shape.peak_chunk_bytes, arena.bytes() + w.temp.bytes());
  }
  allocations += w.temp.allocations;
  w.shape.workspace_bytes = workspace_bytes(w);
  return batch;
}

}  // namespace perch2::thrust_backend
