// Thrust batch renderer (compiled by render.cu with nvcc and by render_omp.cpp with g++).
// Per chunk of hypotheses: transform vertices (hypothesis x vertex), rasterise (hypothesis x triangle) into
// per-hypothesis ROI z-buffers with a packed 64-bit atomic min, resolve (hypothesis x ROI sample), then
// compact the visible samples with a scan. Chunks are sized to RenderSettings::memory_budget_bytes.
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

#include "perch2/core/segments.hpp"
#include "perch2/cuda/render.hpp"
#include "perch2/render/mesh_arrays.hpp"
#include "perch2/render/raster.hpp"
#include "thrust_util.hpp"

namespace perch2::thrust_backend {
namespace render_detail {

/// One model's arrays in device memory.
struct DeviceMesh {
  thrust::device_vector<Vec3f> vertices;
  thrust::device_vector<std::int32_t> triangles;
  thrust::device_vector<Rgb8> vertex_colors, texture;
  thrust::device_vector<Vec2f> corner_uvs;
  thrust::device_vector<TriangleCluster> clusters;
  MeshView view;

  explicit DeviceMesh(const MeshArrays& a)
      : vertices(to_device(a.vertices)),
        triangles(to_device(a.triangles)),
        vertex_colors(to_device(a.vertex_colors)),
        texture(to_device(a.texture)),
        corner_uvs(to_device(a.corner_uvs)),
        clusters(to_device(a.clusters)),
        view(a.view(ptr(vertices), ptr(triangles), ptr(vertex_colors), ptr(corner_uvs), ptr(texture),
                    ptr(clusters))) {}
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

/// Elements per work item: amortises the item -> hypothesis search and still leaves ~10^5 items per chunk.
constexpr int kBlock = 64;

/// A segmented domain of the chunk (vertices, triangles or ROI samples): per chunk hypothesis, element
/// offsets (count + 1, address the buffers) and work-item offsets (count + 1, blocks of kBlock elements).
struct Domain {
  const std::int64_t* elements;
  const std::int64_t* blocks;
};

/// The chunk being rendered: hypotheses [first, first + count) and their segmented work arrays.
struct ChunkArgs {
  int first, count;
  const GridRoi* roi;  // per chunk hypothesis
  Domain vertices, triangles, pixels;
  Vec3f* verts_cam;
  GridSpan* spans;
  DepthTriangle* zbuf;
  PERCH2_HD BlockRange range(const Domain& d, std::int64_t item) const {
    return block_range(d.blocks, d.elements, count, item, kBlock);
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
    const std::int64_t base = c.vertices.elements[r.segment];
    const PosedVertices posed{c.verts_cam + base, c.spans + base};
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
    const Vec3f* verts_cam = c.verts_cam + c.vertices.elements[r.segment];
    for (std::int64_t idx = r.begin; idx < r.end; ++idx) {
      const std::int64_t k = base + idx;
      visible[k] = resolve_sample(m, verts_cam, c.zbuf[k], K, stride, roi.i0 + int(idx % roi.width),
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

/// Host-built offsets of one domain for the chunk.
struct HostDomain {
  std::vector<std::int64_t> elements{0}, blocks{0};
  void add(std::int64_t n) {
    elements.push_back(elements.back() + n);
    blocks.push_back(blocks.back() + (n + kBlock - 1) / kBlock);
  }
};

/// Device copy of a HostDomain.
struct DeviceDomain {
  thrust::device_vector<std::int64_t> elements, blocks;
  Domain upload(const HostDomain& d) {
    elements = to_device(d.elements);
    blocks = to_device(d.blocks);
    return {ptr(elements), ptr(blocks)};
  }
};

template <class T>
void append(std::vector<T>& out, const thrust::device_vector<T>& chunk, std::size_t n) {
  if (n == 0) return;  // Thrust's cross-system copy takes &*out even for an empty range
  const std::size_t at = out.size();
  out.resize(at + n);
  thrust::copy(chunk.begin(), chunk.begin() + std::ptrdiff_t(n), out.begin() + std::ptrdiff_t(at));
}

}  // namespace render_detail

template <class System>
struct Renderer<System>::Impl {
  struct Sizes {
    std::size_t vertices, triangles;
  };
  std::vector<Sizes> host;  // the arrays themselves live on the device only
  std::vector<std::unique_ptr<render_detail::DeviceMesh>> device;
  thrust::device_vector<MeshView> views;
};

template <class System>
Renderer<System>::Renderer(std::vector<Mesh> models) : impl_(std::make_unique<Impl>()) {
  validate_models(models);
  std::vector<MeshView> views;
  for (auto& mesh : models) {
    const MeshArrays arrays(std::move(mesh));
    impl_->host.push_back({arrays.vertices.size(), arrays.triangles.size() / 3});
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
CloudBatch Renderer<System>::render(const std::vector<Hypothesis>& hypotheses, const Intrinsics& camera,
                                    const RenderSettings& s, const Occluders* occluders) const {
  using namespace render_detail;
  validate_render_request(hypotheses, impl_->host.size(), camera, s, occluders);
  const int n = int(hypotheses.size());

  // Hypotheses and occluders to the device.
  std::vector<std::int32_t> model(n), label(n);
  std::vector<Rigid3f> T(n);
  for (int k = 0; k < n; ++k)
    model[k] = hypotheses[k].model, label[k] = hypotheses[k].label, T[k] = to_rigid(hypotheses[k].T_cam_obj);
  const thrust::device_vector<std::int32_t> d_model = to_device(model), d_label = to_device(label);
  const thrust::device_vector<Rigid3f> d_T = to_device(T);
  thrust::device_vector<float> d_occ_depth;
  thrust::device_vector<std::int32_t> d_occ_labels;
  OccluderView occ;
  if (occluders) {
    d_occ_depth = to_device(occluders->depth_m.data);
    d_occ_labels = to_device(occluders->labels.data);
    occ.depth_m = ptr(d_occ_depth);
    occ.labels = occluders->labels.empty() ? nullptr : ptr(d_occ_labels);
    occ.margin_m = s.occlusion_margin_m;
  }
  const HypothesisArgs args{ptr(impl_->views), ptr(d_model), ptr(d_T), ptr(d_label)};

  // ROIs on the device; their sizes come back once to plan the chunks.
  thrust::device_vector<GridRoi> d_roi(n);
  thrust::transform(thrust::device, thrust::counting_iterator<int>(0), thrust::counting_iterator<int>(n),
                    ptr(d_roi), ComputeRoi{args, camera, s.stride, s.near_m});
  const std::vector<GridRoi> roi = to_host(d_roi);

  // Bytes per ROI sample: z-buffer word, resolved sample, visibility flag and slot.
  constexpr std::size_t kPixelBytes = sizeof(DepthTriangle) + sizeof(RenderedSample) + 4 + 8;
  CloudBatch batch;
  batch.offsets.assign(std::size_t(n) + 1, 0);
  DeviceDomain d_vertices, d_triangles, d_pixels;
  thrust::device_vector<std::int64_t> d_slot, d_starts;
  thrust::device_vector<Vec3f> d_verts_cam;
  thrust::device_vector<GridSpan> d_spans;
  thrust::device_vector<DepthTriangle> d_zbuf;
  thrust::device_vector<RenderedSample> d_samples;
  thrust::device_vector<std::int32_t> d_visible, d_pixel, d_cloud;
  thrust::device_vector<float> d_x, d_y, d_z;
  thrust::device_vector<std::uint32_t> d_rgb;
  using Items = thrust::counting_iterator<std::int64_t>;
  const std::size_t budget = s.memory_budget_bytes ? s.memory_budget_bytes : System::default_chunk_bytes;
  for (int first = 0; first < n;) {
    // Grow the chunk while it fits the budget (always at least one hypothesis).
    HostDomain vertices, triangles, pixels;
    int count = 0;
    std::size_t bytes = 0;
    while (first + count < n) {
      const auto& m = impl_->host[model[first + count]];
      const std::int64_t roi_size = roi[first + count].size();
      const std::size_t more =
          m.vertices * (sizeof(Vec3f) + sizeof(GridSpan)) + std::size_t(roi_size) * kPixelBytes;
      if (count > 0 && bytes + more > budget) break;
      bytes += more;
      vertices.add(std::int64_t(m.vertices));
      triangles.add(std::int64_t(m.triangles));
      pixels.add(roi_size);
      ++count;
    }
    const std::int64_t num_pixels = pixels.elements.back();
    d_verts_cam.resize(std::size_t(vertices.elements.back()));
    d_spans.resize(std::size_t(vertices.elements.back()));
    d_zbuf.assign(std::size_t(num_pixels), kEmptyPixel);
    const ChunkArgs c{first,
                      count,
                      ptr(d_roi) + first,
                      d_vertices.upload(vertices),
                      d_triangles.upload(triangles),
                      d_pixels.upload(pixels),
                      ptr(d_verts_cam),
                      ptr(d_spans),
                      ptr(d_zbuf)};

    thrust::for_each(Items(0), Items(vertices.blocks.back()),
                     TransformVertices{args, c, camera, s.stride, s.near_m});
    thrust::for_each(Items(0), Items(triangles.blocks.back()),
                     Rasterize{args, c, camera, s.stride, s.near_m, s.cull_back_faces});
    d_samples.resize(std::size_t(num_pixels));
    d_visible.resize(std::size_t(num_pixels));
    thrust::for_each(Items(0), Items(pixels.blocks.back()),
                     Resolve{args, c, camera, s.stride, occ, ptr(d_samples), ptr(d_visible)});

    // Compact: slot[k] = number of visible samples before k; slot[num_pixels] = chunk total.
    d_slot.resize(std::size_t(num_pixels) + 1);
    write_at(d_slot, 0, std::int64_t(0));
    // Raw pointers with an explicit policy: Thrust's OpenMP scan is sequential over device_reference
    // iterators, whose reads bind a reference through a null policy pointer (UBSan reports it).
    thrust::inclusive_scan(thrust::device, ptr(d_visible), ptr(d_visible) + num_pixels, ptr(d_slot) + 1,
                           thrust::plus<std::int64_t>());
    const std::int64_t total = read_at(d_slot, std::size_t(num_pixels));
    for (auto* v : {&d_x, &d_y, &d_z}) v->resize(std::size_t(total));
    d_rgb.resize(std::size_t(total)), d_pixel.resize(std::size_t(total)), d_cloud.resize(std::size_t(total));
    thrust::for_each(Items(0), Items(pixels.blocks.back()),
                     Scatter{c, ptr(d_samples), ptr(d_visible), ptr(d_slot), ptr(d_x), ptr(d_y), ptr(d_z),
                             ptr(d_rgb), ptr(d_pixel), ptr(d_cloud)});

    // Per-hypothesis offsets: the slot at the start of each ROI.
    d_starts.resize(std::size_t(count) + 1);
    thrust::gather(thrust::device, ptr(d_pixels.elements), ptr(d_pixels.elements) + count + 1, ptr(d_slot),
                   ptr(d_starts));
    const std::vector<std::int64_t> starts = to_host(d_starts);
    const std::int64_t at = std::int64_t(batch.size());
    for (int k = 1; k <= count; ++k) batch.offsets[first + k] = at + starts[k];

    const std::size_t m = std::size_t(total);
    append(batch.x, d_x, m), append(batch.y, d_y, m), append(batch.z, d_z, m);
    append(batch.rgb, d_rgb, m), append(batch.pixel, d_pixel, m), append(batch.cloud, d_cloud, m);
    first += count;
  }
  return batch;
}

}  // namespace perch2::thrust_backend
