// Triangle clusters (per-cluster back-face culling): they partition the triangles, bound them, and culling
// them, or posing only the vertices of those that face the camera, never changes what is rendered. The grid
// filter (grid_candidates) drops only triangles that cover no sample.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#include "perch2/io/io.hpp"
#include "perch2/render/mesh_arrays.hpp"
#include "render_fixtures.hpp"
#include "test_support.hpp"

using namespace perch2;

namespace {

/// The ROI z-buffer of one pose, rasterised through `m` (with or without its clusters).
std::vector<DepthTriangle> zbuffer(const MeshView& m, const Pose& T_cam_obj, const Intrinsics& K,
                                   int stride) {
  const Rigid3f T = to_rigid(T_cam_obj);
  const GridRoi roi = model_roi(m, T, K, stride, 0.01f);
  std::vector<PosedPoint> p_cam(std::size_t(m.num_vertices));
  std::vector<GridSpan> spans(std::size_t(m.num_vertices));
  pose_vertices(m, T, K, stride, 0.01f, 0, m.num_vertices, p_cam.data(), spans.data());
  std::vector<DepthTriangle> z(std::size_t(roi.size()), kEmptyPixel);
  DepthTriangle* zb = z.data();
  rasterize_triangles(m, PosedVertices{p_cam.data(), spans.data()}, 0, m.num_triangles, T, K, stride, 0.01f,
                      roi, true, [zb](int k, DepthTriangle w) { zb[k] = std::min(zb[k], w); });
  return z;
}

/// The corners of every triangle (position and colour), in a canonical order of the triangles.
std::vector<std::array<float, 18>> corner_list(const std::vector<Vec3f>& v, const std::vector<Rgb8>& colors,
                                               const std::vector<std::int32_t>& triangles) {
  std::vector<std::array<float, 18>> out;
  for (std::size_t t = 0; t < triangles.size(); t += 3) {
    std::array<float, 18> c{};
    for (int k = 0; k < 3; ++k) {
      const std::size_t i = std::size_t(triangles[t + std::size_t(k)]);
      const Rgb8 rgb = colors.empty() ? Rgb8{0, 0, 0} : colors[i];
      const float corner[6] = {v[i].x, v[i].y, v[i].z, float(rgb.r), float(rgb.g), float(rgb.b)};
      std::copy(corner, corner + 6, c.begin() + 6 * k);
    }
    out.push_back(c);
  }
  std::sort(out.begin(), out.end());
  return out;
}

/// MeshArrays::block_vertices: the same triangles (corner positions and colours), vertices numbered in order
/// of first use, vertex_xyz the vertices, and every corner's block in its cluster's masks.
void check_vertex_blocks(const Mesh& original, const MeshArrays& a) {
  std::vector<Vec3f> v0;
  std::vector<std::int32_t> t0;
  for (const auto& p : original.vertices) v0.push_back({p.x(), p.y(), p.z()});
  for (const auto& t : original.triangles) t0.insert(t0.end(), {t[0], t[1], t[2]});
  REQUIRE(corner_list(v0, original.vertex_colors, t0) ==
          corner_list(a.vertices, a.vertex_colors, a.triangles));
  const std::size_t nv = a.vertices.size();
  REQUIRE(a.vertex_xyz.size() == 3 * nv);
  for (std::size_t k = 0; k < nv; ++k)
    REQUIRE((a.vertex_xyz[k] == a.vertices[k].x && a.vertex_xyz[nv + k] == a.vertices[k].y &&
             a.vertex_xyz[2 * nv + k] == a.vertices[k].z));
  std::int32_t next_new = 0;
  for (const std::int32_t v : a.triangles) {
    REQUIRE(v <= next_new);  // first used in order
    next_new = std::max(next_new, v + 1);
  }
  for (const TriangleCluster& c : a.clusters)
    for (int t = c.first; t < c.first + c.count; ++t)
      for (int k = 0; k < 3; ++k) {
        const int block = a.triangles[std::size_t(3 * t + k)] / kPoseBlock;
        bool found = false;
        for (int m = c.first_mask; m < c.first_mask + c.num_masks; ++m)
          found = found || (a.vertex_masks[std::size_t(m)].word == block / 64 &&
                            (a.vertex_masks[std::size_t(m)].bits >> (block % 64) & 1u));
        REQUIRE(found);
      }
}

/// render_hypothesis posing only the vertex blocks of the front-facing clusters renders what posing every
/// vertex renders (random poses, some crossing the near plane; strides 1 and 4).
void check_front_cluster_posing(Mesh mesh, int num_poses, float z_min, float z_max, unsigned seed) {
  const MeshArrays a(std::move(mesh));
  const MeshView blocked = a.host_view();
  REQUIRE(blocked.vertex_masks != nullptr);
  MeshView every = blocked;
  every.vertex_masks = nullptr;
  const Intrinsics K = test::vga_camera();
  std::mt19937 rng(seed);
  std::vector<PosedPoint> p_cam(a.vertices.size());
  std::vector<GridSpan> spans(a.vertices.size());
  std::vector<std::int32_t> front(a.clusters.size());
  std::vector<std::uint64_t> blocks(std::size_t(vertex_block_words(int(a.vertices.size()))));
  std::size_t samples = 0;
  for (int k = 0; k < num_poses; ++k) {
    const Rigid3f T = to_rigid(test::random_pose(rng, z_min, z_max));
    for (const int stride : {1, 4}) {
      const RenderParams p{K, stride, 0.01f, true, OccluderView{}};
      const GridRoi roi = model_roi(blocked, T, K, stride, p.near_m);
      std::vector<DepthTriangle> zbuf(std::size_t(roi.size()));
      const HypothesisScratch s{p_cam.data(), spans.data(), zbuf.data(), front.data(), blocks.data()};
      const auto render = [&](const MeshView& m) {
        // Stale values that would render if read: points behind the camera with spans over the whole grid.
        std::fill(p_cam.begin(), p_cam.end(), PosedPoint{0.f, 0.f, -1.f, 0.f});
        std::fill(spans.begin(), spans.end(), GridSpan{0, 0, -kMaxGridSize, -kMaxGridSize, 0.f, 0.f});
        std::vector<RenderedSample> out(std::size_t(roi.size()));
        out.resize(std::size_t(render_hypothesis(m, T, 0, roi, p, s, out.data())));
        return out;
      };
      const std::vector<RenderedSample> x = render(blocked), y = render(every);
      REQUIRE(x.size() == y.size());
      REQUIRE(std::memcmp(x.data(), y.data(), x.size() * sizeof(RenderedSample)) == 0);
      samples += x.size();
    }
  }
  CHECK(samples > 0);
}

void check_clusters(Mesh mesh) {
  const Mesh original = mesh;
  const MeshArrays a(std::move(mesh));
  const int n = int(a.triangles.size() / 3);
  REQUIRE(n == int(original.triangles.size()));
  // A partition of the triangles, in order.
  int next = 0;
  for (const TriangleCluster& c : a.clusters) {
    REQUIRE(c.first == next);
    REQUIRE(c.count >= 1);
    REQUIRE(c.count <= MeshArrays::kClusterTriangles);
    next += c.count;
  }
  REQUIRE(next == n);
  check_vertex_blocks(original, a);
  // Bounds: every corner inside the sphere, every unit normal inside the cone.
  for (const TriangleCluster& c : a.clusters)
    for (int t = c.first; t < c.first + c.count; ++t) {
      const Vec3f p[3] = {a.vertices[a.triangles[3 * t]], a.vertices[a.triangles[3 * t + 1]],
                          a.vertices[a.triangles[3 * t + 2]]};
      for (const Vec3f& q : p) CHECK(std::sqrt(squared_norm(q - c.center)) <= c.radius);
      const Vec3f nrm = cross(p[1] - p[0], p[2] - p[0]);
      const float len = std::sqrt(squared_norm(nrm));
      if (len > 0.f && c.cos_half > 0.f) CHECK(dot(c.axis, (1.f / len) * nrm) >= c.cos_half);
    }
}

void check_culling_changes_nothing(Mesh mesh, int num_poses, float z_min, float z_max, unsigned seed) {
  const MeshArrays a(std::move(mesh));
  const MeshView clustered = a.host_view();
  REQUIRE(clustered.clusters != nullptr);
  MeshView plain = clustered;
  plain.clusters = nullptr, plain.num_clusters = 0;
  const Intrinsics K = test::vga_camera();
  std::mt19937 rng(seed);
  std::size_t culled = 0, total = 0;
  for (int k = 0; k < num_poses; ++k) {
    const Pose T = test::random_pose(rng, z_min, z_max);
    const Vec3f cam = camera_in_object(to_rigid(T));
    for (const TriangleCluster& c : a.clusters)
      culled += cluster_faces_away(c, cam) ? std::size_t(c.count) : 0;
    total += a.triangles.size() / 3;
    for (int stride : {1, 4}) REQUIRE(zbuffer(clustered, T, K, stride) == zbuffer(plain, T, K, stride));
  }
  MESSAGE("clusters culled " << 100.0 * double(culled) / double(total) << "% of the triangles");
  CHECK(culled > total / 4);  // a closed model shows about half its triangles back-facing
}

/// grid_candidates over random poses (some crossing the near plane), strides and ROIs: it returns exactly
/// the triangles span_may_cover accepts (the SSE2 path equals the scalar one), and every triangle it drops
/// has all corners in front of the near plane and no ROI sample inside its projected bounding box
/// (computed in double precision, independently of the spans).
void check_grid_candidates(Mesh mesh, int num_poses, float z_min, float z_max, unsigned seed) {
  const MeshArrays a(std::move(mesh));
  const MeshView m = a.host_view();
  const Intrinsics K = test::vga_camera();
  constexpr float kNear = 0.01f;
  std::mt19937 rng(seed);
  std::size_t kept = 0, dropped = 0, behind = 0;
  for (int k = 0; k < num_poses; ++k) {
    const Rigid3f T = to_rigid(test::random_pose(rng, z_min, z_max));
    for (int stride : {1, 3, 4, 8}) {
      std::vector<PosedPoint> p_cam(std::size_t(m.num_vertices));
      std::vector<GridSpan> spans(std::size_t(m.num_vertices));
      pose_vertices(m, T, K, stride, kNear, 0, m.num_vertices, p_cam.data(), spans.data());
      const GridRoi full{0, 0, K.grid_width(stride), K.grid_height(stride)};
      const GridRoi model = model_roi(m, T, K, stride, kNear);
      const GridRoi part{full.width / 3, full.height / 4, full.width / 3, full.height / 2};
      for (const GridRoi& roi : {full, model, part}) {
        std::vector<char> listed(std::size_t(m.num_triangles), 0);
        int list[kCandidateBatch];
        GridCover covers[kCandidateBatch];
        for (int first = 0; first < m.num_triangles; first += kCandidateBatch) {
          const int last = std::min(m.num_triangles, first + kCandidateBatch);
          const int n = grid_candidates(m.triangles, spans.data(), first, last, roi, list, covers);
          std::vector<int> expected;
          for (int t = first; t < last; ++t) {
            const std::int32_t* f = m.triangles + 3 * t;
            if (span_may_cover(spans[f[0]], spans[f[1]], spans[f[2]], roi)) expected.push_back(t);
          }
          REQUIRE(std::vector<int>(list, list + n) == expected);
          for (int i = 0; i < n; ++i) {
            listed[std::size_t(list[i])] = 1;
            const std::int32_t* f = m.triangles + 3 * list[i];
            const GridRoi c = span_cover(spans[f[0]], spans[f[1]], spans[f[2]], roi);  // the cover it reports
            REQUIRE((covers[i].i0 == c.i0 && covers[i].j0 == c.j0 &&
                     -covers[i].neg_i1 == c.i0 + c.width - 1 && -covers[i].neg_j1 == c.j0 + c.height - 1));
          }
        }
        for (int t = 0; t < m.num_triangles; ++t) {
          const std::int32_t* f = m.triangles + 3 * t;
          double u0 = 1e300, v0 = 1e300, u1 = -1e300, v1 = -1e300;
          bool in_front = true;
          for (int c = 0; c < 3; ++c) {
            const PosedPoint p = p_cam[std::size_t(f[c])];
            in_front = in_front && p.z >= kNear;
            const double u = double(K.fx) * p.x / p.z + K.cx, v = double(K.fy) * p.y / p.z + K.cy;
            u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
          }
          behind += in_front ? 0 : 1;
          if (listed[std::size_t(t)]) {
            ++kept;
            continue;
          }
          ++dropped;
          REQUIRE(in_front);
          constexpr double kTol = 1e-4;  // px: float rounding of the projection, far below the spans' 1e-3
          const int i_lo = std::max(roi.i0, int(std::ceil((u0 + kTol) / stride)));
          const int i_hi = std::min(roi.i0 + roi.width - 1, int(std::floor((u1 - kTol) / stride)));
          const int j_lo = std::max(roi.j0, int(std::ceil((v0 + kTol) / stride)));
          const int j_hi = std::min(roi.j0 + roi.height - 1, int(std::floor((v1 - kTol) / stride)));
          CHECK((i_lo > i_hi || j_lo > j_hi));
        }
      }
    }
  }
  MESSAGE("grid filter kept " << kept << ", dropped " << dropped << " triangles (" << behind
                              << " with a corner behind the near plane)");
  CHECK(dropped > kept);  // small triangles at stride >= 3 mostly miss every sample
  CHECK(behind > 0);      // the near-plane path was exercised
}

}  // namespace

