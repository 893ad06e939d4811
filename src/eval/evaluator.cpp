#include "perch2/eval/evaluator.hpp"

#include <algorithm>
#include <cmath>
#include <exception>
#include <limits>
#include <memory>
#include <numeric>

#include "detection.hpp"
#include "perch2/cpu/render.hpp"
#include "perch2/eval/metrics.hpp"

namespace perch2::eval {

using dataset::BopDataset;
using dataset::PoseEstimate;
using dataset::TargetTask;

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

struct ObjectData {
  dataset::ModelInfo info;
  std::unique_ptr<ModelPoints> points;
  std::vector<Pose> symmetries;
  int render_index = 0;
};

/// Errors of every kept estimate (rows, by decreasing score) against every valid GT instance (columns).
struct ErrorTable {
  std::size_t E = 0, G = 0;
  std::vector<double> add, adds, mssd, mspd;  // E x G
  std::vector<double> vsd;                    // E x G x taus
  double at(const std::vector<double>& m, std::size_t e, std::size_t g) const { return m[e * G + g]; }
};

/// True-positive counters of one metric: one per threshold (VSD: per tau x threshold).
struct Recalls {
  std::vector<long> tp;
  double average(int targets) const {
    if (targets == 0 || tp.empty()) return 0;
    double sum = 0;
    for (long t : tp) sum += double(t) / targets;
    return sum / double(tp.size());
  }
};

struct Accumulator {
  int targets = 0;
  std::vector<double> add, adds, add_or_adds;
  Recalls vsd, mssd, mspd;
  void init(const EvalSettings& s) {
    vsd.tp.assign(s.vsd_taus.size() * s.vsd_thresholds.size(), 0);
    mssd.tp.assign(s.mssd_thresholds.size(), 0);
    mspd.tp.assign(s.mspd_thresholds_px.size(), 0);
  }
  Scores scores(const EvalSettings& s, double max_m) const {
    Scores out;
    out.num_targets = targets;
    out.auc_add = auc_ycb(add, max_m);
    out.auc_adds = auc_ycb(adds, max_m);
    out.auc_add_or_adds = auc_ycb(add_or_adds, max_m);
    if (!adds.empty()) {
      out.adds_below_1cm =
          double(std::count_if(adds.begin(), adds.end(), [](double e) { return e < 0.01; })) / adds.size();
      out.adds_below_2cm =
          double(std::count_if(adds.begin(), adds.end(), [](double e) { return e < 0.02; })) / adds.size();
    }
    out.ar_vsd = vsd.average(targets);
    out.ar_mssd = mssd.average(targets);
    out.ar_mspd = mspd.average(targets);
    out.ar = s.compute_vsd ? (out.ar_vsd + out.ar_mssd + out.ar_mspd) / 3 : (out.ar_mssd + out.ar_mspd) / 2;
    return out;
  }
};

void validate(const EvalSettings& s) {
  auto positive = [](const std::vector<double>& v, const char* name) {
    if (v.empty()) throw InvalidInput(std::string("EvalSettings::") + name, "must not be empty");
    for (double x : v)
      if (!(x > 0) || !std::isfinite(x))
        throw InvalidInput(std::string("EvalSettings::") + name, "values must be > 0");
  };
  positive(s.vsd_taus, "vsd_taus");
  positive(s.vsd_thresholds, "vsd_thresholds");
  positive(s.mssd_thresholds, "mssd_thresholds");
  positive(s.mspd_thresholds_px, "mspd_thresholds_px");
  if (!(s.auc_max_m > 0)) throw InvalidInput("EvalSettings::auc_max_m", "must be > 0");
  if (!(s.vsd_delta_m >= 0)) throw InvalidInput("EvalSettings::vsd_delta_m", "must be >= 0");
  if (!(s.max_sym_disc_step > 0)) throw InvalidInput("EvalSettings::max_sym_disc_step", "must be > 0");
  positive(s.mssd_thresholds_m, "mssd_thresholds_m");
  if (s.max_estimates_per_image < 1)
    throw InvalidInput("EvalSettings::max_estimates_per_image", "must be >= 1");
  if (!(s.visib_gt_min >= 0 && s.visib_gt_min <= 1))
    throw InvalidInput("EvalSettings::visib_gt_min", "must be in [0, 1]");
}

/// Mean time per image as bop_toolkit eval_bop19_pose.py: one time per image (rows of an image must agree
/// to the tolerance), -1 if any row has a negative time.
void check_times(const std::vector<PoseEstimate>& ests, double tol, const std::string& source,
                 EvalReport& rep) {
  std::map<std::pair<int, int>, double> times;
  bool all = true;
  for (const auto& e : ests) {
    if (e.time_s < 0) all = false;
    const auto [it, fresh] = times.emplace(std::make_pair(e.scene_id, e.im_id), e.time_s);
    if (!fresh && std::abs(it->second - e.time_s) > tol)
      throw FileError(source + ":" + std::to_string(e.line),
                      "time " + std::to_string(e.time_s) + " s differs from " + std::to_string(it->second) +
                          " s on an earlier row of scene " + std::to_string(e.scene_id) + " image " +
                          std::to_string(e.im_id) + " (time is per image: the same on each of its rows)");
  }
  rep.num_images_timed = int(times.size());
  if (all && !times.empty()) {
    double sum = 0;
    for (const auto& t : times) sum += t.second;
    rep.mean_time_per_image_s = sum / double(times.size());
  }
}

/// The rendered model of cloud c as a sparse distance image (renderer output is in raster order).
SparseDistance to_sparse(const CloudBatch& b, std::size_t c, const Intrinsics& K) {
  SparseDistance s;
  for (auto i = b.offsets[c]; i < b.offsets[c + 1]; ++i) {
    const std::int32_t p = b.pixel[std::size_t(i)];
    s.pixel.push_back(p);
    s.dist_m.push_back(depth_to_distance(K, p % K.width, p / K.width, b.z[std::size_t(i)]));
  }
  return s;
}

/// Everything an image's evaluation reads (shared, read-only, by every thread).
struct Context {
  const BopDataset& data;
  const std::vector<PoseEstimate>& estimates;
  const EvalSettings& settings;
  const std::map<std::pair<int, int>, std::map<int, std::vector<std::size_t>>>& grouped;
  const std::map<int, ObjectData>& objects;
  const cpu::Renderer* renderer;  // null: no VSD
  // Detection (bop24 targets) only: every estimate of each image (file order) and the models to score them.
  const std::map<std::pair<int, int>, std::vector<std::size_t>>* rows_by_image;
  const std::map<int, detail::ScoringModel>* scoring;
};

/// True positives of one object in one image, per threshold (VSD: per tau x threshold).
struct ObjectTp {
  std::vector<long> vsd, mssd, mspd;
};

struct ImageOutcome {
  std::vector<InstanceResult> instances;
  std::map<int, ObjectTp> tp;
  int evaluated = 0, beyond_top_k = 0;
  detail::DetectionImage detection;
};

/// Valid GT of an image: the inst_count most visible instances of each target object (stable on ties), as
/// eval_calc_scores.py with visib_gt_min = -1. Returns obj -> GT indices (ascending).
std::map<int, std::vector<std::size_t>> valid_instances(const dataset::ImageInfo& info,
                                                        const std::map<int, int>& im_targets) {
  std::vector<std::size_t> order(info.gt.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return info.gt[a].visib_fract > info.gt[b].visib_fract;
  });
  std::map<int, int> to_add = im_targets;
  std::map<int, std::vector<std::size_t>> valid;
  for (const std::size_t g : order) {
    auto it = to_add.find(info.gt[g].obj_id);
    if (it != to_add.end() && it->second > 0) valid[it->first].push_back(g), --it->second;
  }
  for (auto& [obj, gts] : valid) std::sort(gts.begin(), gts.end());
  return valid;
}

