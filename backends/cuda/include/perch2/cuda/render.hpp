// Thrust batch renderer: parallel over (hypothesis, triangle) with a packed 64-bit atomic-min z-buffer per
// hypothesis ROI, a resolve pass for colour and occluders, and a scan that compacts the batch.
#pragma once

#include <memory>
#include <vector>

#include "perch2/cuda/system.hpp"
#include "perch2/render/render.hpp"

namespace perch2::thrust_backend {

template <class System>
class PERCH2_API Renderer {
 public:
  explicit Renderer(std::vector<Mesh> models);  ///< uploads the models once
  ~Renderer();
  Renderer(Renderer&&) noexcept;
  Renderer& operator=(Renderer&&) noexcept;

  CloudBatch render(const std::vector<Hypothesis>& hypotheses, const Intrinsics& camera,
                    const RenderSettings& settings, const Occluders* occluders = nullptr) const;

  std::size_t num_models() const;

  /// Passes, work items and device allocations of the last render() call (see LaunchShape); its
  /// peak_chunk_bytes stays within RenderSettings::memory_budget_bytes whenever one hypothesis fits.
  LaunchShape last_launch_shape() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

extern template class Renderer<CudaSystem>;
extern template class Renderer<OmpSystem>;
extern template class Renderer<OmpPassesSystem>;

}  // namespace perch2::thrust_backend
