#include "perch2/eval/metrics.hpp"

#include <flann/flann.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace perch2::eval {

namespace {
using Tree = flann::KDTreeSingleIndex<flann::L2_Simple<float>>;
constexpr double kInf = std::numeric_limits<double>::infinity();

/// FLANN result set for one nearest neighbour without allocations (KNNSimpleResultSet allocates per query).
struct Nearest : flann::ResultSet<float> {
  float d2 = std::numeric_limits<float>::infinity();
  bool full() const override { return true; }
  void addPoint(float dist2, std::size_t) override { d2 = std::min(d2, dist2); }
  float worstDist() const override { return d2; }
};
}  // namespace

/// Exact nearest-point queries: a kd-tree (FLANN), and in front of it a grid of candidate lists covering the
/// model's box plus a margin. Cell c (centre c, half-diagonal r) lists every model point y with
/// |c - y| <= d_c + 2r, where d_c is the distance from c to the model. For a query q in the cell, the nearest
/// point y* satisfies |q - y*| <= |q - NN(c)| <= d_c + r, so |c - y*| <= |c - q| + |q - y*| <= d_c + 2r:
/// y* is in the list, and scanning the list is exact. Queries outside the grid, and in cells far from the
/// surface whose lists would be long (kMaxCandidates), go to the kd-tree.
struct ModelPoints::Impl {
  std::vector<Eigen::Vector3f> points;
  std::vector<float> rows;
  std::unique_ptr<Tree> tree;
  Eigen::Vector3f origin = Eigen::Vector3f::Zero();
  float cell = 0, inv_cell = 0;
  int nx = 0, ny = 0, nz = 0;
  std::vector<std::int32_t> cell_start;  // candidates of cell c: cand[cell_start[c] .. cell_start[c + 1])
  std::vector<std::int32_t> cand;        // candidate point indices
  std::vector<std::uint8_t> use_tree;    // per cell: the list would be longer than kMaxCandidates
  static constexpr std::size_t kMaxCandidates = 128;

  float tree_nearest_d2(const float* q) const {
    Nearest result;
    tree->findNeighbors(result, q, flann::SearchParams());  // eps = 0: exact
    return result.d2;
  }

  void build_grid() {
    Eigen::AlignedBox3f box;
    for (const auto& p : points) box.extend(p);
    const float size = std::max(box.diagonal().norm(), 1e-6f);
    // ~25 cells along the diagonal and a margin of a tenth of it: candidate lists of a few dozen points
    // near the surface, a few tens of thousands of cells per model.
    cell = size / 40.f, inv_cell = 1.f / cell;
    const Eigen::Vector3f margin = Eigen::Vector3f::Constant(0.1f * size);
    origin = box.min() - margin;
    const Eigen::Vector3f extent = box.max() + margin - origin;
    nx = int(std::ceil(extent.x() * inv_cell)), ny = int(std::ceil(extent.y() * inv_cell));
    nz = int(std::ceil(extent.z() * inv_cell));
    const std::size_t cells = std::size_t(nx) * ny * nz;
    const float half_diag = 0.5f * std::sqrt(3.f) * cell;
    std::vector<std::vector<std::int32_t>> lists(cells);
    use_tree.assign(cells, 0);
#pragma omp parallel for schedule(dynamic, 64)
    for (std::int64_t c = 0; c < std::int64_t(cells); ++c) {
      const int x = int(c % nx), y = int((c / nx) % ny), z = int(c / (std::int64_t(nx) * ny));
      const Eigen::Vector3f centre = origin + cell * Eigen::Vector3f(x + 0.5f, y + 0.5f, z + 0.5f);
      const float d = std::sqrt(tree_nearest_d2(centre.data()));
      // 1e-4 relative slack covers float rounding of distances and of the cell assignment.
      const float radius = (d + 2 * half_diag) * 1.0001f + 1e-7f;
      std::vector<std::vector<std::size_t>> idx;
      std::vector<std::vector<float>> d2;
      flann::Matrix<float> qm(const_cast<float*>(centre.data()), 1, 3);
      flann::SearchParams params;
      params.cores = 1;
      tree->radiusSearch(qm, idx, d2, radius * radius, params);
      if (idx[0].size() > kMaxCandidates) {
        use_tree[std::size_t(c)] = 1;
        continue;
      }
      for (const std::size_t i : idx[0]) lists[std::size_t(c)].push_back(std::int32_t(i));
    }
    cell_start.assign(cells + 1, 0);
    for (std::size_t c = 0; c < cells; ++c) cell_start[c + 1] = cell_start[c] + std::int32_t(lists[c].size());
    cand.reserve(std::size_t(cell_start.back()));
    for (const auto& list : lists) cand.insert(cand.end(), list.begin(), list.end());
  }

