// Embree 3 as the renderer's peer in bench_render (optional: Debian libembree-dev; PERCH2_HAVE_EMBREE).
//
// What a competent user would build with Embree to get perch2's output: one BVH per model in its object
// frame, built once (robust mode: rays do not slip through shared edges); per hypothesis one ray per sample
// of the same stride-grid ROI, transformed into the object frame; each hit becomes a camera-frame point with
// its colour (same texture / vertex-colour shading) and pixel index, in the same CloudBatch layout. Every
// thread that traces sets flush-to-zero and denormals-are-zero in MXCSR first, as Embree's documentation
// asks of every application. How rays are traced (one at a time, as a stream, or as packets of 8 / 16
// over 4x2 / 4x4 tiles) and the BVH build quality are options, so bench_render can measure them all
// (--embree-trace, --embree-quality); the defaults are the fastest measured (EmbreeSettings). Embree has no
// back-face culling in Debian's build; for closed meshes the nearest hit faces the camera anyway.
#pragma once

#include <embree3/rtcore.h>
#include <omp.h>
#include <xmmintrin.h>

#include <stdexcept>
#include <string>
#include <vector>

#include "perch2/core/cloud.hpp"
#include "perch2/render/mesh_arrays.hpp"
#include "perch2/render/render.hpp"

namespace perch2::bench {

/// How the peer hands rays to Embree.
enum class EmbreeTrace { One, Stream, Packet8, Packet16 };

/// The defaults are the fastest measured here (README, "Render"; bench_render --interleave 1, medians of
/// per-round ratios to rtcIntersect1 on the sphere / the banana): packets of 16 rays (AVX-512 on this CPU)
/// over 4x4 tiles 1.28x / 1.09x, 8-ray packets 1.17x / 1.16x, the stream (rtcIntersect1M) 0.83x / 0.87x;
/// with 16-ray packets the medium (Embree's default) and high build qualities trace equally fast (1.01x /
/// 1.14x and 1.02x / 1.14x the low one).
struct EmbreeSettings {
  EmbreeTrace trace = EmbreeTrace::Packet16;
  RTCBuildQuality quality = RTC_BUILD_QUALITY_MEDIUM;
};

inline const char* trace_name(EmbreeTrace t) {
  switch (t) {
    case EmbreeTrace::One:
      return "rtcIntersect1";
    case EmbreeTrace::Stream:
      return "rtcIntersect1M";
    case EmbreeTrace::Packet8:
      return "rtcIntersect8";
    case EmbreeTrace::Packet16:
      return "rtcIntersect16";
  }
  return "?";
}
inline const char* quality_name(RTCBuildQuality q) {
  return q == RTC_BUILD_QUALITY_LOW ? "low" : q == RTC_BUILD_QUALITY_MEDIUM ? "medium" : "high";
}
inline EmbreeTrace parse_trace(const std::string& s) {
  if (s == "1") return EmbreeTrace::One;
  if (s == "1M") return EmbreeTrace::Stream;
  if (s == "8") return EmbreeTrace::Packet8;
  if (s == "16") return EmbreeTrace::Packet16;
  throw std::invalid_argument("--embree-trace: expected 1, 1M, 8 or 16, got '" + s + "'");
}
inline RTCBuildQuality parse_quality(const std::string& s) {
  if (s == "low") return RTC_BUILD_QUALITY_LOW;
  if (s == "medium") return RTC_BUILD_QUALITY_MEDIUM;
  if (s == "high") return RTC_BUILD_QUALITY_HIGH;
  throw std::invalid_argument("--embree-quality: expected low, medium or high, got '" + s + "'");
}

/// Sets flush-to-zero and denormals-are-zero on this thread for its lifetime, restoring MXCSR after.
class FlushDenormals {
 public:
  FlushDenormals() : saved_(_mm_getcsr()) { _mm_setcsr(saved_ | 0x8040u); }  // FTZ (bit 15) | DAZ (bit 6)
  ~FlushDenormals() { _mm_setcsr(saved_); }
  FlushDenormals(const FlushDenormals&) = delete;
  FlushDenormals& operator=(const FlushDenormals&) = delete;

