// Reference registration (see perch2/registration/registration.hpp for the algorithm): one source cloud per
// OpenMP iteration, FLANN kd-trees for correspondences and covariance neighbourhoods, double precision
// Eigen for everything else. Deliberately independent of the Thrust backend's device math.
#include "perch2/cpu/registration.hpp"

#include <flann/flann.hpp>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <mutex>

namespace perch2::cpu {
namespace {

using Tree = flann::KDTreeSingleIndex<flann::L2_Simple<float>>;
using Vec3d = Eigen::Vector3d;
using Mat3d = Eigen::Matrix3d;
using Mat6d = Eigen::Matrix<double, 6, 6>;
using Vec6d = Eigen::Matrix<double, 6, 1>;

/// Points of one segment / cloud, interleaved xyz, with a kd-tree over them (null if empty).
struct Indexed {
  std::vector<float> xyz;
  std::unique_ptr<Tree> tree;
  std::size_t size() const { return xyz.size() / 3; }
  Vec3d point(std::size_t i) const { return Vec3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]); }

  void build() {
    if (xyz.empty()) return;
    flann::Matrix<float> m(xyz.data(), size(), 3);
    tree = std::make_unique<Tree>(m, flann::KDTreeSingleIndexParams(10));
    tree->buildIndex();
  }

  /// Up to k nearest points of q (exact search), nearest first; returns the count.
  int knn(const float* q, int k, std::size_t* idx, float* d2) const {
    if (!tree || k <= 0) return 0;
    flann::KNNSimpleResultSet<float> rs{static_cast<std::size_t>(k)};
    tree->findNeighbors(rs, q, flann::SearchParams(flann::FLANN_CHECKS_UNLIMITED, 0.f, true));
    const int n = int(std::min<std::size_t>(rs.size(), std::size_t(k)));
    rs.copy(idx, d2, std::size_t(n), true);
    return n;
  }

  /// The nearest point of q if its squared distance is below bound_m2 (exact; the same point knn(q, 1)
  /// returns then). The bound prunes the search: queries far from every target end early.
  bool nearest_within(const float* q, float bound_m2, std::size_t& idx, float& d2) const {
    if (!tree) return false;
    struct Nearest final : flann::ResultSet<float> {
      float worst;
      std::size_t index = 0;
      bool found = false;
      explicit Nearest(float b) : worst(b) {}
      bool full() const override { return true; }
      void addPoint(float d, std::size_t i) override {
        if (d < worst) worst = d, index = i, found = true;  // strict, as KNNSimpleResultSet with k = 1
      }
      float worstDist() const override { return worst; }
    } rs(bound_m2);
    tree->findNeighbors(rs, q, flann::SearchParams(flann::FLANN_CHECKS_UNLIMITED, 0.f, true));
    idx = rs.index, d2 = rs.worst;
    return rs.found;
  }
};

Indexed gather(const CloudBatch& c, std::size_t cloud) {
  Indexed out;
  const std::size_t b = std::size_t(c.offsets[cloud]), e = std::size_t(c.offsets[cloud + 1]);
  out.xyz.resize(3 * (e - b));
  for (std::size_t i = b; i < e; ++i) {
    out.xyz[3 * (i - b)] = c.x[i];
    out.xyz[3 * (i - b) + 1] = c.y[i];
    out.xyz[3 * (i - b) + 2] = c.z[i];
  }
  out.build();
  return out;
}

/// Unit normal (eigenvector of the smallest eigenvalue of the neighbourhood covariance), or zero if the
/// neighbourhood has fewer than 3 points or no spread.
Vec3d normal_of(const std::vector<Vec3d>& pts) {
  if (pts.size() < 3) return Vec3d::Zero();
  Vec3d mean = Vec3d::Zero();
  for (const auto& p : pts) mean += p;
  mean /= double(pts.size());
  Mat3d C = Mat3d::Zero();
  for (const auto& p : pts) C += (p - mean) * (p - mean).transpose();
  C /= double(pts.size());
  if (!(C.trace() > 0)) return Vec3d::Zero();
  Eigen::SelfAdjointEigenSolver<Mat3d> es(C);
  if (es.info() != Eigen::Success) return Vec3d::Zero();
  return es.eigenvectors().col(0).normalized();
}