TEST_CASE("the grid filter drops exactly the triangles whose bounds contain no sample") {
  std::mt19937 rng(7);
  check_grid_candidates(test::make_blob(rng, 0.05f, 30, 40), 40, 0.0f, 0.4f, 4);
  check_grid_candidates(test::lumpy_sphere(0.06f, 71, 72), 20, 0.0f, 1.2f, 5);
}

TEST_CASE("triangle clusters partition the triangles and bound their corners and normals") {
  std::mt19937 rng(3);
  check_clusters(test::make_blob(rng, 0.05f, 30, 40));
  check_clusters(test::lumpy_sphere(0.06f, 71, 72));
  check_clusters(test::make_box(0.1f, 0.2f, 0.3f));
  check_clusters(test::make_quad(0.2f, test::make_ramp_texture()));
}

TEST_CASE("culling clusters that face away renders the same z-buffer as culling triangle by triangle") {
  std::mt19937 rng(5);
  check_culling_changes_nothing(test::make_blob(rng, 0.05f, 30, 40), 60, 0.3f, 1.2f, 1);
  check_culling_changes_nothing(test::lumpy_sphere(0.06f, 71, 72), 60, 0.3f, 1.2f, 2);
}

TEST_CASE("posing only the vertex blocks of front-facing clusters renders what posing every vertex renders") {
  std::mt19937 rng(9);
  check_front_cluster_posing(test::make_blob(rng, 0.05f, 30, 40), 60, 0.0f, 1.2f, 6);
  check_front_cluster_posing(test::lumpy_sphere(0.06f, 71, 72), 40, 0.0f, 1.2f, 7);
}

TEST_CASE("cluster culling changes nothing on the scanned LINEMOD cat") {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/linemod_obj_06/obj_06.ply");
  io::MeshLoadOptions mm;
  mm.scale = 0.001f;
  check_clusters(io::load_mesh(path, mm));
  check_culling_changes_nothing(io::load_mesh(path, mm), 40, 0.35f, 1.6f, 3);
  check_front_cluster_posing(io::load_mesh(path, mm), 40, 0.0f, 1.6f, 8);
}