 private:
  unsigned saved_;
};

class EmbreeRenderer {
 public:
  explicit EmbreeRenderer(std::vector<Mesh> models, EmbreeSettings settings = {})
      : settings_(settings), device_(rtcNewDevice(nullptr)) {
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
      rtcSetGeometryBuildQuality(g, settings_.quality);
      rtcCommitGeometry(g);
      RTCScene s = rtcNewScene(device_);
      rtcSetSceneFlags(s, RTC_SCENE_FLAG_ROBUST);
      rtcSetSceneBuildQuality(s, settings_.quality);
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
    std::vector<std::vector<RTCRayHit>> streams(static_cast<std::size_t>(omp_get_max_threads()));
#pragma omp parallel
    {
      const FlushDenormals ftz_daz;
#pragma omp for schedule(dynamic, 1)
      for (int h = 0; h < n; ++h) trace_one(hyps[h], K, s, streams[omp_get_thread_num()], local[h]);
    }
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
  /// One hypothesis' rays: the camera centre and grid rays expressed in the object frame.
  struct ObjectRays {
    Vec3f org;
    Rigid3f T;
    GridRays grid;
    /// Object frame: R^T d. |R^T d| = |d|, so the hit distance along it is the camera-frame depth.
    Vec3f dir(int i, int j) const {
      const Vec3f d = grid(i, j);
      return {T.R.m[0] * d.x + T.R.m[3] * d.y + T.R.m[6] * d.z,
              T.R.m[1] * d.x + T.R.m[4] * d.y + T.R.m[7] * d.z,
              T.R.m[2] * d.x + T.R.m[5] * d.y + T.R.m[8] * d.z};
    }
  };

  void trace_one(const Hypothesis& hyp, const Intrinsics& K, const RenderSettings& s,
                 std::vector<RTCRayHit>& stream, std::vector<RenderedSample>& out) const {
    const MeshView& m = views_[hyp.model];
    const Rigid3f T = to_rigid(hyp.T_cam_obj);
    const GridRoi roi = model_roi(m, T, K, s.stride, s.near_m);
    const ObjectRays rays{camera_in_object(T), T, GridRays(K, s.stride)};
    const RTCScene scene = scenes_[hyp.model];
    out.clear();
    // A hit (depth along the grid ray = tfar) at grid sample (i, j) of triangle `prim`, in raster order.
    const auto emit = [&](int i, int j, float tfar, unsigned prim) {
      const std::int32_t* f = m.triangles + 3 * prim;
      const Vec3f d = rays.dir(i, j);
      const Vec3f hit_obj{rays.org.x + tfar * d.x, rays.org.y + tfar * d.y, rays.org.z + tfar * d.z};
      RenderedSample p;
      p.p_cam = tfar * rays.grid(i, j);
      p.rgb = pack_rgb(shade(m, int(prim), m.vertices[f[0]], m.vertices[f[1]], m.vertices[f[2]], hit_obj));
      p.pixel = s.stride * j * K.width + s.stride * i;
      out.push_back(p);
    };
    switch (settings_.trace) {
      case EmbreeTrace::One:
        return trace_single(scene, roi, rays, s.near_m, emit);
      case EmbreeTrace::Stream:
        return trace_stream(scene, roi, rays, s.near_m, stream, emit);
      case EmbreeTrace::Packet8:
        return trace_packets<RTCRayHit8, 4, 2>(scene, roi, rays, s.near_m, emit);
      case EmbreeTrace::Packet16:
        return trace_packets<RTCRayHit16, 4, 4>(scene, roi, rays, s.near_m, emit);
    }
  }

  /// rtcIntersect1 per ray, in raster order.
  template <class Emit>
  static void trace_single(RTCScene scene, const GridRoi& roi, const ObjectRays& rays, float near_m,
                           const Emit& emit) {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    for (int j = roi.j0; j < roi.j0 + roi.height; ++j)
      for (int i = roi.i0; i < roi.i0 + roi.width; ++i) {
        RTCRayHit r;
        set_ray(r.ray, rays.org, rays.dir(i, j), near_m);
        r.hit.geomID = RTC_INVALID_GEOMETRY_ID, r.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(scene, &ctx, &r);
        if (r.hit.geomID != RTC_INVALID_GEOMETRY_ID) emit(i, j, r.ray.tfar, r.hit.primID);
      }
  }

  /// One coherent stream of the ROI's rays (rtcIntersect1M), then the hits in raster order.
  template <class Emit>
  static void trace_stream(RTCScene scene, const GridRoi& roi, const ObjectRays& rays, float near_m,
                           std::vector<RTCRayHit>& stream, const Emit& emit) {
    stream.resize(std::size_t(roi.size()));
    for (int j = 0; j < roi.height; ++j)
      for (int i = 0; i < roi.width; ++i) {
        RTCRayHit& r = stream[std::size_t(j) * roi.width + i];
        set_ray(r.ray, rays.org, rays.dir(roi.i0 + i, roi.j0 + j), near_m);
        r.hit.geomID = RTC_INVALID_GEOMETRY_ID, r.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
      }
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    rtcIntersect1M(scene, &ctx, stream.data(), unsigned(stream.size()), sizeof(RTCRayHit));
    for (int j = 0; j < roi.height; ++j)
      for (int i = 0; i < roi.width; ++i) {
        const RTCRayHit& r = stream[std::size_t(j) * roi.width + i];
        if (r.hit.geomID != RTC_INVALID_GEOMETRY_ID) emit(roi.i0 + i, roi.j0 + j, r.ray.tfar, r.hit.primID);
      }
  }

  /// Packets over TW x TH tiles of the ROI (lanes outside it invalid); the hits are emitted in raster order
  /// (one row of tiles is traced, then emitted row by row).
  template <class Packet, int TW, int TH, class Emit>
  static void trace_packets(RTCScene scene, const GridRoi& roi, const ObjectRays& rays, float near_m,
                            const Emit& emit) {
    constexpr int N = TW * TH;
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    struct alignas(alignof(Packet)) Valid {  // Embree reads the mask with aligned vector loads
      int lane[N];
    };
    const int tiles_x = (roi.width + TW - 1) / TW;
    std::vector<Packet> row(static_cast<std::size_t>(tiles_x));
    std::vector<Valid> valid(static_cast<std::size_t>(tiles_x));
    for (int j0 = roi.j0; j0 < roi.j0 + roi.height; j0 += TH) {
      for (int t = 0; t < tiles_x; ++t) {
        Packet& p = row[std::size_t(t)];
        int* v = valid[std::size_t(t)].lane;
        for (int l = 0; l < N; ++l) {
          const int i = roi.i0 + t * TW + l % TW, j = j0 + l / TW;
          v[l] = (i < roi.i0 + roi.width && j < roi.j0 + roi.height) ? -1 : 0;
          const Vec3f d = rays.dir(i, j);
          p.ray.org_x[l] = rays.org.x, p.ray.org_y[l] = rays.org.y, p.ray.org_z[l] = rays.org.z;
          p.ray.dir_x[l] = d.x, p.ray.dir_y[l] = d.y, p.ray.dir_z[l] = d.z;
          p.ray.tnear[l] = near_m, p.ray.tfar[l] = 1e30f, p.ray.time[l] = 0, p.ray.mask[l] = ~0u;
          p.ray.id[l] = 0, p.ray.flags[l] = 0;
          p.hit.geomID[l] = RTC_INVALID_GEOMETRY_ID, p.hit.instID[0][l] = RTC_INVALID_GEOMETRY_ID;
        }
        intersect(v, scene, &ctx, &p);
      }
      for (int dj = 0; dj < TH && j0 + dj < roi.j0 + roi.height; ++dj)
        for (int t = 0; t < tiles_x; ++t)
          for (int di = 0; di < TW && roi.i0 + t * TW + di < roi.i0 + roi.width; ++di) {
            const Packet& p = row[std::size_t(t)];
            const int l = dj * TW + di;
            if (p.hit.geomID[l] != RTC_INVALID_GEOMETRY_ID)
              emit(roi.i0 + t * TW + di, j0 + dj, p.ray.tfar[l], p.hit.primID[l]);
          }
    }
  }
  static void intersect(const int* valid, RTCScene s, RTCIntersectContext* c, RTCRayHit8* p) {
    rtcIntersect8(valid, s, c, p);
  }
  static void intersect(const int* valid, RTCScene s, RTCIntersectContext* c, RTCRayHit16* p) {
    rtcIntersect16(valid, s, c, p);
  }

  static void set_ray(RTCRay& r, Vec3f org, Vec3f dir, float near_m) {
    r.org_x = org.x, r.org_y = org.y, r.org_z = org.z;
    r.dir_x = dir.x, r.dir_y = dir.y, r.dir_z = dir.z;
    r.tnear = near_m, r.tfar = 1e30f, r.time = 0, r.mask = ~0u, r.id = 0, r.flags = 0;
  }

  EmbreeSettings settings_;
  RTCDevice device_;
  std::vector<MeshArrays> meshes_;
  std::vector<MeshView> views_;
  std::vector<RTCScene> scenes_;
};

}  // namespace perch2::bench