/// Normals from the k nearest neighbours (the point included) within the same cloud.
std::vector<Vec3d> knn_normals(const Indexed& c, int k) {
  const std::size_t n = c.size();
  std::vector<Vec3d> normals(n, Vec3d::Zero());
  std::vector<std::size_t> idx(static_cast<std::size_t>(k));
  std::vector<float> d2(static_cast<std::size_t>(k));
  std::vector<Vec3d> nb;
  for (std::size_t i = 0; i < n; ++i) {
    const int m = c.knn(&c.xyz[3 * i], k, idx.data(), d2.data());
    nb.clear();
    for (int j = 0; j < m; ++j) nb.push_back(c.point(idx[std::size_t(j)]));
    normals[i] = normal_of(nb);
  }
  return normals;
}

/// Normals from the points of the same cloud whose pixels lie within +-radius pixels in u and v and within
/// max_distance in 3-D (the point included).
std::vector<Vec3d> pixel_normals(const CloudBatch& src, std::size_t cloud, const GicpSettings& s) {
  const std::int64_t b = src.offsets[cloud], e = src.offsets[cloud + 1];
  std::vector<std::pair<std::int32_t, std::int64_t>> by_pixel;  // (pixel, point) sorted
  for (std::int64_t i = b; i < e; ++i) by_pixel.emplace_back(src.pixel[std::size_t(i)], i);
  std::sort(by_pixel.begin(), by_pixel.end());
  const int W = s.image_width_px, r = s.pixel_radius_px;
  const double max_d2 = double(s.pixel_neighbour_max_distance_m) * s.pixel_neighbour_max_distance_m;
  std::vector<Vec3d> normals(std::size_t(e - b), Vec3d::Zero());
  std::vector<Vec3d> nb;
  for (std::int64_t i = b; i < e; ++i) {
    const Vec3d p(src.x[std::size_t(i)], src.y[std::size_t(i)], src.z[std::size_t(i)]);
    const int pix = src.pixel[std::size_t(i)];
    const int u = pix % W, v = pix / W;
    nb.clear();
    for (int vv = std::max(0, v - r); vv <= v + r; ++vv) {
      const std::int32_t lo = vv * W + std::max(0, u - r), hi = vv * W + std::min(W - 1, u + r);
      auto it = std::lower_bound(by_pixel.begin(), by_pixel.end(), std::make_pair(lo, std::int64_t(-1)));
      for (; it != by_pixel.end() && it->first <= hi; ++it) {
        const std::size_t j = std::size_t(it->second);
        const Vec3d q(src.x[j], src.y[j], src.z[j]);
        if ((q - p).squaredNorm() <= max_d2) nb.push_back(q);
      }
    }
    normals[std::size_t(i - b)] = normal_of(nb);
  }
  return normals;
}

Mat3d skew(const Vec3d& r) {
  Mat3d S;
  S << 0, -r.z(), r.y(), r.z(), 0, -r.x(), -r.y(), r.x(), 0;
  return S;
}

/// Per-call constants of one ICP / GICP run.
struct Problem {
  bool gicp = false;
  double eps = 1;
  int max_iterations = 1;
  double max_d2 = 0;
  double translation_eps = 0, rotation_eps = 0;
  int min_inliers = 1;
  bool table = false;
  Vec3d up, e1, e2, origin;
  LmSettings lm;
};