  float nearest_d2(const float* q) const {
    const float fx = (q[0] - origin.x()) * inv_cell, fy = (q[1] - origin.y()) * inv_cell,
                fz = (q[2] - origin.z()) * inv_cell;
    if (!(fx >= 0 && fy >= 0 && fz >= 0 && fx < nx && fy < ny && fz < nz)) return tree_nearest_d2(q);
    const std::size_t c = (std::size_t(int(fz)) * ny + std::size_t(int(fy))) * nx + std::size_t(int(fx));
    if (use_tree[c]) return tree_nearest_d2(q);
    float best = std::numeric_limits<float>::infinity();
    for (std::int32_t k = cell_start[c]; k < cell_start[c + 1]; ++k) {
      const float* p = &rows[3 * std::size_t(cand[std::size_t(k)])];
      const float dx = p[0] - q[0], dy = p[1] - q[1], dz = p[2] - q[2];
      best = std::min(best, dx * dx + dy * dy + dz * dz);
    }
    return best;
  }
};

ModelPoints::ModelPoints(std::vector<Eigen::Vector3f> points_m) : impl_(std::make_unique<Impl>()) {
  if (points_m.empty()) throw InvalidInput("model points", "no points");
  for (const auto& p : points_m)
    if (!p.allFinite()) throw InvalidInput("model points", "non-finite point");
  impl_->points = std::move(points_m);
  impl_->rows.reserve(impl_->points.size() * 3);
  for (const auto& p : impl_->points) impl_->rows.insert(impl_->rows.end(), {p.x(), p.y(), p.z()});
  flann::Matrix<float> data(impl_->rows.data(), impl_->points.size(), 3);
  impl_->tree = std::make_unique<Tree>(data, flann::KDTreeSingleIndexParams(10));
  impl_->tree->buildIndex();
  impl_->build_grid();
}

ModelPoints::~ModelPoints() = default;
ModelPoints::ModelPoints(ModelPoints&&) noexcept = default;
ModelPoints& ModelPoints::operator=(ModelPoints&&) noexcept = default;

const std::vector<Eigen::Vector3f>& ModelPoints::points() const {
  return impl_->points;
}

void ModelPoints::nearest_sq_distances(const std::vector<float>& xyz_rows, std::vector<float>& d2) const {
  const std::size_t n = xyz_rows.size() / 3;
  d2.resize(n);
  for (std::size_t i = 0; i < n; ++i) d2[i] = impl_->nearest_d2(&xyz_rows[3 * i]);
}

double add_error(const Pose& T_est, const Pose& T_gt, const std::vector<Eigen::Vector3f>& points_m) {
  if (points_m.empty()) throw InvalidInput("ADD", "model has no points");
  const Eigen::Isometry3d Te = T_est.cast<double>(), Tg = T_gt.cast<double>();
  double sum = 0;
  for (const auto& p : points_m) sum += (Te * p.cast<double>() - Tg * p.cast<double>()).norm();
  return sum / double(points_m.size());
}

double adds_error(const Pose& T_est, const Pose& T_gt, const ModelPoints& model) {
  // |T_gt x - T_est y| = |T_est^-1 T_gt x - y|: query the object-frame tree with T_est^-1 T_gt x.
  const Eigen::Isometry3d T = T_est.cast<double>().inverse() * T_gt.cast<double>();
  const auto& pts = model.points();
  std::vector<float> rows(pts.size() * 3);
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const Eigen::Vector3d q = T * pts[i].cast<double>();
    rows[3 * i] = float(q.x()), rows[3 * i + 1] = float(q.y()), rows[3 * i + 2] = float(q.z());
  }
  std::vector<float> d2;
  model.nearest_sq_distances(rows, d2);
  double sum = 0;
  for (const float d : d2) sum += std::sqrt(double(d));
  return sum / double(pts.size());
}

