#include "detection.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "perch2/eval/metrics.hpp"

namespace perch2::eval::detail {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

/// The matched GT instance of each estimate (-1: none), by match_greedy().
std::vector<int> match(std::size_t E, std::size_t G, double threshold, const std::vector<double>& error) {
  const auto est_of_gt =
      match_greedy(E, G, threshold, [&](std::size_t e, std::size_t g) { return error[e * G + g]; });
  std::vector<int> gt_of_est(E, -1);
  for (std::size_t g = 0; g < G; ++g)
    if (est_of_gt[g] >= 0) gt_of_est[std::size_t(est_of_gt[g])] = int(g);
  return gt_of_est;
}

}  // namespace

DetectionImage detection_image(const std::vector<dataset::PoseEstimate>& estimates,
                               const std::vector<std::size_t>& rows, const dataset::ImageInfo& info,
                               const std::map<int, ScoringModel>& models, const Intrinsics& K,
                               const EvalSettings& s) {
  DetectionImage out;
  // The best-scored max_estimates_per_image of the image (stable: file order on equal scores).
  std::vector<std::size_t> kept = rows;
  std::stable_sort(kept.begin(), kept.end(),
                   [&](std::size_t a, std::size_t b) { return estimates[a].score > estimates[b].score; });
  const std::size_t max_kept = std::size_t(std::max(0, s.max_estimates_per_image));
  if (kept.size() > max_kept) out.beyond_max = int(kept.size() - max_kept), kept.resize(max_kept);

  std::map<int, std::vector<std::size_t>> gts_of;
  for (std::size_t g = 0; g < info.gt.size(); ++g) {
    gts_of[info.gt[g].obj_id].push_back(g);
    out.positives[info.gt[g].obj_id] += info.gt[g].visib_fract >= s.visib_gt_min ? 1 : 0;
  }
  std::map<int, std::vector<std::size_t>> rows_of;
  for (const std::size_t r : kept) {
    if (gts_of.count(estimates[r].obj_id))
      rows_of[estimates[r].obj_id].push_back(r);
    else
      ++out.object_absent;  // eval_calc_errors.py computes no error for it: not scored
  }

  const double px_scale = 640.0 / K.width;  // MSPD thresholds are pixels at 640 px width
  for (const auto& [obj, ests] : rows_of) {
    const auto& gts = gts_of.at(obj);
    const ScoringModel& m = models.at(obj);
    const std::size_t E = ests.size(), G = gts.size();
    std::vector<double> mssd(E * G), mspd(E * G);
    for (std::size_t e = 0; e < E; ++e)
      for (std::size_t g = 0; g < G; ++g) {
        const Pose& Te = estimates[ests[e]].T_cam_obj;
        const Pose& Tg = info.gt[gts[g]].T_cam_obj;
        const double centres = (Te.translation() - Tg.translation()).cast<double>().norm();
        // eval_calc_errors.py: MSSD = inf when the bounding spheres do not overlap.
        mssd[e * G + g] = centres < m.diameter_m ? mssd_error(Te, Tg, *m.points, *m.symmetries) : kInf;
        mspd[e * G + g] = mspd_error(Te, Tg, K, *m.points, *m.symmetries) * px_scale;
      }
    std::vector<double> mssd_rel(mssd);
    for (double& v : mssd_rel) v /= m.diameter_m;

    std::vector<ScoredEstimate> scored(E);
    for (std::size_t e = 0; e < E; ++e) scored[e].score = estimates[ests[e]].score;
    auto outcomes = [&](const std::vector<double>& thresholds, const std::vector<double>& error) {
      for (const double th : thresholds) {
        const auto gt_of_est = match(E, G, th, error);
        for (std::size_t e = 0; e < E; ++e) {
          Outcome o = Outcome::FalsePositive;
          if (gt_of_est[e] >= 0)
            o = info.gt[gts[std::size_t(gt_of_est[e])]].visib_fract >= s.visib_gt_min ? Outcome::TruePositive
                                                                                      : Outcome::Ignored;
          scored[e].outcome.push_back(o);
        }
      }
    };
    outcomes(s.mssd_thresholds, mssd_rel);
    outcomes(s.mspd_thresholds_px, mspd);
    outcomes(s.mssd_thresholds_m, mssd);
    out.per_object[obj] = std::move(scored);
  }
  return out;
}

