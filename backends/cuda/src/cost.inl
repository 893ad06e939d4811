// Thrust cost stage. Included by cost.cu (nvcc, CUDA system) and cost_omp.cpp (g++, OpenMP system); the
// algorithm text lives here once, over the PERCH2_HD pieces of perch2/cost/cost.hpp and perch2/knn/grid.hpp.
//   Volumes: one thread per hypothesis counts, then lists, the observed points inside its volume (visiting
//            the observed grid within the volume's bounding sphere) as keys (hypothesis, point), in point
//            order (the observed cloud is kept in its grid's order, see Impl::in_grid_order).
//   J_r:     one thread per rendered point visits the observed grid within delta (OutlierVote), and fills the
//            pair records of the observed points of its hypothesis' volume it meets (binary search in the
//            hypothesis' sorted keys; atomic or / min, see PairColorTest), so J_o needs no search and no
//            index over the rendered points.
//            CPU systems (System::cost_whole_hypotheses): one work item per thread classifies whole
//            hypotheses' rendered points, pulled from a counter, finding the records through its own dense
//            slot array (observed point -> position in the hypothesis' list) instead of the binary search.
//   J_o:     one thread per listed (hypothesis, point) classifies it from its record.
//   One thread per hypothesis sums its point classes.
#include <thrust/copy.h>
#include <thrust/device_vector.h>
#include <thrust/execution_policy.h>
#include <thrust/for_each.h>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/scan.h>
#include <thrust/transform.h>
#include <cuda/atomic>
#include <stdexcept>

#include "perch2/core/segments.hpp"
#include "perch2/cuda/cost.hpp"
#include "perch2/cuda/knn.hpp"
#include "perch2/knn/grid.hpp"
#include "thrust_util.hpp"

