// Reference nearest-neighbour search: FLANN KDTreeSingleIndex (exact) per segment, OpenMP over query clouds.
#include "perch2/cpu/knn.hpp"

#include <flann/flann.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

namespace perch2::cpu {

namespace {
using Tree = flann::KDTreeSingleIndex<flann::L2_Simple<float>>;

/// Row-major x y z copy of points [begin, end) of a batch (FLANN's input layout).
void gather_rows(const CloudBatch& b, std::int64_t begin, std::int64_t end, std::vector<float>& rows) {
  rows.resize(std::size_t(end - begin) * 3);
  for (std::int64_t i = begin; i < end; ++i) {
    float* r = &rows[std::size_t(i - begin) * 3];
    r[0] = b.x[std::size_t(i)], r[1] = b.y[std::size_t(i)], r[2] = b.z[std::size_t(i)];
  }
}

flann::SearchParams single_thread_params() {
  flann::SearchParams p;  // eps = 0: exact
  p.cores = 1;            // parallel over query clouds instead
  p.sorted = true;
  return p;
}
}  // namespace

struct KnnIndex::Impl {
  CloudBatch targets;
  std::vector<std::vector<float>> rows;      // per segment, kept alive for FLANN
  std::vector<std::unique_ptr<Tree>> trees;  // null for empty segments
};

KnnIndex::KnnIndex(CloudBatch targets, const KnnIndexSettings& settings) : impl_(std::make_unique<Impl>()) {
  validate_knn_cloud(targets, "kNN targets");
  validate_knn_index_settings(settings);
  impl_->targets = std::move(targets);
  const CloudBatch& t = impl_->targets;
  const std::size_t ns = t.num_clouds();
  impl_->rows.resize(ns);
  impl_->trees.resize(ns);
#pragma omp parallel for schedule(dynamic, 1)
  for (std::int64_t s = 0; s < std::int64_t(ns); ++s) {
    const std::int64_t b = t.offsets[std::size_t(s)], e = t.offsets[std::size_t(s) + 1];
    if (e == b) continue;
    gather_rows(t, b, e, impl_->rows[std::size_t(s)]);
    flann::Matrix<float> data(impl_->rows[std::size_t(s)].data(), std::size_t(e - b), 3);
    auto tree = std::make_unique<Tree>(data, flann::KDTreeSingleIndexParams(settings.flann_leaf_max_size));
    tree->buildIndex();
    impl_->trees[std::size_t(s)] = std::move(tree);
  }
}

KnnIndex::~KnnIndex() = default;
KnnIndex::KnnIndex(KnnIndex&&) noexcept = default;
KnnIndex& KnnIndex::operator=(KnnIndex&&) noexcept = default;

namespace {
/// FLANN result set over a RadiusVisitor. FLANN admits points with d2 < worstDist() (strict), so the bound
/// is passed as the next float up; points it admits beyond the bound (a leaf scanned before the bound
/// shrank) are dropped here.
class VisitorResultSet final : public flann::ResultSet<float> {
 public:
  VisitorResultSet(KnnIndex::RadiusVisitor& v, std::int64_t base) : v_(v), base_(base) {}
  bool full() const override { return true; }
  void addPoint(float d2, std::size_t index) override {
    if (d2 <= v_.bound_m2()) v_.visit(std::int32_t(base_ + std::int64_t(index)), d2);
  }
  float worstDist() const override {
    const float b = v_.bound_m2();
    if (b != bound_) {  // FLANN asks at every node; the bound rarely changes (nextafter is not free)
      bound_ = b;
      worst_ = b < 0.f ? -1.f : std::nextafter(b, std::numeric_limits<float>::infinity());
    }
    return worst_;
  }

