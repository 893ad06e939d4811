// Tracking latency and accuracy on generated sequences: a hand-held camera circling a table of 4-7 objects
// (synth::camera_path), tracked from a start by perch2's own search (--init search, --masks none with the
// objects given) or from the ground truth (--init gt). Prints per sequence ADD-S / ADD(-S) < 2 cm over
// all frames, frames lost, losses and recoveries (and the frames each took), the recovery's searches, and
// the median and 95th percentile of the update's wall time. The frames are rendered first and fed at
// --fps (30; 0: as fast as the tracker goes), so a background search spans the frames it would in a
// camera's stream.
//
//   bench_track [--sequences N] [--frames N] [--seed S] [--init gt|search] [--backend cpu|thrust_omp]
//               [--objects N] [--fps F] [--foreground] [--reference N] [--verbose]
// --reference N: after each sequence, the single-frame search (SixDofEstimator::estimate_scene, --masks none
// with the objects given) on every N-th of its frames, for the latency table against it.
#include <omp.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "bench_support.hpp"
#include "perch2/cpu/backend.hpp"
#include "perch2/cpu/estimators.hpp"
#include "perch2/cuda/backend.hpp"
#include "perch2/cuda/estimators.hpp"
#include "perch2/io/image_io.hpp"
#include "perch2/search/sixdof.hpp"
#include "perch2/synth/synth.hpp"
#include "perch2/track/tracker.hpp"

using namespace perch2;

namespace {

struct Options {
  int sequences = 2, frames = 90, objects = 5;
  double fps = 30;
  int reference = 0;  ///< the single-frame search on every reference-th frame (0: not run)
  std::uint64_t seed = 1;
  std::string init = "gt", backend = "thrust_omp", dump;
  bool verbose = false, restart = false;
  TrackSettings track;
  synth::VideoSettings video;
};

/// ADD (or ADD-S for a symmetric model) over the mesh's vertices, metres.
double add_or_adds(const Pose& est, const Pose& gt, const synth::ObjectModel& m) {
  const bool symmetric = !m.symmetries.discrete.empty() || !m.symmetries.continuous.empty();
  const std::size_t n = m.mesh.vertices.size(), step = std::max<std::size_t>(1, n / 400);
  double sum = 0;
  std::size_t count = 0;
  for (std::size_t i = 0; i < n; i += step, ++count) {  // every step-th vertex (ADD-S: to all of them)
    const Eigen::Vector3f e = est * m.mesh.vertices[i];
    float best = (e - gt * m.mesh.vertices[i]).squaredNorm();
    if (symmetric)
      for (const auto& q : m.mesh.vertices) best = std::min(best, (e - gt * q).squaredNorm());
    sum += std::sqrt(double(best));
  }
  return sum / double(count);
}

/// The scene's objects as the search takes them: copies of a model are one object with a count.
std::vector<SixDofObject> search_objects(const synth::Scene& scene) {
  std::map<int, int> count;
  for (const auto& ob : scene.objects) ++count[ob.model];
  std::vector<SixDofObject> out;
  for (const auto& [model, n] : count) out.push_back({model, n});
  return out;
}

double median_or_0(const std::vector<double>& v) {
  return v.empty() ? 0 : bench::median(v);
}

double percentile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[std::min(v.size() - 1, std::size_t(q * double(v.size())))];
}

