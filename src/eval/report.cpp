// The evaluation report as a table and as JSON.
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <string>

#include "perch2/eval/evaluator.hpp"

namespace perch2::eval {

namespace {

std::string row(const std::string& name, const Scores& s, bool vsd) {
  char buf[256];
  char vsd_text[16] = "      -";
  if (vsd) std::snprintf(vsd_text, sizeof vsd_text, "%7.1f", 100 * s.ar_vsd);
  std::snprintf(buf, sizeof buf, "%-8s %7d %7.1f %7.1f %7.1f %7.1f %7.1f %s %7.1f %7.1f %7.1f\n",
                name.c_str(), s.num_targets, 100 * s.auc_add, 100 * s.auc_adds, 100 * s.auc_add_or_adds,
                100 * s.adds_below_1cm, 100 * s.adds_below_2cm, vsd_text, 100 * s.ar_mssd, 100 * s.ar_mspd,
                100 * s.ar);
  return buf;
}

nlohmann::json scores_json(const Scores& s) {
  return {{"targets", s.num_targets},
          {"auc_add", s.auc_add},
          {"auc_adds", s.auc_adds},
          {"auc_add_or_adds", s.auc_add_or_adds},
          {"adds_below_1cm", s.adds_below_1cm},
          {"adds_below_2cm", s.adds_below_2cm},
          {"ar_vsd", s.ar_vsd},
          {"ar_mssd", s.ar_mssd},
          {"ar_mspd", s.ar_mspd},
          {"ar", s.ar}};
}

nlohmann::json detection_json(const DetectionScores& s) {
  return {{"positives", s.num_positives},
          {"scored", s.num_scored},
          {"ap_mssd", s.ap_mssd},
          {"ap_mspd", s.ap_mspd},
          {"ap_mssd_mm", s.ap_mssd_mm},
          {"ap", s.ap},
          {"precision_at_recall", s.precision_at_recall}};
}

std::string detection_row(const std::string& name, const DetectionScores& s) {
  char buf[160];
  std::snprintf(buf, sizeof buf, "%-8s %9d %7d %7.1f %7.1f %7.1f %7.1f\n", name.c_str(), s.num_positives,
                s.num_scored, 100 * s.ap_mssd, 100 * s.ap_mspd, 100 * s.ap, 100 * s.ap_mssd_mm);
  return buf;
}

}  // namespace

std::string format_detection(const DetectionReport& d) {
  char head[256];
  std::snprintf(head, sizeof head, "%-8s %9s %7s %7s %7s %7s %7s\n%-8s %9s %7s %7s %7s %7s %7s\n", "object",
                "positives", "scored", "AP", "AP", "AP", "AP", "", "", "", "MSSD %", "MSPD %", "%",
                "MSSD mm%");
  std::string out = std::string("6D detection (BOP 2024):\n") + head;
  for (const auto& [obj, s] : d.per_object) out += detection_row("obj " + std::to_string(obj), s);
  out += detection_row("mean", d.overall);
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "bop24_mAP %.4f (MSSD %.4f, MSPD %.4f), MSSD in mm %.4f; estimates not scored: %d beyond the "
                "best of an image, %d of objects not annotated there\n",
                d.overall.ap, d.overall.ap_mssd, d.overall.ap_mspd, d.overall.ap_mssd_mm,
                d.num_ignored_beyond_max, d.num_ignored_object_absent);
  return out + buf;
}