template <class S>
Problem make_problem(const S& s, bool gicp, double eps) {
  Problem P;
  P.gicp = gicp;
  P.eps = eps;
  P.max_iterations = s.max_iterations;
  P.max_d2 = double(s.max_correspondence_distance_m) * s.max_correspondence_distance_m;
  P.translation_eps = s.translation_epsilon_m;
  P.rotation_eps = s.rotation_epsilon_rad;
  P.min_inliers = s.min_inliers;
  P.table = s.dof == Dof::TableXYYaw;
  P.lm = s.lm;
  if (P.table) {
    const Eigen::Vector3f u = s.up_cam.normalized();
    Eigen::Vector3f e1, e2;
    plane_basis(u, e1, e2);
    P.up = u.cast<double>(), P.e1 = e1.cast<double>(), P.e2 = e2.cast<double>();
    P.origin = s.origin_cam.template cast<double>();
  }
  return P;
}

struct Output {
  Pose T = Pose::Identity();
  int iterations = 0, inliers = 0;
  float final_error = std::numeric_limits<float>::infinity();
  bool converged = false;
};

/// LM registration of one source cloud (points s, normals ns in the input frame) to one target segment.
Output register_one(const Indexed& target, const std::vector<Vec3d>* target_normals,
                    const std::vector<Vec3d>& s, const std::vector<Vec3d>* ns, const Problem& P) {
  const std::size_t n = s.size();
  Vec3d centroid = Vec3d::Zero();
  for (const auto& p : s) centroid += p;
  if (n) centroid /= double(n);

  Mat3d R_acc = Mat3d::Identity(), R_cand = Mat3d::Identity();
  Vec3d t_acc = Vec3d::Zero(), t_cand = Vec3d::Zero();
  std::vector<std::int64_t> corr_acc(n, -1), corr_new(n, -1);
  Mat6d H_acc = Mat6d::Zero();
  Vec6d g_acc = Vec6d::Zero();
  double cost_acc = 0, sq_acc = 0, lambda = P.lm.lambda_initial;
  int inl_acc = 0;
  bool have_acc = false;
  Output out;

  auto weight = [&](std::int64_t j, std::size_t i, const Mat3d& R) -> Mat3d {
    if (!P.gicp) return Mat3d::Identity();
    const Vec3d nt = (*target_normals)[std::size_t(j)], m = R * (*ns)[i];
    const Mat3d M = 2 * Mat3d::Identity() - (1 - P.eps) * (nt * nt.transpose() + m * m.transpose());
    return M.inverse();
  };

  const float search_bound = float(P.max_d2) * 1.001f + 1e-9f;
  for (int it = 1; it <= P.max_iterations; ++it) {
    out.iterations = it;
    // One pass at the candidate: new correspondences, normal equations, and the candidate's cost over the
    // accepted pose's correspondences and weights (for the LM acceptance test: the cost the step minimised).
    const Vec3d c_cand = P.table ? P.origin : Vec3d(R_cand * centroid + t_cand);
    Mat6d H = Mat6d::Zero();
    Vec6d g = Vec6d::Zero();
    double cost_new = 0, cost_old = 0, sq = 0;
    int inl = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const Vec3d p = R_cand * s[i] + t_cand;
      const float qf[3] = {float(p.x()), float(p.y()), float(p.z())};
      // Bounded by the correspondence distance (float slack far above the rounding of d2f): a nearest point
      // outside the bound fails the double-precision test below anyway. The accepted pose's correspondence
      // bounds it further (the nearest point is at most that far; the margin covers float rounding).
      float bound = search_bound;
      if (have_acc && corr_acc[i] >= 0) {
        const Vec3d d = target.point(std::size_t(corr_acc[i])) - p;
        cost_old += d.dot(weight(corr_acc[i], i, R_acc) * d);  // W frozen at the accepted linearisation
        const float* t = &target.xyz[3 * std::size_t(corr_acc[i])];
        const float dx = t[0] - qf[0], dy = t[1] - qf[1], dz = t[2] - qf[2];
        bound = std::min(bound,
                         (dx * dx + dy * dy + dz * dz) * (1.f + 1e-5f) + std::numeric_limits<float>::min());
      }
      std::size_t j = 0;
      float d2f = 0;
      corr_new[i] = -1;
      if (target.nearest_within(qf, bound, j, d2f)) {
        const Vec3d d = target.point(j) - p;
        if (d.squaredNorm() <= P.max_d2) {
          corr_new[i] = std::int64_t(j);
          const Mat3d W = weight(std::int64_t(j), i, R_cand);
          Eigen::Matrix<double, 3, 6> J;
          J << skew(p - c_cand), -Mat3d::Identity();
          // J^T W once for H and g (a nested lazy product recomputes it for every coefficient).
          const Eigen::Matrix<double, 6, 3> JtW = J.transpose() * W;
          H.noalias() += JtW * J;
          g.noalias() += JtW * d;
          cost_new += d.dot(W * d);
          sq += d.squaredNorm();
          ++inl;
        }
      }
    }
    const bool accept = !have_acc || cost_old <= cost_acc;
    if (accept) {
      if (have_acc) lambda = std::max(lambda * P.lm.lambda_down, double(P.lm.lambda_min));
      R_acc = R_cand, t_acc = t_cand;
      std::swap(corr_acc, corr_new);
      H_acc = H, g_acc = g, cost_acc = cost_new, sq_acc = sq, inl_acc = inl;
      have_acc = true;
    } else {
      lambda *= P.lm.lambda_up;
      if (lambda > P.lm.lambda_max) break;
    }
    if (inl_acc < P.min_inliers) break;

    // Damped step from the accepted linearisation.
    Vec3d w, v;
    if (P.table) {
      Eigen::Matrix<double, 6, 3> B = Eigen::Matrix<double, 6, 3>::Zero();
      B.block<3, 1>(0, 0) = P.up;
      B.block<3, 1>(3, 1) = P.e1;
      B.block<3, 1>(3, 2) = P.e2;
      Eigen::Matrix3d A = B.transpose() * H_acc * B;
      const Eigen::Vector3d gr = B.transpose() * g_acc;
      for (int k = 0; k < 3; ++k) A(k, k) += lambda * (A(k, k) + P.lm.diagonal_floor);
      Eigen::LDLT<Eigen::Matrix3d> ldlt(A);
      if (ldlt.info() != Eigen::Success) break;
      const Eigen::Vector3d z = ldlt.solve(-gr);
      w = z(0) * P.up, v = z(1) * P.e1 + z(2) * P.e2;
    } else {
      Mat6d A = H_acc;
      for (int k = 0; k < 6; ++k) A(k, k) += lambda * (H_acc(k, k) + P.lm.diagonal_floor);
      Eigen::LDLT<Mat6d> ldlt(A);
      if (ldlt.info() != Eigen::Success) break;
      const Vec6d xi = ldlt.solve(-g_acc);
      w = xi.head<3>(), v = xi.tail<3>();
    }
    if (!w.allFinite() || !v.allFinite()) break;
    if (accept && w.norm() < P.rotation_eps && v.norm() < P.translation_eps) {
      out.converged = true;
      break;
    }
    const Vec3d c_acc = P.table ? P.origin : Vec3d(R_acc * centroid + t_acc);
    const double th = w.norm();
    const Mat3d dR = th > 0 ? Mat3d(Eigen::AngleAxisd(th, w / th)) : Mat3d::Identity();
    R_cand = dR * R_acc;
    t_cand = dR * (t_acc - c_acc) + c_acc + v;
  }
  out.T = Pose::Identity();
  out.T.linear() = R_acc.cast<float>();
  out.T.translation() = t_acc.cast<float>();
  out.inliers = inl_acc;
  out.final_error = inl_acc > 0 ? float(std::sqrt(sq_acc / inl_acc)) : std::numeric_limits<float>::infinity();
  return out;
}

}  // namespace

