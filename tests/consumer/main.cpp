// An outside program using the installed package. It is built with default flags and again with
// -march=native (see tests/CMakeLists.txt), so it checks that the structs crossing the library boundary
// (Hypothesis with its Pose, RegistrationResult) have the library's layout whatever the consumer's
// vectorisation flags: it renders posed boxes with both CPU-runnable backends, checks every point lies on
// the box as *this* program posed it, and reads poses back from ICP. Exits non-zero on any mismatch.
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <sstream>
#include <vector>

#include "perch2/cpu/backend.hpp"
#include "perch2/cuda/backend.hpp"
#include "perch2/dataset/results.hpp"
#include "perch2/eval/metrics.hpp"
#include "perch2/synth/models.hpp"

namespace {

constexpr float kHalf = 0.05f;  // box half-extent, metres

perch2::Mesh box() {
  perch2::Mesh m;
  m.name = "box";
  for (int k = 0; k < 8; ++k)
    m.vertices.emplace_back(k & 1 ? kHalf : -kHalf, k & 2 ? kHalf : -kHalf, k & 4 ? kHalf : -kHalf);
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads)
    m.triangles.emplace_back(q[0], q[1], q[2]), m.triangles.emplace_back(q[0], q[2], q[3]);
  return m;
}

/// Boxes at different places and orientations (three faces visible), each with its own label.
std::vector<perch2::Hypothesis> hypotheses() {
  std::vector<perch2::Hypothesis> out;
  for (int h = 0; h < 6; ++h) {
    perch2::Pose T_cam_obj = perch2::Pose::Identity();
    T_cam_obj.linear() = (Eigen::AngleAxisf(0.4f + 0.2f * float(h), Eigen::Vector3f::UnitY()) *
                          Eigen::AngleAxisf(0.5f, Eigen::Vector3f::UnitX()))
                             .toRotationMatrix();
    T_cam_obj.translation() =
        Eigen::Vector3f(0.04f * float(h - 3), 0.02f * float(h % 2), 0.45f + 0.05f * float(h));
    out.push_back({0, T_cam_obj, h});
  }
  return out;
}

/// FNV-1a over the bytes of v, continuing from h.
template <class T>
std::uint64_t fnv1a(const std::vector<T>& v, std::uint64_t h) {
  const auto* p = reinterpret_cast<const unsigned char*>(v.data());
  for (std::size_t i = 0; i < v.size() * sizeof(T); ++i) h = (h ^ p[i]) * 0x100000001b3ull;
  return h;
}

/// Largest distance of a rendered point from the surface of the box posed by hypothesis h, metres.
float off_surface_m(const perch2::CloudBatch& b, const perch2::Hypothesis& hyp, std::size_t h) {
  const perch2::Pose T_obj_cam = hyp.T_cam_obj.inverse();
  float worst = 0;
  for (auto i = b.offsets[h]; i < b.offsets[h + 1]; ++i) {
    const Eigen::Vector3f p = T_obj_cam * Eigen::Vector3f(b.x[i], b.y[i], b.z[i]);
    worst = std::max(worst, std::abs(p.cwiseAbs().maxCoeff() - kHalf));
  }
  return worst;
}

template <class Backend>
bool check(const char* name, const std::vector<perch2::Hypothesis>& hyps, perch2::CloudBatch& rendered,
           std::uint64_t& digest) {
  const perch2::Intrinsics K{615.f, 615.f, 319.5f, 239.5f, 640, 480};
  rendered = typename Backend::Renderer({box()}).render(hyps, K, perch2::RenderSettings{});
  bool ok = rendered.num_clouds() == hyps.size();
  // Every point on the box as this program posed it, within 0.1 mm (a pose read wrongly is centimetres off).
  for (std::size_t h = 0; ok && h < hyps.size(); ++h)
    ok = rendered.cloud_size(h) > 100 && off_surface_m(rendered, hyps[h], h) < 1e-4f;

  // Each cloud moved by -shift, registered back onto itself: ICP must return T_corr = translation(shift).
  // The shift (1.1 mm) is below half the point spacing (~3 mm at stride 4), so every correspondence is right
  // from the start and the answer is exact up to float rounding (~1e-7 m).
  const Eigen::Vector3f shift(0.0008f, -0.0005f, 0.0006f);
  perch2::CloudBatch sources = rendered;
  for (std::size_t i = 0; i < sources.size(); ++i)
    sources.x[i] -= shift.x(), sources.y[i] -= shift.y(), sources.z[i] -= shift.z();
  std::vector<std::int32_t> segment(hyps.size());
  for (std::size_t h = 0; h < hyps.size(); ++h) segment[h] = std::int32_t(h);
  const perch2::RegistrationResult r =
      typename Backend::Registration(rendered).icp(sources, segment, perch2::IcpSettings{});
  float worst_m = 0;
  ok = ok && r.size() == hyps.size();
  for (std::size_t h = 0; ok && h < r.size(); ++h) {
    const perch2::Pose& T = r.T_corr[h];
    worst_m = std::max({worst_m, (T.translation() - shift).norm(),
                        (T.linear() - Eigen::Matrix3f::Identity()).cwiseAbs().maxCoeff()});
  }
  ok = ok && worst_m < 1e-5f;
  // Bit pattern of the results: CI compares it between builds against different Thrust/CUB/libcu++ copies.
  digest = 0xcbf29ce484222325ull;
  for (const auto* v : {&rendered.x, &rendered.y, &rendered.z}) digest = fnv1a(*v, digest);
  digest = fnv1a(rendered.rgb, fnv1a(rendered.pixel, fnv1a(rendered.offsets, digest)));
  digest = fnv1a(r.T_corr, fnv1a(r.iterations, digest));
  std::printf(
      "consumer: %s rendered %zu points for %zu boxes, ICP error %.2g: %s, results digest [%s] %016llx\n",
      name, rendered.size(), hyps.size(), double(worst_m), ok ? "ok" : "MISMATCH", CONSUMER_FLAGS,
      static_cast<unsigned long long>(digest));
  return ok;
}

}  // namespace

int main() {
  std::printf(
      "consumer: Eigen aligns Isometry3f to %zu bytes in this build; perch2::Hypothesis is %zu bytes\n",
      alignof(Eigen::Isometry3f), sizeof(perch2::Hypothesis));
  try {
    const auto hyps = hypotheses();
    perch2::CloudBatch a, b;
    std::uint64_t digest_a = 0, digest_b = 0;
    const bool ok = check<perch2::cpu::Backend>("cpu", hyps, a, digest_a) &
                    check<perch2::thrust_omp::Backend>("thrust_omp", hyps, b, digest_b);
    const bool same = a.x == b.x && a.y == b.y && a.z == b.z && a.pixel == b.pixel && a.offsets == b.offsets;
    if (!same) std::printf("consumer: cpu and thrust_omp renders differ\n");
    std::ostringstream csv;  // perch2::dataset and perch2::eval link too
    perch2::dataset::write_results_csv(csv, {});
    const bool eval_ok = csv.str() == std::string(perch2::dataset::kBopResultsHeader) + "\n" &&
                         perch2::eval::auc_ycb({0.0}) == 1.0;
    if (!eval_ok) std::printf("consumer: perch2::dataset / perch2::eval gave unexpected results\n");
    const bool synth_ok = !perch2::synth::builtin_models().empty();  // perch2::synth links too
    if (!synth_ok) std::printf("consumer: perch2::synth has no built-in models\n");
    return ok && same && eval_ok && synth_ok ? 0 : 1;
  } catch (const std::exception& e) {
    std::printf("consumer: %s\n", e.what());
    return 1;
  }
}