std::string format_report(const EvalReport& r) {
  char head[256];
  std::snprintf(
      head, sizeof head,
      "%-8s %7s %7s %7s %7s %7s %7s %7s %7s %7s %7s\n%-8s %7s %7s %7s %7s %7s %7s %7s %7s %7s %7s\n",
      "object", "targets", "ADD", "ADD-S", "ADD(-S)", "ADD-S", "ADD-S", "AR", "AR", "AR", "AR", "", "",
      "AUC %", "AUC %", "AUC %", "<1cm %", "<2cm %", "VSD %", "MSSD %", "MSPD %", "%");
  std::string out = head;
  for (const auto& [obj, s] : r.per_object) out += row("obj " + std::to_string(obj), s, r.vsd_computed);
  out += row("all", r.overall, r.vsd_computed);
  char buf[512];
  std::snprintf(
      buf, sizeof buf,
      "estimates: %d read, %d evaluated, %d ignored (image/object not a target), %d ignored (beyond the "
      "k best-scored)\n",
      r.num_estimates, r.num_estimates_evaluated, r.num_ignored_not_target, r.num_ignored_beyond_top_k);
  out += buf;
  if (r.mean_time_per_image_s >= 0)
    std::snprintf(buf, sizeof buf, "mean time per image: %.3f s over %d images\n", r.mean_time_per_image_s,
                  r.num_images_timed);
  else
    std::snprintf(buf, sizeof buf, "mean time per image: not available (a row has a negative time)\n");
  out += buf;
  if (!r.vsd_computed) out += "VSD not computed: AR = mean(AR_MSSD, AR_MSPD)\n";
  if (r.detection_computed) out += "\n" + format_detection(r.detection);
  return out;
}

std::string report_json(const EvalReport& r, const EvalSettings& s) {
  nlohmann::json j;
  j["settings"] = {{"auc_max_m", s.auc_max_m},
                   {"vsd_taus", s.vsd_taus},
                   {"vsd_thresholds", s.vsd_thresholds},
                   {"vsd_delta_m", s.vsd_delta_m},
                   {"mssd_thresholds", s.mssd_thresholds},
                   {"mspd_thresholds_px", s.mspd_thresholds_px},
                   {"max_sym_disc_step", s.max_sym_disc_step},
                   {"compute_vsd", s.compute_vsd},
                   {"max_estimates_per_image", s.max_estimates_per_image},
                   {"visib_gt_min", s.visib_gt_min},
                   {"mssd_thresholds_m", s.mssd_thresholds_m}};
  j["overall"] = scores_json(r.overall);
  j["per_object"] = nlohmann::json::object();
  for (const auto& [obj, sc] : r.per_object) j["per_object"][std::to_string(obj)] = scores_json(sc);
  j["estimates"] = {{"read", r.num_estimates},
                    {"evaluated", r.num_estimates_evaluated},
                    {"ignored_not_target", r.num_ignored_not_target},
                    {"ignored_beyond_top_k", r.num_ignored_beyond_top_k}};
  j["mean_time_per_image_s"] = r.mean_time_per_image_s;
  j["images_timed"] = r.num_images_timed;
  j["vsd_computed"] = r.vsd_computed;
  if (r.detection_computed) {
    const DetectionReport& d = r.detection;
    auto& dj = j["detection"];
    dj["bop24_mAP"] = d.overall.ap;
    dj["bop24_mAP_mssd"] = d.overall.ap_mssd;
    dj["bop24_mAP_mspd"] = d.overall.ap_mspd;
    dj["bop25_mAP_mm"] = d.overall.ap_mssd_mm;
    dj["overall"] = detection_json(d.overall);
    dj["per_object"] = nlohmann::json::object();
    for (const auto& [obj, sc] : d.per_object) dj["per_object"][std::to_string(obj)] = detection_json(sc);
    dj["ignored_beyond_max"] = d.num_ignored_beyond_max;
    dj["ignored_object_absent"] = d.num_ignored_object_absent;
  }
  // Infinite errors (missed instances) are written as null (nlohmann's rendering of non-finite numbers).
  auto& inst = j["instances"] = nlohmann::json::array();
  for (const auto& i : r.instances)
    inst.push_back({{"scene_id", i.scene_id},
                    {"im_id", i.im_id},
                    {"obj_id", i.obj_id},
                    {"gt_index", i.gt_index},
                    {"visib_fract", i.visib_fract},
                    {"add_m", (i.add_m)},
                    {"adds_m", (i.adds_m)},
                    {"add_or_adds_m", (i.add_or_adds_m)},
                    {"mssd_m", (i.mssd_m)},
                    {"mspd_px", (i.mspd_px)},
                    {"add_line", i.add_line},
                    {"adds_line", i.adds_line}});
  return j.dump(2) + "\n";
}

}  // namespace perch2::eval
