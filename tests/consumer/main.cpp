// Renders a box with both CPU-runnable backends through the installed package; exits non-zero on mismatch.
#include <cstdio>

#include "perch2/cpu/backend.hpp"
#include "perch2/cuda/backend.hpp"
#include "perch2/synth/models.hpp"

int main() {
  perch2::Mesh box;
  box.name = "box";
  for (int k = 0; k < 8; ++k)
    box.vertices.emplace_back(k & 1 ? 0.05f : -0.05f, k & 2 ? 0.05f : -0.05f, k & 4 ? 0.05f : -0.05f);
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads)
    box.triangles.emplace_back(q[0], q[1], q[2]), box.triangles.emplace_back(q[0], q[2], q[3]);

  const perch2::Intrinsics K{615.f, 615.f, 319.5f, 239.5f, 640, 480};
  perch2::Pose T_cam_obj = perch2::Pose::Identity();
  T_cam_obj.translation() = Eigen::Vector3f(0.f, 0.f, 0.5f);
  const std::vector<perch2::Hypothesis> hyps{{0, T_cam_obj}};
  const perch2::RenderSettings settings;
  const auto a = perch2::cpu::Backend::Renderer({box}).render(hyps, K, settings);
  const auto b = perch2::thrust_omp::Backend::Renderer({box}).render(hyps, K, settings);
  const auto models = perch2::synth::builtin_models();
  std::printf("consumer: cpu %zu points, thrust_omp %zu points, %zu built-in synth models\n", a.size(),
              b.size(), models.size());
  return a.size() > 0 && a.z == b.z && a.pixel == b.pixel && !models.empty() ? 0 : 1;
}
