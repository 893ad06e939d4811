// Embedding example (the second one in the README): render perturbed pose hypotheses of a model, refine all
// of them against an observed depth frame with one batched GICP call, and measure how far each is from the
// observed points with one batched kNN call.
//   refine_hypotheses MODEL.{obj,ply} [SCALE]     e.g. refine_hypotheses obj_06.ply 0.001
// The "observed" frame is the model rendered at a known pose, so the printed errors can be checked.
#include <cmath>
#include <cstdio>
#include <random>
#include <string>

#include "perch2/core/observed.hpp"
#include "perch2/cuda/backend.hpp"  // perch2::cuda::Backend and perch2::thrust_omp::Backend
#include "perch2/io/io.hpp"

using Backend = perch2::thrust_omp::Backend;  // or perch2::cpu::Backend, perch2::cuda::Backend

namespace {

/// Mean nearest-neighbour distance (mm) of each hypothesis' rendered points to the observed points.
std::vector<double> mean_nn_mm(const Backend::KnnIndex& observed, const perch2::CloudBatch& clouds) {
  const std::vector<std::int32_t> segment(clouds.num_clouds(), 0);  // every cloud searches segment 0
  const perch2::KnnResult nn = observed.knn(clouds, segment, perch2::KnnSettings{});
  std::vector<double> mean(clouds.num_clouds(), 0.0);
  for (std::size_t h = 0; h < clouds.num_clouds(); ++h) {
    for (auto i = clouds.offsets[h]; i < clouds.offsets[h + 1]; ++i)
      mean[h] += std::sqrt(double(nn.sq_distance_m2[std::size_t(i)])) * 1e3;
    mean[h] /= double(std::max<std::size_t>(1, clouds.cloud_size(h)));
  }
  return mean;
}

double angle_deg(const perch2::Pose& a, const perch2::Pose& b) {
  return Eigen::AngleAxisf(a.linear().transpose() * b.linear()).angle() * 180.0 / 3.14159265;
}

}  // namespace

int main(int argc, char** argv) try {
  if (argc < 2) {
    std::fprintf(stderr, "usage: refine_hypotheses MODEL.{obj,ply} [SCALE]\n");
    return 2;
  }
  perch2::io::MeshLoadOptions options;
  options.scale = argc > 2 ? std::stof(argv[2]) : 1.f;  // BOP / LINEMOD models are in mm: 0.001
  const Backend::Renderer renderer({perch2::io::load_mesh(argv[1], options)});
  const perch2::Intrinsics K{615.f, 615.f, 319.5f, 239.5f, 640, 480};

  // The observed frame: the model at T_true, rendered at full resolution into a depth image.
  perch2::Pose T_true = perch2::Pose::Identity();
  T_true.linear() = Eigen::AngleAxisf(0.6f, Eigen::Vector3f(1, 1, 0).normalized()).toRotationMatrix();
  T_true.translation() = Eigen::Vector3f(0.02f, -0.01f, 0.6f);
  perch2::RenderSettings full;
  full.stride = 1;
  const perch2::CloudBatch truth = renderer.render({{0, T_true}}, K, full);
  perch2::RgbdFrame frame;
  frame.camera = K;
  frame.depth_m = perch2::DepthImage(K.width, K.height, 0.f);
  for (std::size_t i = 0; i < truth.size(); ++i) frame.depth_m.data[std::size_t(truth.pixel[i])] = truth.z[i];

  // Targets, built once per frame: the observed points (every 2nd pixel) as one segment.
  perch2::ObservedCloudSettings every_2nd;
  every_2nd.stride = 2;
  const perch2::CloudBatch observed = perch2::observed_cloud(frame, every_2nd);
  const Backend::Registration registration(observed);
  const Backend::KnnIndex index(observed);

  // Hypotheses: T_true perturbed by up to 2 cm and 10 degrees, rendered at stride 4.
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  std::vector<perch2::Hypothesis> hyps;
  for (int k = 0; k < 8; ++k) {
    const Eigen::Vector3f axis = Eigen::Vector3f{u(rng), u(rng), u(rng)}.normalized();
    perch2::Pose dT = perch2::Pose::Identity();
    dT.linear() = Eigen::AngleAxisf(0.17f * u(rng), axis).toRotationMatrix();
    dT.translation() = 0.02f * Eigen::Vector3f{u(rng), u(rng), u(rng)} / std::sqrt(3.f);
    hyps.push_back({0, T_true * dT});
  }
  const perch2::CloudBatch clouds = renderer.render(hyps, K, perch2::RenderSettings{});

  // One batched GICP call refines every hypothesis; refined T_cam_obj = T_corr * T_cam_obj.
  perch2::GicpSettings gicp;
  gicp.max_correspondence_distance_m = 0.03f;
  const std::vector<std::int32_t> segment(hyps.size(), 0);
  const perch2::RegistrationResult r = registration.gicp(clouds, segment, gicp);

  std::vector<perch2::Hypothesis> refined = hyps;
  for (std::size_t h = 0; h < hyps.size(); ++h) refined[h].T_cam_obj = r.T_corr[h] * hyps[h].T_cam_obj;
  const std::vector<double> before = mean_nn_mm(index, clouds);
  const std::vector<double> after = mean_nn_mm(index, renderer.render(refined, K, perch2::RenderSettings{}));

  std::printf("hyp | pose error before: mm   deg | after: mm     deg | mean NN mm before -> after | iters\n");
  for (std::size_t h = 0; h < hyps.size(); ++h) {
    const perch2::Pose &a = hyps[h].T_cam_obj, &b = refined[h].T_cam_obj;
    std::printf("%3zu |          %8.2f %5.2f |    %8.3f %6.3f |          %6.2f -> %6.2f   | %3d%s\n", h,
                (a.translation() - T_true.translation()).norm() * 1e3, angle_deg(a, T_true),
                (b.translation() - T_true.translation()).norm() * 1e3, angle_deg(b, T_true), before[h],
                after[h], r.iterations[h], r.converged[h] ? "" : " (not converged)");
  }
  return 0;
} catch (const std::exception& e) {  // perch2::InvalidInput / FileError name the input and the reason
  std::fprintf(stderr, "refine_hypotheses: %s\n", e.what());
  return 1;
}