template <class Backend>
void run(const Options& o) {
  const auto all = synth::builtin_models();
  std::vector<SixDofModel> models;
  for (const auto& m : all)
    models.push_back({m.mesh, ModelSymmetries::from(m.symmetries.discrete, m.symmetries.continuous)});
  Tracker<Backend> tracker(models, o.track);
  std::unique_ptr<SixDofEstimator<Backend>> estimator;
  if (o.init == "search" || o.reference > 0) estimator = std::make_unique<SixDofEstimator<Backend>>(models);
  std::vector<double> reference_times;
  int reference_poses = 0, reference_within = 0;
  std::vector<double> all_times;
  int all_frames = 0, all_within = 0, all_adds = 0, confident_wrong = 0, lost_frames = 0;
  int losses = 0, recoveries = 0, searches = 0;
  std::vector<double> frames_to_recover;
  for (int seq = 0; seq < o.sequences; ++seq) {
    synth::Rng rng = synth::Rng::stream(o.seed, std::uint64_t(seq));
    synth::SceneSettings ss;
    ss.mode = synth::Mode::SixDof;
    ss.min_objects = ss.max_objects = o.objects;
    ss.min_distractors = 1, ss.max_distractors = 3;
    const synth::Scene scene = synth::compose_scene(all, ss, rng);
    const synth::SceneRenderer renderer(all, scene);
    synth::VideoSettings video = o.video;
    video.frames = o.frames;
    const std::vector<Pose> path = synth::camera_path(ss, video, rng);
    synth::SensorSettings sensor;
    std::vector<RgbdFrame> stream;
    for (int f = 0; f < o.frames; ++f) {
      const synth::Frame fr = renderer.render(path[std::size_t(f)], sensor, rng);
      stream.push_back({fr.camera, fr.depth_m, fr.rgb});
    }
    std::vector<double> times;
    std::vector<int> lost_since(scene.objects.size(), -1);
    int within = 0, adds_ok = 0, frames = 0;
    auto due = std::chrono::steady_clock::now();
    for (int f = 0; f < o.frames; ++f) {
      if (o.fps > 0) {  // the next frame arrives 1 / fps after the last one, or now if the tracker is late
        std::this_thread::sleep_until(due);
        due = std::max(due, std::chrono::steady_clock::now() - std::chrono::milliseconds(1)) +
              std::chrono::microseconds(std::int64_t(1e6 / o.fps));
      }
      const RgbdFrame& frame = stream[std::size_t(f)];
      std::vector<Pose> gt;
      for (const auto& ob : scene.objects) gt.push_back(path[std::size_t(f)].inverse() * ob.T_world_obj);
      TrackResult r;
      if (f == 0 || o.restart) {
        std::vector<TrackStart> starts;
        if (o.init == "gt") {
          for (std::size_t k = 0; k < scene.objects.size(); ++k)
            starts.push_back({scene.objects[k].model, gt[k]});
        } else {
          const std::vector<SixDofObject> objects = search_objects(scene);
          const double t0 = omp_get_wtime();
          const SixDofSceneResult sr = estimator->estimate_scene(frame, objects);
          std::printf("  sequence %d: start search %.2f s, %zu poses\n", seq, omp_get_wtime() - t0,
                      sr.poses.size());
          starts = track_starts(sr);
        }
        r = tracker.start(frame, starts);
      } else {
        r = tracker.update(frame);
        times.push_back(r.timings.total);
        searches += int(r.searched.size());
      }
      for (const TrackedObject& t : r.objects) {
        int& since = lost_since[std::size_t(t.object)];
        if (t.state == TrackState::Lost && since < 0) since = f, ++losses;
        if (t.state == TrackState::Recovered) {  // lost and found in one frame: a loss of 0 frames
          if (since < 0) since = f, ++losses;
          ++recoveries, frames_to_recover.push_back(f - since), since = -1;
        }
      }
      // Each tracked object against its nearest ground-truth instance of the same model.
      for (const TrackedObject& t : r.objects) {
        double best = 1e9, dt = 0;
        for (std::size_t k = 0; k < gt.size(); ++k)
          if (scene.objects[k].model == t.model) {
            const double e = add_or_adds(t.T_cam_obj, gt[k], all[std::size_t(t.model)]);
            if (e < best) best = e, dt = (t.T_cam_obj.translation() - gt[k].translation()).norm();
          }
        ++frames;
        const bool ok = best < 0.02;
        within += ok && t.state != TrackState::Lost;
        lost_frames += t.state == TrackState::Lost;
        confident_wrong += t.state != TrackState::Lost && best > 0.05;
        adds_ok += ok;
        if (o.verbose)
          std::printf(
              "    f%03d obj %d (%s) %-9s err %6.1f mm dt %5.1f score %.2f vis %.2f seg %d r %d/%d/%d o "
              "%d/%d/%d\n",
              f, t.object, all[std::size_t(t.model)].name.c_str(), to_string(t.state), best * 1e3, dt * 1e3,
              t.score, t.visible_fraction, t.segment_points, t.cost.rendered_points,
              t.cost.rendered_depth_outliers, t.cost.rendered_color_outliers, t.cost.observed_in_volume,
              t.cost.observed_depth_outliers, t.cost.observed_color_outliers);
      }
      if (!o.dump.empty() && f < 8) {  // the tracked poses' surface samples (red) and the truth's (green)
        ColorImage img = frame.rgb;
        for (const TrackedObject& t : r.objects)
          for (const auto& [T, colour] : {std::pair{t.T_cam_obj, Rgb8{255, 0, 0}},
                                          std::pair{gt[std::size_t(t.object)], Rgb8{0, 255, 0}}})
            for (const auto& p : synth::sample_surface(all[std::size_t(t.model)].mesh, 0.01f)) {
              const Eigen::Vector3f q = T * p;
              const Vec2f uv = frame.camera.project({q.x(), q.y(), q.z()});
              const int u = int(std::lround(uv.x)), v = int(std::lround(uv.y));
              if (u >= 0 && v >= 0 && u < img.width && v < img.height) img(u, v) = colour;
            }
        io::save_color_image(o.dump + "/f" + std::to_string(f) + ".png", img);
      }
      if (o.verbose)
        std::printf("    f%03d %.1f ms (render %.1f region %.1f refine %.1f check %.1f)\n", f,
                    r.timings.total * 1e3, r.timings.render * 1e3, r.timings.region * 1e3,
                    r.timings.refine * 1e3, r.timings.check * 1e3);
    }
    std::printf(
        "  sequence %d: %zu objects, %d object-frames, within 2 cm and tracked %.1f %%, median %.1f ms, "
        "p95 %.1f ms\n",
        seq, scene.objects.size(), frames, 100.0 * within / std::max(frames, 1), median_or_0(times) * 1e3,
        percentile(times, 0.95) * 1e3);
    for (int f = 0; o.reference > 0 && f < o.frames; f += o.reference) {  // the single-frame search
      const std::vector<SixDofObject> objects = search_objects(scene);
      const double t0 = omp_get_wtime();
      const SixDofSceneResult sr = estimator->estimate_scene(stream[std::size_t(f)], objects);
      reference_times.push_back(omp_get_wtime() - t0);
      for (std::size_t k = 0; k < scene.objects.size(); ++k) {
        const Pose gt = path[std::size_t(f)].inverse() * scene.objects[k].T_world_obj;
        double best = 1e9;
        for (const SixDofPose& p : sr.poses)
          if (p.found && p.model == scene.objects[k].model)
            best = std::min(best, add_or_adds(p.T_cam_obj, gt, all[std::size_t(p.model)]));
        ++reference_poses, reference_within += best < 0.02;
      }
    }
    all_times.insert(all_times.end(), times.begin(), times.end());
    all_frames += frames, all_within += within, all_adds += adds_ok;
  }
  std::printf(
      "%s, %s: %d object-frames: tracked within 2 cm %.1f %%, any state within 2 cm %.1f %%, lost %d, "
      "confident > 5 cm %d; losses %d, recoveries %d (frames to recover median %.0f, max %.0f), searches "
      "%d; update median %.1f ms, p95 %.1f ms at %.0f fps (%s, %d threads)\n",
      Backend::name, o.init.c_str(), all_frames, 100.0 * all_within / std::max(all_frames, 1),
      100.0 * all_adds / std::max(all_frames, 1), lost_frames, confident_wrong, losses, recoveries,
      median_or_0(frames_to_recover), percentile(frames_to_recover, 1.0), searches,
      median_or_0(all_times) * 1e3, percentile(all_times, 0.95) * 1e3, o.fps, bench::cpu_model().c_str(),
      omp_get_max_threads());
  if (o.reference > 0) {
    std::printf("\n| per frame, %d objects | median | p95 | object-frames within 2 cm |\n|---|---|---|---|\n",
                o.objects);
    std::printf("| tracker update (perch2::Tracker) | %.1f ms | %.1f ms | %.1f %% (tracked) |\n",
                median_or_0(all_times) * 1e3, percentile(all_times, 0.95) * 1e3,
                100.0 * all_within / std::max(all_frames, 1));
    std::printf("| single-frame search (estimate_scene, every %d-th frame) | %.0f ms | %.0f ms | %.1f %% |\n",
                o.reference, median_or_0(reference_times) * 1e3, percentile(reference_times, 0.95) * 1e3,
                100.0 * reference_within / std::max(reference_poses, 1));
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--sequences")
      o.sequences = std::stoi(next());
    else if (a == "--frames")
      o.frames = std::stoi(next());
    else if (a == "--objects")
      o.objects = std::stoi(next());
    else if (a == "--seed")
      o.seed = std::stoull(next());
    else if (a == "--init")
      o.init = next();
    else if (a == "--backend")
      o.backend = next();
    else if (a == "--fps")
      o.fps = std::stod(next());
    else if (a == "--search-viewpoints")
      o.track.recovery.search.proposals.viewpoints = std::stoi(next());
    else if (a == "--search-depths")
      o.track.recovery.search.proposals.max_depths = std::stoi(next());
    else if (a == "--search-inplane")
      o.track.recovery.search.proposals.inplane_rotations = std::stoi(next());
    else if (a == "--reference")
      o.reference = std::stoi(next());
    else if (a == "--foreground")
      o.track.recovery.background = false;
    else if (a == "--verbose")
      o.verbose = true;
    else if (a == "--dump")
      o.dump = next();
    else if (a == "--restart")
      o.restart = true;  // every frame from the start (refinement alone)
    // tuning: --round R.margin|gate|cap|warmup|iterations V, --velocity F, --min-score S
    else if (a == "--round") {
      const std::string key = next(), value = next();
      const std::size_t r = std::size_t(std::stoi(key.substr(0, key.find('.'))));
      if (o.track.rounds.size() <= r) o.track.rounds.resize(r + 1);
      TrackRound& round = o.track.rounds[r];
      const std::string field = key.substr(key.find('.') + 1);
      if (field == "margin")
        round.margin_px = std::stoi(value);
      else if (field == "gate")
        round.depth_gate_m = std::stof(value);
      else if (field == "cap")
        round.gicp.max_correspondence_distance_m = std::stof(value);
      else if (field == "warmup")
        round.gicp.icp_warmup_iterations = std::stoi(value);
      else if (field == "iterations")
        round.gicp.max_iterations = std::stoi(value);
      else if (field == "drop")
        o.track.rounds.erase(o.track.rounds.begin() + std::ptrdiff_t(r));
    } else if (a == "--velocity")
      o.track.velocity_factor = std::stof(next());
    else if (a == "--speed")
      o.video.degrees_per_frame = std::stof(next());
    else if (a == "--shake")
      o.video.shake_m = std::stof(next()), o.video.shake_rad = 2 * o.video.shake_m;
    else if (a == "--render-stride")
      o.track.render_stride = std::stoi(next());
    else if (a == "--observed-stride")
      o.track.observed_stride = std::stoi(next());
    else if (a == "--hold-stride")
      o.track.turn_hold.stride = std::stoi(next());
    else if (a == "--hold-levels")
      o.track.turn_hold.levels = std::stoi(next());
    else if (a == "--hold-step")
      o.track.turn_hold.step_rad = std::stof(next());
    else if (a == "--hold-gain")
      o.track.turn_hold.min_gain = std::stof(next());
    else if (a == "--min-score")
      o.track.min_score = std::stof(next());
    else {
      std::fprintf(stderr, "unknown option %s\n", a.c_str());
      return 2;
    }
  }
  try {
    if (o.backend == "cpu")
      run<cpu::Backend>(o);
    else
      run<thrust_omp::Backend>(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_track: %s\n", e.what());
    return 1;
  }
  return 0;
}
