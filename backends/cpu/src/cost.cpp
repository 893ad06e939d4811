// Reference cost stage: per point, the neighbours within delta from an exact FLANN radius search
// (cpu::KnnIndex::radius_visit), classified by the shared OutlierVote; the search stops once the class is
// decided. The observed points inside each hypothesis' volume are found among those within its bounding
// sphere (the same kd-tree).
#include "perch2/cpu/cost.hpp"

#include <algorithm>

#include "perch2/cpu/knn.hpp"
#include "perch2/knn/scan.hpp"

namespace perch2::cpu {

namespace {

/// OutlierVote over an exact radius search that stops as soon as the point's class is decided: any
/// neighbour decides a depth-only inlier, a colour match decides an AnyNeighbour inlier, and under the
/// Nearest rule only points no farther than the nearest so far (ties included) can change the outcome.
struct VoteVisitor final : KnnIndex::RadiusVisitor {
  OutlierVote vote;
  float delta2;
  VoteVisitor(const OutlierVote& v, float d2) : vote(v), delta2(d2) {}
  void visit(std::int32_t index, float d2) override { vote(index, d2); }
  float bound_m2() const override {
    if (vote.done()) return -1.f;
    return vote.found && !vote.any_rule ? vote.best_d2 : delta2;
  }
};

/// Lists the observed points inside a volume among those within its bounding sphere.
struct InsideVisitor final : KnnIndex::RadiusVisitor {
  const CloudBatch& observed;
  const VolumeView& volume;
  const Vec2f* vertices;
  std::vector<std::int32_t>& list;
  InsideVisitor(const CloudBatch& o, const VolumeView& v, const Vec2f* vx, std::vector<std::int32_t>& l)
      : observed(o), volume(v), vertices(vx), list(l) {}
  void visit(std::int32_t i, float) override {
    if (inside_volume(volume, vertices, observed.point(std::size_t(i)))) list.push_back(i);
  }
  float bound_m2() const override { return volume.radius_m * volume.radius_m; }
};

/// Point classes (PointClass) of every query point against the index (cloud c searches segment
/// query_segment[c]).
std::vector<std::uint8_t> classify(const KnnIndex& index, const CloudBatch& queries,
                                   const std::vector<std::int32_t>& query_segment,
                                   const std::vector<Lab<float>>& query_lab,
                                   const std::vector<Lab<float>>& target_lab, const CostSettings& s) {
  std::vector<std::uint8_t> out(queries.size(), kDepthOutlier);
  const OutlierVote blank{{},          target_lab.data(),
                          s.tau_c,     s.lightness_factor,
                          s.use_color, s.color_rule == ColorRule::AnyNeighbour};
#pragma omp parallel for schedule(dynamic, 1)
  for (std::int64_t c = 0; c < std::int64_t(queries.num_clouds()); ++c)
    for (std::int64_t i = queries.offsets[std::size_t(c)]; i < queries.offsets[std::size_t(c) + 1]; ++i) {
      const auto q = std::size_t(i);
      VoteVisitor v(blank, s.delta_m * s.delta_m);
      v.vote.lab = query_lab[q];
      const float p[3] = {queries.x[q], queries.y[q], queries.z[q]};
      index.radius_visit(p, query_segment[std::size_t(c)], v);
      out[q] = v.vote.result();
    }
  return out;
}

}  // namespace

struct Cost::Impl {
  CloudBatch observed;
  KnnIndex index;
  std::vector<Lab<float>> lab,
      lab_shading_invariant;  ///< comparison colours (CostSettings::shading_invariant)
  explicit Impl(const CloudBatch& o)
      : observed(o), index(o), lab(lab_colors(o, false)), lab_shading_invariant(lab_colors(o, true)) {}
  const std::vector<Lab<float>>& observed_lab(const CostSettings& s) const {
    return s.shading_invariant ? lab_shading_invariant : lab;
  }
};

Cost::Cost(const CloudBatch& observed)
    : impl_((validate_cost_observed(observed), std::make_unique<Impl>(observed))) {}
Cost::~Cost() = default;
Cost::Cost(Cost&&) noexcept = default;
Cost& Cost::operator=(Cost&&) noexcept = default;

std::size_t Cost::num_segments() const {
  return impl_->observed.num_clouds();
}

CostResult Cost::evaluate(const CloudBatch& rendered, const CostRequest& request,
                          const CostSettings& s) const {
  const Impl& m = *impl_;
  validate_cost_request(rendered, request, num_segments(), s);
  const std::size_t n = rendered.num_clouds();
  const std::vector<Lab<float>> rendered_lab = lab_colors(rendered, s.shading_invariant);
  CostResult result;
  result.hypotheses.resize(n);

  // J_r: every rendered point against the observed points of its hypothesis' segment.
  const std::vector<std::uint8_t> rclass =
      classify(m.index, rendered, request.observed_segment, rendered_lab, m.observed_lab(s), s);

  // J_o: the observed points inside each hypothesis' volume, against that hypothesis' rendered points.
  const PackedVolumes vol = pack_volumes(request);
  std::vector<std::vector<std::int32_t>> inside(n);
#pragma omp parallel for schedule(dynamic, 8)
  for (std::int64_t h = 0; h < std::int64_t(n); ++h) {
    const VolumeView& v = vol.views[std::size_t(h)];
    const std::size_t seg = std::size_t(request.observed_segment[std::size_t(h)]);
    auto& list = inside[std::size_t(h)];
    if (v.radius_m < 0.f) {
      for (std::int64_t i = m.observed.offsets[seg]; i < m.observed.offsets[seg + 1]; ++i)
        list.push_back(std::int32_t(i));
      continue;
    }
    InsideVisitor visit(m.observed, v, vol.vertices.data(), list);
    const float centre[3] = {v.centre_cam.x, v.centre_cam.y, v.centre_cam.z};
    m.index.radius_visit(centre, std::int32_t(seg), visit);
    std::sort(list.begin(), list.end());  // index order, as a scan of the segment would list them
  }
  CloudBatch queries;
  std::vector<Lab<float>> query_lab;
  for (std::size_t h = 0; h < n; ++h) {
    for (const std::int32_t i : inside[h]) {
      queries.x.push_back(m.observed.x[std::size_t(i)]);
      queries.y.push_back(m.observed.y[std::size_t(i)]);
      queries.z.push_back(m.observed.z[std::size_t(i)]);
      query_lab.push_back(m.observed_lab(s)[std::size_t(i)]);
    }
    queries.offsets.push_back(std::int64_t(queries.x.size()));
  }
  std::vector<std::int32_t> own(n);
  for (std::size_t h = 0; h < n; ++h) own[h] = std::int32_t(h);
  const KnnIndex rendered_index(rendered);  // one kd-tree per hypothesis
  const std::vector<std::uint8_t> oclass = classify(rendered_index, queries, own, query_lab, rendered_lab, s);

  for (std::size_t h = 0; h < n; ++h) {
    CostBreakdown& b = result.hypotheses[h];
    for (std::int64_t i = rendered.offsets[h]; i < rendered.offsets[h + 1]; ++i) {
      const std::uint8_t c = rclass[std::size_t(i)];
      b.rendered_inliers += c == kInlier, b.rendered_depth_outliers += c == kDepthOutlier;
      b.rendered_color_outliers += c == kColorOutlier;
    }
    b.rendered_points = std::int32_t(rendered.cloud_size(h));
    b.observed_in_volume = std::int32_t(queries.cloud_size(h));
    for (std::int64_t i = queries.offsets[h]; i < queries.offsets[h + 1]; ++i) {
      const std::uint8_t c = oclass[std::size_t(i)];
      b.observed_depth_outliers += c == kDepthOutlier, b.observed_color_outliers += c == kColorOutlier;
    }
    finish_cost(b, s);
  }
  return result;
}

}  // namespace perch2::cpu
