// Triangle clusters (per-cluster back-face culling): they partition the triangles, bound them, and culling
// them never changes what is rendered.
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

}  // namespace

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