namespace perch2::thrust_backend {

namespace cost_kernels {

struct ToLab {
  bool shading_invariant;
  PERCH2_HD Lab<float> operator()(std::uint32_t rgb) const { return comparison_lab(rgb, shading_invariant); }
};

/// What a point is compared against: a grid over the other cloud and that cloud's colours.
struct Side {
  GridView grid;
  const Lab<float>* lab;
};

struct VoteParams {
  float delta_m, tau_c, kL;
  bool use_color, any_rule;
};

/// (hypothesis, observed point) as one sortable key.
PERCH2_HD inline std::uint64_t volume_key(std::int64_t h, std::int32_t o) {
  return (std::uint64_t(h) << 32) | std::uint32_t(o);
}

/// The pair records of the observed points of the volumes (one per listed key).
struct PairRecords {
  const std::uint64_t* keys;  ///< sorted; hypothesis h owns [offsets[h], offsets[h + 1])
  const std::int64_t* offsets;
  std::uint32_t* flags;
  std::uint64_t* nearest;
  FailedColours failed_r, failed_o;  ///< shared by all threads (relaxed atomics)
  const std::uint32_t* rendered_rgb;
  const Lab<float>* observed_lab;
  const Lab<float>* rendered_lab;
  PairColorTest test;
};

/// OutlierVote of rendered point p plus the pair-record updates of the volume points it meets.
struct PairVisitor {
  OutlierVote vote;
  const PairRecords* r;
  std::int64_t h;
  std::int32_t p;
  std::uint32_t key;  ///< FailedColours::key of p's colour
  /// Whole hypotheses: slot[o] = o's position in h's keys, or -1; nullptr: binary search in h's keys.
  const std::int32_t* slot;
  PERCH2_HD void operator()(std::int32_t o, float d2) {
    const PairColorTest& t = r->test;
    const bool test_colour = t.use_color && t.any_rule && key != 0u;
    if (test_colour && !vote.color_match) {
      cuda::atomic_ref<std::uint32_t, cuda::thread_scope_device> known(*r->failed_r.slot(o, key));
      if (vote(o, d2, known.load(cuda::memory_order_relaxed) == key))
        known.store(key, cuda::memory_order_relaxed);
    } else {
      vote(o, d2);
    }
    const std::int64_t lo = record_of(o);
    if (lo < 0) return;
    cuda::atomic_ref<std::uint32_t, cuda::thread_scope_device> flags(r->flags[lo]);
    std::uint32_t set = kPairFound;
    if (t.use_color && !t.any_rule) {
      const std::uint64_t k = pair_key(d2, p);
      auto* word = reinterpret_cast<unsigned long long*>(r->nearest + lo);
      cuda::atomic_ref<unsigned long long, cuda::thread_scope_device> ref(*word);
      if (k < ref.load(cuda::memory_order_relaxed)) ref.fetch_min(k, cuda::memory_order_relaxed);
    }
    const std::uint32_t now = flags.load(cuda::memory_order_relaxed);
    if (test_colour && !(now & kPairColorMatch)) {
      cuda::atomic_ref<std::uint32_t, cuda::thread_scope_device> failed(*r->failed_o.slot(o, key));
      if (failed.load(cuda::memory_order_relaxed) != key) {
        if (t.matches(r->observed_lab[o], r->rendered_lab, p))
          set |= kPairColorMatch;
        else
          failed.store(key, cuda::memory_order_relaxed);
      }
    } else if (t.use_color && t.any_rule && !(now & kPairColorMatch) &&
               t.matches(r->observed_lab[o], r->rendered_lab, p)) {
      set |= kPairColorMatch;  // a colour outside 0xRRGGBB: no key, no memory
    }
    if ((now | set) != now) flags.fetch_or(set, cuda::memory_order_relaxed);
  }
  /// Position of o's pair record among all keys, or -1 when o is not in h's volume.
  PERCH2_HD std::int64_t record_of(std::int32_t o) const {
    if (slot) return slot[o] < 0 ? -1 : r->offsets[h] + slot[o];
    const std::uint64_t okey = volume_key(h, o);
    std::int64_t lo = r->offsets[h], len = r->offsets[h + 1] - lo;  // lower bound of okey
    while (len > 0) {
      const std::int64_t half = len / 2;
      if (r->keys[lo + half] < okey)
        lo += half + 1, len -= half + 1;
      else
        len = half;
    }
    return lo == r->offsets[h + 1] || r->keys[lo] != okey ? -1 : lo;
  }
  /// Only a hypothesis without volume points may stop at the point's own decision.
  PERCH2_HD bool done() const { return r->offsets[h + 1] == r->offsets[h] && vote.done(); }
};

/// J_r: class of rendered point i (its cloud found from the offsets) against the observed segment; fills
/// the pair records.
struct ClassifyRendered {
  Side observed;
  VoteParams params;
  const Vec3f* points;
  const Lab<float>* lab;
  const std::int64_t* offsets;
  int num_clouds;
  const std::int32_t* segment_of_cloud;
  PairRecords records;
  PERCH2_HD std::uint8_t operator()(std::int64_t i) const {
    return classify(i, find_segment(offsets, num_clouds, i), nullptr);
  }
  /// Rendered point i of cloud c; slot: see PairVisitor.
  PERCH2_HD std::uint8_t classify(std::int64_t i, int c, const std::int32_t* slot) const {
    const VoteParams& s = params;
    PairVisitor visit{{lab[i], observed.lab, s.tau_c, s.kL, s.use_color, s.any_rule},
                      &records,
                      c,
                      std::int32_t(i),
                      FailedColours::key(records.rendered_rgb[i]),
                      slot};
    grid_radius_visit(observed.grid, segment_of_cloud[c], points[i], s.delta_m, visit);
    return visit.vote.result();
  }
};

/// J_r by whole hypotheses (CPU systems): work item `worker` pulls hypotheses from the counter `next`,
/// marks the positions of its volume points' records in its own slot array (num_observed entries, all -1
/// between hypotheses), classifies the hypothesis' rendered points and clears the marks.
struct ClassifyRenderedWhole {
  ClassifyRendered each;
  std::int32_t* slots;
  std::int64_t num_observed;
  int* next;
  std::uint8_t* classes;
  PERCH2_HD void operator()(std::int64_t worker) const {
    std::int32_t* slot = slots + worker * num_observed;
    const PairRecords& r = each.records;
    cuda::atomic_ref<int, cuda::thread_scope_device> counter(*next);
    for (int h = counter.fetch_add(1, cuda::memory_order_relaxed); h < each.num_clouds;
         h = counter.fetch_add(1, cuda::memory_order_relaxed)) {
      const std::int64_t b = r.offsets[h], e = r.offsets[h + 1];
      for (std::int64_t j = b; j < e; ++j) slot[r.keys[j] & 0xffffffffu] = std::int32_t(j - b);
      for (std::int64_t i = each.offsets[h]; i < each.offsets[h + 1]; ++i)
        classes[i] = each.classify(i, h, slot);
      for (std::int64_t j = b; j < e; ++j) slot[r.keys[j] & 0xffffffffu] = -1;
    }
  }
};

/// Visits the observed points near a volume and counts (list == nullptr) or lists those inside it.
struct InsideVisitor {
  const Vec3f* points;
  const VolumeView* volume;
  const Vec2f* vertices;
  std::uint64_t* list;
  std::int64_t h;
  std::int64_t n = 0;
  PERCH2_HD void operator()(std::int32_t index, float) {
    if (!inside_volume(*volume, vertices, points[index])) return;
    if (list) list[n] = volume_key(h, index);
    ++n;
  }
};

/// The observed points in hypothesis h's volume: counted (out == nullptr) or written as volume keys from
/// out[offsets[h]].
struct VolumePoints {
  GridView grid;
  const Vec3f* points;
  const std::int64_t* segment_offsets;
  const VolumeView* volumes;
  const Vec2f* vertices;
  const std::int32_t* segment_of_cloud;
  const std::int64_t* out_offsets;
  std::uint64_t* out;
  PERCH2_HD std::int64_t operator()(std::int64_t h) const {
    const VolumeView& v = volumes[h];
    const int s = segment_of_cloud[h];
    std::uint64_t* list = out ? out + out_offsets[h] : nullptr;
    if (v.radius_m < 0.f) {  // the whole segment
      const std::int64_t b = segment_offsets[s], e = segment_offsets[s + 1];
      if (list)
        for (std::int64_t i = b; i < e; ++i) list[i - b] = volume_key(h, std::int32_t(i));
      return e - b;
    }
    InsideVisitor visit{points, &v, vertices, list, h};
    grid_radius_visit(grid, s, v.centre_cam, v.radius_m, visit);
    return visit.n;
  }
};

/// J_o: class of listed volume point j from its pair record.
struct ClassifyObserved {
  PairRecords records;
  PERCH2_HD std::uint8_t operator()(std::int64_t j) const {
    const PairRecords& r = records;
    const auto o = std::int32_t(r.keys[j] & 0xffffffffu);
    return r.test.result(r.flags[j], r.nearest[j], r.observed_lab[o], r.rendered_lab);
  }
};

struct ClassCounts {
  std::int32_t inliers, depth, color;
};

/// Sums the classes of elements [offsets[h], offsets[h + 1]).
struct SumClasses {
  const std::uint8_t* classes;
  const std::int64_t* offsets;
  PERCH2_HD ClassCounts operator()(std::int64_t h) const {
    ClassCounts c{0, 0, 0};
    for (std::int64_t i = offsets[h]; i < offsets[h + 1]; ++i) {
      c.inliers += classes[i] == kInlier;
      c.depth += classes[i] == kDepthOutlier;
      c.color += classes[i] == kColorOutlier;
    }
    return c;
  }
};

inline std::vector<Vec3f> to_aos(const CloudBatch& b) {
  std::vector<Vec3f> p(b.size());
  for (std::size_t i = 0; i < b.size(); ++i) p[i] = {b.x[i], b.y[i], b.z[i]};
  return p;
}

}  // namespace cost_kernels

template <class System>
struct Cost<System>::Impl {
  KnnIndex<System> index;
  std::vector<std::int64_t> offsets_host;
  thrust::device_vector<std::int64_t> offsets;
  thrust::device_vector<Vec3f> points;
  thrust::device_vector<Lab<float>> lab, lab_shading_invariant;  ///< CostSettings::shading_invariant

