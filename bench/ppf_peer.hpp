// OpenCV's PPF + ICP (cv::ppf_match_3d, the contrib surface_matching module) as a benchmark peer: the model
// clouds, the detectors trained once per model, the scene's normals, ICP of a pose and its fitness, shared by
// bench_real (per instance, on a mask) and bench_detect (every catalogue model over the whole scene).
// Include only when PERCH2_HAVE_PPF is defined (bench/CMakeLists.txt sets it when OpenCV's surface_matching
// module is found). Millimetres, depth only.
#pragma once

#include <opencv2/flann.hpp>
#include <opencv2/surface_matching.hpp>
#include <opencv2/surface_matching/ppf_helpers.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <functional>
#include <map>
#include <memory>
#include <random>
#include <vector>

#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/dataset/bop.hpp"

namespace perch2::bench::ppf_peer {

// Millimetres, the model file's and the sample's units: the pose clustering in match() merges poses whose
// translations lie within the relative sampling step taken as an absolute distance (setSearchParams'
// default) whatever their rotations, and averages them; 0.025 mm leaves the poses apart as in the sample,
// 0.025 m would average a cat's flipped and upright poses.
constexpr float kPpfUnit = 1000.f;
constexpr double kPpfSampling = 0.025;  // PPF3DDetector(0.025, 0.05), as in the sample
// Scene normals from 30 neighbours (a disc of ~3 px, 4-6 mm on the real frames; the sample's 6 are as noisy
// as the Kinect's depth steps), oriented to the camera.
constexpr int kPpfNormalNeighbours = 30;
constexpr double kPpfFitnessDistance = 0.03;  // x diameter: see fitness()

/// The model's vertices (millimetres) with area-weighted vertex normals, as OpenCV's N x 6 point cloud.
inline cv::Mat vertices_with_normals(const Mesh& mesh) {
  std::vector<Eigen::Vector3f> n(mesh.vertices.size(), Eigen::Vector3f::Zero());
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3f a = mesh.vertices[std::size_t(t[0])];
    const Eigen::Vector3f c =
        (mesh.vertices[std::size_t(t[1])] - a).cross(mesh.vertices[std::size_t(t[2])] - a);
    for (int k = 0; k < 3; ++k) n[std::size_t(t[k])] += c;
  }
  cv::Mat pc(int(mesh.vertices.size()), 6, CV_32F);
  for (int i = 0; i < pc.rows; ++i) {
    const Eigen::Vector3f v = mesh.vertices[std::size_t(i)], u = n[std::size_t(i)].normalized();
    for (int k = 0; k < 3; ++k) pc.at<float>(i, k) = kPpfUnit * v[k], pc.at<float>(i, 3 + k) = u[k];
  }
  return pc;
}

/// The rows of `pc` kept greedily in order so that no two lie closer than `spacing` (a uniform surface
/// sample when the rows are a fine mesh's vertices).
inline cv::Mat thinned(const cv::Mat& pc, float spacing) {
  std::map<std::array<int, 3>, std::vector<int>> grid;  // cells of side `spacing`
  std::vector<int> kept;
  for (int i = 0; i < pc.rows; ++i) {
    const cv::Vec3f p(pc.ptr<float>(i));
    const std::array<int, 3> c{int(std::floor(p[0] / spacing)), int(std::floor(p[1] / spacing)),
                               int(std::floor(p[2] / spacing))};
    bool free = true;
    for (int dx = -1; dx <= 1 && free; ++dx)
      for (int dy = -1; dy <= 1 && free; ++dy)
        for (int dz = -1; dz <= 1 && free; ++dz) {
          const auto it = grid.find({c[0] + dx, c[1] + dy, c[2] + dz});
          if (it == grid.end()) continue;
          for (const int j : it->second)
            if (cv::norm(p - cv::Vec3f(pc.ptr<float>(j))) < spacing) free = false;
        }
    if (free) grid[c].push_back(i), kept.push_back(i);
  }
  cv::Mat out(int(kept.size()), pc.cols, CV_32F);
  for (int r = 0; r < out.rows; ++r) pc.row(kept[std::size_t(r)]).copyTo(out.row(r));
  return out;
}