/// Errors of every kept estimate against every valid instance of one object in one image.
ErrorTable error_table(const Context& c, const ObjectData& od, const dataset::ImageInfo& info,
                       const std::vector<std::size_t>& ests, const std::vector<std::size_t>& gts,
                       const Intrinsics& K, const DepthImage& depth_test) {
  const std::size_t num_taus = c.settings.vsd_taus.size();
  ErrorTable t;
  t.E = ests.size(), t.G = gts.size();
  const std::size_t pairs = t.E * t.G;
  t.add.resize(pairs), t.adds.resize(pairs), t.mssd.resize(pairs), t.mspd.resize(pairs);
  t.vsd.assign(pairs * num_taus, 1.0);
  std::vector<SparseDistance> est_render, gt_render;
  if (c.renderer && pairs > 0) {
    std::vector<Hypothesis> h;
    for (const std::size_t e : ests) h.push_back({od.render_index, c.estimates[e].T_cam_obj});
    for (const std::size_t g : gts) h.push_back({od.render_index, info.gt[g].T_cam_obj});
    RenderSettings rs;
    rs.stride = 1;               // VSD compares full-resolution depth
    rs.cull_back_faces = false;  // like an OpenGL depth render of possibly open meshes
    const CloudBatch b = c.renderer->render(h, K, rs);
    for (std::size_t e = 0; e < t.E; ++e) est_render.push_back(to_sparse(b, e, K));
    for (std::size_t g = 0; g < t.G; ++g) gt_render.push_back(to_sparse(b, t.E + g, K));
  }
  const auto& pts = od.points->points();
  for (std::size_t p = 0; p < pairs; ++p) {
    const std::size_t e = p / t.G, g = p % t.G;
    const Pose& Te = c.estimates[ests[e]].T_cam_obj;
    const Pose& Tg = info.gt[gts[g]].T_cam_obj;
    t.add[p] = add_error(Te, Tg, pts);
    t.adds[p] = adds_error(Te, Tg, *od.points);
    // eval_calc_errors.py's shortcuts, kept so that the numbers match bop_toolkit's: MSSD = inf when the
    // bounding spheres do not overlap, VSD = 1 when their projections do not.
    const Eigen::Vector3d te = Te.translation().cast<double>(), tg = Tg.translation().cast<double>();
    const double diameter = od.info.diameter_m;
    t.mssd[p] = (te - tg).norm() < diameter ? mssd_error(Te, Tg, pts, od.symmetries) : kInf;
    t.mspd[p] = mspd_error(Te, Tg, K, pts, od.symmetries);
    if (c.renderer && sphere_projections_overlap(0.5 * diameter, te, tg)) {
      const auto v = vsd_errors(est_render[e], gt_render[g], depth_test, K, c.settings.vsd_delta_m,
                                c.settings.vsd_taus, od.info.diameter_m);
      std::copy(v.begin(), v.end(), t.vsd.begin() + std::ptrdiff_t(p * num_taus));
    }
  }
  return t;
}

