// What the tabletop search returns (perch2/search/tabletop.hpp): the poses found, on the table and in the
// camera, with their scores and cost breakdowns, the counts of hypotheses per pass and the time per pass; and
// rest_pose_from, a model's rest pose on the table from any pose in which it stands there.
#pragma once

#include <Eigen/Geometry>
#include <cmath>
#include <cstddef>
#include <vector>

#include "perch2/core/pose.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/search/tabletop/settings.hpp"

namespace perch2 {

struct TabletopPose {
  int model = 0;     ///< index into the estimator's models
  int instance = 0;  ///< 0 .. count - 1 among this model's poses, best first
  Pose T_cam_obj = Pose::Identity();
  Pose T_world_obj = Pose::Identity();
  float x_m = 0, y_m = 0, yaw_rad = 0;  ///< table frame placement (see perch2/search/tabletop.hpp)
  float score = 0;     ///< what selection minimised: cost total, or ICP fitness (m^2) for BruteForceIcp
  CostBreakdown cost;  ///< the explanation cost at this pose (scored as in Parallel mode)
};

struct TabletopTimings {  ///< seconds, wall clock
  double table = 0, observed = 0, hypotheses = 0, render = 0, refine = 0, cost = 0, select = 0, total = 0;
  double yaw = 0;  ///< the yaw search (its renders and costs are also in render and cost)
};

struct TabletopResult {
  std::vector<TabletopPose> poses;  ///< grouped by request order, best first within a model
  Pose T_cam_world = Pose::Identity();
  bool table_estimated = false;        ///< true if T_cam_world came from estimate_table_plane
  std::size_t hypotheses_grid = 0;     ///< grid hypotheses before pruning
  std::size_t hypotheses_kept = 0;     ///< ... with enough observed support
  std::size_t hypotheses_refined = 0;  ///< refined by ICP (Tree mode: summed over levels)
  std::size_t hypotheses_coarse = 0;   ///< scored at coarse_score_stride (after de-duplication)
  std::size_t hypotheses_scored = 0;   ///< scored at score_stride (Tree mode: summed over levels)
  std::size_t yaw_candidates = 0;      ///< turned poses the yaw search scored
  std::vector<ObjectCount> missing;    ///< non-strict mode: instances requested but not found
  /// With TabletopSettings::keep_scored: every scored hypothesis after refinement (Tree mode: every level),
  /// instance = -1; score as in TabletopPose.
  std::vector<TabletopPose> scored;
  TabletopTimings timings;
};

/// The rest pose T_place_obj of a model from any pose T_world_obj in which it stands on the table (e.g. a
/// dataset's ground truth or a generator's placement): the pose with its table-plane position and its yaw
/// removed, keeping its height, roll and pitch. Yaw is measured by the object's x axis projected onto the
/// table (its y axis if x is vertical). Then T_world_obj = Trans(x, y, 0) * RotZ(yaw) * T_place_obj.
inline Pose rest_pose_from(const Pose& T_world_obj) {
  Eigen::Vector3f axis = T_world_obj.linear().col(0);
  if (Eigen::Vector2f(axis.x(), axis.y()).norm() < 1e-3f) axis = T_world_obj.linear().col(1);
  const float yaw = std::atan2(axis.y(), axis.x());
  Pose T_world_place = Pose::Identity();
  T_world_place.linear() = Eigen::AngleAxisf(yaw, Eigen::Vector3f::UnitZ()).toRotationMatrix();
  T_world_place.translation() =
      Eigen::Vector3f(T_world_obj.translation().x(), T_world_obj.translation().y(), 0.f);
  return T_world_place.inverse() * T_world_obj;
}

}  // namespace perch2
