// Selection in the tabletop search (perch2/search/tabletop.hpp): the acceptance tests of a pose
// (min_rendered_points, min_inlier_fraction, min_observed_in_volume), the footprints' overlap in the table
// plane (convex polygons, separating axes, overlap_tolerance_m), and the Parallel modes' selection: per
// model the best `count` acceptable, non-overlapping poses, the model whose next pose explains its points
// best taking first. (Tree mode selects level by level in tree.hpp.)
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <numeric>
#include <vector>

#include "perch2/cost/cost.hpp"
#include "perch2/search/tabletop/context.hpp"

namespace perch2::tabletop_detail {

/// Footprint polygon of a candidate in table coordinates.
inline std::vector<Eigen::Vector2f> posed_polygon(const Footprint& f, const Candidate& c) {
  const Eigen::Rotation2Df R(c.yaw);
  std::vector<Eigen::Vector2f> out;
  for (const auto& p : f.polygon_xy_m) out.push_back(R * p + Eigen::Vector2f(c.x, c.y));
  return out;
}

/// Interpenetration depth of two convex polygons (separating axis theorem): the smallest overlap of their
/// projections over both polygons' edge normals; <= 0 if they are separated.
inline float penetration_m(const std::vector<Eigen::Vector2f>& a, const std::vector<Eigen::Vector2f>& b) {
  float depth = std::numeric_limits<float>::infinity();
  for (const auto* poly : {&a, &b})
    for (std::size_t i = 0; i < poly->size(); ++i) {
      const Eigen::Vector2f e = (*poly)[(i + 1) % poly->size()] - (*poly)[i];
      if (!(e.squaredNorm() > 1e-12f)) continue;  // a (near-)repeated vertex has no normal
      const Eigen::Vector2f n = Eigen::Vector2f(e.y(), -e.x()).normalized();
      float a0 = INFINITY, a1 = -INFINITY, b0 = INFINITY, b1 = -INFINITY;
      for (const auto& p : a) a0 = std::min(a0, n.dot(p)), a1 = std::max(a1, n.dot(p));
      for (const auto& p : b) b0 = std::min(b0, n.dot(p)), b1 = std::max(b1, n.dot(p));
      depth = std::min(depth, std::min(a1, b1) - std::max(a0, b0));
    }
  return depth;
}

/// Distance of p from a convex polygon (either winding), metres; 0 inside.
inline float distance_outside_m(const std::vector<Eigen::Vector2f>& poly, const Eigen::Vector2f& p) {
  bool pos = false, neg = false;
  float nearest = INFINITY;
  for (std::size_t i = 0; i < poly.size(); ++i) {
    const Eigen::Vector2f a = poly[i], e = poly[(i + 1) % poly.size()] - a;
    const float cross = e.x() * (p.y() - a.y()) - e.y() * (p.x() - a.x());
    (cross > 0.f ? pos : neg) |= cross != 0.f;
    const float t = e.squaredNorm() > 0.f ? std::clamp((p - a).dot(e) / e.squaredNorm(), 0.f, 1.f) : 0.f;
    nearest = std::min(nearest, (a + t * e - p).norm());
  }
  return pos && neg ? nearest : 0.f;
}

/// The share of a hypothesis' points (rendered and observed in its volume) it leaves unexplained: comparable
/// across models of different sizes, unlike the raw-count total.
inline float unexplained_fraction(const CostBreakdown& b) {
  return float(b.rendered_outliers() + b.observed_unexplained()) /
         float(std::max(1, b.rendered_points + b.observed_in_volume));
}

/// The acceptance tests of a scored pose: min_rendered_points shown, min_inlier_fraction of them explained,
/// and (but for BF-ICP, which has no volume) min_observed_in_volume readings in its volume.
template <class Backend>
bool acceptable(const Context<Backend>& ctx, const CostBreakdown& b) {
  if (ctx.settings.mode != SearchMode::BruteForceIcp &&
      b.observed_in_volume < ctx.settings.min_observed_in_volume)
    return false;
  return b.rendered_points >= ctx.settings.min_rendered_points &&
         float(b.rendered_inliers) >= ctx.settings.min_inlier_fraction * float(b.rendered_points);
}

/// Whether two candidates' footprints interpenetrate by more than overlap_tolerance_m.
template <class Backend>
bool overlaps(const Context<Backend>& ctx, const Candidate& a, const Candidate& b) {
  return penetration_m(posed_polygon(ctx.footprints[a.model], a), posed_polygon(ctx.footprints[b.model], b)) >
         ctx.settings.overlap_tolerance_m;
}

/// Selection of the parallel modes. Per model, acceptable candidates in order of score; a candidate is
/// taken unless it overlaps one already taken of the same model (or, with exclusive_placements, of any
/// model). Across models, the model whose next candidate explains its points best (smallest unexplained
/// share plus the hidden term, see hidden_point_weight; BF-ICP: smallest fitness) takes first. Appends the
/// poses to result (grouped by request order) and returns the indices of the chosen candidates in that
/// order.
template <class Backend>
std::vector<std::size_t> select_parallel(const Context<Backend>& ctx, const Frame<Backend>& f,
                                         const std::vector<Candidate>& cands,
                                         const std::vector<float>& scores,
                                         const std::vector<CostBreakdown>& costs,
                                         const std::vector<float>& hidden,
                                         const std::vector<ObjectCount>& objects, TabletopResult& result) {
  const bool bf = ctx.settings.mode == SearchMode::BruteForceIcp;
  std::vector<std::size_t> order(cands.size());
  std::iota(order.begin(), order.end(), std::size_t(0));
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return scores[a] < scores[b]; });
  std::vector<std::vector<std::size_t>> ranked(ctx.models.size());  // acceptable, best first
  for (const std::size_t h : order)
    if (acceptable(ctx, costs[h])) ranked[std::size_t(cands[h].model)].push_back(h);
  std::vector<int> need(ctx.models.size(), 0);
  for (const auto& o : objects) need[std::size_t(o.model)] = o.count;
  std::vector<std::size_t> next(ctx.models.size(), 0);
  std::vector<std::vector<std::size_t>> taken(ctx.models.size());
  std::vector<std::size_t> all_taken;
  auto blocked = [&](std::size_t h) {
    const auto& others = ctx.settings.exclusive_placements ? all_taken : taken[std::size_t(cands[h].model)];
    return std::any_of(others.begin(), others.end(),
                       [&](std::size_t k) { return overlaps(ctx, cands[k], cands[h]); });
  };
  for (;;) {
    std::ptrdiff_t best = -1;
    float best_key = INFINITY;
    for (const auto& o : objects) {
      const auto m = std::size_t(o.model);
      if (need[m] == 0) continue;
      while (next[m] < ranked[m].size() && blocked(ranked[m][next[m]])) ++next[m];
      if (next[m] == ranked[m].size()) continue;
      const std::size_t h = ranked[m][next[m]];
      const float key = bf ? scores[h]
                           : unexplained_fraction(costs[h]) +
                                 (hidden.empty() ? 0.f : ctx.settings.hidden_point_weight * hidden[h]);
      if (best < 0 || key < best_key) best = std::ptrdiff_t(h), best_key = key;
    }
    if (best < 0) break;
    const auto m = std::size_t(cands[std::size_t(best)].model);
    taken[m].push_back(std::size_t(best)), all_taken.push_back(std::size_t(best));
    --need[m], ++next[m];
  }
  std::vector<std::size_t> chosen;
  for (const auto& o : objects) {
    const auto m = std::size_t(o.model);
    for (std::size_t k = 0; k < taken[m].size(); ++k) {
      const std::size_t h = taken[m][k];
      result.poses.push_back(make_pose(ctx, f, cands[h], int(k), scores[h], costs[h]));
      chosen.push_back(h);
    }
    if (need[m] > 0) result.missing.push_back({o.model, need[m]});
  }
  return chosen;
}

}  // namespace perch2::tabletop_detail
