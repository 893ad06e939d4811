// Per-image BOP estimation in either mode (perch2::dataset::BopRunner): what `perch2 estimate` runs, and
// the per-image errors it reports (perch2.ImageError).
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/unique_ptr.h>

#include <tuple>

#include "common.hpp"
#include "perch2/dataset/runner.hpp"

namespace perch2_py {

using namespace perch2;
using namespace perch2::dataset;

namespace {

/// A runner with its calls serialised (its estimator keeps workspaces between calls).
struct PyRunner {
  BopRunner runner;
  std::unique_ptr<std::mutex> mutex = std::make_unique<std::mutex>();

  template <class F>
  auto call(F&& f) const {
    nb::gil_scoped_release release;
    std::lock_guard<std::mutex> lock(*mutex);
    return f(runner);
  }
};

PyObject* image_error_type = nullptr;

}  // namespace

void bind_runner(nb::module_& m) {
  // perch2.ImageError: one image lost (a bad file, a malformed entry); carries scene_id, im_id and reason.
  image_error_type =
      PyErr_NewExceptionWithDoc("perch2._perch2.ImageError", doc("ImageError"), PyExc_RuntimeError, nullptr);
  m.attr("ImageError") = nb::handle(image_error_type);
  nb::register_exception_translator([](const std::exception_ptr& p, void*) {
    try {
      std::rethrow_exception(p);
    } catch (const ImageError& e) {
      nb::object err = nb::handle(image_error_type)(e.what());
      err.attr("scene_id") = e.scene_id;
      err.attr("im_id") = e.im_id;
      err.attr("reason") = e.reason;
      PyErr_SetObject(image_error_type, err.ptr());
    }
  });

  nb::enum_<RunMode> mode(m, "RunMode");
  mode.value("Tabletop", RunMode::Tabletop, "3-DoF (x, y, yaw on the table)")
      .value("SixDof", RunMode::SixDof, "6-DoF (full pose)");
  nb::enum_<BackendKind> backend(m, "BackendKind");
  backend.value("Cpu", BackendKind::Cpu).value("ThrustOmp", BackendKind::ThrustOmp);

  nb::class_<RunOptions> ro(m, "RunOptions", doc("RunOptions"));
  ro.def(nb::init<>())
      .def(
          "__init__",
          [](RunOptions* self, const std::string& mode, const std::string& backend,
             const std::string& variant, const std::string& masks, const std::string& box,
             std::optional<TabletopSettings> tabletop, std::optional<SixDofSettings> sixdof) {
            RunOptions o;
            o.mode = parse_mode(mode);
            o.backend = dataset::parse_backend(backend);
            o.variant = dataset::parse_variant(variant);
            o.masks = masks;
            if (box != "full" && box != "visible")
              throw InvalidInput("box", "must be full or visible, got " + box);
            o.box = box == "full" ? BoxKind::Full : BoxKind::Visible;
            if (tabletop) o.tabletop = *tabletop;
            if (sixdof) o.sixdof = *sixdof;
            new (self) RunOptions(std::move(o));
          },
          nb::arg("mode"), nb::arg("backend") = "thrust_omp", nb::arg("variant") = "perch2c",
          nb::arg("masks") = "gt", nb::arg("box") = "full", nb::arg("tabletop").none() = nb::none(),
          nb::arg("sixdof").none() = nb::none(),
          "As `perch2 estimate`'s options: mode \"3dof\" | \"6dof\", backend \"cpu\" | \"thrust_omp\", "
          "variant "
          "(3-DoF; perch2c | perch2a | perch2b | perch | depth-only | bf-icp), masks \"gt\" or a detection "
          "file "
          "and box \"full\" | \"visible\" (6-DoF), and the estimators' settings.");
  PERCH2_RW(ro, RunOptions, mode);
  PERCH2_RW(ro, RunOptions, backend);
  PERCH2_RW(ro, RunOptions, variant);
  PERCH2_RW(ro, RunOptions, tabletop);
  PERCH2_RW(ro, RunOptions, masks);
  PERCH2_RW(ro, RunOptions, box);
  PERCH2_RW(ro, RunOptions, sixdof);
  PERCH2_RW(ro, RunOptions, detect);
  PERCH2_RW(ro, RunOptions, min_instance_points);

  nb::class_<ImageResult> ir(m, "ImageResult", doc("ImageResult"));
  ir.def_ro("scene_id", &ImageResult::scene_id).def_ro("im_id", &ImageResult::im_id);
  PERCH2_RO(ir, ImageResult, rows);
  PERCH2_RO(ir, ImageResult, row_models);
  PERCH2_RO(ir, ImageResult, row_found);
  PERCH2_RO(ir, ImageResult, stages);
  PERCH2_RO(ir, ImageResult, seconds);
  PERCH2_RO(ir, ImageResult, requested);
  PERCH2_RO(ir, ImageResult, missing);
  PERCH2_RO(ir, ImageResult, unusable);
  PERCH2_RO(ir, ImageResult, instances);
  PERCH2_RO(ir, ImageResult, tabletop);
  PERCH2_RO(ir, ImageResult, sixdof);
  // Pickled without the estimator's full result (tabletop / sixdof come back as None): what a worker process
  // sends to the process that writes the results.
  using State = std::tuple<int, int, std::vector<PoseEstimate>, std::vector<int>, std::vector<bool>,
                           std::vector<std::pair<std::string, double>>, double, int, int, int, int>;
  ir.def("__getstate__", [](const ImageResult& r) {
      return State{r.scene_id, r.im_id,     r.rows,    r.row_models, r.row_found, r.stages,
                   r.seconds,  r.requested, r.missing, r.unusable,   r.instances};
    }).def("__setstate__", [](ImageResult& r, const State& st) {
    new (&r) ImageResult{};
    std::tie(r.scene_id, r.im_id, r.rows, r.row_models, r.row_found, r.stages, r.seconds, r.requested,
             r.missing, r.unusable, r.instances) = st;
  });

  m.def("load_options", &load_options, nb::arg("options"), doc("load_options"));
  m.def("run_images", &run_images, nb::arg("dataset"), nb::arg("first_scene") = 0,
        nb::arg("last_scene") = 1 << 30, doc("run_images"));

  static const std::string runner_doc = std::string(doc("file:perch2/dataset/runner.hpp")) + "\n\n" +
                                        doc("BopRunner") +
                                        "\n\nCalls release the GIL; calls on one runner are serialised.";
  nb::class_<PyRunner>(m, "BopRunner", runner_doc.c_str())
      .def(
          "__init__",
          [](PyRunner* self, const BopDataset& data, RunOptions options, std::vector<int> obj_ids) {
            nb::gil_scoped_release release;
            new (self) PyRunner{BopRunner(data, std::move(options), std::move(obj_ids))};
          },
          nb::arg("dataset"), nb::arg("options"), nb::arg("obj_ids") = std::vector<int>{},
          doc("BopRunner.BopRunner"))
      .def(
          "images", [](const PyRunner& r, int first, int last) { return r.runner.images(first, last); },
          nb::arg("first_scene") = 0, nb::arg("last_scene") = 1 << 30, doc("BopRunner.images"))
      .def(
          "targets", [](const PyRunner& r, int s, int i) { return r.runner.targets(s, i); },
          nb::arg("scene_id"), nb::arg("im_id"), doc("BopRunner.targets"))
      .def(
          "load_options", [](const PyRunner& r) { return r.runner.load_options(); },
          doc("BopRunner.load_options"))
      .def(
          "load_image",
          [](const PyRunner& r, int s, int i) {
            return r.call([&](const BopRunner& x) { return x.load_image(s, i); });
          },
          nb::arg("scene_id"), nb::arg("im_id"), doc("BopRunner.load_image"))
      .def(
          "estimate",
          [](const PyRunner& r, int s, int i) {
            return r.call([&](const BopRunner& x) { return x.estimate(s, i); });
          },
          nb::arg("scene_id"), nb::arg("im_id"), doc("BopRunner.estimate"))
      .def(
          "estimate",
          [](const PyRunner& r, const BopImage& image) {
            return r.call([&](const BopRunner& x) { return x.estimate(image); });
          },
          nb::arg("image"), "Estimates an image already in memory (its targets from the dataset).")
      .def(
          "estimate",
          [](const PyRunner& r, int s, int i, const ImageFiles& files) {
            return r.call([&](const BopRunner& x) { return x.estimate(s, i, files); });
          },
          nb::arg("scene_id"), nb::arg("im_id"), nb::arg("files"), doc("BopRunner.estimate"))
      .def(
          "image_files",
          [](const PyRunner& r, int s, int i) {
            return r.call([&](const BopRunner& x) { return x.image_files(s, i); });
          },
          nb::arg("scene_id"), nb::arg("im_id"), doc("BopRunner.image_files"))
      .def_prop_ro(
          "options", [](const PyRunner& r) { return r.runner.options(); }, "the run's options (a copy)")
      .def(
          "obj_ids", [](const PyRunner& r) { return r.runner.obj_ids(); }, doc("BopRunner.obj_ids"))
      .def(
          "meshes", [](const PyRunner& r) { return r.runner.meshes(); }, doc("BopRunner.meshes"))
      .def(
          "model_index", [](const PyRunner& r, int obj_id) { return r.runner.model_index(obj_id); },
          nb::arg("obj_id"), doc("BopRunner.model_index"))
      .def(
          "describe", [](const PyRunner& r) { return r.runner.describe(); }, doc("BopRunner.describe"));
}

}  // namespace perch2_py
