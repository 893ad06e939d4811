// Reference batch renderer: one hypothesis per OpenMP iteration, a private z-buffer over its ROI.
// Its working memory is one ROI and one posed model per thread, so RenderSettings::memory_budget_bytes
// does not apply to it.
#pragma once

#include <memory>
#include <vector>

#include "perch2/core/export.hpp"
#include "perch2/render/render.hpp"

namespace perch2::cpu {

class PERCH2_API Renderer {
 public:
  /// Validates and keeps the models (metres, object frame). Throws InvalidInput on a bad mesh.
  explicit Renderer(std::vector<Mesh> models);
  ~Renderer();
  Renderer(Renderer&&) noexcept;
  Renderer& operator=(Renderer&&) noexcept;

  /// Renders every hypothesis on the stride grid of `camera` (full-resolution intrinsics).
  CloudBatch render(const std::vector<Hypothesis>& hypotheses, const Intrinsics& camera,
                    const RenderSettings& settings, const Occluders* occluders = nullptr) const;

  std::size_t num_models() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace perch2::cpu
