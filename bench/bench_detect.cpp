// 6D detection (BOP 2024) against the catalogue's size: SixDofEstimator::detect on a generated decoy set
// (built-in models placed; models/ also holds three look-alikes of each: another print, 0.8x the size,
// other colours; test_targets_bop24.json lists the images only), once with the whole catalogue and once
// with the placed models alone, image by image in the same run (both see the same machine load), each
// scored by perch2::eval (bop24_mAP). The targets: <= 5 s per image with the catalogue, <= 1.5x the
// placed models' time.
//   1. Generates the set into SCRATCH (fixed seed; later runs with the same --scenes and --seed reuse it).
//   2. Per image: detect() with the catalogue, then with the placed models (DetectSettings defaults, or
//      --jobs-per-object / --viewpoints); wall time of each call.
//   3. Per catalogue: bop24_mAP (MSSD, MSPD), median and mean seconds per image, the retrieval's share;
//      the ratio of the catalogue's mean time to the placed models'.
// The peer (when OpenCV's surface_matching module is found at configure time; --peer 0 skips it): OpenCV's
// PPF + ICP searching every catalogue model over the whole scene and keeping its best-supported poses, on
// the same images in the same process, timed and scored the same way (see ppf_detect and bench/ppf_peer.hpp).
// Usage: bench_detect [--scenes N (4)] [--seed S (47)] [--dir SCRATCH (/tmp/perch2_bench_detect)]
//                     [--jobs-per-object N] [--viewpoints N] [--perch2 0|1 (1)] [--peer 0|1 (1)]
//                     [--peer-poses N (per model)] [--peer-threshold F (support)] [--peer-sweep 0|1 (0)]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <vector>

#ifdef PERCH2_HAVE_PPF
#include <opencv2/imgproc.hpp>

#include "ppf_peer.hpp"
#endif

#include "bench_support.hpp"
#include "perch2/cuda/estimators.hpp"  // SixDofEstimator<thrust_omp::Backend>, the production build
#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/results.hpp"
#include "perch2/eval/evaluator.hpp"
#include "perch2/search/sixdof.hpp"
#include "perch2/search/sixdof_bop.hpp"
#include "perch2/synth/synth.hpp"

using namespace perch2;
namespace fs = std::filesystem;

namespace {

struct Options {
  int scenes = 4;
  std::uint64_t seed = 47;
  std::string dir = "/tmp/perch2_bench_detect";
  int jobs_per_object = -1, viewpoints = -1;  ///< < 0: DetectSettings' defaults
  bool perch2 = true;                         ///< --perch2 0: the peer alone
  bool peer = true;                           ///< --peer 0: perch2 alone
  int peer_poses = 10;                        ///< PPF poses refined per model and image
  double peer_threshold = 0.3;                ///< support a peer pose needs to be written
  bool peer_sweep = false;                    ///< also score the peer at other thresholds
};

Options parse(int argc, char** argv) {
  Options o;
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    if (k + 1 >= argc) throw InvalidInput(a, "needs a value (see the usage in bench/bench_detect.cpp)");
    const std::string v = argv[++k];
    if (a == "--scenes")
      o.scenes = std::stoi(v);
    else if (a == "--seed")
      o.seed = std::stoull(v);
    else if (a == "--dir")
      o.dir = v;
    else if (a == "--jobs-per-object")
      o.jobs_per_object = std::stoi(v);
    else if (a == "--viewpoints")
      o.viewpoints = std::stoi(v);
    else if (a == "--perch2")
      o.perch2 = v != "0";
    else if (a == "--peer")
      o.peer = v != "0";
    else if (a == "--peer-poses")
      o.peer_poses = std::stoi(v);
    else if (a == "--peer-threshold")
      o.peer_threshold = std::stod(v);
    else if (a == "--peer-sweep")
      o.peer_sweep = v != "0";
    else
      throw InvalidInput(a, "unknown option (see the usage in bench/bench_detect.cpp)");
  }
  if (o.scenes < 1) throw InvalidInput("--scenes", "must be >= 1");
  if (o.peer_poses < 1) throw InvalidInput("--peer-poses", "must be >= 1");
  return o;
}

