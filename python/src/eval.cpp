// Pose evaluation against a BOP dataset: ADD / ADD-S / ADD(-S) AUC and the BOP average recalls.
#include <nanobind/stl/function.h>

#include "common.hpp"
#include "perch2/eval/evaluator.hpp"

namespace perch2_py {

using namespace perch2;
using namespace perch2::eval;

void bind_eval(nb::module_& m) {
  nb::class_<EvalSettings> es(m, "EvalSettings", doc("EvalSettings"));
  es.def(nb::init<>());
  PERCH2_RW(es, EvalSettings, auc_max_m);
  PERCH2_RW(es, EvalSettings, vsd_taus);
  PERCH2_RW(es, EvalSettings, vsd_thresholds);
  PERCH2_RW(es, EvalSettings, vsd_delta_m);
  PERCH2_RW(es, EvalSettings, mssd_thresholds);
  PERCH2_RW(es, EvalSettings, mspd_thresholds_px);
  PERCH2_RW(es, EvalSettings, max_sym_disc_step);
  PERCH2_RW(es, EvalSettings, compute_vsd);
  PERCH2_RW(es, EvalSettings, time_tolerance_s);
  PERCH2_RW(es, EvalSettings, max_estimates_per_image);
  PERCH2_RW(es, EvalSettings, visib_gt_min);
  PERCH2_RW(es, EvalSettings, mssd_thresholds_m);

  nb::class_<Scores> sc(m, "Scores", doc("Scores"));
  PERCH2_RO(sc, Scores, num_targets);
  PERCH2_RO(sc, Scores, auc_add);
  PERCH2_RO(sc, Scores, auc_adds);
  PERCH2_RO(sc, Scores, auc_add_or_adds);
  PERCH2_RO(sc, Scores, adds_below_1cm);
  PERCH2_RO(sc, Scores, adds_below_2cm);
  PERCH2_RO(sc, Scores, ar_vsd);
  PERCH2_RO(sc, Scores, ar_mssd);
  PERCH2_RO(sc, Scores, ar_mspd);
  PERCH2_RO(sc, Scores, ar);

  nb::class_<InstanceResult> ir(m, "InstanceResult", doc("InstanceResult"));
  ir.def_ro("scene_id", &InstanceResult::scene_id)
      .def_ro("im_id", &InstanceResult::im_id)
      .def_ro("obj_id", &InstanceResult::obj_id)
      .def_ro("gt_index", &InstanceResult::gt_index)
      .def_ro("visib_fract", &InstanceResult::visib_fract);
  PERCH2_RO(ir, InstanceResult, add_m);
  PERCH2_RO(ir, InstanceResult, adds_m);
  PERCH2_RO(ir, InstanceResult, add_or_adds_m);
  PERCH2_RO(ir, InstanceResult, mssd_m);
  PERCH2_RO(ir, InstanceResult, mspd_px);
  PERCH2_RO(ir, InstanceResult, add_line);
  PERCH2_RO(ir, InstanceResult, adds_line);

  nb::class_<DetectionScores> ds(m, "DetectionScores", doc("DetectionScores"));
  PERCH2_RO(ds, DetectionScores, num_positives);
  PERCH2_RO(ds, DetectionScores, num_scored);
  PERCH2_RO(ds, DetectionScores, ap_mssd);
  PERCH2_RO(ds, DetectionScores, ap_mspd);
  PERCH2_RO(ds, DetectionScores, ap_mssd_mm);
  PERCH2_RO(ds, DetectionScores, ap);
  PERCH2_RO(ds, DetectionScores, precision_at_recall);

  nb::class_<DetectionReport> dr(m, "DetectionReport", doc("DetectionReport"));
  PERCH2_RO(dr, DetectionReport, per_object);
  PERCH2_RO(dr, DetectionReport, overall);
  PERCH2_RO(dr, DetectionReport, num_ignored_beyond_max);
  PERCH2_RO(dr, DetectionReport, num_ignored_object_absent);

  nb::class_<EvalReport> er(m, "EvalReport", doc("EvalReport"));
  er.def_ro("per_object", &EvalReport::per_object).def_ro("overall", &EvalReport::overall);
  er.def_ro("instances", &EvalReport::instances);
  PERCH2_RO(er, EvalReport, num_estimates);
  PERCH2_RO(er, EvalReport, num_estimates_evaluated);
  PERCH2_RO(er, EvalReport, num_ignored_not_target);
  PERCH2_RO(er, EvalReport, num_ignored_beyond_top_k);
  PERCH2_RO(er, EvalReport, num_images_timed);
  PERCH2_RO(er, EvalReport, mean_time_per_image_s);
  PERCH2_RO(er, EvalReport, vsd_computed);
  PERCH2_RO(er, EvalReport, detection_computed);
  PERCH2_RO(er, EvalReport, detection);

  m.def(
      "evaluate_report",
      [](const dataset::BopDataset& data, const std::vector<dataset::PoseEstimate>& estimates,
         const EvalSettings& s, const std::string& source,
         std::optional<std::function<void(int, int)>> progress) {
        Progress p;
        if (progress)
          p = [cb = *progress](int done, int total) {
            nb::gil_scoped_acquire acquire;  // the evaluation runs without the GIL
            cb(done, total);
          };
        nb::gil_scoped_release release;
        return evaluate(data, estimates, s, source, p);
      },
      nb::arg("dataset"), nb::arg("estimates"), nb::arg("settings") = EvalSettings{},
      nb::arg("source") = "results", nb::arg("progress").none() = nb::none(),
      (std::string(doc("file:perch2/eval/evaluator.hpp")) + "\n\n" + doc("evaluate") +
       "\nprogress(done, total), if given, is called after each image.")
          .c_str());
  m.def("format_report", &format_report, nb::arg("report"), doc("format_report"));
  m.def("format_detection", &format_detection, nb::arg("detection"), doc("format_detection"));
  m.def("plot_report", &plot_report, nb::arg("report"), nb::arg("settings"), nb::arg("png_path"),
        doc("plot_report"));
  m.def("report_json", &report_json, nb::arg("report"), nb::arg("settings") = EvalSettings{},
        doc("report_json"));
}

}  // namespace perch2_py
