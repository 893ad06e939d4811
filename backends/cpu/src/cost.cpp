// Reference cost stage, one hypothesis per task: the observed points inside its volume (found among those
// within the volume's bounding sphere by the observed kd-tree), then one exact FLANN radius search per
// rendered point (cpu::KnnIndex::radius_visit) over the observed points within delta. Each search classifies
// its rendered point with the shared OutlierVote (J_r) and fills the pair records of the volume's observed
// points it meets, from which J_o follows without searching the rendered points (PairColorTest).
#include "perch2/cpu/cost.hpp"

#include <algorithm>

#include "perch2/cpu/knn.hpp"
#include "perch2/knn/scan.hpp"

namespace perch2::cpu {

namespace {

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

/// The J_r search of one rendered point p of hypothesis h, which also fills the J_o records of the observed
/// points of V(h) it meets (see PairColorTest in perch2/cost/cost.hpp). slot[o] is o's position in V(h)'s
/// list, or -1. With an empty V(h) the search stops as soon as p's class is decided.
struct PairVisitor final : KnnIndex::RadiusVisitor {
  OutlierVote vote;
  float delta2;
  const std::int32_t* slot;
  const Lab<float>* observed_lab;
  const Lab<float>* rendered_lab;
  PairColorTest test;
  std::uint32_t* flags;
  std::uint64_t* nearest;
  FailedColours failed_r, failed_o;  ///< this thread's, for J_r and J_o
  std::int32_t p;
  std::uint32_t key;  ///< FailedColours::key of p's colour
  bool has_volume;

  void visit(std::int32_t o, float d2) override {
    const bool test_colour = test.use_color && test.any_rule && key != 0u;
    std::uint32_t* known = test_colour && !vote.color_match ? failed_r.slot(o, key) : nullptr;
    if (vote(o, d2, known && *known == key) && known) *known = key;
    const std::int32_t k = slot[o];
    if (k < 0) return;
    if (test.use_color && !test.any_rule) nearest[k] = std::min(nearest[k], pair_key(d2, p));
    if (test.use_color && test.any_rule && !(flags[k] & kPairColorMatch)) {
      std::uint32_t* failed = key != 0u ? failed_o.slot(o, key) : nullptr;
      if (!(failed && *failed == key)) {
        if (test.matches(observed_lab[o], rendered_lab, p))
          flags[k] |= kPairColorMatch;
        else if (failed)
          *failed = key;
      }
    }
    flags[k] |= kPairFound;
  }
  float bound_m2() const override {
    if (has_volume) return delta2;
    if (vote.done()) return -1.f;
    return vote.found && !vote.any_rule ? vote.best_d2 : delta2;
  }
};

/// Lists the observed points of segment seg inside volume v, in index order.
std::vector<std::int32_t> volume_points(const KnnIndex& index, const CloudBatch& observed, std::size_t seg,
                                        const VolumeView& v, const Vec2f* vertices) {
  std::vector<std::int32_t> list;
  if (v.radius_m < 0.f) {
    for (std::int64_t i = observed.offsets[seg]; i < observed.offsets[seg + 1]; ++i)
      list.push_back(std::int32_t(i));
    return list;
  }
  InsideVisitor visit(observed, v, vertices, list);
  const float centre[3] = {v.centre_cam.x, v.centre_cam.y, v.centre_cam.z};
  index.radius_visit(centre, std::int32_t(seg), visit);
  std::sort(list.begin(), list.end());  // index order, as a scan of the segment would list them
  return list;
}

void count_class(std::uint8_t c, std::int32_t& inliers, std::int32_t& depth, std::int32_t& color) {
  inliers += c == kInlier, depth += c == kDepthOutlier, color += c == kColorOutlier;
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
  const PackedVolumes vol = pack_volumes(request);
  const bool any_rule = s.color_rule == ColorRule::AnyNeighbour;
  const OutlierVote blank{{}, m.observed_lab(s).data(), s.tau_c, s.lightness_factor, s.use_color, any_rule};
  const PairColorTest test{s.tau_c, s.lightness_factor, s.use_color, any_rule};
  CostResult result;
  result.hypotheses.resize(n);

  // Per hypothesis: list the observed points of its volume, then one radius search per rendered point
  // classifies that point (J_r) and fills the volume points' pair records (J_o).
#pragma omp parallel
  {
    std::vector<std::int32_t> slot(m.observed.size(), -1);
    std::vector<std::uint32_t> flags;
    std::vector<std::uint64_t> nearest;
    // Per thread, so no atomics are needed; 0 = empty.
    std::vector<std::uint32_t> failed_r(s.use_color ? m.observed.size() * FailedColours::kSlots : 0, 0u);
    std::vector<std::uint32_t> failed_o(failed_r.size(), 0u);
#pragma omp for schedule(dynamic, 1)
    for (std::int64_t hi = 0; hi < std::int64_t(n); ++hi) {
      const auto h = std::size_t(hi);
      const auto seg = std::size_t(request.observed_segment[h]);
      const std::vector<std::int32_t> inside =
          volume_points(m.index, m.observed, seg, vol.views[h], vol.vertices.data());
      for (std::size_t k = 0; k < inside.size(); ++k) slot[std::size_t(inside[k])] = std::int32_t(k);
      flags.assign(inside.size(), 0u);
      nearest.assign(inside.size(), kNoPair);
      CostBreakdown& b = result.hypotheses[h];
      for (std::int64_t i = rendered.offsets[h]; i < rendered.offsets[h + 1]; ++i) {
        const auto q = std::size_t(i);
        PairVisitor v{};
        v.vote = blank, v.vote.lab = rendered_lab[q];
        v.delta2 = s.delta_m * s.delta_m, v.slot = slot.data(), v.observed_lab = m.observed_lab(s).data();
        v.rendered_lab = rendered_lab.data();
        v.test = test, v.flags = flags.data(), v.nearest = nearest.data();
        v.failed_r = {failed_r.data()}, v.failed_o = {failed_o.data()};
        v.key = FailedColours::key(rendered.rgb[q]);
        v.p = std::int32_t(i), v.has_volume = !inside.empty();
        const float p[3] = {rendered.x[q], rendered.y[q], rendered.z[q]};
        m.index.radius_visit(p, std::int32_t(seg), v);
        count_class(v.vote.result(), b.rendered_inliers, b.rendered_depth_outliers,
                    b.rendered_color_outliers);
      }
      std::int32_t unused = 0;
      for (std::size_t k = 0; k < inside.size(); ++k) {
        const std::size_t o = std::size_t(inside[k]);
        count_class(test.result(flags[k], nearest[k], m.observed_lab(s)[o], rendered_lab.data()), unused,
                    b.observed_depth_outliers, b.observed_color_outliers);
        slot[o] = -1;
      }
      b.rendered_points = std::int32_t(rendered.cloud_size(h));
      b.observed_in_volume = std::int32_t(inside.size());
      finish_cost(b, s);
    }
  }
  return result;
}

}  // namespace perch2::cpu
