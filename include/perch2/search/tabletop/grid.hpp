// The grid pass of the tabletop search (perch2/search/tabletop.hpp): hypotheses every xy_step_m over the
// workspace, at every yaw_step_rad (one yaw for a yaw-symmetric model), kept where enough object readings lie
// within the model's reach (its footprint's circumradius + support_margin_m); no segmentation needed. Also
// dedupe, which keeps once the hypotheses that refinement moved to the same placement.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <numeric>
#include <string>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/search/tabletop/context.hpp"

namespace perch2::tabletop_detail {

/// Positions every step_m over the workspace (centred on it) with at least min_support_points of
/// readings_xy within the model's reach, each at every grid yaw (one if yaw-symmetric); counts the positions
/// before pruning (times their yaws) into grid_count.
template <class Backend>
std::vector<Candidate> grid(const Context<Backend>& ctx, const Frame<Backend>& f, int model,
                            const std::vector<Eigen::Vector2f>& readings_xy, float step_m,
                            std::size_t& grid_count) {
  const TabletopSettings& s = ctx.settings;
  const Eigen::Vector2f lo = f.workspace.min(), hi = f.workspace.max();
  const int nx = int(std::floor((hi.x() - lo.x()) / step_m)) + 1;
  const int ny = int(std::floor((hi.y() - lo.y()) / step_m)) + 1;
  if (double(nx) * double(ny) > 1e6)
    throw InvalidInput("tabletop workspace", "spans " + std::to_string(nx) + " x " + std::to_string(ny) +
                                                 " grid positions (over a million): give workspace_xy_m or a "
                                                 "larger xy_step_m");
  const Eigen::Vector2f c = f.workspace.center();
  const int nyaw =
      ctx.models[model].yaw_symmetric ? 1 : std::max(1, int(std::lround(kTwoPi / s.yaw_step_rad)));
  const float reach = ctx.circumradius[model] + s.support_margin_m;
  std::vector<Candidate> out;
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) {
      const Eigen::Vector2f p(c.x() + (float(i) - 0.5f * float(nx - 1)) * step_m,
                              c.y() + (float(j) - 0.5f * float(ny - 1)) * step_m);
      grid_count += std::size_t(nyaw);
      int support = 0;
      for (const auto& q : readings_xy) support += (q - p).squaredNorm() <= reach * reach;
      if (support < s.min_support_points) continue;
      for (int k = 0; k < nyaw; ++k) out.push_back({model, p.x(), p.y(), float(k) * kTwoPi / float(nyaw)});
    }
  return out;
}

/// The grid hypotheses of every requested model, pruned by the object readings' support: counts all into
/// result.hypotheses_grid and the kept ones into result.hypotheses_kept.
template <class Backend>
std::vector<Candidate> hypotheses(const Context<Backend>& ctx, const Frame<Backend>& f,
                                  const std::vector<ObjectCount>& objects, TabletopResult& result) {
  std::vector<Candidate> out;
  for (const auto& o : objects) {
    const std::vector<Candidate> c =
        grid(ctx, f, o.model, f.object_xy, ctx.settings.xy_step_m, result.hypotheses_grid);
    out.insert(out.end(), c.begin(), c.end());
  }
  result.hypotheses_kept = out.size();
  return out;
}

/// Candidates that landed on the same placement, kept once (the first of each): x, y quantised to
/// `xy_m`, yaw (wrapped to [0, 2 pi)) to `yaw_rad`, yaw ignored where symmetric[model]. xy_m <= 0: all kept.
inline std::vector<Candidate> dedupe(const std::vector<Candidate>& in, float xy_m, float yaw_rad,
                                     const std::vector<bool>& symmetric) {
  if (!(xy_m > 0.f)) return in;
  const std::int64_t yaw_bins = yaw_rad > 0.f ? std::max<std::int64_t>(1, std::llround(kTwoPi / yaw_rad)) : 1;
  std::vector<std::array<std::int64_t, 4>> key(in.size());
  for (std::size_t i = 0; i < in.size(); ++i) {
    const Candidate& c = in[i];
    float yaw = std::fmod(c.yaw, kTwoPi);
    if (yaw < 0.f) yaw += kTwoPi;
    const bool no_yaw = symmetric[std::size_t(c.model)] || yaw_bins == 1;
    key[i] = {c.model, std::llround(c.x / xy_m), std::llround(c.y / xy_m),
              no_yaw ? 0 : std::llround(yaw / yaw_rad) % yaw_bins};  // 2 pi wraps to bin 0
  }
  std::vector<std::size_t> order(in.size());
  std::iota(order.begin(), order.end(), std::size_t(0));
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return key[a] < key[b]; });
  std::vector<char> keep(in.size(), 0);
  for (std::size_t k = 0; k < order.size(); ++k)
    keep[order[k]] = k == 0 || key[order[k]] != key[order[k - 1]];
  std::vector<Candidate> out;
  for (std::size_t i = 0; i < in.size(); ++i)
    if (keep[i]) out.push_back(in[i]);
  return out;
}

}  // namespace perch2::tabletop_detail