DetectionReport detection_report(const std::vector<DetectionImage>& images, const EvalSettings& s) {
  DetectionReport rep;
  std::map<int, int> positives;
  std::map<int, std::vector<ScoredEstimate>> all;
  for (const DetectionImage& im : images) {
    rep.num_ignored_beyond_max += im.beyond_max;
    rep.num_ignored_object_absent += im.object_absent;
    for (const auto& [obj, n] : im.positives) positives[obj] += n;
    for (const auto& [obj, ests] : im.per_object) {
      auto& list = all[obj];
      list.insert(list.end(), ests.begin(), ests.end());
    }
  }
  const std::size_t n_mssd = s.mssd_thresholds.size(), n_mspd = s.mspd_thresholds_px.size();
  const std::size_t n_all = n_mssd + n_mspd + s.mssd_thresholds_m.size();
  for (const auto& [obj, n_pos] : positives) {
    if (n_pos == 0) continue;  // eval_bop24_pose.py: an object without targets is not in the mean
    std::vector<ScoredEstimate> ests = all[obj];
    std::stable_sort(ests.begin(), ests.end(),
                     [](const ScoredEstimate& a, const ScoredEstimate& b) { return a.score > b.score; });
    DetectionScores sc;
    sc.num_positives = n_pos;
    sc.num_scored = int(ests.size());
    std::vector<double> ap(n_all);
    sc.precision_at_recall.assign(101, 0.0);
    for (std::size_t t = 0; t < n_all; ++t) {
      std::vector<bool> tp;
      for (const auto& e : ests)
        if (e.outcome[t] != Outcome::Ignored) tp.push_back(e.outcome[t] == Outcome::TruePositive);
      const auto curve = interpolated_precision(precision_recall(tp, n_pos));
      ap[t] = std::accumulate(curve.begin(), curve.end(), 0.0) / double(curve.size());
      if (t < n_mssd + n_mspd)
        for (std::size_t k = 0; k < curve.size(); ++k)
          sc.precision_at_recall[k] += curve[k] / double(n_mssd + n_mspd);
    }
    auto mean = [&](std::size_t from, std::size_t to) {
      return std::accumulate(ap.begin() + std::ptrdiff_t(from), ap.begin() + std::ptrdiff_t(to), 0.0) /
             double(to - from);
    };
    sc.ap_mssd = mean(0, n_mssd);
    sc.ap_mspd = mean(n_mssd, n_mssd + n_mspd);
    sc.ap_mssd_mm = mean(n_mssd + n_mspd, n_all);
    sc.ap = (sc.ap_mssd + sc.ap_mspd) / 2;
    rep.per_object[obj] = std::move(sc);
  }
  // Means over the objects (eval_bop24_pose.py: mAP per error type, then bop24_mAP of the two).
  DetectionScores& o = rep.overall;
  o.precision_at_recall.assign(101, 0.0);
  const double n = double(rep.per_object.size());
  for (const auto& [obj, sc] : rep.per_object) {
    o.num_positives += sc.num_positives, o.num_scored += sc.num_scored;
    o.ap_mssd += sc.ap_mssd / n, o.ap_mspd += sc.ap_mspd / n, o.ap_mssd_mm += sc.ap_mssd_mm / n;
    for (std::size_t k = 0; k < 101; ++k) o.precision_at_recall[k] += sc.precision_at_recall[k] / n;
  }
  o.ap = (o.ap_mssd + o.ap_mspd) / 2;
  return rep;
}

}  // namespace perch2::eval::detail
