// Reference batch renderer: hypotheses in parallel (OpenMP), each with a private z-buffer over its ROI.
#include "perch2/cpu/render.hpp"

#include <omp.h>

#include <algorithm>

#include "perch2/render/mesh_arrays.hpp"
#include "perch2/render/raster.hpp"

namespace perch2::cpu {
namespace {

/// One hypothesis' visible samples, in raster order of the stride grid.
struct LocalCloud {
  std::vector<RenderedSample> samples;
};

/// Scratch reused by one thread across hypotheses (no per-hypothesis frame allocation). Grows only: the
/// rendering overwrites what it reads.
struct Scratch {
  std::vector<DepthTriangle> zbuf;
  std::vector<PosedPoint> verts_cam;
  std::vector<GridSpan> spans;
  std::vector<std::int32_t> front_clusters;
  std::vector<std::uint64_t> vertex_blocks;
  std::vector<RenderedSample> samples;  ///< room for an ROI's samples; the visible ones are copied out
};

template <class T>
T* at_least(std::vector<T>& v, int n) {
  if (v.size() < std::size_t(n)) v.resize(std::size_t(n));
  return v.data();
}

void render_one(const MeshView& m, const Rigid3f& T_cam_obj, std::int32_t label, const RenderParams& p,
                Scratch& scratch, LocalCloud& out) {
  const GridRoi roi = model_roi(m, T_cam_obj, p.K, p.stride, p.near_m);
  const HypothesisScratch s{at_least(scratch.verts_cam, m.num_vertices),
                            at_least(scratch.spans, m.num_vertices), at_least(scratch.zbuf, roi.size()),
                            at_least(scratch.front_clusters, m.num_clusters),
                            at_least(scratch.vertex_blocks, vertex_block_words(m.num_vertices))};
  RenderedSample* samples = at_least(scratch.samples, roi.size());
  const int n = render_hypothesis(m, T_cam_obj, label, roi, p, s, samples);
  out.samples.assign(samples, samples + n);
}

}  // namespace

struct Renderer::Impl {
  std::vector<MeshArrays> meshes;
  std::vector<MeshView> views;
};

Renderer::Renderer(std::vector<Mesh> models) : impl_(std::make_unique<Impl>()) {
  validate_models(models);
  impl_->meshes.reserve(models.size());
  for (auto& mesh : models) impl_->meshes.emplace_back(std::move(mesh));
  for (const auto& arrays : impl_->meshes) impl_->views.push_back(arrays.host_view());
}
Renderer::~Renderer() = default;
Renderer::Renderer(Renderer&&) noexcept = default;
Renderer& Renderer::operator=(Renderer&&) noexcept = default;
std::size_t Renderer::num_models() const {
  return impl_->meshes.size();
}

CloudBatch Renderer::render(const std::vector<Hypothesis>& hypotheses, const Intrinsics& camera,
                            const RenderSettings& settings, const Occluders* occluders) const {
  validate_render_request(hypotheses, impl_->meshes.size(), camera, settings, occluders);
  RenderParams p{camera, settings.stride, settings.near_m, settings.cull_back_faces, OccluderView{}};
  if (occluders) {
    p.occ.depth_m = occluders->depth_m.data.data();
    p.occ.labels = occluders->labels.empty() ? nullptr : occluders->labels.data.data();
    p.occ.margin_m = settings.occlusion_margin_m;
  }
  const int n = int(hypotheses.size());
  std::vector<Rigid3f> T(static_cast<std::size_t>(n));
  for (int h = 0; h < n; ++h) T[h] = to_rigid(hypotheses[h].T_cam_obj);

  CloudBatch batch;
  batch.offsets.assign(std::size_t(n) + 1, 0);
  constexpr int kChunk = 256;  // bounds the per-hypothesis outputs held before they are appended
  std::vector<LocalCloud> local(std::size_t(std::min(n, kChunk)));
  std::vector<Scratch> scratch(static_cast<std::size_t>(omp_get_max_threads()));
  for (int begin = 0; begin < n; begin += kChunk) {
    const int end = std::min(n, begin + kChunk);
#pragma omp parallel for schedule(dynamic, 1)
    for (int h = begin; h < end; ++h)
      render_one(impl_->views[hypotheses[h].model], T[h], hypotheses[h].label, p,
                 scratch[omp_get_thread_num()], local[h - begin]);
    for (int h = begin; h < end; ++h) {
      const auto& samples = local[h - begin].samples;
      const std::size_t at = batch.size();
      batch.resize(at + samples.size());
      for (std::size_t k = 0; k < samples.size(); ++k) {
        batch.x[at + k] = samples[k].p_cam.x, batch.y[at + k] = samples[k].p_cam.y;
        batch.z[at + k] = samples[k].p_cam.z, batch.rgb[at + k] = samples[k].rgb;
        batch.pixel[at + k] = samples[k].pixel, batch.cloud[at + k] = h;
      }
      batch.offsets[h + 1] = std::int64_t(batch.size());
    }
  }
  return batch;
}

}  // namespace perch2::cpu
