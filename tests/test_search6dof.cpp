// 6-DoF PERCH 2.0: pose proposals (Section V-B) and the estimator (Fig. 4) on small generated scenes.
#include <doctest/doctest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <vector>

#include "perch2/search/proposals.hpp"
#include "perch2/synth/synth.hpp"
#include "test_support.hpp"

using namespace perch2;

namespace {

constexpr float kPi = 3.14159265f;

ModelSymmetries symmetries_of(const synth::ObjectModel& m) {
  return ModelSymmetries::from(m.symmetries.discrete, m.symmetries.continuous);
}

Pose rotation_pose(const Eigen::Vector3f& axis, float angle) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisf(angle, axis.normalized()).toRotationMatrix();
  return T;
}

}  // namespace

// ---- proposals -------------------------------------------------------------------------------------------

TEST_CASE("fibonacci directions are unit, evenly spread, and the hemisphere variant stays at z >= 0") {
  for (bool hemi : {false, true}) {
    const auto d = fibonacci_directions(80, hemi);
    REQUIRE(d.size() == 80);
    float min_nn = INFINITY, max_nn = 0;
    Eigen::Vector3f mean = Eigen::Vector3f::Zero();
    for (std::size_t i = 0; i < d.size(); ++i) {
      CHECK(d[i].norm() == doctest::Approx(1.f).epsilon(1e-5));
      if (hemi) CHECK(d[i].z() >= 0.f);
      mean += d[i];
      float nn = INFINITY;
      for (std::size_t j = 0; j < d.size(); ++j)
        if (j != i) nn = std::min(nn, std::acos(std::clamp(d[i].dot(d[j]), -1.f, 1.f)));
      min_nn = std::min(min_nn, nn), max_nn = std::max(max_nn, nn);
    }
    // Even: nearest-neighbour angles within a factor of 1.6 of each other (a random set of 80 points on
    // the sphere spans a factor of >5). 80 equal cells of the sphere are ~0.4 rad across.
    INFO("hemisphere " << hemi << " nn angles " << min_nn << " .. " << max_nn);
    CHECK(max_nn / min_nn < 1.6f);
    CHECK(min_nn > (hemi ? 0.18f : 0.3f));
    if (!hemi) CHECK(mean.norm() / 80.f < 0.02f);  // balanced: no side favoured
  }
}

TEST_CASE("rotation proposals: viewpoints x in-plane for an asymmetric model, all distinct") {
  ProposalSettings s;
  const auto R = rotation_proposals(s);
  CHECK(R.size() == std::size_t(s.viewpoints * s.inplane_rotations));  // 320: nothing merged
  for (const auto& r : R) CHECK((r * r.transpose() - Eigen::Matrix3f::Identity()).norm() < 1e-4f);
  const float threshold = symmetry_threshold(s, view_rotations(s));
  CHECK(threshold == doctest::Approx(0.33f).epsilon(0.02));  // 0.95 x the 80-viewpoint spacing
  for (std::size_t i = 0; i < R.size(); ++i)
    for (std::size_t j = 0; j < i; ++j) CHECK(rotation_angle(R[i], R[j]) >= threshold);
  // The view frame's z axis points from the camera at the object: for viewpoint v, R * (-v) = z.
  const auto v = fibonacci_directions(s.viewpoints);
  for (int i = 0; i < s.viewpoints; ++i)
    for (int k = 0; k < s.inplane_rotations; ++k)
      CHECK((R[std::size_t(i * s.inplane_rotations + k)] * -v[std::size_t(i)] - Eigen::Vector3f::UnitZ())
                .norm() < 1e-4f);
  s.hemisphere = true;
  s.inplane_rotations = 1;
  CHECK(rotation_proposals(s).size() == 80);
}

TEST_CASE("rotation proposals of symmetric models are fewer and no two are equivalent under a symmetry") {
  ProposalSettings s;
  const std::size_t full = std::size_t(s.viewpoints * s.inplane_rotations);
  const float threshold = symmetry_threshold(s, view_rotations(s));
  struct Case {
    const char* name;
    ModelSymmetries sym;
    std::size_t max_count;
  };
  ModelSymmetries box;  // 180 deg about x, y and z (the block): 4 equivalent copies of every rotation
  box.discrete = {rotation_pose(Eigen::Vector3f::UnitX(), kPi), rotation_pose(Eigen::Vector3f::UnitY(), kPi),
                  rotation_pose(Eigen::Vector3f::UnitZ(), kPi)};
  ModelSymmetries bowl;  // continuous about z: only the axis direction matters (a 2-D set)
  bowl.continuous_axes = {Eigen::Vector3f::UnitZ()};
  ModelSymmetries can;  // continuous about z and the flip (a plain cylinder)
  can.continuous_axes = {Eigen::Vector3f::UnitZ()};
  can.discrete = {rotation_pose(Eigen::Vector3f::UnitX(), kPi)};
  ModelSymmetries ball;  // two axes: every rotation is equivalent
  ball.continuous_axes = {Eigen::Vector3f::UnitZ(), Eigen::Vector3f::UnitX()};
  for (const Case& c : {Case{"box", box, full / 2}, Case{"bowl", bowl, full / 3}, Case{"can", can, full / 5},
                        Case{"ball", ball, 1}}) {
    const auto R = rotation_proposals(s, c.sym);
    INFO(c.name << ": " << R.size() << " of " << full);
    CHECK(R.size() <= c.max_count);
    CHECK(R.size() >= 1);
    for (std::size_t i = 0; i < R.size(); ++i)
      for (std::size_t j = 0; j < i; ++j) CHECK(symmetric_rotation_distance(R[i], R[j], c.sym) >= threshold);
    // Still a cover: every rotation of the full set is within the threshold of a kept one.
    for (const auto& r : rotation_proposals(s)) {
      float nearest = INFINITY;
      for (const auto& k : R) nearest = std::min(nearest, symmetric_rotation_distance(r, k, c.sym));
      CHECK(nearest < threshold);
    }
  }
  // The generator's block uses the box's symmetries through ModelSymmetries::from.
  const auto block = synth::builtin_models()[7];
  CHECK(rotation_proposals(s, symmetries_of(block)).size() == rotation_proposals(s, box).size());
}