/// Per-instance errors after the threshold-free matching (ADD family, MSSD, MSPD).
void instance_results(const Context& c, const ObjectData& od, const ErrorTable& t, std::pair<int, int> im_key,
                      int obj, const dataset::ImageInfo& info, const std::vector<std::size_t>& ests,
                      const std::vector<std::size_t>& gts, std::vector<InstanceResult>& out) {
  auto matched = [&](const std::vector<double>& m, std::vector<int>& est_of_gt) {
    est_of_gt =
        detail::match_greedy(t.E, t.G, kInf, [&](std::size_t e, std::size_t g) { return t.at(m, e, g); });
    std::vector<double> err(t.G, kInf);
    for (std::size_t g = 0; g < t.G; ++g)
      if (est_of_gt[g] >= 0) err[g] = t.at(m, std::size_t(est_of_gt[g]), g);
    return err;
  };
  std::vector<int> add_match, adds_match, unused;
  const auto add = matched(t.add, add_match), adds = matched(t.adds, adds_match);
  const auto mssd = matched(t.mssd, unused), mspd = matched(t.mspd, unused);
  for (std::size_t g = 0; g < t.G; ++g) {
    InstanceResult r;
    r.scene_id = im_key.first, r.im_id = im_key.second, r.obj_id = obj, r.gt_index = int(gts[g]);
    r.visib_fract = info.gt[gts[g]].visib_fract;
    r.add_m = add[g], r.adds_m = adds[g], r.add_or_adds_m = od.info.is_symmetric() ? adds[g] : add[g];
    r.mssd_m = mssd[g], r.mspd_px = mspd[g];
    r.add_line = add_match[g] >= 0 ? c.estimates[ests[std::size_t(add_match[g])]].line : 0;
    r.adds_line = adds_match[g] >= 0 ? c.estimates[ests[std::size_t(adds_match[g])]].line : 0;
    out.push_back(r);
  }
}

/// BOP true positives: one matching per threshold (pose_matching.match_poses with that threshold).
ObjectTp bop_true_positives(const EvalSettings& s, const ErrorTable& t, double diameter_m, double px_scale) {
  ObjectTp tp;
  auto count = [&](double threshold, auto error) {
    const auto est_of_gt = detail::match_greedy(t.E, t.G, threshold, error);
    return long(std::count_if(est_of_gt.begin(), est_of_gt.end(), [](int e) { return e >= 0; }));
  };
  for (const double th : s.mssd_thresholds)
    tp.mssd.push_back(
        count(th, [&](std::size_t e, std::size_t g) { return t.at(t.mssd, e, g) / diameter_m; }));
  for (const double th : s.mspd_thresholds_px)
    tp.mspd.push_back(count(th, [&](std::size_t e, std::size_t g) { return t.at(t.mspd, e, g) * px_scale; }));
  const std::size_t num_taus = s.vsd_taus.size();
  for (std::size_t k = 0; k < num_taus; ++k)
    for (const double th : s.vsd_thresholds)
      tp.vsd.push_back(
          count(th, [&](std::size_t e, std::size_t g) { return t.vsd[(e * t.G + g) * num_taus + k]; }));
  return tp;
}

