// BOP datasets: the reader (images as numpy views of the loaded image), detection files (COCO RLE, both
// forms) and the results CSV.
#include <nanobind/stl/tuple.h>

#include "common.hpp"
#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/detections.hpp"
#include "perch2/dataset/results.hpp"

namespace perch2_py {

using namespace perch2;
using namespace perch2::dataset;

namespace {

/// Views of an image's masks, kept alive by the image (owner).
nb::list mask_views(nb::handle owner, std::vector<Mask>& masks) {
  nb::list out;
  for (Mask& m : masks) out.append(view(m.data.data(), {std::size_t(m.height), std::size_t(m.width)}, owner));
  return out;
}

}  // namespace

void bind_dataset(nb::module_& m) {
  nb::class_<ContinuousSymmetry> cs(m, "ContinuousSymmetry", doc("ContinuousSymmetry"));
  cs.def(nb::init<>());
  PERCH2_VEC3(cs, ContinuousSymmetry, axis);
  perch2_py::vec3_rw(cs, "offset_m", &ContinuousSymmetry::offset_m,
                     "a point of the axis, object frame, metres");

  nb::class_<ModelInfo> mi(m, "ModelInfo", doc("ModelInfo"));
  mi.def(nb::init<>());
  mi.def_rw("obj_id", &ModelInfo::obj_id);
  PERCH2_RW(mi, ModelInfo, diameter_m);
  mi.def_prop_ro(
      "symmetries_discrete", [](const ModelInfo& x) { return poses_array(x.symmetries_discrete); },
      nb::rv_policy::move,
      (std::string(doc("ModelInfo.symmetries_discrete")) + " ((n, 4, 4), a new array)").c_str());
  mi.def_rw("symmetries_continuous", &ModelInfo::symmetries_continuous);
  mi.def("is_symmetric", &ModelInfo::is_symmetric);

  nb::class_<GtInstance> gt(m, "GtInstance", doc("GtInstance"));
  gt.def_ro("obj_id", &GtInstance::obj_id);
  gt.def_prop_ro(
      "T_cam_obj", [](const GtInstance& g) { return pose_array(g.T_cam_obj); }, nb::rv_policy::move,
      doc("GtInstance.T_cam_obj"));
  PERCH2_RO(gt, GtInstance, has_info);
  PERCH2_RO(gt, GtInstance, visib_fract);
  PERCH2_RO(gt, GtInstance, bbox_obj);
  PERCH2_RO(gt, GtInstance, bbox_visib);
  gt.def_ro("px_count_all", &GtInstance::px_count_all)
      .def_ro("px_count_valid", &GtInstance::px_count_valid)
      .def_ro("px_count_visib", &GtInstance::px_count_visib);

  nb::class_<ImageInfo> ii(m, "ImageInfo", doc("ImageInfo"));
  ii.def_ro("scene_id", &ImageInfo::scene_id).def_ro("im_id", &ImageInfo::im_id);
  PERCH2_RO(ii, ImageInfo, camera);
  PERCH2_RO(ii, ImageInfo, depth_scale_mm);
  ii.def_prop_ro(
      "T_cam_world",
      [](const ImageInfo& x) -> nb::object {
        return x.T_cam_world ? nb::cast(pose_array(*x.T_cam_world)) : nb::none();
      },
      doc("ImageInfo.T_cam_world"));
  PERCH2_RO(ii, ImageInfo, gt);

  nb::class_<Target> tg(m, "Target", doc("Target"));
  tg.def(nb::init<>());
  tg.def_rw("scene_id", &Target::scene_id)
      .def_rw("im_id", &Target::im_id)
      .def_rw("obj_id", &Target::obj_id)
      .def_rw("inst_count", &Target::inst_count);
  tg.def("__repr__", [](const Target& t) {
    return "Target(scene_id=" + std::to_string(t.scene_id) + ", im_id=" + std::to_string(t.im_id) +
           ", obj_id=" + std::to_string(t.obj_id) + ", inst_count=" + std::to_string(t.inst_count) + ")";
  });

  nb::class_<ImageLoadOptions> lo(m, "ImageLoadOptions", doc("ImageLoadOptions"));
  lo.def(nb::init<>());
  PERCH2_RW(lo, ImageLoadOptions, rgb);
  PERCH2_RW(lo, ImageLoadOptions, depth);
  PERCH2_RW(lo, ImageLoadOptions, masks_visib);
  PERCH2_RW(lo, ImageLoadOptions, masks);

  nb::class_<BopImage> bi(m, "BopImage", doc("BopImage"));
  PERCH2_RO(bi, BopImage, info);
  bi.def_prop_ro(
        "frame", [](BopImage& b) -> RgbdFrame& { return b.frame; }, nb::rv_policy::reference_internal,
        "the RGB-D frame (its depth_m and rgb are views of this image's storage)")
      .def_prop_ro(
          "masks_visib", [](nb::handle s) { return mask_views(s, nb::cast<BopImage&>(s).masks_visib); },
          "one H x W uint8 mask per ground-truth instance (views of this image's storage), if loaded")
      .def_prop_ro(
          "masks", [](nb::handle s) { return mask_views(s, nb::cast<BopImage&>(s).masks); },
          "one H x W uint8 full-silhouette mask per ground-truth instance (views), if loaded")
      .def(
          "visible_labels",
          [](const BopImage& b) {
            LabelImage l = b.visible_labels();
            return owned(std::move(l.data), {std::size_t(l.height), std::size_t(l.width)});
          },
          doc("BopImage.visible_labels"));

  nb::class_<BadImage> bad(m, "BadImage", doc("BadImage"));
  bad.def_ro("scene_id", &BadImage::scene_id).def_ro("im_id", &BadImage::im_id);
  PERCH2_RO(bad, BadImage, path);
  PERCH2_RO(bad, BadImage, reason);
  bad.def("__repr__", [](const BadImage& b) {
    return "BadImage(scene_id=" + std::to_string(b.scene_id) + ", im_id=" + std::to_string(b.im_id) + ", " +
           b.path + ": " + b.reason + ")";
  });

  nb::class_<FileBytes> fb(m, "FileBytes", doc("FileBytes"));
  fb.def(
        "__init__",
        [](FileBytes* self, const std::string& path, nb::bytes bytes) {
          new (self) FileBytes{path, std::string(bytes.c_str(), bytes.size())};
        },
        nb::arg("path"), nb::arg("bytes"))
      .def_rw("path", &FileBytes::path, "the path the bytes came from (named in errors)")
      .def_prop_rw(
          "bytes", [](const FileBytes& f) { return nb::bytes(f.bytes.data(), f.bytes.size()); },
          [](FileBytes& f, nb::bytes b) { f.bytes.assign(b.c_str(), b.size()); }, "the file's bytes (a copy)")
      .def("__getstate__",
           [](const FileBytes& f) {
             return nb::make_tuple(f.path, nb::bytes(f.bytes.data(), f.bytes.size()));
           })
      .def("__setstate__", [](FileBytes& f, const std::pair<std::string, nb::bytes>& st) {
        new (&f) FileBytes{st.first, std::string(st.second.c_str(), st.second.size())};
      });

  nb::class_<ImageFiles> files(m, "ImageFiles", doc("ImageFiles"));
  files.def(nb::init<>());
  PERCH2_RW(files, ImageFiles, rgb);
  PERCH2_RW(files, ImageFiles, depth);
  PERCH2_RW(files, ImageFiles, masks_visib);
  PERCH2_RW(files, ImageFiles, masks);
  files
      .def("__getstate__",
           [](const ImageFiles& f) { return nb::make_tuple(f.rgb, f.depth, f.masks_visib, f.masks); })
      .def("__setstate__",
           [](ImageFiles& f, const std::tuple<std::optional<FileBytes>, std::optional<FileBytes>,
                                              std::vector<FileBytes>, std::vector<FileBytes>>& st) {
             new (&f) ImageFiles{std::get<0>(st), std::get<1>(st), std::get<2>(st), std::get<3>(st)};
           });
  m.def(
      "decode_image",
      [](const ImageInfo& info, const ImageFiles& f) {
        nb::gil_scoped_release release;
        return decode_image(info, f);
      },
      nb::arg("info"), nb::arg("files"), doc("decode_image"));

  nb::enum_<TargetTask> task(m, "TargetTask", doc("TargetTask"));
  task.value("NoTargets", TargetTask::NoTargets)
      .value("Localization", TargetTask::Localization)
      .value("Detection", TargetTask::Detection);

  nb::class_<DatasetOptions> dopt(m, "DatasetOptions", doc("DatasetOptions"));
  dopt.def(nb::init<>());
  PERCH2_RW(dopt, DatasetOptions, split);
  PERCH2_RW(dopt, DatasetOptions, targets_file);
  PERCH2_RW(dopt, DatasetOptions, models_dir);
  PERCH2_RW(dopt, DatasetOptions, ground_truth);

  nb::class_<BopDataset>(m, "BopDataset", doc("file:perch2/dataset/bop.hpp"))
      .def(
          "__init__",
          [](BopDataset* self, const std::string& root, const std::string& split,
             const std::string& targets_file, const std::string& models_dir, bool ground_truth) {
            nb::gil_scoped_release release;
            new (self) BopDataset(root, {split, targets_file, models_dir, ground_truth});
          },
          nb::arg("root"), nb::arg("split") = "test", nb::arg("targets_file") = "",
          nb::arg("models_dir") = "", nb::arg("ground_truth") = true, doc("BopDataset.BopDataset"))
      .def("target_task", &BopDataset::target_task, doc("BopDataset.target_task"))
      .def("root", &BopDataset::root)
      .def("split_path", &BopDataset::split_path)
      .def("models_path", &BopDataset::models_path)
      .def("models_info", &BopDataset::models_info, "obj_id -> ModelInfo (copies)")
      .def("model_info", &BopDataset::model_info, nb::arg("obj_id"), doc("BopDataset.model_info"))
      .def("model_path", &BopDataset::model_path, nb::arg("obj_id"), doc("BopDataset.model_path"))
      .def("load_model", &BopDataset::load_model, nb::arg("obj_id"), nb::call_guard<nb::gil_scoped_release>(),
           doc("BopDataset.load_model"))
      .def("scene_ids", &BopDataset::scene_ids, doc("BopDataset.scene_ids"))
      .def("image_ids", &BopDataset::image_ids, doc("BopDataset.image_ids"))
      .def("info", &BopDataset::info, nb::arg("scene_id"), nb::arg("im_id"), doc("BopDataset.info"))
      .def("has_image", &BopDataset::has_image, nb::arg("scene_id"), nb::arg("im_id"))
      .def("targets_path", &BopDataset::targets_path, doc("BopDataset.targets_path"))
      .def("targets", &BopDataset::targets, "the targets (copies)")
      .def("target_images", &BopDataset::target_images, doc("BopDataset.target_images"))
      .def("bad_images", &BopDataset::bad_images, doc("BopDataset.bad_images"))
      .def(
          "bad_image",
          [](const BopDataset& d, int s, int i) -> std::optional<BadImage> {
            const BadImage* b = d.bad_image(s, i);
            return b ? std::optional<BadImage>(*b) : std::nullopt;
          },
          nb::arg("scene_id"), nb::arg("im_id"), doc("BopDataset.bad_image"))
      .def("warnings", &BopDataset::warnings, doc("BopDataset.bad_images"))
      .def(
          "read_image_files",
          [](const BopDataset& d, int scene_id, int im_id, bool rgb, bool depth, bool masks_visib,
             bool masks) {
            nb::gil_scoped_release release;
            return d.read_image_files(scene_id, im_id, {rgb, depth, masks_visib, masks});
          },
          nb::arg("scene_id"), nb::arg("im_id"), nb::arg("rgb") = true, nb::arg("depth") = true,
          nb::arg("masks_visib") = true, nb::arg("masks") = false, doc("BopDataset.read_image_files"))
      .def(
          "load_image",
          [](const BopDataset& d, int scene_id, int im_id, bool rgb, bool depth, bool masks_visib,
             bool masks) {
            nb::gil_scoped_release release;
            return d.load_image(scene_id, im_id, {rgb, depth, masks_visib, masks});
          },
          nb::arg("scene_id"), nb::arg("im_id"), nb::arg("rgb") = true, nb::arg("depth") = true,
          nb::arg("masks_visib") = true, nb::arg("masks") = false,
          (std::string(doc("BopDataset.load_image")) +
           "\nThe returned image's arrays are views of its storage.")
              .c_str());
  m.def("targets_by_image", &targets_by_image, nb::arg("targets"), nb::arg("first_scene") = 0,
        nb::arg("last_scene") = 1 << 30, doc("targets_by_image"));
  m.def("bop_id", &bop_id, nb::arg("id"), doc("bop_id"));
  m.def("load_models_info", &load_models_info, nb::arg("path"), doc("load_models_info"));

  // ---- detections
  nb::class_<Rle> rle(m, "Rle", doc("file:perch2/dataset/detections.hpp"));
  rle.def(nb::init<>());
  rle.def_rw("height", &Rle::height).def_rw("width", &Rle::width);
  PERCH2_RW(rle, Rle, counts);
  m.def(
      "rle_encode", [](nb::handle mask) { return rle_encode(mask_from(mask, "mask")); }, nb::arg("mask"),
      (std::string(doc("rle_encode")) + " mask: H x W bool or uint8.").c_str());
  m.def(
      "rle_decode",
      [](const Rle& r) {
        Mask mk = rle_decode(r);
        return owned(std::move(mk.data), {std::size_t(mk.height), std::size_t(mk.width)});
      },
      nb::arg("rle"), (std::string(doc("rle_decode")) + " Returns an H x W uint8 array (0/1).").c_str());
  m.def("rle_to_string", &rle_to_string, nb::arg("rle"), doc("rle_to_string"));
  m.def("rle_from_string", &rle_from_string, nb::arg("counts"), nb::arg("height"), nb::arg("width"),
        doc("rle_from_string"));

  nb::class_<Detection> det(m, "Detection", doc("Detection"));
  det.def(nb::init<>())
      .def(
          "__init__",
          [](Detection* self, int scene_id, int image_id, int category_id, float score,
             std::array<float, 4> bbox, nb::handle mask, double time_s) {
            Detection d;
            d.scene_id = scene_id, d.image_id = image_id, d.category_id = category_id, d.score = score,
            d.bbox = bbox;
            if (!mask.is_none()) d.segmentation = rle_encode(mask_from(mask, "mask"));
            d.time_s = time_s;
            new (self) Detection(std::move(d));
          },
          nb::arg("scene_id"), nb::arg("image_id"), nb::arg("category_id"), nb::arg("score"), nb::arg("bbox"),
          nb::arg("mask").none() = nb::none(), nb::arg("time_s") = -1.0,
          "A detection; mask (H x W bool/uint8) is run-length encoded (COCO).")
      .def_rw("scene_id", &Detection::scene_id, doc("Detection.scene_id"))
      .def_rw("image_id", &Detection::image_id)
      .def_rw("category_id", &Detection::category_id, doc("Detection.category_id"))
      .def_rw("score", &Detection::score)
      .def("has_mask", &Detection::has_mask)
      .def(
          "mask",
          [](const Detection& d) {
            Mask mk = d.mask();
            return owned(std::move(mk.data), {std::size_t(mk.height), std::size_t(mk.width)});
          },
          "The decoded mask, H x W uint8 (0/1), a new array.");
  PERCH2_RW(det, Detection, bbox);
  PERCH2_RW(det, Detection, segmentation);
  PERCH2_RW(det, Detection, time_s);
  m.def("load_detections", &load_detections, nb::arg("path"), nb::call_guard<nb::gil_scoped_release>(),
        doc("load_detections"));
  m.def("save_detections", &save_detections, nb::arg("path"), nb::arg("detections"),
        nb::arg("compressed") = true, doc("save_detections"));
  m.def("detections_by_image", &detections_by_image, nb::arg("detections"), doc("detections_by_image"));

  // ---- results CSV
  nb::class_<PoseEstimate> pe(m, "PoseEstimate", doc("file:perch2/dataset/results.hpp"));
  pe.def(nb::init<>())
      .def(
          "__init__",
          [](PoseEstimate* self, int scene_id, int im_id, int obj_id, double score, nb::handle T_cam_obj,
             double time_s) {
            new (self)
                PoseEstimate{scene_id, im_id, obj_id, score, pose_from(T_cam_obj, "T_cam_obj"), time_s, 0};
          },
          nb::arg("scene_id"), nb::arg("im_id"), nb::arg("obj_id"), nb::arg("score"), nb::arg("T_cam_obj"),
          nb::arg("time_s") = -1.0)
      .def_rw("scene_id", &PoseEstimate::scene_id)
      .def_rw("im_id", &PoseEstimate::im_id)
      .def_rw("obj_id", &PoseEstimate::obj_id)
      .def_rw("score", &PoseEstimate::score)
      .def_prop_rw(
          "T_cam_obj", [](const PoseEstimate& p) { return pose_array(p.T_cam_obj); },
          [](PoseEstimate& p, nb::handle v) { p.T_cam_obj = pose_from(v, "T_cam_obj"); }, nb::rv_policy::move,
          doc("PoseEstimate.T_cam_obj"))
      .def("__repr__", [](const PoseEstimate& p) {
        return "PoseEstimate(scene_id=" + std::to_string(p.scene_id) + ", im_id=" + std::to_string(p.im_id) +
               ", obj_id=" + std::to_string(p.obj_id) + ", score=" + std::to_string(p.score) + ")";
      });
  PERCH2_RW(pe, PoseEstimate, time_s);
  PERCH2_RO(pe, PoseEstimate, line);
  m.def("save_results_csv", &save_results_csv, nb::arg("path"), nb::arg("estimates"),
        nb::arg("append") = false, doc("save_results_csv"));
  pe.def("__getstate__",
         [](const PoseEstimate& p) {
           std::array<float, 16> T{};
           for (int r = 0; r < 4; ++r)
             for (int c = 0; c < 4; ++c) T[std::size_t(4 * r + c)] = p.T_cam_obj.matrix()(r, c);
           return std::make_tuple(p.scene_id, p.im_id, p.obj_id, p.score, T, p.time_s, p.line);
         })
      .def("__setstate__",
           [](PoseEstimate& p,
              const std::tuple<int, int, int, double, std::array<float, 16>, double, int>& st) {
             new (&p) PoseEstimate{std::get<0>(st),  std::get<1>(st), std::get<2>(st), std::get<3>(st),
                                   Pose::Identity(), std::get<5>(st), std::get<6>(st)};
             for (int r = 0; r < 4; ++r)
               for (int c = 0; c < 4; ++c)
                 p.T_cam_obj.matrix()(r, c) = std::get<4>(st)[std::size_t(4 * r + c)];
           });
  tg.def("__getstate__", [](const Target& t) {
      return std::make_tuple(t.scene_id, t.im_id, t.obj_id, t.inst_count);
    }).def("__setstate__", [](Target& t, const std::tuple<int, int, int, int>& st) {
    new (&t) Target{std::get<0>(st), std::get<1>(st), std::get<2>(st), std::get<3>(st)};
  });
  m.def(
      "load_results_csv",
      [](const std::string& path, bool drop_torn_last_line, bool return_torn_line) -> nb::object {
        int torn = 0;
        std::vector<PoseEstimate> rows;
        {
          nb::gil_scoped_release release;
          rows = load_results_csv(path, drop_torn_last_line, &torn);
        }
        if (return_torn_line) return nb::make_tuple(std::move(rows), torn);
        return nb::cast(std::move(rows));
      },
      nb::arg("path"), nb::arg("drop_torn_last_line") = false, nb::arg("return_torn_line") = false,
      (std::string(doc("load_results_csv")) + "\nreturn_torn_line: return (rows, torn_line) instead of rows.")
          .c_str());
  m.def("completed_images", &completed_images, nb::arg("path"), nb::call_guard<nb::gil_scoped_release>(),
        doc("completed_images"));

  // ResultsWriter owns its files until close() (or the end of a with block, or its collection).
  struct PyWriter {
    std::unique_ptr<ResultsWriter> w;
    ResultsWriter& get() const {
      if (!w) throw InvalidInput("ResultsWriter", "is closed");
      return *w;
    }
  };
  nb::class_<PyWriter>(m, "ResultsWriter", doc("ResultsWriter"))
      .def(
          "__init__",
          [](PyWriter* self, const std::string& path, bool resume, bool fsync) {
            nb::gil_scoped_release release;
            new (self) PyWriter{std::make_unique<ResultsWriter>(path, ResultsWriter::Options{resume, fsync})};
          },
          nb::arg("path"), nb::arg("resume") = false, nb::arg("fsync") = false,
          (std::string(doc("ResultsWriter.ResultsWriter")) + "\nresume: " +
           doc("ResultsWriter.Options.resume") + "\nfsync: " + doc("ResultsWriter.Options.fsync"))
              .c_str())
      .def(
          "write_image",
          [](const PyWriter& w, int scene_id, int im_id, const std::vector<PoseEstimate>& rows) {
            ResultsWriter& x = w.get();
            nb::gil_scoped_release release;
            x.write_image(scene_id, im_id, rows);
          },
          nb::arg("scene_id"), nb::arg("im_id"), nb::arg("rows"), doc("ResultsWriter.write_image"))
      .def(
          "is_done", [](const PyWriter& w, int s, int i) { return w.get().is_done(s, i); },
          nb::arg("scene_id"), nb::arg("im_id"))
      .def(
          "done", [](const PyWriter& w) { return w.get().done(); }, doc("ResultsWriter.done"))
      .def(
          "resume_notes", [](const PyWriter& w) { return w.get().resume_notes(); },
          doc("ResultsWriter.resume_notes"))
      .def_prop_ro("path", [](const PyWriter& w) { return w.get().path(); })
      .def_prop_ro("done_path", [](const PyWriter& w) { return w.get().done_path(); })
      .def(
          "close", [](PyWriter& w) { w.w.reset(); }, "Closes both files (further calls raise InvalidInput).")
      .def("__enter__", [](nb::handle self) { return nb::borrow(self); })
      .def(
          "__exit__", [](PyWriter& w, nb::handle, nb::handle, nb::handle) { w.w.reset(); },
          nb::arg("type").none(), nb::arg("value").none(), nb::arg("traceback").none());
}

}  // namespace perch2_py