/// Points spread over the mesh's surface (millimetres) with their triangles' normals, thinned to `spacing`
/// apart: the cloud of a CAD-like mesh whose vertices do not cover its faces (a box has 8). The triangles
/// are sampled at random (fixed seed) in proportion to their areas, 4 points per spacing^2 of area, before
/// thinning.
inline cv::Mat surface_points(const Mesh& mesh, float spacing) {
  std::vector<double> cumulative;
  double area = 0;
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3f a = mesh.vertices[std::size_t(t[0])];
    area += 0.5 * double(kPpfUnit * kPpfUnit) *
            (mesh.vertices[std::size_t(t[1])] - a).cross(mesh.vertices[std::size_t(t[2])] - a).norm();
    cumulative.push_back(area);
  }
  const int n = int(std::ceil(4 * area / (double(spacing) * spacing)));
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> uniform(0, 1);
  cv::Mat pc(n, 6, CV_32F);
  for (int i = 0; i < n; ++i) {
    const std::size_t k = std::size_t(
        std::lower_bound(cumulative.begin(), cumulative.end(), uniform(rng) * area) - cumulative.begin());
    const auto& t = mesh.triangles[std::min(k, mesh.triangles.size() - 1)];
    const Eigen::Vector3f a = mesh.vertices[std::size_t(t[0])], b = mesh.vertices[std::size_t(t[1])],
                          c = mesh.vertices[std::size_t(t[2])];
    double s = uniform(rng), r = uniform(rng);
    if (s + r > 1) s = 1 - s, r = 1 - r;
    const Eigen::Vector3f p = a + float(s) * (b - a) + float(r) * (c - a),
                          u = (b - a).cross(c - a).normalized();
    for (int j = 0; j < 3; ++j) pc.at<float>(i, j) = kPpfUnit * p[j], pc.at<float>(i, 3 + j) = u[j];
  }
  return thinned(pc, spacing);
}

/// OpenCV's PPF detectors, trained once per model (see train_ppf), and the models' clouds for ICP.
struct PpfModels {
  std::map<int, int> model_of;
  std::map<int, cv::Mat> cloud;    // obj_id -> N x 6 (millimetres, unit normals), for ICP
  std::map<int, cv::Mat> sampled;  // obj_id -> the thinned cloud the detector was trained on
  std::map<int, double> diameter_m;
  std::map<int, std::unique_ptr<cv::ppf_match_3d::PPF3DDetector>> detector;
  std::map<int, double> train_cpu_s;  // obj_id -> thinning and training
  double total_train_cpu_s = 0;
};

/// A model's cloud for ICP (N x 6, millimetres) from its mesh and diameter (metres).
using ModelCloud = std::function<cv::Mat(const Mesh&, double diameter_m)>;

// Training gets the model's cloud thinned to `sampling` x the diameter apart, the spacing the setting names,
// as the sample trains on a sampled cloud (PPF3DDetector(sampling, 0.05); bench_real: kPpfSampling, the
// sample's). Given every vertex, samplePCByQuantization cuts each side of the bounding box into 1 / 0.025 =
// 40 cells (1.7-3.2 mm on the cat, finer than 0.025 x 154.5 mm) and keeps 5749 of the cat's 15736 vertices;
// trainModel then hashes all 5749^2 pairs, and in OpenCV 4.6 each insert walks the bucket's list of pairs
// with the same quantised feature (t_hash_int.cpp), so training grows with the sum of those lists' squared
// lengths (1.2e11 steps here: hours, measured 90 s for 1516 points and over 300 s for 2569). Thinned, 1252
// remain and training takes seconds. `cloud_of` gives the cloud (bench_real: every vertex of the scan).
inline PpfModels train_ppf(const dataset::BopDataset& data, const ModelCloud& cloud_of,
                           double sampling = kPpfSampling) {
  PpfModels m;
  for (const auto& [id, info] : data.models_info()) {
    m.model_of[id] = int(m.model_of.size());
    m.cloud[id] = cloud_of(data.load_model(id), info.diameter_m);
    const std::clock_t c0 = std::clock();
    const cv::Mat sampled = thinned(m.cloud[id], float(sampling) * kPpfUnit * info.diameter_m);
    m.detector[id] = std::make_unique<cv::ppf_match_3d::PPF3DDetector>(sampling, 0.05);
    m.detector[id]->trainModel(sampled);
    m.sampled[id] = sampled, m.diameter_m[id] = info.diameter_m;
    const double cpu = double(std::clock() - c0) / CLOCKS_PER_SEC;
    m.train_cpu_s[id] = cpu, m.total_train_cpu_s += cpu;
    std::fprintf(stderr, "PPF: trained obj %d on %d of its %d cloud points in %.1f CPU s\n", id, sampled.rows,
                 m.cloud[id].rows, cpu);
  }
  return m;
}