ImageOutcome evaluate_image(const Context& c, std::pair<int, int> im_key,
                            const std::map<int, int>& im_targets) {
  ImageOutcome out;
  const auto& info = c.data.info(im_key.first, im_key.second);
  const auto valid = valid_instances(info, im_targets);

  // Kept estimates: the k best-scored per object (stable: file order on equal scores).
  std::map<int, std::vector<std::size_t>> kept;
  const auto group = c.grouped.find(im_key);
  if (group != c.grouped.end())
    for (const auto& [obj, idx] : group->second) {
      std::vector<std::size_t> sorted = idx;
      std::stable_sort(sorted.begin(), sorted.end(), [&](std::size_t a, std::size_t b) {
        return c.estimates[a].score > c.estimates[b].score;
      });
      const std::size_t k = std::size_t(im_targets.at(obj));
      if (sorted.size() > k) out.beyond_top_k += int(sorted.size() - k), sorted.resize(k);
      out.evaluated += int(sorted.size());
      kept[obj] = std::move(sorted);
    }

  Intrinsics K = info.camera;
  DepthImage depth_test;
  if (c.renderer && !kept.empty()) {
    dataset::ImageLoadOptions o;
    o.rgb = o.masks_visib = o.masks = false;
    dataset::BopImage image = c.data.load_image(im_key.first, im_key.second, o);
    K = image.frame.camera;
    depth_test = std::move(image.frame.depth_m);
  }
  if (K.width <= 0)
    throw FileError(c.data.split_path(), "image size of scene " + std::to_string(im_key.first) +
                                             " unknown (no camera.json and no readable depth/rgb PNG)");
  for (const auto& [obj, n_targets] : im_targets) {
    const auto vit = valid.find(obj);
    const std::vector<std::size_t> gts = vit == valid.end() ? std::vector<std::size_t>{} : vit->second;
    const auto kit = kept.find(obj);
    const std::vector<std::size_t> ests = kit == kept.end() ? std::vector<std::size_t>{} : kit->second;
    const ObjectData& od = c.objects.at(obj);
    const ErrorTable t = error_table(c, od, info, ests, gts, K, depth_test);
    instance_results(c, od, t, im_key, obj, info, ests, gts, out.instances);
    out.tp[obj] = bop_true_positives(c.settings, t, od.info.diameter_m, 640.0 / K.width);
  }
  if (c.rows_by_image) {
    const auto rows = c.rows_by_image->find(im_key);
    out.detection = detail::detection_image(
        c.estimates, rows == c.rows_by_image->end() ? std::vector<std::size_t>{} : rows->second, info,
        *c.scoring, K, c.settings);
  }
  return out;
}

void add_to(std::vector<long>& sum, const std::vector<long>& v) {
  for (std::size_t k = 0; k < v.size(); ++k) sum[k] += v[k];
}

}  // namespace