  static KnnIndexSettings radius_only() {
    KnnIndexSettings s;
    s.grid.cell_representatives = false;  // the cost runs radius searches only
    return s;
  }

  /// The observed cloud in its grid's order (segment, cell, index; segments keep their ranges). The grid
  /// over it maps every sorted position to itself, so a grid visit, which walks sorted positions upwards,
  /// meets points in increasing index order: each volume's list of (hypothesis, point) keys comes out
  /// sorted, with no sort per call, and neighbouring points sit together in memory.
  static CloudBatch in_grid_order(const CloudBatch& observed) {
    const HostGrid grid(observed, radius_only().grid);
    CloudBatch out;
    out.offsets = observed.offsets;
    out.resize(observed.size());
    for (std::size_t i = 0; i < observed.size(); ++i) {
      const auto j = std::size_t(grid.point_index[i]);
      out.x[i] = observed.x[j], out.y[i] = observed.y[j], out.z[i] = observed.z[j];
      out.rgb[i] = observed.rgb[j], out.pixel[i] = observed.pixel[j], out.cloud[i] = observed.cloud[j];
    }
    return out;
  }

  explicit Impl(const CloudBatch& observed) : Impl(in_grid_order(observed), 0) {}
  Impl(const CloudBatch& observed, int /*in grid order*/)
      : index(observed, radius_only()),
        offsets_host(observed.offsets),
        offsets(to_device(observed.offsets)),
        points(to_device(cost_kernels::to_aos(observed))) {
    std::vector<std::int32_t> order;
    append_to_host(order, index.view().grid.point_index, observed.size());
    for (std::size_t i = 0; i < order.size(); ++i)
      if (order[i] != std::int32_t(i))  // the volume lists would come out unsorted
        throw std::logic_error("thrust cost: the observed grid does not keep the grid order it was given");
    const thrust::device_vector<std::uint32_t> rgb = to_device(observed.rgb);
    lab.resize(rgb.size()), lab_shading_invariant.resize(rgb.size());
    thrust::transform(thrust::device, ptr(rgb), ptr(rgb) + rgb.size(), ptr(lab), cost_kernels::ToLab{false});
    thrust::transform(thrust::device, ptr(rgb), ptr(rgb) + rgb.size(), ptr(lab_shading_invariant),
                      cost_kernels::ToLab{true});
  }
  const Lab<float>* observed_lab(const CostSettings& s) const {
    return ptr(s.shading_invariant ? lab_shading_invariant : lab);
  }
};

template <class System>
Cost<System>::Cost(const CloudBatch& observed)
    : impl_((validate_cost_observed(observed), std::make_unique<Impl>(observed))) {}
template <class System>
Cost<System>::~Cost() = default;
template <class System>
Cost<System>::Cost(Cost&&) noexcept = default;
template <class System>
Cost<System>& Cost<System>::operator=(Cost&&) noexcept = default;

template <class System>
std::size_t Cost<System>::num_segments() const {
  return impl_->offsets_host.size() - 1;
}

template <class System>
CostResult Cost<System>::evaluate(const CloudBatch& rendered, const CostRequest& request,
                                  const CostSettings& s) const {
  using namespace cost_kernels;
  const Impl& m = *impl_;
  validate_cost_request(rendered, request, num_segments(), s);
  const std::int64_t n = std::int64_t(rendered.num_clouds());
  const std::int64_t nr = std::int64_t(rendered.size());
  const VoteParams params{s.delta_m, s.tau_c, s.lightness_factor, s.use_color,
                          s.color_rule == ColorRule::AnyNeighbour};
  const thrust::counting_iterator<std::int64_t> first(0);

  // Rendered points and colours.
  const thrust::device_vector<Vec3f> rpoints = to_device(to_aos(rendered));
  const thrust::device_vector<std::uint32_t> rgb = to_device(rendered.rgb);
  thrust::device_vector<Lab<float>> rlab(rgb.size());
  thrust::transform(thrust::device, ptr(rgb), ptr(rgb) + rgb.size(), ptr(rlab), ToLab{s.shading_invariant});
  const thrust::device_vector<std::int64_t> roffsets = to_device(rendered.offsets);
  const thrust::device_vector<std::int32_t> seg = to_device(request.observed_segment);

  // The observed points inside each volume (count, scan, fill, sort), with blank pair records.
  const PackedVolumes packed = pack_volumes(request);
  const thrust::device_vector<VolumeView> volumes = to_device(packed.views);
  const thrust::device_vector<Vec2f> vertices = to_device(packed.vertices);
  thrust::device_vector<std::int64_t> pair_offsets(static_cast<std::size_t>(n) + 1, 0);
  VolumePoints lister{m.index.view().grid, ptr(m.points), ptr(m.offsets), ptr(volumes),
                      ptr(vertices),       ptr(seg),      nullptr,        nullptr};
  thrust::transform(thrust::device, first, first + n, ptr(pair_offsets) + 1, lister);
  thrust::inclusive_scan(thrust::device, ptr(pair_offsets) + 1, ptr(pair_offsets) + n + 1,
                         ptr(pair_offsets) + 1);
  const std::int64_t num_pairs = read_at(pair_offsets, std::size_t(n));
  thrust::device_vector<std::uint64_t> keys(static_cast<std::size_t>(num_pairs));
  lister.out_offsets = ptr(pair_offsets), lister.out = ptr(keys);
  thrust::for_each(thrust::device, first, first + n, lister);
  // Each hypothesis' keys are in point order already: the grid visit meets the points in index order
  // (Impl::in_grid_order).
  thrust::device_vector<std::uint32_t> flags(static_cast<std::size_t>(num_pairs), 0u);
  thrust::device_vector<std::uint64_t> nearest(static_cast<std::size_t>(num_pairs), kNoPair);
  const std::size_t memo = s.use_color ? m.lab.size() * FailedColours::kSlots : 0;
  thrust::device_vector<std::uint32_t> failed_r(memo, 0u), failed_o(memo, 0u);
  const PairRecords records{ptr(keys),       ptr(pair_offsets),
                            ptr(flags),      ptr(nearest),
                            {ptr(failed_r)}, {ptr(failed_o)},
                            ptr(rgb),        m.observed_lab(s),
                            ptr(rlab),       {s.tau_c, s.lightness_factor, s.use_color, params.any_rule}};

  // J_r, filling the pair records; then J_o from them.
  thrust::device_vector<std::uint8_t> rclass(static_cast<std::size_t>(nr));
  const Side observed_side{m.index.view().grid, m.observed_lab(s)};
  const ClassifyRendered classify{observed_side, params, ptr(rpoints), ptr(rlab),
                                  ptr(roffsets), int(n), ptr(seg),     records};
  if constexpr (System::cost_whole_hypotheses) {
    const int workers = cpu_system_workers();
    const std::int64_t num_observed = std::int64_t(m.lab.size());
    thrust::device_vector<std::int32_t> slots(std::size_t(workers) * std::size_t(num_observed), -1);
    thrust::device_vector<int> next(1, 0);
    thrust::for_each(thrust::device, first, first + workers,
                     ClassifyRenderedWhole{classify, ptr(slots), num_observed, ptr(next), ptr(rclass)});
  } else {
    thrust::transform(thrust::device, first, first + nr, ptr(rclass), classify);
  }
  thrust::device_vector<std::uint8_t> oclass(static_cast<std::size_t>(num_pairs));
  thrust::transform(thrust::device, first, first + num_pairs, ptr(oclass), ClassifyObserved{records});

  // Per-hypothesis sums.
  thrust::device_vector<ClassCounts> rsum(static_cast<std::size_t>(n)), osum(static_cast<std::size_t>(n));
  thrust::transform(thrust::device, first, first + n, ptr(rsum), SumClasses{ptr(rclass), ptr(roffsets)});
  thrust::transform(thrust::device, first, first + n, ptr(osum), SumClasses{ptr(oclass), ptr(pair_offsets)});
  const std::vector<ClassCounts> r = to_host(rsum), o = to_host(osum);
  const std::vector<std::int64_t> po = to_host(pair_offsets);
  CostResult result;
  result.hypotheses.resize(std::size_t(n));
  for (std::size_t h = 0; h < std::size_t(n); ++h) {
    CostBreakdown& b = result.hypotheses[h];
    b.rendered_points = std::int32_t(rendered.cloud_size(h));
    b.rendered_inliers = r[h].inliers, b.rendered_depth_outliers = r[h].depth;
    b.rendered_color_outliers = r[h].color;
    b.observed_in_volume = std::int32_t(po[h + 1] - po[h]);
    b.observed_depth_outliers = o[h].depth, b.observed_color_outliers = o[h].color;
    finish_cost(b, s);
  }
  return result;
}

}  // namespace perch2::thrust_backend