/// Generates the decoy set unless `dir` already holds the one of these settings.
void generate(const Options& o) {
  const std::string stamp = o.dir + "/bench_stamp.txt",
                    want = std::to_string(o.scenes) + " " + std::to_string(o.seed);
  std::string have;
  std::getline(std::ifstream(stamp), have);
  if (have == want && fs::is_directory(o.dir + "/test")) return;
  synth::DatasetSettings s;
  s.num_scenes = o.scenes, s.images_per_scene = 1, s.seed = o.seed;
  s.scene.mode = synth::Mode::SixDof;
  s.decoys = true, s.detection_targets = true;
  fs::remove_all(o.dir);
  const auto summary = synth::generate_dataset(synth::builtin_models(), s, o.dir);
  std::printf("generated %d images, %d instances -> %s\n", summary.scenes, summary.instances, o.dir.c_str());
  std::ofstream(stamp) << want << '\n';
}

/// One catalogue's estimator, its BOP rows and times.
struct Run {
  std::string name;
  std::vector<int> obj_ids;  ///< per model of the estimator
  std::vector<dataset::PoseEstimate> rows;
  std::vector<double> seconds, retrieve_s;
};

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n == 0 ? 0 : n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

double mean(const std::vector<double>& v) {
  double s = 0;
  for (const double x : v) s += x;
  return v.empty() ? 0 : s / double(v.size());
}

#ifdef PERCH2_HAVE_PPF
namespace ppf = cv::ppf_match_3d;
using bench::ppf_peer::kPpfUnit;
using bench::ppf_peer::PpfModels;

// The peer: OpenCV's PPF + ICP searching every catalogue model over the whole scene, as a user with the
// models and the depth image would run it. Depth only: models of one shape with other prints (obj 1-3, 4-5
// and their look-alikes) are the same to it, and so are the turns of a printed can about its axis or a
// printed box's 180-degree flips, which BOP scores as wrong (models_info declares no symmetry for them).
// Models: the surface sampled kCloudSpacing x the diameter apart (surface_points: the built-in meshes are
// CAD-like, a box has 8 vertices, so bench_real's every-vertex cloud would leave faces empty); the detector
// PPF3DDetector(0.05, 0.05) trained on that cloud thinned to kSampling x the diameter (train_ppf; Drost et
// al.'s and OpenCV's default sampling): at bench_real's 0.025 these meshes keep 735-2188 points and training
// takes 12-220 s per model (over 5 min for the bowl, hours for the catalogue); at 0.05 216-601 and 0.2-3 s.
// Scene (peer_scene): every reading of every kStride-th row and column, back-projected in millimetres. The
// dominant plane (RANSAC) is the table a user scanning a table drops, with everything not on the objects on
// it: kept are the readings above the plane by more than the depth noise (3 sigma of the set's Kinect model,
// at least kPlaneMm) and at most kMaxHeight x the largest diameter, whose feet lie kHullMarginMm inside the
// convex hull of the plane's inliers, in connected clusters of kMinCluster readings or more (PCL's tabletop
// recipe: plane, prism above it, Euclidean clusters; the clusters drop the wall's foot behind the table,
// whose few readings would stretch the box match() quantises). Normals as bench_real's (with_normals).
// Per model (ppf_detect): match() with the scene quantised to kSceneStep x the model's diameter (match's
// step is relative to the scene box's longest side) and every 5th sample a reference point, as bench_real;
// each reference point gives one pose, most votes first. In millimetres match's own clustering merges
// nothing (see ppf_peer.hpp), so the top poses are mostly one instance seen from neighbouring reference
// points: the peer takes, in order of votes, the poses that differ from those taken (centre > kDistinct x
// the diameter away or rotation > kDistinctDeg), up to --peer-poses of them, and refines each by ICP onto
// the readings within the model's reach of its centre (refine_icp with kIcpLevels levels: with the sample's
// 8 the coarsest level keeps 1/128 of the ~2,000 camera-facing points and ICP threw cans and bottles from
// their true poses by 0.2-4.6 m; 4 levels converged from 20 mm / 20 degrees off on the same objects).
// Support (support()): the fraction of the model's sampled points facing the camera whose pixel's depth
// reading lies within kSupportDepth x the diameter of the point's depth. bench_real's fitness (nearest
// reading within 0.03 x the diameter) gave a can lying along a box's edge 0.83 on seed 47's image 4, as much
// as true poses: the box's faces, seen obliquely, lie within 4 mm of the can's visible side.
// Kept: per model, in order of support, poses no closer than kNms x the diameter to a kept pose of that
// model, with support >= --peer-threshold; then the image's best 100 (the evaluator scores at most 100).
// --peer-poses 10 and --peer-threshold 0.3 were chosen on seed 47 (--peer-sweep 1): bop24_mAP 0.377, 0.395,
// 0.387, 0.379 with 5, 10, 20, 30 poses per model; thresholds 0 to 0.3 keep the same detections' ranks.
constexpr int kStride = 2;
constexpr float kPlaneMm = 10.f;
constexpr int kPlaneIterations = 300;
constexpr double kMaxHeight = 1.5;  // x the largest diameter
constexpr float kHullMarginMm = 20.f;
constexpr float kClusterMm = 20.f;  // neighbours on the stride grid closer than this are connected
constexpr int kMinCluster = 100;
constexpr double kCloudSpacing = 0.0125;  // x diameter: the ICP cloud
constexpr double kSampling = 0.05;        // x diameter: the detector's training cloud
constexpr double kSceneStep = 0.05;       // x diameter
constexpr double kRefStep = 1.0 / 5.0;
constexpr double kDistinct = 0.1, kDistinctDeg = 30;
constexpr int kIcpLevels = 4;
constexpr int kMinCrop = 50;  // readings within reach below which a pose is not refined (nor kept)
constexpr double kFacingDeg = 75;
constexpr double kSupportDepth = 0.02;  // x diameter
constexpr double kNms = 0.5;            // x diameter
constexpr std::size_t kMaxPerImage = 100;