struct Registration::Impl {
  std::vector<Indexed> segments;
  mutable std::mutex mutex;
  mutable std::map<int, std::vector<std::vector<Vec3d>>> target_normals;  // by k_neighbors

  const std::vector<std::vector<Vec3d>>& normals(int k) const {
    std::lock_guard<std::mutex> lock(mutex);
    auto it = target_normals.find(k);
    if (it != target_normals.end()) return it->second;
    std::vector<std::vector<Vec3d>> all(segments.size());
#pragma omp parallel for schedule(dynamic)
    for (std::ptrdiff_t sgm = 0; sgm < std::ptrdiff_t(segments.size()); ++sgm)
      all[std::size_t(sgm)] = knn_normals(segments[std::size_t(sgm)], k);
    return target_normals.emplace(k, std::move(all)).first->second;
  }

  template <class S>
  RegistrationResult run(const CloudBatch& src, const std::vector<std::int32_t>& seg, const S& settings,
                         bool gicp) const {
    const std::size_t num = src.num_clouds();
    RegistrationResult res;
    res.T_corr.assign(num, Pose::Identity());
    res.iterations.assign(num, 0);
    res.inliers.assign(num, 0);
    res.final_error.assign(num, std::numeric_limits<float>::infinity());
    res.converged.assign(num, 0);
    double eps = 1;
    const std::vector<std::vector<Vec3d>>* tn = nullptr;
    const GicpSettings* gs = nullptr;
    if constexpr (std::is_same_v<S, GicpSettings>) {
      gs = &settings;
      eps = settings.covariance_epsilon;
      tn = &normals(settings.k_neighbors);
    }
    const Problem P = make_problem(settings, gicp, eps);
#pragma omp parallel for schedule(dynamic)
    for (std::ptrdiff_t c = 0; c < std::ptrdiff_t(num); ++c) {
      const std::size_t cu = std::size_t(c);
      std::vector<Vec3d> pts;
      for (std::int64_t i = src.offsets[cu]; i < src.offsets[cu + 1]; ++i)
        pts.emplace_back(src.x[std::size_t(i)], src.y[std::size_t(i)], src.z[std::size_t(i)]);
      std::vector<Vec3d> ns;
      if (gs) {
        if (gs->source_covariance == SourceCovariance::FromKnn)
          ns = knn_normals(gather(src, cu), gs->k_neighbors);
        else
          ns = pixel_normals(src, cu, *gs);
      }
      const std::size_t sg = std::size_t(seg[cu]);
      const Output o = register_one(segments[sg], tn ? &(*tn)[sg] : nullptr, pts, gs ? &ns : nullptr, P);
      res.T_corr[cu] = o.T;
      res.iterations[cu] = o.iterations;
      res.inliers[cu] = o.inliers;
      res.final_error[cu] = o.final_error;
      res.converged[cu] = o.converged ? 1 : 0;
    }
    return res;
  }
};