 private:
  KnnIndex::RadiusVisitor& v_;
  std::int64_t base_;
  mutable float bound_ = std::numeric_limits<float>::quiet_NaN(), worst_ = -1.f;  // NaN: never equal
};
}  // namespace

void KnnIndex::radius_visit(const float p[3], std::int32_t segment, RadiusVisitor& visitor) const {
  const Tree* tree = impl_->trees.at(std::size_t(segment)).get();
  if (!tree || !(visitor.bound_m2() >= 0.f)) return;
  VisitorResultSet rs(visitor, impl_->targets.offsets[std::size_t(segment)]);
  flann::SearchParams params = single_thread_params();
  tree->findNeighbors(rs, p, params);
}

std::size_t KnnIndex::num_segments() const {
  return impl_->targets.num_clouds();
}
const CloudBatch& KnnIndex::targets() const {
  return impl_->targets;
}

KnnResult KnnIndex::knn(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
                        const KnnSettings& settings) const {
  validate_knn_settings(settings);
  validate_knn_queries(queries, query_segment, num_segments());
  const int k = settings.k;
  const float max_d2 = settings.max_distance_m * settings.max_distance_m;
  KnnResult out;
  out.k = k;
  out.index.assign(queries.size() * std::size_t(k), -1);
  out.sq_distance_m2.assign(queries.size() * std::size_t(k), std::numeric_limits<float>::infinity());
  const flann::SearchParams params = single_thread_params();
#pragma omp parallel
  {
    std::vector<float> rows;
    std::vector<std::size_t> idx;
    std::vector<float> d2;
#pragma omp for schedule(dynamic, 4)
    for (std::int64_t c = 0; c < std::int64_t(queries.num_clouds()); ++c) {
      const std::int64_t qb = queries.offsets[std::size_t(c)], qe = queries.offsets[std::size_t(c) + 1];
      const std::size_t s = std::size_t(query_segment[std::size_t(c)]);
      const Tree* tree = impl_->trees[s].get();
      if (qe == qb || !tree) continue;
      const std::int64_t seg_begin = impl_->targets.offsets[s];
      const std::size_t seg_size = impl_->targets.cloud_size(s);
      const std::size_t ke = std::min(std::size_t(k), seg_size), nq = std::size_t(qe - qb);
      gather_rows(queries, qb, qe, rows);
      idx.resize(nq * ke);
      d2.resize(nq * ke);
      flann::Matrix<float> qm(rows.data(), nq, 3);
      flann::Matrix<std::size_t> im(idx.data(), nq, ke);
      flann::Matrix<float> dm(d2.data(), nq, ke);
      tree->knnSearch(qm, im, dm, ke, params);
      for (std::size_t i = 0; i < nq; ++i)
        for (std::size_t j = 0; j < ke; ++j) {
          const float dist = dm[i][j];
          if (!(dist <= max_d2)) break;  // sorted: the rest are farther
          const std::size_t o = (std::size_t(qb) + i) * std::size_t(k) + j;
          out.index[o] = std::int32_t(seg_begin + std::int64_t(im[i][j]));
          out.sq_distance_m2[o] = dist;
        }
    }
  }
  return out;
}

RadiusResult KnnIndex::radius(const CloudBatch& queries, const std::vector<std::int32_t>& query_segment,
                              float radius_m, int max_neighbors, KnnMethod) const {
  validate_radius_request(radius_m, max_neighbors);
  validate_knn_queries(queries, query_segment, num_segments());
  // FLANN keeps d2 < radius (strict); the next float up makes it d2 <= radius_m^2.
  const float r2 = radius_m * radius_m;
  const float flann_r2 = std::nextafter(r2, std::numeric_limits<float>::infinity());
  flann::SearchParams params = single_thread_params();
  params.max_neighbors = max_neighbors > 0 ? max_neighbors : -1;
  const std::size_t nq_total = queries.size();
  std::vector<std::vector<std::int32_t>> found_idx(nq_total);
  std::vector<std::vector<float>> found_d2(nq_total);
#pragma omp parallel
  {
    std::vector<float> rows;
    std::vector<std::vector<std::size_t>> idx;
    std::vector<std::vector<float>> d2;
#pragma omp for schedule(dynamic, 4)
    for (std::int64_t c = 0; c < std::int64_t(queries.num_clouds()); ++c) {
      const std::int64_t qb = queries.offsets[std::size_t(c)], qe = queries.offsets[std::size_t(c) + 1];
      const std::size_t s = std::size_t(query_segment[std::size_t(c)]);
      const Tree* tree = impl_->trees[s].get();
      if (qe == qb || !tree) continue;
      const std::int64_t seg_begin = impl_->targets.offsets[s];
      gather_rows(queries, qb, qe, rows);
      flann::Matrix<float> qm(rows.data(), std::size_t(qe - qb), 3);
      idx.clear();
      d2.clear();
      tree->radiusSearch(qm, idx, d2, flann_r2, params);
      for (std::size_t i = 0; i < std::size_t(qe - qb); ++i) {
        const std::size_t q = std::size_t(qb) + i;
        auto& fi = found_idx[q];
        auto& fd = found_d2[q];
        for (std::size_t j = 0; j < idx[i].size(); ++j) {
          if (!(d2[i][j] <= r2)) continue;
          fi.push_back(std::int32_t(seg_begin + std::int64_t(idx[i][j])));
          fd.push_back(d2[i][j]);
        }
        // FLANN orders exact ties arbitrarily: order them by index like every other method.
        knn_sort_pairs(fd.data(), fi.data(), std::int64_t(fd.size()));
      }
    }
  }
  RadiusResult out;
  out.offsets.assign(nq_total + 1, 0);
  for (std::size_t q = 0; q < nq_total; ++q)
    out.offsets[q + 1] = out.offsets[q] + std::int64_t(found_idx[q].size());
  out.index.resize(std::size_t(out.offsets.back()));
  out.sq_distance_m2.resize(std::size_t(out.offsets.back()));
  for (std::size_t q = 0; q < nq_total; ++q) {
    std::copy(found_idx[q].begin(), found_idx[q].end(), out.index.begin() + out.offsets[q]);
    std::copy(found_d2[q].begin(), found_d2[q].end(), out.sq_distance_m2.begin() + out.offsets[q]);
  }
  return out;
}

}  // namespace perch2::cpu
