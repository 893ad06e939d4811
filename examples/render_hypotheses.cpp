// Minimal embedding example (the one in the README): render pose hypotheses of a model into point clouds.
//   render_hypotheses MODEL.{obj,ply} [SCALE]     e.g. render_hypotheses obj_06.ply 0.001
#include <cstdio>
#include <string>

#include "perch2/cuda/backend.hpp"  // perch2::cuda::Backend and perch2::thrust_omp::Backend
#include "perch2/io/io.hpp"

using Backend = perch2::thrust_omp::Backend;  // or perch2::cpu::Backend, perch2::cuda::Backend

int main(int argc, char** argv) try {
  if (argc < 2) {
    std::fprintf(stderr, "usage: render_hypotheses MODEL.{obj,ply} [SCALE]\n");
    return 2;
  }
  perch2::io::MeshLoadOptions options;
  options.scale = argc > 2 ? std::stof(argv[2]) : 1.f;  // BOP / LINEMOD models are in mm: 0.001
  Backend::Renderer renderer({perch2::io::load_mesh(argv[1], options)});

  const perch2::Intrinsics K{615.f, 615.f, 319.5f, 239.5f, 640, 480};  // fx fy cx cy width height
  std::vector<perch2::Hypothesis> hyps;                                // (model index, T_cam_obj)
  for (int k = 0; k < 16; ++k) {
    perch2::Pose T_cam_obj = perch2::Pose::Identity();
    T_cam_obj.linear() = Eigen::AngleAxisf(k * 0.39f, Eigen::Vector3f::UnitY()).toRotationMatrix();
    T_cam_obj.translation() = Eigen::Vector3f(0.f, 0.f, 0.6f);
    hyps.push_back({0, T_cam_obj});
  }
  perch2::RenderSettings settings;  // stride 4: every 4th pixel (intrinsics K/4)
  const perch2::CloudBatch clouds = renderer.render(hyps, K, settings);
  // clouds.x/y/z: camera frame, metres; rgb: 0xRRGGBB; pixel: v * width + u; cloud: hypothesis index.
  for (std::size_t h = 0; h < clouds.num_clouds(); ++h)
    std::printf("hypothesis %2zu: %zu points\n", h, clouds.cloud_size(h));
  return 0;
} catch (const std::exception& e) {  // perch2::InvalidInput / FileError name the input and the reason
  std::fprintf(stderr, "render_hypotheses: %s\n", e.what());
  return 1;
}