/// The scene readings above the table (see the comment above): N x 3 and N x 6 with normals, millimetres.
struct PeerScene {
  cv::Mat points, normals;
  int readings = 0, plane_inliers = 0;
};

PeerScene peer_scene(const RgbdFrame& f, float max_height_mm) {
  PeerScene s;
  const int W = (f.camera.width + kStride - 1) / kStride, H = (f.camera.height + kStride - 1) / kStride;
  std::vector<Eigen::Vector3f> pts;
  std::vector<int> at(std::size_t(W * H), -1);  // stride grid -> index in pts
  for (int v = 0; v < f.camera.height; v += kStride)
    for (int u = 0; u < f.camera.width; u += kStride)
      if (f.depth_m(u, v) > 0) {
        const Vec3f p = f.depth_m(u, v) * f.camera.ray(float(u), float(v));
        at[std::size_t((v / kStride) * W + u / kStride)] = int(pts.size());
        pts.push_back(kPpfUnit * Eigen::Vector3f(p.x, p.y, p.z));
      }
  s.readings = int(pts.size());
  if (pts.size() < 100) return s;
  // RANSAC on at most 4000 of the readings, then least squares on the inliers among all.
  std::mt19937 rng(7);
  std::uniform_int_distribution<std::size_t> pick(0, pts.size() - 1);
  std::vector<std::size_t> probe;
  for (std::size_t i = 0; i < pts.size(); i += std::max<std::size_t>(1, pts.size() / 4000))
    probe.push_back(i);
  Eigen::Vector3f best_n = Eigen::Vector3f::UnitZ();
  float best_d = 0;
  std::size_t best_count = 0;
  for (int it = 0; it < kPlaneIterations; ++it) {
    const Eigen::Vector3f a = pts[pick(rng)], b = pts[pick(rng)], c = pts[pick(rng)];
    const Eigen::Vector3f n = (b - a).cross(c - a);
    if (n.norm() < 1e-3f) continue;
    const Eigen::Vector3f u = n.normalized();
    const float d = -u.dot(a);
    std::size_t count = 0;
    for (const std::size_t i : probe) count += std::abs(u.dot(pts[i]) + d) < kPlaneMm;
    if (count > best_count) best_count = count, best_n = u, best_d = d;
  }
  Eigen::Vector3f centre = Eigen::Vector3f::Zero();
  int inliers = 0;
  for (const auto& p : pts)
    if (std::abs(best_n.dot(p) + best_d) < kPlaneMm) centre += p, ++inliers;
  centre /= float(inliers);
  Eigen::Matrix3f cov = Eigen::Matrix3f::Zero();
  for (const auto& p : pts)
    if (std::abs(best_n.dot(p) + best_d) < kPlaneMm) cov += (p - centre) * (p - centre).transpose();
  Eigen::Vector3f n = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f>(cov).eigenvectors().col(0);
  if (n.dot(-centre) < 0) n = -n;  // the camera (origin) is above the table
  const Eigen::Vector3f e1 = n.unitOrthogonal(), e2 = n.cross(e1);
  std::vector<cv::Point2f> feet, hull;
  for (const auto& p : pts)
    if (std::abs(n.dot(p - centre)) < kPlaneMm) feet.emplace_back(e1.dot(p - centre), e2.dot(p - centre));
  s.plane_inliers = int(feet.size());
  cv::convexHull(feet, hull);
  // The prism: above the plane beyond the sensor's noise (3 sigma of the Kinect model the set's depth
  // follows, 1.2 mm + 1.9 mm/m^2 (z - 0.4 m)^2, synth::SensorSettings' defaults; at least kPlaneMm), feet
  // kHullMarginMm inside the hull.
  auto band = [](float z_mm) {
    const float dz = std::max(0.f, z_mm / 1000.f - 0.4f);
    return std::max(kPlaneMm, 3 * (1.2f + 1.9f * dz * dz));
  };
  std::vector<char> above(pts.size(), 0);
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const Eigen::Vector3f& p = pts[i];
    const float h = n.dot(p - centre);
    above[i] = h > band(p.z()) && h <= max_height_mm &&
               cv::pointPolygonTest(hull, cv::Point2f(e1.dot(p - centre), e2.dot(p - centre)), true) >=
                   kHullMarginMm;
  }
  // Euclidean clusters on the stride grid (8-neighbours closer than kClusterMm); smaller than kMinCluster
  // readings are dropped (the wall's foot behind the table, stray readings).
  std::vector<int> cluster(pts.size(), -1);
  std::vector<cv::Vec3f> kept;
  for (int start = 0; start < W * H; ++start) {
    const int i0 = at[std::size_t(start)];
    if (i0 < 0 || !above[std::size_t(i0)] || cluster[std::size_t(i0)] >= 0) continue;
    std::vector<int> members{start};
    cluster[std::size_t(i0)] = start;
    for (std::size_t k = 0; k < members.size(); ++k) {
      const int gx = members[k] % W, gy = members[k] / W, i = at[std::size_t(members[k])];
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int x = gx + dx, y = gy + dy;
          if (x < 0 || y < 0 || x >= W || y >= H) continue;
          const int j = at[std::size_t(y * W + x)];
          if (j < 0 || !above[std::size_t(j)] || cluster[std::size_t(j)] >= 0) continue;
          if ((pts[std::size_t(j)] - pts[std::size_t(i)]).norm() >= kClusterMm) continue;
          cluster[std::size_t(j)] = start, members.push_back(y * W + x);
        }
    }
    if (int(members.size()) < kMinCluster) continue;
    for (const int g : members) {
      const Eigen::Vector3f& p = pts[std::size_t(at[std::size_t(g)])];
      kept.emplace_back(p.x(), p.y(), p.z());
    }
  }
  if (kept.size() < 10) return s;
  s.points = cv::Mat(int(kept.size()), 3, CV_32F, kept.data()).clone();
  s.normals = bench::ppf_peer::with_normals(s.points);
  return s;
}

