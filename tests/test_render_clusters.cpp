// Triangle clusters (per-cluster back-face culling): they partition the triangles, bound them, and culling
// them never changes what is rendered. The grid filter (grid_candidates) drops only triangles that cover
// no sample.
#include <cmath>
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

TEST_CASE("cluster culling changes nothing on the scanned LINEMOD cat") {
  PERCH2_REQUIRE_SHARED_DATA(path, "models/linemod_obj_06/obj_06.ply");
  io::MeshLoadOptions mm;
  mm.scale = 0.001f;
  check_clusters(io::load_mesh(path, mm));
  check_culling_changes_nothing(io::load_mesh(path, mm), 40, 0.35f, 1.6f, 3);
}