std::vector<Pose> symmetry_transformations(const dataset::ModelInfo& info, double max_sym_disc_step) {
  if (!(max_sym_disc_step > 0)) throw InvalidInput("max_sym_disc_step", "must be > 0");
  std::vector<Pose> discrete{Pose::Identity()};
  discrete.insert(discrete.end(), info.symmetries_discrete.begin(), info.symmetries_discrete.end());
  std::vector<Pose> continuous;
  // (pi * diameter) / (max_sym_disc_step * diameter) steps: the farthest vertex moves at most
  // max_sym_disc_step * diameter between consecutive rotations (misc.get_symmetry_transformations).
  for (const auto& c : info.symmetries_continuous) {
    const int steps = int(std::ceil(M_PI / max_sym_disc_step));
    for (int i = 0; i < steps; ++i) {
      Pose S = Pose::Identity();
      S.linear() =
          Eigen::AngleAxisd(i * 2.0 * M_PI / steps, c.axis.cast<double>()).toRotationMatrix().cast<float>();
      S.translation() = -(S.linear() * c.offset_m) + c.offset_m;  // rotation about the axis through offset
      continuous.push_back(S);
    }
  }
  if (continuous.empty()) return discrete;
  std::vector<Pose> out;
  for (const auto& D : discrete)
    for (const auto& C : continuous) out.push_back(C * D);  // R = R_c R_d, t = R_c t_d + t_c
  return out;
}

double mssd_error(const Pose& T_est, const Pose& T_gt, const std::vector<Eigen::Vector3f>& points_m,
                  const std::vector<Pose>& symmetries) {
  if (points_m.empty() || symmetries.empty()) throw InvalidInput("MSSD", "no points or no symmetries");
  const Eigen::Isometry3d Te = T_est.cast<double>();
  std::vector<Eigen::Vector3d> est(points_m.size());
  for (std::size_t i = 0; i < points_m.size(); ++i) est[i] = Te * points_m[i].cast<double>();
  double best = kInf;
  for (const auto& S : symmetries) {
    const Eigen::Isometry3d Tg = T_gt.cast<double>() * S.cast<double>();
    double worst2 = 0;
    for (std::size_t i = 0; i < points_m.size() && worst2 < best * best; ++i)
      worst2 = std::max(worst2, (est[i] - Tg * points_m[i].cast<double>()).squaredNorm());
    best = std::min(best, std::sqrt(worst2));  // early exit above only skips symmetries that cannot win
  }
  return best;
}

double mspd_error(const Pose& T_est, const Pose& T_gt, const Intrinsics& K,
                  const std::vector<Eigen::Vector3f>& points_m, const std::vector<Pose>& symmetries) {
  if (points_m.empty() || symmetries.empty()) throw InvalidInput("MSPD", "no points or no symmetries");
  auto project = [&](const Eigen::Vector3d& p) {
    return Eigen::Vector2d(K.fx * p.x() / p.z() + K.cx, K.fy * p.y() / p.z() + K.cy);
  };
  const Eigen::Isometry3d Te = T_est.cast<double>();
  std::vector<Eigen::Vector2d> est(points_m.size());
  for (std::size_t i = 0; i < points_m.size(); ++i) est[i] = project(Te * points_m[i].cast<double>());
  double best = kInf;
  for (const auto& S : symmetries) {
    const Eigen::Isometry3d Tg = T_gt.cast<double>() * S.cast<double>();
    double worst2 = 0;
    for (std::size_t i = 0; i < points_m.size() && worst2 < best * best; ++i)
      worst2 = std::max(worst2, (est[i] - project(Tg * points_m[i].cast<double>())).squaredNorm());
    best = std::min(best, std::sqrt(worst2));
  }
  return best;
}

float depth_to_distance(const Intrinsics& K, int u, int v, float z_m) {
  const double x = (u - double(K.cx)) / K.fx, y = (v - double(K.cy)) / K.fy;
  return float(z_m * std::sqrt(x * x + y * y + 1.0));
}