/// A refined peer pose of one model.
struct PeerPose {
  int obj = 0;
  double support = 0;
  cv::Matx44d pose;
  cv::Vec3d centre;  ///< the model's centroid at the pose (mm)
  int rank = 0;      ///< among the model's refined poses of the image, in order of votes
};

/// What the peer found in one image: every refined pose, with the time spent.
struct PeerImage {
  std::vector<PeerPose> poses;
  int scene_points = 0, readings = 0;
  double match_s = 0, refine_s = 0, scene_s = 0;
};

double rotation_deg(const cv::Matx44d& a, const cv::Matx44d& b) {
  double trace = 0;  // trace(Ra^T Rb)
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) trace += a(r, c) * b(r, c);
  return std::acos(std::clamp((trace - 1) / 2, -1.0, 1.0)) * 180 / M_PI;
}

cv::Vec3d apply(const cv::Matx44d& T, const cv::Vec3d& p) {
  return {T(0, 0) * p[0] + T(0, 1) * p[1] + T(0, 2) * p[2] + T(0, 3),
          T(1, 0) * p[0] + T(1, 1) * p[1] + T(1, 2) * p[2] + T(1, 3),
          T(2, 0) * p[0] + T(2, 1) * p[1] + T(2, 2) * p[2] + T(2, 3)};
}

