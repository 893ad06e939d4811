// Pieces of the evaluation shared by its files: the greedy matching of bop_toolkit, and the BOP 2024
// detection scoring (evaluator.hpp, "6D detection"): per image, the outcome of each kept estimate at each
// threshold; over the images, AP per object and threshold. Private to perch2::eval.
#pragma once

#include <cstdint>
#include <map>
#include <vector>

#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/results.hpp"
#include "perch2/eval/evaluator.hpp"

namespace perch2::eval::detail {

/// bop_toolkit pose_matching.match_poses(): estimates in the given order (decreasing score) each take the
/// not yet matched GT instance with the smallest error strictly below `threshold`. Returns the matched
/// estimate per GT instance (-1: none). `error(e, g)` gives the error.
template <class ErrorFn>
std::vector<int> match_greedy(std::size_t E, std::size_t G, double threshold, ErrorFn error) {
  std::vector<int> est_of_gt(G, -1);
  for (std::size_t e = 0; e < E; ++e) {
    int best = -1;
    double best_error = threshold;
    for (std::size_t g = 0; g < G; ++g)
      if (est_of_gt[g] < 0 && error(e, g) < best_error) best = int(g), best_error = error(e, g);
    if (best >= 0) est_of_gt[std::size_t(best)] = int(e);
  }
  return est_of_gt;
}

/// A model as the detection errors need it (points in metres, symmetries, diameter).
struct ScoringModel {
  const std::vector<Eigen::Vector3f>* points = nullptr;
  const std::vector<Pose>* symmetries = nullptr;
  double diameter_m = 0;
};

/// Outcome of an estimate at one threshold.
enum class Outcome : std::int8_t { Ignored = -1, FalsePositive = 0, TruePositive = 1 };

/// One scored estimate: its score and its outcome at each threshold (MSSD, then MSPD, then MSSD in metres,
/// in EvalSettings order).
struct ScoredEstimate {
  double score = 0;
  std::vector<Outcome> outcome;
};

struct DetectionImage {
  std::map<int, std::vector<ScoredEstimate>> per_object;  ///< by decreasing score (stable)
  std::map<int, int> positives;                           ///< instances at least visib_gt_min visible
  int beyond_max = 0, object_absent = 0;
};

/// The image's estimates (`rows`: indices into `estimates`, file order) scored against its annotations.
DetectionImage detection_image(const std::vector<dataset::PoseEstimate>& estimates,
                               const std::vector<std::size_t>& rows, const dataset::ImageInfo& info,
                               const std::map<int, ScoringModel>& models, const Intrinsics& K,
                               const EvalSettings& settings);

/// AP per object and the means over objects, from the images in evaluation order.
DetectionReport detection_report(const std::vector<DetectionImage>& images, const EvalSettings& settings);

}  // namespace perch2::eval::detail
