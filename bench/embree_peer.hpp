// Embree 3 as the renderer's peer in bench_render (optional: Debian libembree-dev; PERCH2_HAVE_EMBREE).
//
// What a user would build with Embree to get perch2's output: one BVH per model in its object frame, built
// once (robust mode: rays do not slip through shared edges); per hypothesis one ray per sample of the same
// stride-grid ROI, transformed into the object frame and traced as one coherent stream; each hit becomes a
// camera-frame point with its colour (same texture / vertex-colour shading) and pixel index, in the same
// CloudBatch layout. Embree has no back-face culling in Debian's build; for closed meshes the nearest hit
// faces the camera anyway.
#pragma once

#include <embree3/rtcore.h>
#include <omp.h>

#include <stdexcept>
#include <vector>

#include "perch2/core/cloud.hpp"
#include "perch2/render/mesh_arrays.hpp"
#include "perch2/render/render.hpp"

namespace perch2::bench {

class EmbreeRenderer {
 public:
  explicit EmbreeRenderer(std::vector<Mesh> models) : device_(rtcNewDevice(nullptr)) {
    if (!device_) throw std::runtime_error("rtcNewDevice failed");
    for (auto& mesh : models) meshes_.emplace_back(std::move(mesh));
    for (const MeshArrays& m : meshes_) {
      RTCGeometry g = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
      // Embree reads vertex buffers in 16-byte loads: one float of padding after the last vertex.
      float* v = static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                             3 * sizeof(float), m.vertices.size() + 1));
      for (std::size_t k = 0; k < m.vertices.size(); ++k)
        v[3 * k] = m.vertices[k].x, v[3 * k + 1] = m.vertices[k].y, v[3 * k + 2] = m.vertices[k].z;
      auto* t = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                               3 * sizeof(unsigned), m.triangles.size() / 3));
      for (std::size_t k = 0; k < m.triangles.size(); ++k) t[k] = unsigned(m.triangles[k]);
      rtcCommitGeometry(g);
      RTCScene s = rtcNewScene(device_);
      rtcSetSceneFlags(s, RTC_SCENE_FLAG_ROBUST);
      rtcSetSceneBuildQuality(s, RTC_BUILD_QUALITY_HIGH);
      rtcAttachGeometry(s, g);
      rtcReleaseGeometry(g);
      rtcCommitScene(s);
      scenes_.push_back(s);
      views_.push_back(m.host_view());
    }
  }
  ~EmbreeRenderer() {
    for (RTCScene s : scenes_) rtcReleaseScene(s);
    rtcReleaseDevice(device_);
  }
  EmbreeRenderer(const EmbreeRenderer&) = delete;
  EmbreeRenderer& operator=(const EmbreeRenderer&) = delete;

  CloudBatch render(const std::vector<Hypothesis>& hyps, const Intrinsics& K, const RenderSettings& s) const {
    const int n = int(hyps.size());
    std::vector<std::vector<RenderedSample>> local(hyps.size());
    std::vector<std::vector<RTCRayHit>> rays(static_cast<std::size_t>(omp_get_max_threads()));
#pragma omp parallel for schedule(dynamic, 1)
    for (int h = 0; h < n; ++h) trace_one(hyps[h], K, s, rays[omp_get_thread_num()], local[h]);
    CloudBatch batch;
    batch.offsets.assign(hyps.size() + 1, 0);
    for (int h = 0; h < n; ++h) {
      const std::size_t at = batch.size();
      batch.resize(at + local[h].size());
      for (std::size_t k = 0; k < local[h].size(); ++k) {
        const RenderedSample& p = local[h][k];
        batch.x[at + k] = p.p_cam.x, batch.y[at + k] = p.p_cam.y, batch.z[at + k] = p.p_cam.z;
        batch.rgb[at + k] = p.rgb, batch.pixel[at + k] = p.pixel, batch.cloud[at + k] = h;
      }
      batch.offsets[h + 1] = std::int64_t(batch.size());
    }
    return batch;
  }

 private:
  void trace_one(const Hypothesis& hyp, const Intrinsics& K, const RenderSettings& s,
                 std::vector<RTCRayHit>& rays, std::vector<RenderedSample>& out) const {
    const MeshView& m = views_[hyp.model];
    const Rigid3f T = to_rigid(hyp.T_cam_obj);
    const GridRoi roi = model_roi(m, T, K, s.stride, s.near_m);
    rays.resize(std::size_t(roi.size()));
    // Object frame: origin R^T (0 - t), direction R^T d. |R^T d| = |d|, so the hit distance is the depth.
    const Vec3f org{-(T.R.m[0] * T.t.x + T.R.m[3] * T.t.y + T.R.m[6] * T.t.z),
                    -(T.R.m[1] * T.t.x + T.R.m[4] * T.t.y + T.R.m[7] * T.t.z),
                    -(T.R.m[2] * T.t.x + T.R.m[5] * T.t.y + T.R.m[8] * T.t.z)};
    const GridRays grid(K, s.stride);
    for (int j = 0; j < roi.height; ++j)
      for (int i = 0; i < roi.width; ++i) {
        const Vec3f d = grid(roi.i0 + i, roi.j0 + j);
        RTCRayHit& r = rays[std::size_t(j) * roi.width + i];
        r.ray.org_x = org.x, r.ray.org_y = org.y, r.ray.org_z = org.z;
        r.ray.dir_x = T.R.m[0] * d.x + T.R.m[3] * d.y + T.R.m[6] * d.z;
        r.ray.dir_y = T.R.m[1] * d.x + T.R.m[4] * d.y + T.R.m[7] * d.z;
        r.ray.dir_z = T.R.m[2] * d.x + T.R.m[5] * d.y + T.R.m[8] * d.z;
        r.ray.tnear = s.near_m, r.ray.tfar = 1e30f, r.ray.time = 0, r.ray.mask = ~0u, r.ray.id = 0;
        r.ray.flags = 0;
        r.hit.geomID = RTC_INVALID_GEOMETRY_ID, r.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
      }
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    rtcIntersect1M(scenes_[hyp.model], &ctx, rays.data(), unsigned(rays.size()), sizeof(RTCRayHit));
    out.clear();
    for (int j = 0; j < roi.height; ++j)
      for (int i = 0; i < roi.width; ++i) {
        const RTCRayHit& r = rays[std::size_t(j) * roi.width + i];
        if (r.hit.geomID == RTC_INVALID_GEOMETRY_ID) continue;
        const int u = s.stride * (roi.i0 + i), v = s.stride * (roi.j0 + j);
        const std::int32_t* f = m.triangles + 3 * r.hit.primID;
        const Vec3f hit_obj{r.ray.org_x + r.ray.tfar * r.ray.dir_x, r.ray.org_y + r.ray.tfar * r.ray.dir_y,
                            r.ray.org_z + r.ray.tfar * r.ray.dir_z};
        RenderedSample p;
        p.p_cam = r.ray.tfar * grid(roi.i0 + i, roi.j0 + j);
        p.rgb = pack_rgb(
            shade(m, int(r.hit.primID), m.vertices[f[0]], m.vertices[f[1]], m.vertices[f[2]], hit_obj));
        p.pixel = v * K.width + u;
        out.push_back(p);
      }
  }

  RTCDevice device_;
  std::vector<MeshArrays> meshes_;
  std::vector<MeshView> views_;
  std::vector<RTCScene> scenes_;
};

}  // namespace perch2::bench