/// The models' centroids (object frame, mm) and reach (largest distance of a cloud point from it).
struct ModelShape {
  cv::Vec3d centroid;
  double reach = 0;
};

std::map<int, ModelShape> model_shapes(const PpfModels& models) {
  std::map<int, ModelShape> out;
  for (const auto& [id, cloud] : models.cloud) {
    ModelShape m;
    for (int i = 0; i < cloud.rows; ++i)
      m.centroid +=
          cv::Vec3d(cloud.at<float>(i, 0), cloud.at<float>(i, 1), cloud.at<float>(i, 2)) / cloud.rows;
    for (int i = 0; i < cloud.rows; ++i)
      m.reach = std::max(
          m.reach, cv::norm(cv::Vec3d(cloud.at<float>(i, 0), cloud.at<float>(i, 1), cloud.at<float>(i, 2)) -
                            m.centroid));
    out[id] = m;
  }
  return out;
}

/// The support of a pose: the fraction of the model's sampled points facing the camera (normal within
/// kFacingDeg of the line of sight; more grazing points get no reading) whose pixel's depth reading lies
/// within kSupportDepth x the diameter of the point's depth.
double support(const cv::Mat& sampled, const cv::Matx44d& pose, const RgbdFrame& f, double d_mm) {
  const cv::Mat posed = ppf::transformPCPose(sampled, pose);
  const float min_cos = float(std::cos(kFacingDeg * M_PI / 180)), tolerance = float(kSupportDepth * d_mm);
  int facing = 0, supported = 0;
  for (int i = 0; i < posed.rows; ++i) {
    const float* p = posed.ptr<float>(i);
    if (p[2] <= 0) continue;
    if (-(p[0] * p[3] + p[1] * p[4] + p[2] * p[5]) <
        min_cos * std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]))
      continue;
    ++facing;
    const int u = int(std::lround(f.camera.fx * p[0] / p[2] + f.camera.cx)),
              v = int(std::lround(f.camera.fy * p[1] / p[2] + f.camera.cy));
    if (u < 0 || v < 0 || u >= f.camera.width || v >= f.camera.height || f.depth_m(u, v) <= 0) continue;
    supported += std::abs(p[2] - kPpfUnit * f.depth_m(u, v)) < tolerance;
  }
  return facing ? double(supported) / facing : 0;
}