std::vector<double> vsd_errors(const SparseDistance& est, const SparseDistance& gt,
                               const DepthImage& depth_test_m, const Intrinsics& K, double delta_m,
                               const std::vector<double>& taus, double diameter_m) {
  check_size(depth_test_m, K.width, K.height, "VSD test depth");
  if (!(diameter_m > 0)) throw InvalidInput("VSD", "diameter must be > 0");
  // Merge the two sorted pixel lists; pixels rendered by neither model cannot be in the union.
  std::size_t union_count = 0, inter_count = 0;
  std::vector<double> inter_dists;  // |d_gt - d_est| / diameter on the visible intersection
  std::size_t i = 0, j = 0;
  while (i < est.pixel.size() || j < gt.pixel.size()) {
    const std::int32_t pe = i < est.pixel.size() ? est.pixel[i] : std::numeric_limits<std::int32_t>::max();
    const std::int32_t pg = j < gt.pixel.size() ? gt.pixel[j] : std::numeric_limits<std::int32_t>::max();
    const std::int32_t p = std::min(pe, pg);
    const float d_est = pe == p ? est.dist_m[i++] : 0.f;
    const float d_gt = pg == p ? gt.dist_m[j++] : 0.f;
    const int u = p % K.width, v = p / K.width;
    const float z_test = depth_test_m.data[std::size_t(p)];
    const double d_test = z_test > 0 ? depth_to_distance(K, u, v, z_test) : 0.0;
    const bool vis_gt = d_gt > 0 && (d_test == 0 || d_gt - d_test <= delta_m);
    const bool vis_est = d_est > 0 && ((d_test == 0 || d_est - d_test <= delta_m) || vis_gt);
    if (vis_gt || vis_est) ++union_count;
    if (vis_gt && vis_est) ++inter_count, inter_dists.push_back(std::abs(double(d_gt) - d_est) / diameter_m);
  }
  std::vector<double> out;
  for (const double tau : taus) {
    if (union_count == 0) {
      out.push_back(1.0);
      continue;
    }
    std::size_t cost = 0;
    for (const double d : inter_dists) cost += d >= tau;
    out.push_back(double(cost + (union_count - inter_count)) / double(union_count));
  }
  return out;
}

bool sphere_projections_overlap(double radius_m, const Eigen::Vector3d& p1, const Eigen::Vector3d& p2) {
  if (p1.z() == 0 || p2.z() == 0) return false;
  const double proj_dist = ((p1 / p1.z()).head<2>() - (p2 / p2.z()).head<2>()).norm();
  return proj_dist < radius_m * (1.0 / p1.z() + 1.0 / p2.z());
}

double auc_ycb(std::vector<double> errors_m, double max_m) {
  // YCB-Video toolbox: D(D > max) = inf; d = sort(D); accuracy = (1:n)/n; VOCap(d, accuracy).
  const std::size_t n = errors_m.size();
  if (n == 0) return 0;
  for (double& e : errors_m)
    if (!(e <= max_m)) e = kInf;
  std::sort(errors_m.begin(), errors_m.end());
  // VOCap: keep finite entries; mrec = [0; rec; max], mpre = [0; prec; prec(end)]; running max of mpre;
  // area = sum over changes of mrec of (mrec(i) - mrec(i-1)) * mpre(i), normalised by max.
  std::vector<double> mrec{0.0}, mpre{0.0};
  for (std::size_t k = 0; k < n && std::isfinite(errors_m[k]); ++k)
    mrec.push_back(errors_m[k]), mpre.push_back(double(k + 1) / double(n));
  if (mrec.size() == 1) return 0;  // every error is a failure (the toolbox's try/catch gives 0)
  mrec.push_back(max_m), mpre.push_back(mpre.back());
  for (std::size_t k = 1; k < mpre.size(); ++k) mpre[k] = std::max(mpre[k], mpre[k - 1]);
  double area = 0;
  for (std::size_t k = 1; k < mrec.size(); ++k)
    if (mrec[k] != mrec[k - 1]) area += (mrec[k] - mrec[k - 1]) * mpre[k];
  return area / max_m;
}

PrecisionRecall precision_recall(const std::vector<bool>& true_positive, int positives) {
  PrecisionRecall pr;
  long tp = 0;
  for (std::size_t k = 0; k < true_positive.size(); ++k) {
    tp += true_positive[k] ? 1 : 0;
    pr.recall.push_back(positives > 0 ? double(tp) / double(positives) : 0.0);
    pr.precision.push_back(double(tp) / double(k + 1));
  }
  return pr;
}

std::vector<double> interpolated_precision(const PrecisionRecall& pr) {
  // calc_ap(): mrec = [0, rec, 1], mpre = [0, pre, 0]; for each r of np.linspace(0, 1, 101) (= k * 0.01, the
  // last exactly 1) the max of mpre over mrec >= r. The sentinels only add precision 0.
  std::vector<double> out(101, 0.0);
  for (int k = 0; k <= 100; ++k) {
    const double r = k == 100 ? 1.0 : k * 0.01;
    for (std::size_t i = 0; i < pr.recall.size(); ++i)
      if (pr.recall[i] >= r) out[std::size_t(k)] = std::max(out[std::size_t(k)], pr.precision[i]);
  }
  return out;
}

double average_precision(const PrecisionRecall& pr) {
  const auto p = interpolated_precision(pr);
  return std::accumulate(p.begin(), p.end(), 0.0) / double(p.size());
}

}  // namespace perch2::eval