Registration::Registration(const CloudBatch& targets) : impl_(std::make_unique<Impl>()) {
  validate_registration_targets(targets);
  impl_->segments.resize(targets.num_clouds());
  for (std::size_t s = 0; s < targets.num_clouds(); ++s) impl_->segments[s] = gather(targets, s);
}
Registration::~Registration() = default;
Registration::Registration(Registration&&) noexcept = default;
Registration& Registration::operator=(Registration&&) noexcept = default;

std::size_t Registration::num_segments() const {
  return impl_->segments.size();
}

RegistrationResult Registration::icp(const CloudBatch& sources,
                                     const std::vector<std::int32_t>& source_segment,
                                     const IcpSettings& settings) const {
  validate(settings);
  validate_registration_sources(sources, source_segment, impl_->segments.size());
  return impl_->run(sources, source_segment, settings, false);
}

RegistrationResult Registration::gicp(const CloudBatch& sources,
                                      const std::vector<std::int32_t>& source_segment,
                                      const GicpSettings& settings) const {
  validate(settings);
  validate_registration_sources(sources, source_segment, impl_->segments.size(),
                                settings.source_covariance == SourceCovariance::FromPixelNeighbourhood);
  if (settings.icp_warmup_iterations > 0)
    return gicp_after_icp_warmup(
        sources, settings,
        [&](const CloudBatch& c, const IcpSettings& s) { return impl_->run(c, source_segment, s, false); },
        [&](const CloudBatch& c, const GicpSettings& s) { return impl_->run(c, source_segment, s, true); });
  return impl_->run(sources, source_segment, settings, true);
}

}  // namespace perch2::cpu