/// Every catalogue model matched over the scene, its distinct top poses refined and supported (see above).
PeerImage ppf_detect(const RgbdFrame& f, PpfModels& models, const std::map<int, ModelShape>& shapes,
                     int poses_per_model, float max_height_mm) {
  PeerImage out;
  auto t = std::chrono::steady_clock::now();
  auto lap = [&t] {
    const auto now = std::chrono::steady_clock::now();
    const double s = std::chrono::duration<double>(now - t).count();
    t = now;
    return s;
  };
  const PeerScene scene = peer_scene(f, max_height_mm);
  out.readings = scene.readings, out.scene_points = scene.points.rows;
  if (scene.points.rows < 10) return out;
  double longest = 0;
  for (int k = 0; k < 3; ++k) {
    double lo, hi;
    cv::minMaxLoc(scene.points.col(k), &lo, &hi);
    longest = std::max(longest, hi - lo);
  }
  out.scene_s = lap();
  for (auto& [obj, detector] : models.detector) {
    const double d_mm = kPpfUnit * models.diameter_m.at(obj);
    const ModelShape& shape = shapes.at(obj);
    std::vector<ppf::Pose3DPtr> results;
    detector->match(scene.normals, results, kRefStep, std::min(1.0, kSceneStep * d_mm / longest));
    out.match_s += lap();
    std::vector<ppf::Pose3DPtr> taken;
    std::vector<cv::Vec3d> taken_centre;
    for (const ppf::Pose3DPtr& p : results) {
      if (int(taken.size()) >= poses_per_model) break;
      const cv::Vec3d c = apply(p->pose, shape.centroid);
      bool distinct = true;
      for (std::size_t j = 0; j < taken.size() && distinct; ++j)
        distinct = cv::norm(c - taken_centre[j]) > kDistinct * d_mm ||
                   rotation_deg(p->pose, taken[j]->pose) > kDistinctDeg;
      if (distinct) taken.push_back(p), taken_centre.push_back(c);
    }
    const double reach = shape.reach + 0.1 * d_mm;
    for (std::size_t j = 0; j < taken.size(); ++j) {
      // ICP onto the readings within the model's reach of its centre at the PPF pose.
      std::vector<int> near;
      for (int i = 0; i < scene.normals.rows; ++i) {
        const float* r = scene.normals.ptr<float>(i);
        const cv::Vec3d dv(r[0] - taken_centre[j][0], r[1] - taken_centre[j][1], r[2] - taken_centre[j][2]);
        if (dv.dot(dv) < reach * reach) near.push_back(i);
      }
      if (int(near.size()) < kMinCrop) continue;
      cv::Mat crop(int(near.size()), 6, CV_32F);
      for (int r = 0; r < crop.rows; ++r) scene.normals.row(near[std::size_t(r)]).copyTo(crop.row(r));
      bench::ppf_peer::refine_icp(models.cloud.at(obj), taken[j], crop, kIcpLevels);
      PeerPose pp;
      pp.obj = obj, pp.rank = int(j), pp.pose = taken[j]->pose,
      pp.centre = apply(taken[j]->pose, shape.centroid);
      pp.support = support(models.sampled.at(obj), taken[j]->pose, f, d_mm);
      out.poses.push_back(pp);
    }
    out.refine_s += lap();
  }
  return out;
}

/// The poses written for one image: per model non-maximum suppression in order of support, the threshold,
/// then the image's best kMaxPerImage.
std::vector<PeerPose> peer_keep(std::vector<PeerPose> poses, const PpfModels& models, double threshold,
                                int poses_per_model) {
  poses.erase(std::remove_if(poses.begin(), poses.end(),
                             [&](const PeerPose& p) { return p.rank >= poses_per_model; }),
              poses.end());
  std::stable_sort(poses.begin(), poses.end(),
                   [](const PeerPose& a, const PeerPose& b) { return a.support > b.support; });
  std::vector<PeerPose> kept;
  for (const PeerPose& p : poses) {
    if (p.support < threshold) break;
    const double d_mm = kPpfUnit * models.diameter_m.at(p.obj);
    const bool clear = std::none_of(kept.begin(), kept.end(), [&](const PeerPose& k) {
      return k.obj == p.obj && cv::norm(k.centre - p.centre) < kNms * d_mm;
    });
    if (clear) kept.push_back(p);
    if (kept.size() == kMaxPerImage) break;
  }
  return kept;
}
#endif

/// The BOP rows of the peer's kept poses of one image.
#ifdef PERCH2_HAVE_PPF
void add_peer_rows(std::vector<dataset::PoseEstimate>& rows, const std::vector<PeerPose>& kept, int scene_id,
                   int im_id, double seconds) {
  for (const PeerPose& p : kept) {
    dataset::PoseEstimate e;
    e.scene_id = scene_id, e.im_id = im_id, e.obj_id = p.obj;
    e.score = float(p.support), e.T_cam_obj = bench::ppf_peer::to_pose(p.pose), e.time_s = seconds;
    rows.push_back(e);
  }
}
#endif

}  // namespace