TEST_CASE("proposal depths span the mask's robust depth range plus half the object's thickness") {
  const Mesh mesh = synth::make_box({0.06f, 0.1f, 0.2f});  // middle side 0.1: + 0.05 m behind z_far
  DepthImage depth(40, 30, 0.f);
  Image<std::uint8_t> mask(40, 30, 0);
  for (int v = 5; v < 25; ++v)
    for (int u = 5; u < 35; ++u) mask(u, v) = 1, depth(u, v) = 0.8f + 0.002f * float(u - 5);  // 0.80..0.858
  depth(0, 0) = 3.f;  // outside the mask: ignored
  ProposalSettings s;
  s.depth_quantile_near = 0.f, s.depth_quantile_far = 1.f;
  const auto z = proposal_depths(depth, mask, mesh, s);
  REQUIRE(!z.empty());
  CHECK(z.front() >= 0.8f);  // the steps are centred in the range
  CHECK(z.front() <= 0.8f + 0.5f * s.depth_step_m);
  CHECK(z.back() <= 0.858f + 0.05f + 1e-5f);
  CHECK(z.back() > 0.858f + 0.05f - s.depth_step_m);
  for (std::size_t i = 1; i < z.size(); ++i) CHECK(z[i] - z[i - 1] == doctest::Approx(s.depth_step_m));
  // A stray reading (table behind a bleeding mask) does not stretch the robust range.
  mask(0, 0) = 1;
  s.depth_quantile_near = 0.05f, s.depth_quantile_far = 0.95f;
  CHECK(proposal_depths(depth, mask, mesh, s).back() < 1.f);
  // Capped at max_depths, evenly.
  s.max_depths = 2;
  CHECK(proposal_depths(depth, mask, mesh, s).size() == 2);
  // Bad inputs.
  Image<std::uint8_t> empty(40, 30, 0);
  CHECK_THROWS_WITH_AS(proposal_depths(depth, empty, mesh, s), doctest::Contains("empty"), InvalidInput);
  Image<std::uint8_t> no_depth(40, 30, 0);
  no_depth(1, 28) = 1;
  CHECK_THROWS_WITH_AS(proposal_depths(depth, no_depth, mesh, s), doctest::Contains("no valid depth"),
                       InvalidInput);
  CHECK_THROWS_AS(proposal_depths(depth, Image<std::uint8_t>(4, 3, 1), mesh, s), InvalidInput);
  s.depth_step_m = 0;
  CHECK_THROWS_WITH_AS(proposal_depths(depth, mask, mesh, s), doctest::Contains("depth_step_m"),
                       InvalidInput);
}

TEST_CASE("pose proposals lie on the ray through the box centre at the requested depths") {
  const Intrinsics cam{300.f, 300.f, 160.f, 120.f, 320, 240};
  const Eigen::Vector2f centre(250.f, 60.f);
  const auto R = rotation_proposals(ProposalSettings{});
  const std::vector<float> z{0.7f, 0.72f, 0.74f};
  const auto T = pose_proposals(cam, centre, R, z);
  REQUIRE(T.size() == R.size() * z.size());
  for (std::size_t i = 0; i < T.size(); ++i) {
    const Eigen::Vector3f t = T[i].translation();
    CHECK(t.z() == doctest::Approx(z[i % z.size()]));
    const Vec2f px = cam.project({t.x(), t.y(), t.z()});
    CHECK(px.x == doctest::Approx(centre.x()).epsilon(1e-4));
    CHECK(px.y == doctest::Approx(centre.y()).epsilon(1e-4));
    CHECK(is_valid_pose(T[i]));
  }
  // The view frame's z (the viewing direction) is turned onto the ray: viewpoint v of the object is
  // seen along the line of sight, not along the optical axis.
  const Eigen::Vector3f ray = T[0].translation().normalized();
  const Eigen::Vector3f v = fibonacci_directions(80).front();
  CHECK((T[0].linear() * -v - ray).norm() < 1e-4f);
  CHECK_THROWS_AS(pose_proposals(cam, Eigen::Vector2f(NAN, 1.f), R, z), InvalidInput);
}