EvalReport evaluate(const BopDataset& data, const std::vector<PoseEstimate>& estimates,
                    const EvalSettings& settings, const std::string& source, const Progress& progress) {
  validate(settings);
  if (data.targets_path().empty())
    throw FileError(data.root(), "no targets file (test_targets_bop19.json or test_targets_bop24.json)");
  EvalReport rep;
  rep.num_estimates = int(estimates.size());
  rep.vsd_computed = settings.compute_vsd;
  for (const auto& e : estimates)
    if (!data.models_info().count(e.obj_id))
      throw FileError(
          source + ":" + std::to_string(e.line),
          "obj_id " + std::to_string(e.obj_id) + " is not in " + data.models_path() + "/models_info.json");
  check_times(estimates, settings.time_tolerance_s, source, rep);

  // Targets per image and object (detection targets name only images: every annotated instance of one is
  // a target); estimates grouped the same way.
  std::map<std::pair<int, int>, std::map<int, int>> targets;
  for (const auto& t : data.targets()) targets[{t.scene_id, t.im_id}][t.obj_id] += t.inst_count;
  if (data.target_task() == TargetTask::Detection)
    for (const auto& [scene, im] : data.target_images())
      if (data.has_image(scene, im))
        for (const auto& gt : data.info(scene, im).gt) ++targets[{scene, im}][gt.obj_id];
  std::map<std::pair<int, int>, std::map<int, std::vector<std::size_t>>> grouped;
  for (std::size_t k = 0; k < estimates.size(); ++k) {
    const auto& e = estimates[k];
    const auto im = targets.find({e.scene_id, e.im_id});
    if (im == targets.end() || !im->second.count(e.obj_id)) {
      ++rep.num_ignored_not_target;
      continue;
    }
    grouped[{e.scene_id, e.im_id}][e.obj_id].push_back(k);
  }

  // Models of every target object: points + kd-tree, symmetries, render index.
  std::map<int, ObjectData> objects;
  std::vector<Mesh> meshes;
  for (const auto& [im, objs] : targets)
    for (const auto& [obj, n] : objs) {
      if (objects.count(obj)) continue;
      ObjectData& od = objects[obj];
      od.info = data.model_info(obj);
      Mesh mesh = data.load_model(obj);
      od.points = std::make_unique<ModelPoints>(mesh.vertices);
      od.symmetries = symmetry_transformations(od.info, settings.max_sym_disc_step);
      od.render_index = int(meshes.size());
      meshes.push_back(std::move(mesh));
    }
  std::unique_ptr<cpu::Renderer> renderer;
  if (settings.compute_vsd && !meshes.empty()) renderer = std::make_unique<cpu::Renderer>(std::move(meshes));

  // Detection: every estimate of an image counts (up to max_estimates_per_image); those in target images
  // without annotations are of absent objects.
  const bool detection = data.target_task() == TargetTask::Detection;
  std::map<std::pair<int, int>, std::vector<std::size_t>> rows_by_image;
  std::map<int, detail::ScoringModel> scoring;
  if (detection) {
    for (std::size_t k = 0; k < estimates.size(); ++k)
      if (targets.count({estimates[k].scene_id, estimates[k].im_id}))
        rows_by_image[{estimates[k].scene_id, estimates[k].im_id}].push_back(k);
    for (const auto& [obj, od] : objects)
      scoring[obj] = {&od.points->points(), &od.symmetries, od.info.diameter_m};
  }

  // Images in parallel (each image's errors, renders and depth are its own); merged in order afterwards.
  const Context ctx{
      data,    estimates, settings, grouped, objects, renderer.get(), detection ? &rows_by_image : nullptr,
      &scoring};
  const std::vector<std::pair<std::pair<int, int>, std::map<int, int>>> work(targets.begin(), targets.end());
  std::vector<ImageOutcome> outcomes(work.size());
  std::vector<std::exception_ptr> errors(work.size());
  int done = 0;
#pragma omp parallel for schedule(dynamic, 1)
  for (std::int64_t i = 0; i < std::int64_t(work.size()); ++i) {
    try {
      outcomes[std::size_t(i)] = evaluate_image(ctx, work[std::size_t(i)].first, work[std::size_t(i)].second);
    } catch (...) {
      errors[std::size_t(i)] = std::current_exception();
    }
#pragma omp critical(perch2_eval_progress)
    if (progress) progress(++done, int(work.size()));
  }
  for (const auto& e : errors)
    if (e) std::rethrow_exception(e);

  Accumulator all;
  all.init(settings);
  std::map<int, Accumulator> per_object;
  for (const ImageOutcome& o : outcomes) {
    rep.num_estimates_evaluated += o.evaluated;
    rep.num_ignored_beyond_top_k += o.beyond_top_k;
    for (const InstanceResult& r : o.instances) {
      Accumulator& acc = per_object[r.obj_id];
      if (acc.mssd.tp.empty()) acc.init(settings);
      for (Accumulator* a : {&acc, &all}) {
        a->targets += 1;
        a->add.push_back(r.add_m), a->adds.push_back(r.adds_m), a->add_or_adds.push_back(r.add_or_adds_m);
      }
      rep.instances.push_back(r);
    }
    for (const auto& [obj, tp] : o.tp) {
      Accumulator& acc = per_object[obj];
      if (acc.mssd.tp.empty()) acc.init(settings);
      for (Accumulator* a : {&acc, &all}) {
        add_to(a->mssd.tp, tp.mssd), add_to(a->mspd.tp, tp.mspd);
        if (renderer) add_to(a->vsd.tp, tp.vsd);
      }
    }
  }

  for (const auto& [obj, acc] : per_object) rep.per_object[obj] = acc.scores(settings, settings.auc_max_m);
  rep.overall = all.scores(settings, settings.auc_max_m);
  if (detection) {
    std::vector<detail::DetectionImage> images;
    for (ImageOutcome& o : outcomes) images.push_back(std::move(o.detection));
    rep.detection = detail::detection_report(images, settings);
    rep.detection_computed = true;
  }
  return rep;
}

}  // namespace perch2::eval