int main(int argc, char** argv) try {
  const Options o = parse(argc, argv);
  generate(o);
  const dataset::BopDataset data(o.dir);
  const int placed = int(synth::builtin_models().size());  // obj_ids 1..placed; decoys after them
  std::vector<Run> runs;
  if (o.perch2) runs = {{"perch2 catalogue", {}, {}, {}, {}}, {"perch2 placed models", {}, {}, {}, {}}};
  std::vector<SixDofModel> catalogue, placed_models;
  std::vector<int> catalogue_ids;
  for (const auto& [id, info] : data.models_info()) {
    catalogue_ids.push_back(id);
    if (!o.perch2) continue;
    catalogue.push_back(sixdof_model(data.load_model(id), info)), runs[0].obj_ids.push_back(id);
    if (id <= placed) placed_models.push_back(catalogue.back()), runs[1].obj_ids.push_back(id);
  }
  using Estimator = SixDofEstimator<thrust_omp::Backend>;
  std::unique_ptr<const Estimator> estimators[2];  // catalogue, placed models
  if (o.perch2)
    estimators[0] = std::make_unique<const Estimator>(std::move(catalogue)),
    estimators[1] = std::make_unique<const Estimator>(std::move(placed_models));
  DetectSettings settings;
  if (o.jobs_per_object >= 0) settings.retrieval_jobs_per_object = o.jobs_per_object;
  if (o.viewpoints >= 0) settings.retrieval_viewpoints = o.viewpoints;
  std::printf(
      "6D detection, %zu images, catalogue of %zu models (%d placed), backend thrust_omp, %s, "
      "load average %.2f at start\n",
      data.target_images().size(), catalogue_ids.size(), placed, bench::cpu_model().c_str(),
      bench::load_average());
#ifdef PERCH2_HAVE_PPF
  std::unique_ptr<PpfModels> peer;
  std::map<int, ModelShape> shapes;
  std::vector<std::vector<PeerPose>> peer_found;  // per image: every refined pose
  std::vector<std::pair<int, int>> peer_images;
  double peer_match_s = 0, peer_refine_s = 0;
  std::size_t peer_refined = 0;
  float max_height_mm = 0;
  if (o.peer) {
    peer = std::make_unique<PpfModels>(bench::ppf_peer::train_ppf(
        data,
        [](const Mesh& mesh, double d) {
          return bench::ppf_peer::surface_points(mesh, float(kCloudSpacing * kPpfUnit * d));
        },
        kSampling));
    shapes = model_shapes(*peer);
    for (const auto& [id, d] : peer->diameter_m)
      max_height_mm = std::max(max_height_mm, float(kMaxHeight * kPpfUnit * d));
    std::vector<double> train;
    for (const auto& [id, s] : peer->train_cpu_s) train.push_back(s);
    std::printf("PPF + ICP peer: trained %zu models in %.1f CPU s (median %.2f s, max %.2f s per model)\n",
                train.size(), peer->total_train_cpu_s, median(train),
                *std::max_element(train.begin(), train.end()));
    runs.push_back({"OpenCV PPF + ICP catalogue", catalogue_ids, {}, {}, {}});
  }
#else
  if (o.peer) std::printf("PPF + ICP peer: not built (OpenCV's surface_matching module was not found)\n");
#endif
  for (const auto& [scene_id, im_id] : data.target_images()) {
    const dataset::BopImage image = data.load_image(scene_id, im_id);
    for (int r = 0; r < (o.perch2 ? 2 : 0); ++r) {
      const auto t = std::chrono::steady_clock::now();
      const SixDofSceneResult found = estimators[r]->detect(image.frame, settings);
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
      for (const SixDofPose& p : found.poses) {
        dataset::PoseEstimate e;
        e.scene_id = scene_id, e.im_id = im_id, e.obj_id = runs[r].obj_ids[std::size_t(p.model)];
        e.score = p.score, e.T_cam_obj = p.T_cam_obj, e.time_s = s;
        runs[r].rows.push_back(e);
      }
      runs[r].seconds.push_back(s), runs[r].retrieve_s.push_back(found.search.timings.retrieve);
      std::printf("  image %d/%d %-26s %5.1f s, %2zu detections, %3zu jobs (%zu retrieved out)\n", scene_id,
                  im_id, runs[r].name.c_str(), s, found.poses.size(), found.jobs, found.retrieved_out);
      std::fflush(stdout);
    }
#ifdef PERCH2_HAVE_PPF
    if (peer) {
      const auto t = std::chrono::steady_clock::now();
      PeerImage found = ppf_detect(image.frame, *peer, shapes, o.peer_poses, max_height_mm);
      const std::vector<PeerPose> kept = peer_keep(found.poses, *peer, o.peer_threshold, o.peer_poses);
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
      Run& run = runs.back();
      add_peer_rows(run.rows, kept, scene_id, im_id, s);
      run.seconds.push_back(s), run.retrieve_s.push_back(0);
      std::printf(
          "  image %d/%d %-26s %5.1f s, %2zu detections (%zu refined poses; %d of %d readings above "
          "the table; scene %.1f s, match %.1f s, ICP + support %.1f s; VmRSS %ld MiB)\n",
          scene_id, im_id, run.name.c_str(), s, kept.size(), found.poses.size(), found.scene_points,
          found.readings, found.scene_s, found.match_s, found.refine_s, bench::status_kb("VmRSS") / 1024);
      std::fflush(stdout);
      peer_match_s += found.match_s, peer_refine_s += found.refine_s, peer_refined += found.poses.size();
      peer_found.push_back(std::move(found.poses)), peer_images.push_back({scene_id, im_id});
    }
#endif
  }
  eval::EvalSettings es;
  es.compute_vsd = false;
  std::printf(
      "\n| method | models | bop24_mAP | MSSD | MSPD | median s / image | mean s / image |\n"
      "|---|---|---|---|---|---|---|\n");
  for (const Run& r : runs) {
    std::string csv = r.name;
    std::replace(csv.begin(), csv.end(), ' ', '_');
    dataset::save_results_csv(o.dir + "/" + csv + ".csv", r.rows);
    const eval::EvalReport report = eval::evaluate(data, r.rows, es, r.name);
    const eval::DetectionScores& d = report.detection.overall;
    std::printf("| %s | %zu | %.3f | %.3f | %.3f | %.2f | %.2f |\n", r.name.c_str(), r.obj_ids.size(), d.ap,
                d.ap_mssd, d.ap_mspd, median(r.seconds), mean(r.seconds));
  }
  if (o.perch2) {
    for (int r = 0; r < 2; ++r)
      std::printf(
          "%s: retrieval %.0f %% of the time\n", runs[std::size_t(r)].name.c_str(),
          100 * mean(runs[std::size_t(r)].retrieve_s) / std::max(mean(runs[std::size_t(r)].seconds), 1e-9));
    std::printf("perch2 catalogue / placed models, mean time: %.2fx (same run, image by image)\n",
                mean(runs[0].seconds) / std::max(mean(runs[1].seconds), 1e-9));
  }
#ifdef PERCH2_HAVE_PPF
  if (peer && !peer_found.empty())
    std::printf(
        "PPF + ICP peer: match() %.2f s per model and image, ICP + support %.3f s per refined pose "
        "(training, once: %.1f CPU s, %.2f s per model)\n",
        peer_match_s / double(peer_found.size() * peer->detector.size()),
        peer_refine_s / double(std::max<std::size_t>(peer_refined, 1)), peer->total_train_cpu_s,
        peer->total_train_cpu_s / double(peer->detector.size()));
  if (peer && o.peer_sweep) {
    // The same refined poses kept with other thresholds and fewer poses per model (the time column is the
    // run's: fewer poses would spend less on ICP).
    std::printf("\npeer sweep: bop24_mAP by support threshold (columns) and poses per model (rows)\n       ");
    const std::vector<double> thresholds{0.0, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8};
    for (const double th : thresholds) std::printf(" %6.2f", th);
    std::printf("\n");
    for (const int k : {5, 10, 20, 30, 50, 80}) {
      if (k > o.peer_poses) break;
      std::printf("  %3d  ", k);
      for (const double th : thresholds) {
        std::vector<dataset::PoseEstimate> rows;
        for (std::size_t i = 0; i < peer_found.size(); ++i)
          add_peer_rows(rows, peer_keep(peer_found[i], *peer, th, k), peer_images[i].first,
                        peer_images[i].second, 0);
        std::printf(" %6.3f", eval::evaluate(data, rows, es, "sweep").detection.overall.ap);
      }
      std::printf("\n");
    }
  }
#endif
  std::printf("load average %.2f at the end\n", bench::load_average());
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_detect: %s\n", e.what());
  return 1;
}