/// The N x 3 scene points (millimetres) with computeNormalsPC3d's normals, oriented to the camera: N x 6.
inline cv::Mat with_normals(const cv::Mat& scene) {
  cv::Mat scene_n;
  cv::ppf_match_3d::computeNormalsPC3d(scene, scene_n, kPpfNormalNeighbours, true, cv::Vec3f(0.f, 0.f, 0.f));
  return scene_n;
}

/// The N x 6 cloud's rows whose normals face the camera at the origin.
inline cv::Mat facing_camera(const cv::Mat& pc) {
  std::vector<int> keep;
  for (int i = 0; i < pc.rows; ++i) {
    const float* r = pc.ptr<float>(i);
    if (r[0] * r[3] + r[1] * r[4] + r[2] * r[5] < 0) keep.push_back(i);
  }
  cv::Mat out(int(keep.size()), pc.cols, CV_32F);
  for (int r = 0; r < out.rows; ++r) pc.row(keep[std::size_t(r)]).copyTo(out.row(r));
  return out;
}

/// ICP(100, 0.005, 2.5, 8) as in the sample (`levels`: its last argument), on the model points that face the
/// camera at the pose: OpenCV's ICP pairs every model point with its nearest scene point, and the far side of
/// the model would pull it towards the visible surface. Refines `pose` in place.
inline void refine_icp(const cv::Mat& model_cloud, const cv::ppf_match_3d::Pose3DPtr& pose,
                       const cv::Mat& scene_n, int levels = 8) {
  cv::ppf_match_3d::ICP icp(100, 0.005f, 2.5f, levels);
  const cv::Mat visible = facing_camera(cv::ppf_match_3d::transformPCPose(model_cloud, pose->pose));
  cv::Matx44d refine = cv::Matx44d::eye();
  if (visible.rows >= 6) icp.registerModelToScene(visible, scene_n, pose->residual, refine);
  pose->appendPose(refine);
}

using SceneIndex = cv::flann::GenericIndex<cvflann::L2<float>>;

/// The fitness of the posed model points `posed` (rows: x, y, z, ...): the fraction within `distance` of a
/// point of `scene_index`, as Open3D's evaluate_registration. OpenCV's ICP residual sums over the pairs left
/// after its outlier rejection and is rescaled per pose, so it favours poses that match few points.
inline double fitness(const cv::Mat& posed, SceneIndex& scene_index, float distance) {
  const cv::Mat points = posed.colRange(0, 3).clone();
  cv::Mat nn(points.rows, 1, CV_32S), d2(points.rows, 1, CV_32F);
  scene_index.knnSearch(points, nn, d2, 1, cvflann::SearchParams());
  return double(cv::countNonZero(d2 <= distance * distance)) / points.rows;
}

/// OpenCV's pose (millimetres) as perch2's T_cam_obj (metres, rotation re-orthonormalised).
inline Pose to_pose(const cv::Matx44d& m) {
  Pose T = Pose::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) T.linear()(r, c) = float(m(r, c));
    T.translation()[r] = float(m(r, 3)) / kPpfUnit;
  }
  T.linear() = Eigen::Quaternionf(T.linear()).normalized().toRotationMatrix();
  return T;
}

}  // namespace perch2::bench::ppf_peer
