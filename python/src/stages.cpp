// The pipeline's stages for users who build their own: Renderer, KnnIndex, Registration, Cost (each on
// the backend chosen by name) and their settings.
#include "common.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/knn/knn.hpp"
#include "perch2/registration/registration.hpp"
#include "perch2/render/render.hpp"

namespace perch2_py {

using namespace perch2;

namespace {

template <class B>
using RendererOf = typename B::Renderer;
template <class B>
using KnnIndexOf = typename B::KnnIndex;
template <class B>
using RegistrationOf = typename B::Registration;
template <class B>
using CostOf = typename B::Cost;

using PyRenderer = PerBackend<RendererOf>;
using PyKnnIndex = PerBackend<KnnIndexOf>;
using PyRegistration = PerBackend<RegistrationOf>;
using PyCost = PerBackend<CostOf>;

/// One entry per cloud: an int broadcast to n, or an integer array of length n; `fill` when None.
std::vector<std::int32_t> per_cloud(nb::handle obj, const std::string& name, std::size_t n,
                                    std::int32_t fill) {
  if (obj.is_none()) return std::vector<std::int32_t>(n, fill);
  if (PyLong_Check(obj.ptr())) return std::vector<std::int32_t>(n, nb::cast<std::int32_t>(obj));
  return int_vector(obj, name, long(n));
}

Intrinsics camera_arg(nb::handle obj) {
  Intrinsics K;
  if (!nb::try_cast(obj, K, false))
    throw InvalidInput("camera", "must be a perch2.Intrinsics (full resolution, with the image size)");
  K.validate("camera");
  return K;
}

std::string with_backend(const char* key) {
  return std::string(doc(key)) +
         "\n\nbackend: \"thrust_omp\" (default), \"cpu\" (the reference) or \"cuda\" (nvcc builds).";
}

}  // namespace

void bind_stages(nb::module_& m) {
  // ---- render
  nb::class_<RenderSettings> rs(m, "RenderSettings", doc("RenderSettings"));
  rs.def(nb::init<>());
  PERCH2_RW(rs, RenderSettings, stride);
  PERCH2_RW(rs, RenderSettings, near_m);
  PERCH2_RW(rs, RenderSettings, cull_back_faces);
  PERCH2_RW(rs, RenderSettings, occlusion_margin_m);
  PERCH2_RW(rs, RenderSettings, memory_budget_bytes);

  nb::class_<PyRenderer>(m, "Renderer", with_backend("file:perch2/render/render.hpp").c_str())
      .def(
          "__init__",
          [](PyRenderer* self, std::vector<Mesh> models, const std::string& backend) {
            new (self) PyRenderer(backend, std::move(models));
          },
          nb::arg("models"), nb::arg("backend") = "thrust_omp", doc("Renderer.Renderer"))
      .def(
          "render",
          [](const PyRenderer& r, nb::handle model, nb::handle T_cam_obj, nb::handle camera,
             const RenderSettings& s, nb::handle occluder_depth, nb::handle occluder_labels,
             nb::handle label) {
            const std::vector<Pose> T = poses_from(T_cam_obj, "T_cam_obj");
            const std::vector<std::int32_t> models = per_cloud(model, "model", T.size(), 0);
            const std::vector<std::int32_t> labels = per_cloud(label, "label", T.size(), -1);
            std::vector<Hypothesis> hyps(T.size());
            for (std::size_t h = 0; h < T.size(); ++h) hyps[h] = {models[h], T[h], labels[h]};
            const Intrinsics K = camera_arg(camera);
            std::optional<Occluders> occ;
            if (!occluder_depth.is_none()) {
              occ.emplace();
              occ->depth_m = depth_from(occluder_depth, "occluder_depth", std::nullopt);
              if (!occluder_labels.is_none()) occ->labels = labels_from(occluder_labels, "occluder_labels");
            } else if (!occluder_labels.is_none()) {
              throw InvalidInput("occluder_labels", "need occluder_depth");
            }
            return r.call(
                [&](const auto& renderer) { return renderer.render(hyps, K, s, occ ? &*occ : nullptr); });
          },
          nb::arg("model"), nb::arg("T_cam_obj"), nb::arg("camera"), nb::arg("settings") = RenderSettings{},
          nb::arg("occluder_depth").none() = nb::none(), nb::arg("occluder_labels").none() = nb::none(),
          nb::arg("label").none() = nb::none(),
          (std::string(doc("Renderer.render")) +
           "\n\nmodel: an index into the models (int, or one per hypothesis); T_cam_obj: (n, 4, 4) or (4, 4) "
           "poses "
           "(object -> camera, metres);\ncamera: perch2.Intrinsics at full resolution; occluder_depth (H x W "
           "float32 "
           "metres) and occluder_labels (H x W ints)\nhide rendered pixels behind observed ones (Occluders); "
           "label: "
           "per hypothesis, the observed label it explains (-1: none).\nReturns a CloudBatch: cloud h holds "
           "hypothesis h's visible points on the stride grid (arrays owned by the result, no copy).")
              .c_str())
      .def_prop_ro("backend", [](const PyRenderer& r) { return backend_name(r.backend); })
      .def("num_models",
           [](const PyRenderer& r) { return r.with([](const auto& x) { return x.num_models(); }); });

  // ---- kNN
  nb::enum_<KnnMethod> km(m, "KnnMethod");
  PERCH2_ENUM(km, KnnMethod, Auto);
  PERCH2_ENUM(km, KnnMethod, BruteForce);
  PERCH2_ENUM(km, KnnMethod, PerQuery);
  PERCH2_ENUM(km, KnnMethod, Grid);

  nb::class_<KnnSettings> ks(m, "KnnSettings", doc("KnnSettings"));
  ks.def(nb::init<>());
  PERCH2_RW(ks, KnnSettings, k);
  PERCH2_RW(ks, KnnSettings, max_distance_m);
  PERCH2_RW(ks, KnnSettings, method);
  PERCH2_RW(ks, KnnSettings, memory_budget_bytes);
  PERCH2_RW(ks, KnnSettings, auto_scan_max_points);

  nb::class_<GridSettings> gs(m, "GridSettings", doc("GridSettings"));
  gs.def(nb::init<>());
  PERCH2_RW(gs, GridSettings, cell_size_m);
  PERCH2_RW(gs, GridSettings, points_per_cell);
  PERCH2_RW(gs, GridSettings, max_cells_per_point);
  PERCH2_RW(gs, GridSettings, knn_ball_cells);
  PERCH2_RW(gs, GridSettings, cell_representatives);

  nb::class_<KnnIndexSettings> kis(m, "KnnIndexSettings", doc("KnnIndexSettings"));
  kis.def(nb::init<>());
  PERCH2_RW(kis, KnnIndexSettings, grid);
  PERCH2_RW(kis, KnnIndexSettings, flann_leaf_max_size);

  nb::class_<KnnResult>(m, "KnnResult", doc("KnnResult"))
      .def_ro("k", &KnnResult::k)
      .def_prop_ro(
          "index",
          [](nb::handle s) {
            KnnResult& r = nb::cast<KnnResult&>(s);
            return view(r.index.data(), {r.num_queries(), std::size_t(r.k)}, s);
          },
          (std::string(doc("KnnResult.index")) + " (num_queries x k view)").c_str())
      .def_prop_ro(
          "sq_distance_m2",
          [](nb::handle s) {
            KnnResult& r = nb::cast<KnnResult&>(s);
            return view(r.sq_distance_m2.data(), {r.num_queries(), std::size_t(r.k)}, s);
          },
          (std::string(doc("KnnResult.sq_distance_m2")) + " (num_queries x k view)").c_str())
      .def("num_queries", &KnnResult::num_queries);

  nb::class_<RadiusResult>(m, "RadiusResult", doc("RadiusResult"))
      .def_prop_ro(
          "offsets",
          [](nb::handle s) {
            auto& r = nb::cast<RadiusResult&>(s);
            return view(r.offsets.data(), {r.offsets.size()}, s);
          },
          doc("RadiusResult.offsets"))
      .def_prop_ro(
          "index",
          [](nb::handle s) {
            auto& r = nb::cast<RadiusResult&>(s);
            return view(r.index.data(), {r.index.size()}, s);
          },
          doc("RadiusResult.index"))
      .def_prop_ro(
          "sq_distance_m2",
          [](nb::handle s) {
            auto& r = nb::cast<RadiusResult&>(s);
            return view(r.sq_distance_m2.data(), {r.sq_distance_m2.size()}, s);
          },
          doc("RadiusResult.sq_distance_m2"))
      .def("num_queries", &RadiusResult::num_queries);

  nb::class_<PyKnnIndex>(m, "KnnIndex", with_backend("file:perch2/knn/knn.hpp").c_str())
      .def(
          "__init__",
          [](PyKnnIndex* self, const CloudBatch& targets, const KnnIndexSettings& s,
             const std::string& backend) {
            const BackendId id = parse_backend(backend);
            nb::gil_scoped_release release;
            new (self) PyKnnIndex(backend_name(id), targets, s);
          },
          nb::arg("targets"), nb::arg("settings") = KnnIndexSettings{}, nb::arg("backend") = "thrust_omp",
          "Builds the index over the target segments (each cloud of `targets` is one segment, metres) once.")
      .def(
          "knn",
          [](const PyKnnIndex& x, const CloudBatch& queries, nb::handle query_segment, const KnnSettings& s) {
            const auto seg = per_cloud(query_segment, "query_segment", queries.num_clouds(), 0);
            return x.call([&](const auto& index) { return index.knn(queries, seg, s); });
          },
          nb::arg("queries"), nb::arg("query_segment").none() = nb::none(),
          nb::arg("settings") = KnnSettings{},
          "k nearest neighbours of every query point within its cloud's target segment query_segment[c]\n"
          "(an int for all clouds, or one per cloud; default 0). Returns a KnnResult (views of its arrays).")
      .def(
          "radius",
          [](const PyKnnIndex& x, const CloudBatch& queries, nb::handle query_segment, float radius_m,
             int max_neighbors, KnnMethod method) {
            const auto seg = per_cloud(query_segment, "query_segment", queries.num_clouds(), 0);
            return x.call([&](const auto& index) {
              return index.radius(queries, seg, radius_m, max_neighbors, method);
            });
          },
          nb::arg("queries"), nb::arg("query_segment").none() = nb::none(), nb::arg("radius_m"),
          nb::arg("max_neighbors") = 0, nb::arg("method") = KnnMethod::Auto,
          "All neighbours within radius_m (inclusive) in the query cloud's segment, sorted by distance; "
          "with\n"
          "max_neighbors > 0 only the nearest max_neighbors. Returns a RadiusResult.")
      .def_prop_ro("backend", [](const PyKnnIndex& r) { return backend_name(r.backend); })
      .def("num_segments",
           [](const PyKnnIndex& r) { return r.with([](const auto& x) { return x.num_segments(); }); });

  // ---- registration
  nb::enum_<Dof> dof(m, "Dof", doc("Dof"));
  PERCH2_ENUM(dof, Dof, Six);
  PERCH2_ENUM(dof, Dof, TableXYYaw);
  nb::enum_<SourceCovariance> sc(m, "SourceCovariance", doc("SourceCovariance"));
  PERCH2_ENUM(sc, SourceCovariance, FromKnn);
  PERCH2_ENUM(sc, SourceCovariance, FromPixelNeighbourhood);

  nb::class_<LmSettings> lm(m, "LmSettings", doc("LmSettings"));
  lm.def(nb::init<>());
  PERCH2_RW(lm, LmSettings, lambda_initial);
  PERCH2_RW(lm, LmSettings, lambda_up);
  PERCH2_RW(lm, LmSettings, lambda_down);
  PERCH2_RW(lm, LmSettings, lambda_min);
  PERCH2_RW(lm, LmSettings, lambda_max);
  PERCH2_RW(lm, LmSettings, diagonal_floor);

  nb::class_<IcpSettings> icp(m, "IcpSettings", doc("IcpSettings"));
  icp.def(nb::init<>());
  PERCH2_RW(icp, IcpSettings, max_iterations);
  PERCH2_RW(icp, IcpSettings, max_correspondence_distance_m);
  PERCH2_RW(icp, IcpSettings, translation_epsilon_m);
  PERCH2_RW(icp, IcpSettings, rotation_epsilon_rad);
  PERCH2_RW(icp, IcpSettings, min_inliers);
  PERCH2_RW(icp, IcpSettings, dof);
  PERCH2_VEC3(icp, IcpSettings, up_cam);
  PERCH2_VEC3(icp, IcpSettings, origin_cam);
  PERCH2_RW(icp, IcpSettings, lm);

  nb::class_<GicpSettings> gicp(m, "GicpSettings", doc("GicpSettings"));
  gicp.def(nb::init<>());
  PERCH2_RW(gicp, GicpSettings, k_neighbors);
  PERCH2_RW(gicp, GicpSettings, covariance_epsilon);
  PERCH2_RW(gicp, GicpSettings, source_covariance);
  PERCH2_RW(gicp, GicpSettings, image_width_px);
  PERCH2_RW(gicp, GicpSettings, pixel_radius_px);
  PERCH2_RW(gicp, GicpSettings, pixel_neighbour_max_distance_m);
  PERCH2_RW(gicp, GicpSettings, max_iterations);
  PERCH2_RW(gicp, GicpSettings, max_correspondence_distance_m);
  PERCH2_RW(gicp, GicpSettings, translation_epsilon_m);
  PERCH2_RW(gicp, GicpSettings, rotation_epsilon_rad);
  PERCH2_RW(gicp, GicpSettings, min_inliers);
  PERCH2_RW(gicp, GicpSettings, dof);
  PERCH2_VEC3(gicp, GicpSettings, up_cam);
  PERCH2_VEC3(gicp, GicpSettings, origin_cam);
  PERCH2_RW(gicp, GicpSettings, lm);
  PERCH2_RW(gicp, GicpSettings, icp_warmup_iterations);

  nb::class_<RegistrationResult>(m, "RegistrationResult", doc("RegistrationResult"))
      .def_prop_ro(
          "T_corr", [](const RegistrationResult& r) { return poses_array(r.T_corr); }, nb::rv_policy::move,
          (std::string(doc("RegistrationResult.T_corr")) + "\n(n, 4, 4) float32, a new array.").c_str())
      .def_prop_ro(
          "iterations",
          [](nb::handle s) {
            auto& r = nb::cast<RegistrationResult&>(s);
            return view(r.iterations.data(), {r.iterations.size()}, s);
          },
          doc("RegistrationResult.iterations"))
      .def_prop_ro(
          "inliers",
          [](nb::handle s) {
            auto& r = nb::cast<RegistrationResult&>(s);
            return view(r.inliers.data(), {r.inliers.size()}, s);
          },
          doc("RegistrationResult.inliers"))
      .def_prop_ro(
          "final_error",
          [](nb::handle s) {
            auto& r = nb::cast<RegistrationResult&>(s);
            return view(r.final_error.data(), {r.final_error.size()}, s);
          },
          doc("RegistrationResult.final_error"))
      .def_prop_ro(
          "converged",
          [](nb::handle s) {
            auto& r = nb::cast<RegistrationResult&>(s);
            return view(r.converged.data(), {r.converged.size()}, s);
          },
          doc("RegistrationResult.converged"))
      .def("__len__", &RegistrationResult::size);

  nb::class_<PyRegistration>(m, "Registration",
                             with_backend("file:perch2/registration/registration.hpp").c_str())
      .def(
          "__init__",
          [](PyRegistration* self, const CloudBatch& targets, const std::string& backend) {
            const BackendId id = parse_backend(backend);
            nb::gil_scoped_release release;
            new (self) PyRegistration(backend_name(id), targets);
          },
          nb::arg("targets"), nb::arg("backend") = "thrust_omp", doc("Registration.Registration"))
      .def(
          "icp",
          [](const PyRegistration& x, const CloudBatch& sources, nb::handle source_segment,
             const IcpSettings& s) {
            const auto seg = per_cloud(source_segment, "source_segment", sources.num_clouds(), 0);
            return x.call([&](const auto& reg) { return reg.icp(sources, seg, s); });
          },
          nb::arg("sources"), nb::arg("source_segment").none() = nb::none(),
          nb::arg("settings") = IcpSettings{},
          (std::string(doc("Registration.icp")) +
           " source_segment: an int for all clouds or one per cloud (default 0).")
              .c_str())
      .def(
          "gicp",
          [](const PyRegistration& x, const CloudBatch& sources, nb::handle source_segment,
             const GicpSettings& s) {
            const auto seg = per_cloud(source_segment, "source_segment", sources.num_clouds(), 0);
            return x.call([&](const auto& reg) { return reg.gicp(sources, seg, s); });
          },
          nb::arg("sources"), nb::arg("source_segment").none() = nb::none(),
          nb::arg("settings") = GicpSettings{},
          (std::string(doc("Registration.gicp")) +
           " source_segment: an int for all clouds or one per cloud (default 0).")
              .c_str())
      .def_prop_ro("backend", [](const PyRegistration& r) { return backend_name(r.backend); });

  // ---- cost
  nb::enum_<ColorRule> cr(m, "ColorRule", doc("ColorRule"));
  PERCH2_ENUM(cr, ColorRule, AnyNeighbour);
  PERCH2_ENUM(cr, ColorRule, Nearest);
  nb::enum_<Normalization> nz(m, "Normalization", doc("Normalization"));
  PERCH2_ENUM(nz, Normalization, Counts);
  PERCH2_ENUM(nz, Normalization, Fractions);

  nb::class_<CostSettings> cs(m, "CostSettings", doc("CostSettings"));
  cs.def(nb::init<>());
  PERCH2_RW(cs, CostSettings, delta_m);
  PERCH2_RW(cs, CostSettings, use_color);
  PERCH2_RW(cs, CostSettings, tau_c);
  PERCH2_RW(cs, CostSettings, lightness_factor);
  PERCH2_RW(cs, CostSettings, shading_invariant);
  PERCH2_RW(cs, CostSettings, color_rule);
  PERCH2_RW(cs, CostSettings, normalization);
  PERCH2_RW(cs, CostSettings, weight_rendered);
  PERCH2_RW(cs, CostSettings, weight_observed);

  nb::class_<Footprint> fp(m, "Footprint", doc("Footprint"));
  fp.def(nb::init<>());
  PERCH2_RW(fp, Footprint, polygon_xy_m);
  PERCH2_RW(fp, Footprint, z_min_m);
  PERCH2_RW(fp, Footprint, z_max_m);
  m.def(
      "table_footprint",
      [](const Mesh& model, nb::handle T_place_obj, float z_floor_m) {
        return table_footprint(model, pose_from(T_place_obj, "T_place_obj"), z_floor_m);
      },
      nb::arg("model"), nb::arg("T_place_obj"), nb::arg("z_floor_m"), doc("table_footprint"));

  nb::class_<CostRequest> rq(m, "CostRequest", doc("CostRequest"));
  rq.def(nb::init<>())
      .def(
          "add",
          [](CostRequest& r, std::int32_t segment, std::int32_t footprint, nb::handle T) {
            r.add(segment, footprint, T.is_none() ? Pose::Identity() : pose_from(T, "T_cam_volume"));
          },
          nb::arg("segment"), nb::arg("footprint") = -1, nb::arg("T_cam_volume").none() = nb::none(),
          doc("CostRequest.add"))
      .def_prop_ro(
          "T_cam_volume", [](const CostRequest& r) { return poses_array(r.T_cam_volume); },
          nb::rv_policy::move,
          (std::string(doc("CostRequest.T_cam_volume")) + " ((n, 4, 4), a new array; set through add())")
              .c_str())
      .def("__len__", &CostRequest::size);
  PERCH2_RW(rq, CostRequest, footprints);
  PERCH2_RW(rq, CostRequest, observed_segment);
  PERCH2_RW(rq, CostRequest, footprint);

  nb::class_<CostBreakdown> cb(m, "CostBreakdown", doc("CostBreakdown"));
  cb.def(nb::init<>());
  PERCH2_RO(cb, CostBreakdown, rendered_points);
  PERCH2_RO(cb, CostBreakdown, rendered_inliers);
  PERCH2_RO(cb, CostBreakdown, rendered_depth_outliers);
  PERCH2_RO(cb, CostBreakdown, rendered_color_outliers);
  PERCH2_RO(cb, CostBreakdown, observed_in_volume);
  PERCH2_RO(cb, CostBreakdown, observed_depth_outliers);
  PERCH2_RO(cb, CostBreakdown, observed_color_outliers);
  PERCH2_RO(cb, CostBreakdown, J_r);
  PERCH2_RO(cb, CostBreakdown, J_o);
  PERCH2_RO(cb, CostBreakdown, total);
  cb.def("observed_unexplained", &CostBreakdown::observed_unexplained)
      .def("rendered_outliers", &CostBreakdown::rendered_outliers)
      .def("__repr__", [](const CostBreakdown& b) {
        return "CostBreakdown(total=" + std::to_string(b.total) + ", J_r=" + std::to_string(b.J_r) +
               ", J_o=" + std::to_string(b.J_o) + ", rendered_points=" + std::to_string(b.rendered_points) +
               ", observed_in_volume=" + std::to_string(b.observed_in_volume) + ")";
      });

  nb::class_<PyCost>(m, "Cost", with_backend("file:perch2/cost/cost.hpp").c_str())
      .def(
          "__init__",
          [](PyCost* self, const CloudBatch& observed, const std::string& backend) {
            const BackendId id = parse_backend(backend);
            nb::gil_scoped_release release;
            new (self) PyCost(backend_name(id), observed);
          },
          nb::arg("observed"), nb::arg("backend") = "thrust_omp",
          "Keeps the observed segments (camera frame, metres, rgb) and builds their search structures.")
      .def(
          "evaluate",
          [](const PyCost& x, const CloudBatch& rendered, std::optional<CostRequest> request,
             const CostSettings& s) {
            CostRequest r;
            if (request) {
              r = std::move(*request);
            } else {
              for (std::size_t h = 0; h < rendered.num_clouds(); ++h) r.add(0);  // whole segment 0
            }
            return x.call([&](const auto& cost) { return cost.evaluate(rendered, r, s).hypotheses; });
          },
          nb::arg("rendered"), nb::arg("request").none() = nb::none(), nb::arg("settings") = CostSettings{},
          "Scores every rendered cloud (one per hypothesis); request None: every hypothesis against the "
          "whole\n"
          "observed segment 0. Returns one CostBreakdown per hypothesis.")
      .def_prop_ro("backend", [](const PyCost& r) { return backend_name(r.backend); })
      .def("num_segments",
           [](const PyCost& r) { return r.with([](const auto& x) { return x.num_segments(); }); });
}

}  // namespace perch2_py
