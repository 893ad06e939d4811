// The estimators (3-DoF tabletop and 6-DoF from detections) on the backend chosen by name, their settings
// and results, and the library's BOP 6-DoF glue (instances from ground truth or detections, result rows).
#include "perch2/cpu/estimators.hpp"
#include "common.hpp"
#include "perch2/cuda/estimators.hpp"
#include "perch2/search/sixdof.hpp"
#include "perch2/search/sixdof_bop.hpp"
#include "perch2/search/tabletop.hpp"
#include "perch2/search/tabletop_bop.hpp"

namespace perch2_py {

using namespace perch2;

namespace {

template <class B>
using TabletopOf = TabletopEstimator<B>;
template <class B>
using SixDofOf = SixDofEstimator<B>;
using PyTabletop = PerBackend<TabletopOf>;
using PySixDof = PerBackend<SixDofOf>;

SearchVariant parse_variant(nb::handle v) {
  SearchVariant out;
  if (nb::try_cast(v, out, false)) return out;
  if (!nb::isinstance<nb::str>(v))
    throw InvalidInput("variant", "must be a perch2.SearchVariant or its name");
  auto plain = [](std::string s) {
    s.erase(std::remove(s.begin(), s.end(), '-'), s.end());
    return s;
  };
  const std::string name = nb::cast<std::string>(v);
  std::string names;
  for (SearchVariant x : {SearchVariant::Perch2C, SearchVariant::Perch2A, SearchVariant::Perch2B,
                          SearchVariant::Perch, SearchVariant::DepthOnlyC, SearchVariant::BfIcp}) {
    if (plain(name) == plain(to_string(x))) return x;
    names += std::string(names.empty() ? "" : "|") + to_string(x);
  }
  throw InvalidInput("variant", "unknown variant '" + name + "' (" + names + ")");
}

std::vector<TabletopModel> tabletop_models(nb::handle models) {
  std::vector<TabletopModel> out;
  std::size_t k = 0;
  for (nb::handle item : models) {
    TabletopModel tm;
    Mesh mesh;
    if (nb::try_cast(item, tm, false))
      out.push_back(std::move(tm));
    else if (nb::try_cast(item, mesh, false))
      out.push_back({std::move(mesh), false, std::nullopt});
    else
      throw InvalidInput("models[" + std::to_string(k) + "]",
                         "must be a perch2.Mesh or a perch2.TabletopModel");
    ++k;
  }
  return out;
}

/// {model: count} (model an index or a mesh name), or a sequence of (model, count) / ObjectCount.
std::vector<ObjectCount> object_counts(const PyTabletop& est, nb::handle objects) {
  auto index = [&](nb::handle key, const std::string& who) -> int {
    if (nb::isinstance<nb::str>(key)) {
      const std::string name = nb::cast<std::string>(key);
      return est.with([&](const auto& e) { return e.model_index(name); });
    }
    if (!PyLong_Check(key.ptr())) throw InvalidInput(who, "a model is an index (int) or a mesh name (str)");
    return nb::cast<int>(key);
  };
  std::vector<ObjectCount> out;
  if (nb::isinstance<nb::dict>(objects)) {
    for (auto [key, value] : nb::borrow<nb::dict>(objects)) {
      if (!PyLong_Check(value.ptr())) throw InvalidInput("objects", "counts must be ints");
      out.push_back({index(key, "objects"), nb::cast<int>(value)});
    }
    return out;
  }
  std::size_t k = 0;
  for (nb::handle item : objects) {
    const std::string who = "objects[" + std::to_string(k++) + "]";
    ObjectCount oc;
    if (nb::try_cast(item, oc, false)) {
      out.push_back(oc);
      continue;
    }
    if (nb::len(item) != 2) throw InvalidInput(who, "must be (model, count)");
    out.push_back({index(item[0], who), nb::cast<int>(item[1])});
  }
  return out;
}

SixDofInstance make_instance(int model, nb::handle mask, nb::handle box, const std::string& who) {
  SixDofInstance in;
  in.model = model;
  in.mask = mask_from(mask, who + " mask");
  if (!box.is_none()) {  // integers, or a detector's float box (rounded as the BOP detection reader does)
    std::size_t n = 0;
    const std::vector<float> b = float_rows(box, who + " box (x, y, w, h)", 4, &n, true);
    if (n != 1) throw InvalidInput(who + " box (x, y, w, h)", "must be 4 numbers");
    for (float v : b)
      if (!std::isfinite(v)) throw InvalidInput(who + " box (x, y, w, h)", "must be finite");
    in.box_xywh = {int(std::lround(b[0])), int(std::lround(b[1])), int(std::lround(b[2])),
                   int(std::lround(b[3]))};
  }
  return in;
}

/// Objects for estimate_scene from SixDofObject values or (model, count) pairs.
std::vector<SixDofObject> objects_from(nb::handle objects) {
  std::vector<SixDofObject> out;
  std::size_t k = 0;
  for (nb::handle o : objects) {
    const std::string who = "objects[" + std::to_string(k++) + "]";
    if (nb::isinstance<SixDofObject>(o)) {
      out.push_back(nb::cast<SixDofObject>(o));
      continue;
    }
    try {
      const auto pair = nb::cast<std::pair<int, int>>(o);
      out.push_back({pair.first, pair.second});
    } catch (const nb::cast_error&) {
      throw InvalidInput(who, "must be a perch2.SixDofObject or a (model, count) pair of ints");
    }
  }
  return out;
}

/// Instances from SixDofInstance objects or (model, mask[, box]) tuples; masks checked against the frame.
std::vector<SixDofInstance> instances_from(nb::handle instances, const RgbdFrame& frame) {
  std::vector<SixDofInstance> out;
  std::size_t k = 0;
  for (nb::handle item : instances) {
    const std::string who = "instances[" + std::to_string(k++) + "]";
    SixDofInstance in;
    if (!nb::try_cast(item, in, false)) {
      const std::size_t n = nb::len(item);
      if (n != 2 && n != 3)
        throw InvalidInput(who, "must be a perch2.SixDofInstance or (model, mask[, box])");
      if (!PyLong_Check(item[0].ptr())) throw InvalidInput(who, "model must be an index (int)");
      in = make_instance(nb::cast<int>(item[0]), item[1], n == 3 ? nb::handle(item[2]) : nb::handle(Py_None),
                         who);
    }
    if (in.mask.width != frame.camera.width || in.mask.height != frame.camera.height)
      throw InvalidInput(who + " mask", "is " + std::to_string(in.mask.width) + " x " +
                                            std::to_string(in.mask.height) + " (W x H), the depth is " +
                                            std::to_string(frame.camera.width) + " x " +
                                            std::to_string(frame.camera.height));
    out.push_back(std::move(in));
  }
  return out;
}

template <class T>
void pose_prop(nb::class_<T>& cls, const char* name, Pose T::*field, const char* key) {
  cls.def_prop_rw(
      name, [field](const T& x) { return pose_array(x.*field); },
      [field, name](T& x, nb::handle v) { x.*field = pose_from(v, name); }, nb::rv_policy::move,
      (std::string(doc(key)) + " (4 x 4 float32; a new array on each read)").c_str());
}

/// settings (a live reference), backend and models of an estimator binding.
template <class Settings, class Py>
void estimator_accessors(nb::class_<Py>& cls, const char* nested_example) {
  cls.def_prop_ro(
         "settings",
         [](Py& e) -> Settings& { return e.with([](auto& x) -> Settings& { return x.settings(); }); },
         nb::rv_policy::reference_internal,
         (std::string(
              "The estimator's settings (a live reference: changes apply to the next estimate; nested "
              "settings such as ") +
          nested_example + " are settable in place).")
             .c_str())
      .def_prop_ro("backend", [](const Py& e) { return backend_name(e.backend); })
      .def_prop_ro(
          "models", [](const Py& e) { return e.with([](const auto& x) { return x.models(); }); },
          "The models (copies).");
}

std::string estimator_doc(const char* file_key, const char* ctor_key, const char* extra) {
  return std::string(doc(file_key)) + "\n\n" + doc(ctor_key) + "\n" + extra;
}

}  // namespace

std::vector<SixDofModel> sixdof_models(nb::handle models) {
  std::vector<SixDofModel> out;
  std::size_t k = 0;
  for (nb::handle item : models) {
    SixDofModel sm;
    Mesh mesh;
    if (nb::try_cast(item, sm, false))
      out.push_back(std::move(sm));
    else if (nb::try_cast(item, mesh, false))
      out.push_back({std::move(mesh), {}});
    else
      throw InvalidInput("models[" + std::to_string(k) + "]",
                         "must be a perch2.Mesh (no symmetries) or a perch2.SixDofModel");
    ++k;
  }
  return out;
}

void bind_estimators(nb::module_& m) {
  // ---- 3-DoF tabletop
  nb::class_<TablePlaneSettings> tp(m, "TablePlaneSettings", doc("TablePlaneSettings"));
  tp.def(nb::init<>());
  PERCH2_RW(tp, TablePlaneSettings, stride);
  PERCH2_RW(tp, TablePlaneSettings, iterations);
  PERCH2_RW(tp, TablePlaneSettings, inlier_distance_m);
  PERCH2_RW(tp, TablePlaneSettings, min_inlier_fraction);
  PERCH2_RW(tp, TablePlaneSettings, min_inliers);
  PERCH2_RW(tp, TablePlaneSettings, seed);

  nb::enum_<SearchMode> mode(m, "SearchMode");
  PERCH2_ENUM(mode, SearchMode, Parallel);
  PERCH2_ENUM(mode, SearchMode, Tree);
  PERCH2_ENUM(mode, SearchMode, BruteForceIcp);
  nb::enum_<SearchVariant> var(m, "SearchVariant", "The paper's Table I variants (see TabletopEstimator).");
  var.value("Perch2C", SearchVariant::Perch2C)
      .value("Perch2A", SearchVariant::Perch2A)
      .value("Perch2B", SearchVariant::Perch2B)
      .value("Perch", SearchVariant::Perch)
      .value("DepthOnlyC", SearchVariant::DepthOnlyC)
      .value("BfIcp", SearchVariant::BfIcp);

  nb::class_<TurnSearchSettings> turns(m, "TurnSearchSettings", doc("TurnSearchSettings"));
  turns.def(nb::init<>());
  PERCH2_RW(turns, TurnSearchSettings, sweep_turns);
  PERCH2_RW(turns, TurnSearchSettings, sweep_stride);
  PERCH2_RW(turns, TurnSearchSettings, geometry_tolerance);
  PERCH2_RW(turns, TurnSearchSettings, fine_turns);
  PERCH2_RW(turns, TurnSearchSettings, fine_stride);
  PERCH2_RW(turns, TurnSearchSettings, climb_stride);
  PERCH2_RW(turns, TurnSearchSettings, starts);
  PERCH2_RW(turns, TurnSearchSettings, climbed_starts);
  PERCH2_RW(turns, TurnSearchSettings, climb_step_rad);
  PERCH2_RW(turns, TurnSearchSettings, climb_shift_m);
  PERCH2_RW(turns, TurnSearchSettings, levels);
  PERCH2_RW(turns, TurnSearchSettings, moves_per_level);
  PERCH2_RW(turns, TurnSearchSettings, final_stride);

  nb::class_<YawSearchSettings> ys(m, "YawSearchSettings", doc("YawSearchSettings"));
  ys.def(nb::init<>());
  PERCH2_RW(ys, YawSearchSettings, enabled);
  PERCH2_RW(ys, YawSearchSettings, turns);

  nb::class_<TabletopSettings> ts(m, "TabletopSettings", doc("TabletopSettings"));
  ts.def(nb::init<>());
  PERCH2_RW(ts, TabletopSettings, xy_step_m);
  PERCH2_RW(ts, TabletopSettings, yaw_step_rad);
  ts.def_prop_rw(
      "workspace_xy_m",
      [](const TabletopSettings& s) -> std::optional<std::array<float, 4>> {
        if (!s.workspace_xy_m) return std::nullopt;
        return std::array<float, 4>{s.workspace_xy_m->min().x(), s.workspace_xy_m->min().y(),
                                    s.workspace_xy_m->max().x(), s.workspace_xy_m->max().y()};
      },
      [](TabletopSettings& s, nb::handle v) {
        if (v.is_none()) {
          s.workspace_xy_m.reset();
          return;
        }
        std::size_t n = 0;
        const std::vector<float> b =
            float_rows(v, "workspace_xy_m (x_min, y_min, x_max, y_max)", 4, &n, true);
        if (n != 1) throw InvalidInput("workspace_xy_m", "must be 4 numbers (x_min, y_min, x_max, y_max)");
        s.workspace_xy_m = Eigen::AlignedBox2f(Eigen::Vector2f(b[0], b[1]), Eigen::Vector2f(b[2], b[3]));
      },
      nb::for_setter(nb::arg("value").none()),
      (std::string(doc("TabletopSettings.workspace_xy_m")) + "\nAs (x_min, y_min, x_max, y_max) or None.")
          .c_str());
  PERCH2_RW(ts, TabletopSettings, workspace_margin_m);
  PERCH2_RW(ts, TabletopSettings, clip_workspace_to_table);
  PERCH2_RW(ts, TabletopSettings, min_height_m);
  PERCH2_RW(ts, TabletopSettings, max_height_m);
  PERCH2_RW(ts, TabletopSettings, min_support_points);
  PERCH2_RW(ts, TabletopSettings, support_margin_m);
  PERCH2_RW(ts, TabletopSettings, observed);
  PERCH2_RW(ts, TabletopSettings, render);
  PERCH2_RW(ts, TabletopSettings, score_stride);
  PERCH2_RW(ts, TabletopSettings, coarse_score_stride);
  PERCH2_RW(ts, TabletopSettings, rescore_extra_places);
  PERCH2_RW(ts, TabletopSettings, rescore_yaws);
  PERCH2_RW(ts, TabletopSettings, rescore_place_radius_m);
  PERCH2_RW(ts, TabletopSettings, occluder_marking);
  PERCH2_RW(ts, TabletopSettings, missing_depth_hides);
  PERCH2_RW(ts, TabletopSettings, refine);
  PERCH2_RW(ts, TabletopSettings, icp_max_points);
  PERCH2_RW(ts, TabletopSettings, min_icp_inlier_fraction);
  PERCH2_RW(ts, TabletopSettings, dedupe_xy_m);
  PERCH2_RW(ts, TabletopSettings, dedupe_yaw_rad);
  PERCH2_RW(ts, TabletopSettings, icp);
  PERCH2_RW(ts, TabletopSettings, cost);
  PERCH2_RW(ts, TabletopSettings, mode);
  PERCH2_RW(ts, TabletopSettings, min_rendered_points);
  PERCH2_RW(ts, TabletopSettings, min_inlier_fraction);
  PERCH2_RW(ts, TabletopSettings, hidden_point_weight);
  PERCH2_RW(ts, TabletopSettings, min_observed_in_volume);
  PERCH2_RW(ts, TabletopSettings, second_look);
  PERCH2_RW(ts, TabletopSettings, second_look_margin_m);
  PERCH2_RW(ts, TabletopSettings, overlap_tolerance_m);
  PERCH2_RW(ts, TabletopSettings, exclusive_placements);
  PERCH2_RW(ts, TabletopSettings, tree_max_occluding_fraction);
  PERCH2_RW(ts, TabletopSettings, strict_instances);
  PERCH2_RW(ts, TabletopSettings, keep_scored);
  PERCH2_RW(ts, TabletopSettings, polish_rounds);
  PERCH2_RW(ts, TabletopSettings, polish_stride);
  PERCH2_RW(ts, TabletopSettings, polish_max_distance_m);
  PERCH2_RW(ts, TabletopSettings, polish_iterations);
  PERCH2_RW(ts, TabletopSettings, yaw_search);
  PERCH2_RW(ts, TabletopSettings, table);

  m.def(
      "tabletop_variant",
      [](nb::handle v, std::optional<TabletopSettings> base) {
        return tabletop_variant(parse_variant(v), base.value_or(TabletopSettings{}));
      },
      nb::arg("variant"), nb::arg("base").none() = nb::none(), doc("tabletop_variant"));

  nb::class_<TabletopModel> tm(m, "TabletopModel", doc("TabletopModel"));
  tm.def(
        "__init__",
        [](TabletopModel* self, Mesh mesh, bool yaw_symmetric, nb::handle T_place_obj) {
          new (self) TabletopModel{std::move(mesh), yaw_symmetric,
                                   T_place_obj.is_none()
                                       ? std::nullopt
                                       : std::optional<Pose>(pose_from(T_place_obj, "T_place_obj"))};
        },
        nb::arg("mesh"), nb::arg("yaw_symmetric") = false, nb::arg("T_place_obj").none() = nb::none())
      .def_prop_rw(
          "T_place_obj",
          [](const TabletopModel& x) -> nb::object {
            return x.T_place_obj ? nb::cast(pose_array(*x.T_place_obj)) : nb::none();
          },
          [](TabletopModel& x, nb::handle v) {
            if (v.is_none())
              x.T_place_obj.reset();
            else
              x.T_place_obj = pose_from(v, "T_place_obj");
          },
          nb::for_setter(nb::arg("value").none()), doc("TabletopModel.T_place_obj"));
  PERCH2_RW(tm, TabletopModel, mesh);
  PERCH2_RW(tm, TabletopModel, yaw_symmetric);

  nb::class_<ObjectCount> oc(m, "ObjectCount", doc("ObjectCount"));
  oc.def(nb::init<int, int>(), nb::arg("model"), nb::arg("count") = 1);
  oc.def_rw("model", &ObjectCount::model, "index into the estimator's models");
  oc.def_rw("count", &ObjectCount::count, "instances of it in the frame");

  nb::class_<TabletopPose> tpose(m, "TabletopPose");
  PERCH2_RO(tpose, TabletopPose, model);
  PERCH2_RO(tpose, TabletopPose, instance);
  pose_prop(tpose, "T_cam_obj", &TabletopPose::T_cam_obj, "TabletopPose.T_cam_obj");
  pose_prop(tpose, "T_world_obj", &TabletopPose::T_world_obj, "TabletopPose.T_world_obj");
  PERCH2_RO(tpose, TabletopPose, x_m);
  PERCH2_RO(tpose, TabletopPose, y_m);
  PERCH2_RO(tpose, TabletopPose, yaw_rad);
  PERCH2_RO(tpose, TabletopPose, score);
  PERCH2_RO(tpose, TabletopPose, cost);
  tpose.def("__repr__", [](const TabletopPose& p) {
    return "TabletopPose(model=" + std::to_string(p.model) + ", instance=" + std::to_string(p.instance) +
           ", x_m=" + std::to_string(p.x_m) + ", y_m=" + std::to_string(p.y_m) +
           ", yaw_rad=" + std::to_string(p.yaw_rad) + ", score=" + std::to_string(p.score) + ")";
  });

  nb::class_<TabletopTimings> tt(m, "TabletopTimings", doc("TabletopTimings"));
  for (auto [name, field] : {std::pair{"table", &TabletopTimings::table},
                             {"observed", &TabletopTimings::observed},
                             {"hypotheses", &TabletopTimings::hypotheses},
                             {"render", &TabletopTimings::render},
                             {"refine", &TabletopTimings::refine},
                             {"cost", &TabletopTimings::cost},
                             {"select", &TabletopTimings::select},
                             {"yaw", &TabletopTimings::yaw},
                             {"total", &TabletopTimings::total}})
    tt.def_ro(name, field, "seconds, wall clock");

  nb::class_<TabletopResult> tr(m, "TabletopResult");
  PERCH2_RO(tr, TabletopResult, poses);
  pose_prop(tr, "T_cam_world", &TabletopResult::T_cam_world, "TabletopResult.T_cam_world");
  PERCH2_RO(tr, TabletopResult, table_estimated);
  PERCH2_RO(tr, TabletopResult, hypotheses_grid);
  PERCH2_RO(tr, TabletopResult, hypotheses_kept);
  PERCH2_RO(tr, TabletopResult, hypotheses_refined);
  PERCH2_RO(tr, TabletopResult, hypotheses_coarse);
  PERCH2_RO(tr, TabletopResult, hypotheses_scored);
  PERCH2_RO(tr, TabletopResult, yaw_candidates);
  PERCH2_RO(tr, TabletopResult, missing);
  PERCH2_RO(tr, TabletopResult, scored);
  PERCH2_RO(tr, TabletopResult, timings);

  static const std::string tabletop_doc = estimator_doc(
      "file:perch2/search/tabletop.hpp", "TabletopEstimator.TabletopEstimator",
      "\nTabletopEstimator(models, backend=\"thrust_omp\", variant=None, settings=None): models are "
      "perch2.Mesh\n"
      "(default rest pose, not yaw-symmetric) or perch2.TabletopModel; variant (a SearchVariant or its "
      "name,\n"
      "e.g. \"perch2-c\") applies tabletop_variant() on top of settings (default TabletopSettings()).\n"
      "estimate(depth, rgb, K, objects, T_cam_world=None, depth_scale_m=None) or estimate(frame, objects, "
      "...):\n"
      "objects is {model: count} with model an index or a mesh name. The GIL is released while it runs; the\n"
      "numpy inputs are copied once into a frame (pass a perch2.RgbdFrame to copy nothing).");
  nb::class_<PyTabletop> tabletop(m, "TabletopEstimator", tabletop_doc.c_str());
  estimator_accessors<TabletopSettings>(tabletop, "settings.cost.delta_m");
  tabletop
      .def(
          "__init__",
          [](PyTabletop* self, nb::handle models, const std::string& backend, nb::handle variant,
             std::optional<TabletopSettings> settings) {
            std::vector<TabletopModel> ms = tabletop_models(models);
            TabletopSettings s = settings.value_or(TabletopSettings{});
            if (!variant.is_none()) s = tabletop_variant(parse_variant(variant), s);
            const BackendId id = parse_backend(backend);
            nb::gil_scoped_release release;
            new (self) PyTabletop(backend_name(id), std::move(ms), std::move(s));
          },
          nb::arg("models"), nb::arg("backend") = "thrust_omp", nb::arg("variant").none() = nb::none(),
          nb::arg("settings").none() = nb::none())
      .def(
          "model_index",
          [](const PyTabletop& e, const std::string& name) {
            return e.with([&](const auto& x) { return x.model_index(name); });
          },
          nb::arg("name"), doc("TabletopEstimator.model_index"))
      .def(
          "estimate",
          [](const PyTabletop& e, const RgbdFrame& frame, nb::handle objects, nb::handle T_cam_world) {
            const std::vector<ObjectCount> oc = object_counts(e, objects);
            std::optional<Pose> T;
            if (!T_cam_world.is_none()) T = pose_from(T_cam_world, "T_cam_world");
            return e.call([&](const auto& x) { return x.estimate(frame, oc, T); });
          },
          nb::arg("frame"), nb::arg("objects"), nb::arg("T_cam_world").none() = nb::none(),
          doc("TabletopEstimator.estimate"))
      .def(
          "estimate",
          [](const PyTabletop& e, nb::handle depth, nb::handle rgb, nb::handle K, nb::handle objects,
             nb::handle T_cam_world, std::optional<float> depth_scale_m) {
            const RgbdFrame frame = frame_from(depth, rgb, K, depth_scale_m);
            const std::vector<ObjectCount> oc = object_counts(e, objects);
            std::optional<Pose> T;
            if (!T_cam_world.is_none()) T = pose_from(T_cam_world, "T_cam_world");
            return e.call([&](const auto& x) { return x.estimate(frame, oc, T); });
          },
          nb::arg("depth"), nb::arg("rgb").none(), nb::arg("K"), nb::arg("objects"),
          nb::arg("T_cam_world").none() = nb::none(), nb::arg("depth_scale_m").none() = nb::none(),
          "depth: H x W float32 metres (0 = no reading) or uint16 with depth_scale_m; rgb: H x W x 3 uint8 "
          "or None\n"
          "(the RGB-D cost needs it); K: 3 x 3 or perch2.Intrinsics; objects: {model: count}; T_cam_world: "
          "the\n"
          "table frame -> camera (4 x 4), or None to estimate the table plane. Copies the arrays once.")
      .def(
          "detect",
          [](const PyTabletop& e, nb::handle depth, nb::handle rgb, nb::handle K,
             std::optional<TabletopDetectSettings> settings, nb::handle T_cam_world,
             std::optional<float> depth_scale_m) {
            const RgbdFrame frame = frame_from(depth, rgb, K, depth_scale_m);
            std::optional<Pose> T;
            if (!T_cam_world.is_none()) T = pose_from(T_cam_world, "T_cam_world");
            const TabletopDetectSettings d = settings.value_or(TabletopDetectSettings{});
            return e.call([&](const auto& x) { return x.detect(frame, d, T); });
          },
          nb::arg("depth"), nb::arg("rgb").none(), nb::arg("K"), nb::arg("settings").none() = nb::none(),
          nb::arg("T_cam_world").none() = nb::none(), nb::arg("depth_scale_m").none() = nb::none(),
          (std::string(doc("TabletopEstimator.detect")) +
           "\ndepth, rgb, K and T_cam_world as in estimate(). Copies the arrays once.")
              .c_str());

  // ---- 6-DoF
  nb::class_<ProposalSettings> ps(m, "ProposalSettings", doc("ProposalSettings"));
  ps.def(nb::init<>());
  PERCH2_RW(ps, ProposalSettings, viewpoints);
  PERCH2_RW(ps, ProposalSettings, hemisphere);
  PERCH2_RW(ps, ProposalSettings, inplane_rotations);
  PERCH2_RW(ps, ProposalSettings, symmetry_threshold_rad);
  PERCH2_RW(ps, ProposalSettings, depth_step_m);
  PERCH2_RW(ps, ProposalSettings, depth_quantile_near);
  PERCH2_RW(ps, ProposalSettings, depth_quantile_far);
  PERCH2_RW(ps, ProposalSettings, max_depths);

  nb::class_<ScreenSettings> scr(m, "ScreenSettings", doc("ScreenSettings"));
  scr.def(nb::init<>());
  PERCH2_RW(scr, ScreenSettings, stride);
  PERCH2_RW(scr, ScreenSettings, min_points);
  PERCH2_RW(scr, ScreenSettings, icp_iterations);
  PERCH2_RW(scr, ScreenSettings, keep_fraction);
  PERCH2_RW(scr, ScreenSettings, min_keep);
  PERCH2_RW(scr, ScreenSettings, use_color);
  PERCH2_RW(scr, ScreenSettings, in_scene);
  PERCH2_RW(scr, ScreenSettings, hidden);

  nb::class_<CoarseMeshSettings> cms(m, "CoarseMeshSettings", doc("CoarseMeshSettings"));
  cms.def(nb::init<>());
  PERCH2_RW(cms, CoarseMeshSettings, min_stride);
  PERCH2_RW(cms, CoarseMeshSettings, min_triangles);
  PERCH2_RW(cms, CoarseMeshSettings, cell_fraction);
  PERCH2_RW(cms, CoarseMeshSettings, texture_factor);

  nb::class_<ModelSymmetries> sym(m, "ModelSymmetries", doc("ModelSymmetries"));
  sym.def(nb::init<>())
      .def(
          "__init__",
          [](ModelSymmetries* self, nb::handle discrete, nb::handle continuous_axes) {
            ModelSymmetries s;
            if (!discrete.is_none()) {
              if (nb::len(discrete) > 0) s.discrete = poses_from(discrete, "discrete");
            }
            if (!continuous_axes.is_none() && nb::len(continuous_axes) > 0) {
              std::size_t n = 0;
              const std::vector<float> a = float_rows(continuous_axes, "continuous_axes", 3, &n, true);
              for (std::size_t i = 0; i < n; ++i)
                s.continuous_axes.emplace_back(a[3 * i], a[3 * i + 1], a[3 * i + 2]);
            }
            new (self) ModelSymmetries(std::move(s));
          },
          nb::arg("discrete").none() = nb::none(), nb::arg("continuous_axes").none() = nb::none(),
          "discrete: (n, 4, 4) symmetry transforms T_obj_obj' (metres, identity not listed); "
          "continuous_axes: (k, 3)\n"
          "rotation axes in the object frame.")
      .def_prop_ro(
          "discrete", [](const ModelSymmetries& s) { return poses_array(s.discrete); }, nb::rv_policy::move,
          "(n, 4, 4), a new array")
      .def("empty", &ModelSymmetries::empty);
  PERCH2_RW(sym, ModelSymmetries, continuous_axes);

  nb::class_<SixDofModel> sm(m, "SixDofModel", doc("SixDofModel"));
  sm.def(nb::init<Mesh, ModelSymmetries>(), nb::arg("mesh"), nb::arg("symmetries") = ModelSymmetries{});
  sm.def_rw("mesh", &SixDofModel::mesh, "object frame, metres");
  sm.def_rw("symmetries", &SixDofModel::symmetries, "from models_info.json (BOP)");

  nb::class_<SixDofInstance> si(m, "SixDofInstance", doc("SixDofInstance"));
  si.def(
        "__init__",
        [](SixDofInstance* self, int model, nb::handle mask, nb::handle box) {
          new (self) SixDofInstance(make_instance(model, mask, box, "SixDofInstance"));
        },
        nb::arg("model"), nb::arg("mask"), nb::arg("box").none() = nb::none(),
        "model: index into the estimator's models; mask: H x W bool or uint8 (copied); box: (x, y, w, h) "
        "pixels,\n"
        "None = the mask's box.")
      .def_rw("model", &SixDofInstance::model)
      .def_prop_ro(
          "mask",
          [](nb::handle s) {
            auto& in = nb::cast<SixDofInstance&>(s);
            return view(in.mask.data.data(), {std::size_t(in.mask.height), std::size_t(in.mask.width)}, s);
          },
          "H x W uint8 (a view of the instance's storage)")
      .def_rw("box_xywh", &SixDofInstance::box_xywh);

  nb::class_<LocalSearchSettings> ls(m, "LocalSearchSettings", doc("LocalSearchSettings"));
  ls.def(nb::init<>());
  PERCH2_RW(ls, LocalSearchSettings, candidates_per_instance);
  PERCH2_RW(ls, LocalSearchSettings, turns);
  PERCH2_RW(ls, LocalSearchSettings, polish);

  nb::class_<SurfaceFitSettings> fs(m, "SurfaceFitSettings", doc("SurfaceFitSettings"));
  fs.def(nb::init<>());
  PERCH2_RW(fs, SurfaceFitSettings, iterations);
  PERCH2_RW(fs, SurfaceFitSettings, max_distance_m);
  PERCH2_RW(fs, SurfaceFitSettings, tukey_c);
  PERCH2_RW(fs, SurfaceFitSettings, min_scale_m);
  PERCH2_RW(fs, SurfaceFitSettings, neighbours);
  PERCH2_RW(fs, SurfaceFitSettings, min_points);
  PERCH2_RW(fs, SurfaceFitSettings, min_curvature_ratio);
  PERCH2_RW(fs, SurfaceFitSettings, translation_epsilon_m);
  PERCH2_RW(fs, SurfaceFitSettings, rotation_epsilon_rad);
  PERCH2_RW(fs, SurfaceFitSettings, max_step_m);
  PERCH2_RW(fs, SurfaceFitSettings, max_step_rad);

  nb::class_<SixDofSettings> ss(m, "SixDofSettings", doc("SixDofSettings"));
  ss.def(nb::init<>());
  PERCH2_RW(ss, SixDofSettings, proposals);
  PERCH2_RW(ss, SixDofSettings, observed);
  PERCH2_RW(ss, SixDofSettings, render);
  PERCH2_RW(ss, SixDofSettings, first_pass_min_points);
  PERCH2_RW(ss, SixDofSettings, screen);
  PERCH2_RW(ss, SixDofSettings, coarse_mesh);
  PERCH2_RW(ss, SixDofSettings, first_pass_target_stride);
  PERCH2_RW(ss, SixDofSettings, keep_per_instance);
  PERCH2_RW(ss, SixDofSettings, distinct_translation_m);
  PERCH2_RW(ss, SixDofSettings, distinct_rotation_rad);
  PERCH2_RW(ss, SixDofSettings, dedupe_after_warmup);
  PERCH2_RW(ss, SixDofSettings, second_pass_stride);
  PERCH2_RW(ss, SixDofSettings, score_stride);
  PERCH2_RW(ss, SixDofSettings, gicp);
  PERCH2_RW(ss, SixDofSettings, second_pass_cap_m);
  PERCH2_RW(ss, SixDofSettings, second_pass_iterations);
  PERCH2_RW(ss, SixDofSettings, cost);
  PERCH2_RW(ss, SixDofSettings, first_pass_cost);
  PERCH2_RW(ss, SixDofSettings, trim_quantile_low);
  PERCH2_RW(ss, SixDofSettings, trim_quantile_high);
  PERCH2_RW(ss, SixDofSettings, trim_margin_m);
  PERCH2_RW(ss, SixDofSettings, min_rendered_points);
  PERCH2_RW(ss, SixDofSettings, local);
  PERCH2_RW(ss, SixDofSettings, fit);
  PERCH2_RW(ss, SixDofSettings, fit_stride);
  PERCH2_RW(ss, SixDofSettings, fit_sample_spacing_m);
  PERCH2_RW(ss, SixDofSettings, fit_cost_slack);
  PERCH2_RW(ss, SixDofSettings, scene);
  PERCH2_RW(ss, SixDofSettings, memory_budget_bytes);
  PERCH2_RW(ss, SixDofSettings, bytes_per_point);

  nb::class_<SixDofPose> sp(m, "SixDofPose");
  PERCH2_RO(sp, SixDofPose, instance);
  sp.def_ro("model", &SixDofPose::model, "index into the estimator's models");
  pose_prop(sp, "T_cam_obj", &SixDofPose::T_cam_obj, "SixDofPose.T_cam_obj");
  PERCH2_RO(sp, SixDofPose, score);
  PERCH2_RO(sp, SixDofPose, found);
  PERCH2_RO(sp, SixDofPose, depth_agreement);
  sp.def_ro("cost", &SixDofPose::cost, "the final cost at this pose");
  sp.def("__repr__", [](const SixDofPose& p) {
    return "SixDofPose(instance=" + std::to_string(p.instance) + ", model=" + std::to_string(p.model) +
           ", score=" + std::to_string(p.score) + ", found=" + (p.found ? "True" : "False") + ")";
  });

  nb::class_<SegmentationSettings> sgs(m, "SegmentationSettings", doc("SegmentationSettings"));
  sgs.def(nb::init<>());
  PERCH2_RW(sgs, SegmentationSettings, remove_plane);
  PERCH2_RW(sgs, SegmentationSettings, plane);
  PERCH2_RW(sgs, SegmentationSettings, max_planes);
  PERCH2_RW(sgs, SegmentationSettings, plane_distance_m);
  PERCH2_RW(sgs, SegmentationSettings, max_height_m);
  PERCH2_RW(sgs, SegmentationSettings, min_depth_m);
  PERCH2_RW(sgs, SegmentationSettings, max_depth_m);
  PERCH2_RW(sgs, SegmentationSettings, jump_m);
  PERCH2_RW(sgs, SegmentationSettings, jump_per_m);
  PERCH2_RW(sgs, SegmentationSettings, min_area_fraction);
  PERCH2_RW(sgs, SegmentationSettings, min_pixels);

  nb::class_<TablePlane> tpl(m, "TablePlane", doc("TablePlane"));
  PERCH2_RO(tpl, TablePlane, normal_cam);
  PERCH2_RO(tpl, TablePlane, offset_m);
  pose_prop(tpl, "T_cam_world", &TablePlane::T_cam_world, "TablePlane.T_cam_world");
  PERCH2_RO(tpl, TablePlane, inliers);
  PERCH2_RO(tpl, TablePlane, samples);

  nb::class_<SceneSettings> scs(m, "SceneSettings", doc("SceneSettings"));
  scs.def(nb::init<>());
  PERCH2_RW(scs, SceneSettings, segmentation);
  PERCH2_RW(scs, SceneSettings, min_area_fraction);
  PERCH2_RW(scs, SceneSettings, max_area_faces);
  PERCH2_RW(scs, SceneSettings, piece_extent_factor);
  PERCH2_RW(scs, SceneSettings, piece_area_faces);
  PERCH2_RW(scs, SceneSettings, half_jobs);
  PERCH2_RW(scs, SceneSettings, max_pieces);
  PERCH2_RW(scs, SceneSettings, min_segment_points);
  PERCH2_RW(scs, SceneSettings, min_inlier_fraction);
  PERCH2_RW(scs, SceneSettings, min_explained_points);
  PERCH2_RW(scs, SceneSettings, max_colour_mismatch);
  PERCH2_RW(scs, SceneSettings, explain_distance_m);
  PERCH2_RW(scs, SceneSettings, min_colour_fraction);
  PERCH2_RW(scs, SceneSettings, colour_samples);
  PERCH2_RW(scs, SceneSettings, residual_pass);
  PERCH2_RW(scs, SceneSettings, refine_after_placing);
  PERCH2_RW(scs, SceneSettings, local_search_placed_only);
  PERCH2_RW(scs, SceneSettings, spare_placements);
  PERCH2_RW(scs, SceneSettings, retrieval_jobs_per_object);

  nb::class_<FrameSegment> fseg(m, "FrameSegment", doc("FrameSegment"));
  PERCH2_RO(fseg, FrameSegment, label);
  PERCH2_RO(fseg, FrameSegment, pixels);
  PERCH2_RO(fseg, FrameSegment, area_m2);
  PERCH2_RO(fseg, FrameSegment, box_xywh);
  PERCH2_RO(fseg, FrameSegment, depth_min_m);
  PERCH2_RO(fseg, FrameSegment, depth_max_m);
  PERCH2_RO(fseg, FrameSegment, centroid_cam);
  PERCH2_RO(fseg, FrameSegment, extent_m);

  nb::class_<FrameSegments> fsegs(m, "FrameSegments", doc("FrameSegments"));
  fsegs
      .def_prop_ro(
          "labels",
          [](nb::handle self) {
            LabelImage& l = nb::cast<FrameSegments&>(self).labels;
            return view(l.data.data(), {std::size_t(l.height), std::size_t(l.width)}, self);
          },
          "H x W int32 (a view): 0 = support, background or dropped; k + 1 = segments[k]")
      .def_ro("segments", &FrameSegments::segments, doc("FrameSegments.segments"))
      .def_ro("plane", &FrameSegments::plane, doc("FrameSegments.plane"))
      .def_ro("support_pixels", &FrameSegments::support_pixels, doc("FrameSegments.support_pixels"))
      .def_ro("dropped_segments", &FrameSegments::dropped_segments, doc("FrameSegments.dropped_segments"));
  m.def(
      "segment_frame",
      [](const RgbdFrame& frame, const SegmentationSettings& settings, float min_model_face_m2) {
        nb::gil_scoped_release release;
        return segment_frame(frame, settings, min_model_face_m2);
      },
      nb::arg("frame"), nb::arg("settings") = SegmentationSettings{}, nb::arg("min_model_face_m2") = 0.f,
      doc("segment_frame"));
  m.def(
      "segment_readings",
      [](const RgbdFrame& frame, nb::handle mask, const SegmentationSettings& settings,
         float min_model_face_m2) {
        const Image<std::uint8_t> m = mask_from(mask, "mask");
        if (m.width != frame.camera.width || m.height != frame.camera.height)
          throw InvalidInput("mask", "is " + std::to_string(m.height) + " x " + std::to_string(m.width) +
                                         ", the frame " + std::to_string(frame.camera.height) + " x " +
                                         std::to_string(frame.camera.width));
        nb::gil_scoped_release release;
        return segment_readings(frame, m.data, settings, min_model_face_m2);
      },
      nb::arg("frame"), nb::arg("mask"), nb::arg("settings") = SegmentationSettings{},
      nb::arg("min_model_face_m2") = 0.f, doc("segment_readings"));

  nb::class_<SixDofObject> sobj(m, "SixDofObject", doc("SixDofObject"));
  sobj.def(nb::init<>())
      .def(
          "__init__",
          [](SixDofObject* self, int model, int count) {
            new (self) SixDofObject{model, count};
          },
          nb::arg("model"), nb::arg("count") = 1);
  PERCH2_RW(sobj, SixDofObject, model);
  PERCH2_RW(sobj, SixDofObject, count);

  nb::class_<SixDofTimings> st(m, "SixDofTimings", doc("SixDofTimings"));
  for (auto [name, field] : {std::pair{"observed", &SixDofTimings::observed},
                             {"proposals", &SixDofTimings::proposals},
                             {"render", &SixDofTimings::render},
                             {"refine", &SixDofTimings::refine},
                             {"cost", &SixDofTimings::cost},
                             {"select", &SixDofTimings::select},
                             {"fit", &SixDofTimings::fit},
                             {"total", &SixDofTimings::total}})
    st.def_ro(name, field, "seconds, wall clock");
  PERCH2_RO(st, SixDofTimings, screen);
  PERCH2_RO(st, SixDofTimings, first_pass);
  PERCH2_RO(st, SixDofTimings, second_pass);
  PERCH2_RO(st, SixDofTimings, local);
  PERCH2_RO(st, SixDofTimings, segment);
  PERCH2_RO(st, SixDofTimings, explain);
  PERCH2_RO(st, SixDofTimings, retrieve);

  nb::class_<SixDofResult> sr(m, "SixDofResult");
  PERCH2_RO(sr, SixDofResult, poses);
  PERCH2_RO(sr, SixDofResult, hypotheses);
  PERCH2_RO(sr, SixDofResult, rotations);
  PERCH2_RO(sr, SixDofResult, depths);
  PERCH2_RO(sr, SixDofResult, segment_points);
  PERCH2_RO(sr, SixDofResult, trimmed_pixels);
  PERCH2_RO(sr, SixDofResult, hypotheses_total);
  PERCH2_RO(sr, SixDofResult, chunks);
  PERCH2_RO(sr, SixDofResult, second_pass_hypotheses);
  PERCH2_RO(sr, SixDofResult, local_candidates);
  PERCH2_RO(sr, SixDofResult, first_pass_distinct);
  PERCH2_RO(sr, SixDofResult, proposals_screened_out);
  PERCH2_RO(sr, SixDofResult, peak_chunk_bytes);
  PERCH2_RO(sr, SixDofResult, fits_kept);
  PERCH2_RO(sr, SixDofResult, timings);

  nb::class_<TabletopDetectSettings> tds(m, "TabletopDetectSettings", doc("TabletopDetectSettings"));
  tds.def(nb::init<>());
  PERCH2_RW(tds, TabletopDetectSettings, max_per_model);
  PERCH2_RW(tds, TabletopDetectSettings, max_per_frame);
  PERCH2_RW(tds, TabletopDetectSettings, min_score);

  nb::class_<DetectSettings> dts(m, "DetectSettings", doc("DetectSettings"));
  dts.def(nb::init<>());
  PERCH2_RW(dts, DetectSettings, max_per_model);
  PERCH2_RW(dts, DetectSettings, max_per_frame);
  PERCH2_RW(dts, DetectSettings, min_score);
  PERCH2_RW(dts, DetectSettings, max_colour_mismatch);
  PERCH2_RW(dts, DetectSettings, retrieval_jobs_per_object);
  PERCH2_RW(dts, DetectSettings, retrieval_viewpoints);
  PERCH2_RW(dts, DetectSettings, retrieval_inplane_rotations);
  PERCH2_RW(dts, DetectSettings, retrieval_screen_keep);
  PERCH2_RW(dts, DetectSettings, retrieval_align_inplane);
  PERCH2_RW(dts, DetectSettings, retrieval_align_min_elongation);
  PERCH2_RW(dts, DetectSettings, seed_depth);
  PERCH2_RW(dts, DetectSettings, retrieval_acceptable_only);
  PERCH2_RW(dts, DetectSettings, half_evidence_readings);
  PERCH2_RW(dts, DetectSettings, max_below_plane_m);

  nb::class_<SixDofSceneResult> ssr(m, "SixDofSceneResult", doc("SixDofSceneResult"));
  PERCH2_RO(ssr, SixDofSceneResult, poses);
  PERCH2_RO(ssr, SixDofSceneResult, missing);
  PERCH2_RO(ssr, SixDofSceneResult, segments);
  PERCH2_RO(ssr, SixDofSceneResult, segment_points);
  PERCH2_RO(ssr, SixDofSceneResult, below_plane);
  PERCH2_RO(ssr, SixDofSceneResult, plane);
  PERCH2_RO(ssr, SixDofSceneResult, jobs);
  PERCH2_RO(ssr, SixDofSceneResult, halves);
  PERCH2_RO(ssr, SixDofSceneResult, screened_out);
  PERCH2_RO(ssr, SixDofSceneResult, retrieved_out);
  PERCH2_RO(ssr, SixDofSceneResult, candidates);
  PERCH2_RO(ssr, SixDofSceneResult, rounds);
  PERCH2_RO(ssr, SixDofSceneResult, refined);
  PERCH2_RO(ssr, SixDofSceneResult, reverted);
  PERCH2_RO(ssr, SixDofSceneResult, residual_segments);
  PERCH2_RO(ssr, SixDofSceneResult, search);

  static const std::string sixdof_doc = estimator_doc(
      "file:perch2/search/sixdof.hpp", "SixDofEstimator.SixDofEstimator",
      "\nSixDofEstimator(models, backend=\"thrust_omp\", settings=None): models are perch2.SixDofModel (mesh "
      "+\n"
      "symmetries, e.g. perch2.sixdof_model(mesh, model_info)) or perch2.Mesh (no symmetries).\n"
      "estimate(depth, rgb, K, instances, depth_scale_m=None) or estimate(frame, instances): an instance is "
      "a\n"
      "perch2.SixDofInstance or (model, mask, box) with mask an H x W bool/uint8 array from any detector and "
      "box\n"
      "(x, y, w, h) pixels or None (the mask's box). The GIL is released while it runs; the numpy inputs "
      "are\n"
      "copied once (masks too).");
  nb::class_<PySixDof> sixdof(m, "SixDofEstimator", sixdof_doc.c_str());
  estimator_accessors<SixDofSettings>(sixdof, "settings.local.turns.final_stride");
  sixdof
      .def(
          "__init__",
          [](PySixDof* self, nb::handle models, const std::string& backend,
             std::optional<SixDofSettings> settings) {
            std::vector<SixDofModel> ms = sixdof_models(models);
            const BackendId id = parse_backend(backend);
            nb::gil_scoped_release release;
            new (self) PySixDof(backend_name(id), std::move(ms), settings.value_or(SixDofSettings{}));
          },
          nb::arg("models"), nb::arg("backend") = "thrust_omp", nb::arg("settings").none() = nb::none())
      .def(
          "estimate",
          [](const PySixDof& e, const RgbdFrame& frame, nb::handle instances) {
            const std::vector<SixDofInstance> in = instances_from(instances, frame);
            return e.call([&](const auto& x) { return x.estimate(frame, in); });
          },
          nb::arg("frame"), nb::arg("instances"), doc("SixDofEstimator.estimate"))
      .def(
          "estimate",
          [](const PySixDof& e, nb::handle depth, nb::handle rgb, nb::handle K, nb::handle instances,
             std::optional<float> depth_scale_m) {
            const RgbdFrame frame = frame_from(depth, rgb, K, depth_scale_m);
            const std::vector<SixDofInstance> in = instances_from(instances, frame);
            return e.call([&](const auto& x) { return x.estimate(frame, in); });
          },
          nb::arg("depth"), nb::arg("rgb").none(), nb::arg("K"), nb::arg("instances"),
          nb::arg("depth_scale_m").none() = nb::none(),
          "depth: H x W float32 metres (0 = no reading) or uint16 with depth_scale_m; rgb: H x W x 3 uint8 "
          "or None;\n"
          "K: 3 x 3 or perch2.Intrinsics; instances: [(model, mask, box), ...]. Copies the arrays once.")
      .def(
          "estimate_scene",
          [](const PySixDof& e, const RgbdFrame& frame, nb::handle objects) {
            const std::vector<SixDofObject> in = objects_from(objects);
            return e.call([&](const auto& x) { return x.estimate_scene(frame, in); });
          },
          nb::arg("frame"), nb::arg("objects"), doc("SixDofEstimator.estimate_scene"))
      .def(
          "estimate_scene",
          [](const PySixDof& e, nb::handle depth, nb::handle rgb, nb::handle K, nb::handle objects,
             std::optional<float> depth_scale_m) {
            const RgbdFrame frame = frame_from(depth, rgb, K, depth_scale_m);
            const std::vector<SixDofObject> in = objects_from(objects);
            return e.call([&](const auto& x) { return x.estimate_scene(frame, in); });
          },
          nb::arg("depth"), nb::arg("rgb").none(), nb::arg("K"), nb::arg("objects"),
          nb::arg("depth_scale_m").none() = nb::none(),
          "No detector: objects are perch2.SixDofObject or (model, count) pairs; depth, rgb and K as in\n"
          "estimate(). Copies the arrays once.")
      .def(
          "detect",
          [](const PySixDof& e, const RgbdFrame& frame, std::optional<DetectSettings> settings) {
            const DetectSettings d = settings.value_or(DetectSettings{});
            return e.call([&](const auto& x) { return x.detect(frame, d); });
          },
          nb::arg("frame"), nb::arg("settings").none() = nb::none(), doc("SixDofEstimator.detect"))
      .def(
          "detect",
          [](const PySixDof& e, nb::handle depth, nb::handle rgb, nb::handle K,
             std::optional<DetectSettings> settings, std::optional<float> depth_scale_m) {
            const RgbdFrame frame = frame_from(depth, rgb, K, depth_scale_m);
            const DetectSettings d = settings.value_or(DetectSettings{});
            return e.call([&](const auto& x) { return x.detect(frame, d); });
          },
          nb::arg("depth"), nb::arg("rgb").none(), nb::arg("K"), nb::arg("settings").none() = nb::none(),
          nb::arg("depth_scale_m").none() = nb::none(),
          "6D detection: every instance of every model, no counts given; depth, rgb and K as in estimate().\n"
          "Copies the arrays once.");

  // ---- BOP 6-DoF glue (perch2/search/sixdof_bop.hpp)
  m.def("sixdof_model", &sixdof_model, nb::arg("mesh"), nb::arg("info"), doc("sixdof_model"));
  nb::enum_<BoxKind> bk(m, "BoxKind", doc("BoxKind"));
  bk.value("Full", BoxKind::Full).value("Visible", BoxKind::Visible);
  nb::class_<BopInstances> bi(m, "BopInstances", doc("BopInstances"));
  bi.def(nb::init<>());
  PERCH2_RW(bi, BopInstances, instances);
  PERCH2_RW(bi, BopInstances, obj_ids);
  PERCH2_RW(bi, BopInstances, sources);
  PERCH2_RW(bi, BopInstances, skipped);
  m.def("bop_instances_from_gt", &bop_instances_from_gt, nb::arg("image"), nb::arg("model_of_obj_id"),
        nb::arg("box") = BoxKind::Full, doc("bop_instances_from_gt"));
  m.def("bop_instances_from_detections", &bop_instances_from_detections, nb::arg("image"),
        nb::arg("detections"), nb::arg("indices"), nb::arg("model_of_obj_id"), nb::arg("min_score") = 0.f,
        doc("bop_instances_from_detections"));
  m.def("only_targets", &only_targets, nb::arg("instances"), nb::arg("targets"), doc("only_targets"));
  m.def("usable_instances", &usable_instances, nb::arg("instances"), nb::arg("frame"), nb::arg("observed"),
        nb::arg("min_points") = 10, doc("usable_instances"));
  m.def("symmetric_about_z", &symmetric_about_z, nb::arg("info"), doc("symmetric_about_z"));
  m.def("tabletop_model", &tabletop_model, nb::arg("mesh"), nb::arg("info"), doc("tabletop_model"));
  m.def(
      "estimate_bop_image",
      [](const PyTabletop& e, const dataset::BopImage& image, const std::vector<dataset::Target>& targets,
         const std::map<int, int>& model_of_obj_id) {
        return e.call([&](const auto& x) {
          TabletopResult r;
          std::vector<dataset::PoseEstimate> rows =
              estimate_bop_image(x, image, targets, model_of_obj_id, &r);
          return std::make_pair(std::move(rows), std::move(r));
        });
      },
      nb::arg("estimator"), nb::arg("image"), nb::arg("targets"), nb::arg("model_of_obj_id"),
      "3-DoF (perch2/search/tabletop_bop.hpp): estimates the targets of one image with the table frame of\n"
      "scene_camera.json when given; one BOP row per pose (score = 1 / (1 + selection score)). Returns "
      "(rows, "
      "result).");
  m.def(
      "estimate_bop_image",
      [](const PySixDof& e, const dataset::BopImage& image, const BopInstances& in) {
        return e.call([&](const auto& x) {
          SixDofResult r;
          std::vector<dataset::PoseEstimate> rows = estimate_bop_image(x, image, in, &r);
          return std::make_pair(std::move(rows), std::move(r));
        });
      },
      nb::arg("estimator"), nb::arg("image"), nb::arg("instances"),
      (std::string(doc("estimate_bop_image")) + "\nReturns (rows, result).").c_str());
}

}  // namespace perch2_py
