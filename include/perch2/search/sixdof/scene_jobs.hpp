// estimate_scene()'s jobs (no detector): which model is searched where. A model gets a job on every segment
// of a compatible size (SceneSettings: not smaller than min_area_fraction of its smallest face, not larger
// than max_area_faces of its largest), around the segment's box, or, if the segment is too wide or too
// large for one object (two touching, a distractor on top), around each of its model-sized pieces
// (segment_pieces: k-means on its readings); a model that takes whole a segment another model's rule cut also
// gets a job on each half of it (add_half_jobs). Colour screening drops the jobs whose readings show colours
// the model lacks (screen_colours), before anything is rendered; detect() then keeps on each segment only the
// models that fit it best (retrieval.hpp). Each job's GICP targets and J_o's points are its segment and
// the nearby small ones an occluder may have cut from it (group_segments, group_clouds), or its piece's
// own readings (with_pieces); JobTargets builds them once per set of jobs.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "perch2/core/observed.hpp"
#include "perch2/cost/cost.hpp"
#include "perch2/search/proposals.hpp"
#include "perch2/search/segmentation.hpp"
#include "perch2/search/sixdof/context.hpp"
#include "perch2/search/sixdof/first_pass.hpp"

namespace perch2 {
namespace sixdof_detail {

/// Segment `seg`'s pixels split into `pieces` parts by k-means on their camera-frame points (k-means++
/// seeding with a fixed seed, so results are deterministic); each part's pixels (full-resolution indices,
/// ascending; a part may be empty).
inline std::vector<std::vector<std::int32_t>> segment_pieces(const RgbdFrame& frame, const LabelImage& labels,
                                                             const FrameSegment& seg, int pieces) {
  const int w = frame.camera.width;
  std::vector<std::size_t> pix;
  std::vector<Eigen::Vector3f> pts;
  const Eigen::Vector4i& b = seg.box_xywh;
  for (int v = b[1]; v <= b[1] + b[3]; ++v)
    for (int u = b[0]; u <= b[0] + b[2]; ++u) {
      const std::size_t i = std::size_t(v) * std::size_t(w) + std::size_t(u);
      if (labels.data[i] != seg.label) continue;
      pix.push_back(i);
      pts.push_back(segmentation_detail::point_at(frame.camera, u, v, frame.depth_m.data[i]));
    }
  std::vector<std::vector<std::int32_t>> out;
  if (pieces <= 1 || pts.size() < std::size_t(pieces)) {
    out.emplace_back(pix.begin(), pix.end());
    return out;
  }
  std::mt19937 rng(7);
  std::vector<Eigen::Vector3f> centre{
      pts[std::uniform_int_distribution<std::size_t>(0, pts.size() - 1)(rng)]};
  std::vector<float> d2(pts.size(), INFINITY);
  while (int(centre.size()) < pieces) {  // k-means++: the next centre with probability ~ squared distance
    double total = 0;
    for (std::size_t i = 0; i < pts.size(); ++i)
      total += d2[i] = std::min(d2[i], (pts[i] - centre.back()).squaredNorm());
    double r = std::uniform_real_distribution<double>(0, total)(rng);
    std::size_t pick = 0;
    while (pick + 1 < pts.size() && (r -= d2[pick]) > 0) ++pick;
    centre.push_back(pts[pick]);
  }
  std::vector<int> owner(pts.size(), 0);
  for (int it = 0; it < 10; ++it) {
    std::vector<Eigen::Vector3f> sum(centre.size(), Eigen::Vector3f::Zero());
    std::vector<int> n(centre.size(), 0);
    for (std::size_t i = 0; i < pts.size(); ++i) {
      float best = INFINITY;
      for (std::size_t c = 0; c < centre.size(); ++c)
        if (const float d = (pts[i] - centre[c]).squaredNorm(); d < best) best = d, owner[i] = int(c);
      sum[std::size_t(owner[i])] += pts[i], ++n[std::size_t(owner[i])];
    }
    for (std::size_t c = 0; c < centre.size(); ++c)
      if (n[c] > 0) centre[c] = sum[c] / float(n[c]);
  }
  out.resize(centre.size());
  for (std::size_t i = 0; i < pix.size(); ++i) out[std::size_t(owner[i])].push_back(std::int32_t(pix[i]));
  return out;
}

/// A segment piece as the jobs on it need it: its pixels, box and valid depths.
struct SegmentPiece {
  std::vector<std::int32_t> pixels;  ///< full-resolution indices
  Eigen::Vector4i box_xywh{0, 0, 0, 0};
  std::vector<float> depths_m;  ///< its valid readings, ascending
  float area_m2 = 0;            ///< surface area its readings see, m^2 (as FrameSegment::area_m2)
};

/// The pieces of segment k cut in n parts, per (k, n): every model that cuts a segment alike shares them.
using PieceCache = std::map<std::pair<int, int>, std::vector<SegmentPiece>>;

/// Segment `seg` cut in `pieces` parts (segment_pieces), each with its box and sorted depths; empty parts
/// are left out.
inline std::vector<SegmentPiece> cut_segment(const RgbdFrame& frame, const LabelImage& labels,
                                             const FrameSegment& seg, int pieces) {
  std::vector<SegmentPiece> out;
  const int w = frame.camera.width;
  for (std::vector<std::int32_t>& pixels : segment_pieces(frame, labels, seg, pieces)) {
    if (pixels.empty()) continue;
    SegmentPiece p;
    int x0 = w, y0 = frame.camera.height, x1 = -1, y1 = -1;
    for (const std::int32_t i : pixels) {
      const int u = i % w, v = i / w;
      x0 = std::min(x0, u), x1 = std::max(x1, u), y0 = std::min(y0, v), y1 = std::max(y1, v);
      const float z = frame.depth_m.data[std::size_t(i)];
      if (z > 0 && std::isfinite(z)) {
        p.depths_m.push_back(z);
        p.area_m2 += z * z / (frame.camera.fx * frame.camera.fy);
      }
    }
    std::sort(p.depths_m.begin(), p.depths_m.end());
    p.box_xywh = {x0, y0, x1 - x0, y1 - y0};
    p.pixels = std::move(pixels);
    out.push_back(std::move(p));
  }
  return out;
}

/// Drops the jobs whose model lacks the colours of their readings (SceneSettings::min_colour_fraction):
/// up to colour_samples of each job's readings (its piece's, or its segment's), each matched if some
/// colour of the model is within tau_c (CIEDE2000, the cost's comparison colours).
template <class Backend>
void screen_colours(const Shared<Backend>& sh, const RgbdFrame& frame, const LabelImage& labels,
                    std::vector<Job>& jobs) {
  const SceneSettings& ss = sh.settings.scene;
  const CostSettings& c = sh.settings.cost;
  std::map<int, std::vector<Lab<float>>> palette;  // per model, its comparison colours
  // (model, reading's colour bin of 6 bits per channel, as model_colours()): matched
  std::map<std::pair<int, std::uint32_t>, bool> known;
  auto matched = [&](int model, std::uint32_t rgb) {
    const auto [it, fresh] = known.try_emplace({model, rgb & 0xfcfcfcu}, false);
    if (!fresh) return it->second;
    auto p = palette.find(model);
    if (p == palette.end()) {  // one colour per CIELAB cell of 2 units: ~1 unit from any model colour
      p = palette.emplace(model, std::vector<Lab<float>>{}).first;
      std::set<std::array<int, 3>> cells;
      for (const std::uint32_t m : sh.colours[std::size_t(model)]) {
        const Lab<float> lab = comparison_lab(m, c.shading_invariant);
        const std::array<int, 3> cell{int(std::floor(lab.L / 2)), int(std::floor(lab.a / 2)),
                                      int(std::floor(lab.b / 2))};
        if (cells.insert(cell).second) p->second.push_back(lab);
      }
    }
    const Lab<float> lab = comparison_lab(rgb, c.shading_invariant);
    for (const Lab<float>& m : p->second)
      if (ciede2000(lab, m, c.lightness_factor) <= c.tau_c) return it->second = true;
    return false;
  };
  std::map<std::int32_t, std::vector<std::int32_t>> pixels_of;  // segment label -> its pixels
  for (std::size_t i = 0; i < labels.data.size(); ++i)
    if (labels.data[i] > 0 && frame.depth_m.data[i] > 0) pixels_of[labels.data[i]].push_back(std::int32_t(i));
  std::vector<Job> kept;
  for (Job& job : jobs) {
    const std::vector<std::int32_t>& px = job.piece_pixels.empty() ? pixels_of[job.label] : job.piece_pixels;
    const std::size_t n = std::min(px.size(), std::size_t(ss.colour_samples));
    std::size_t hits = 0;
    for (std::size_t k = 0; k < n; ++k) {
      const std::int32_t p = px[k * px.size() / n];
      hits += matched(job.model, pack_rgb(frame.rgb.data[std::size_t(p)]));
    }
    job.colour_fraction = job.retrieval_score = n > 0 ? float(hits) / float(n) : 0.f;
    if (n > 0 && job.colour_fraction >= ss.min_colour_fraction) kept.push_back(std::move(job));
  }
  jobs = std::move(kept);
}

/// Segment k cut in `pieces` parts (cut_segment), from the cache or cut now and kept there.
inline const std::vector<SegmentPiece>& cut_of(const RgbdFrame& frame, const FrameSegments& segments, int k,
                                               int pieces, PieceCache& cache) {
  auto cut = cache.find({k, pieces});
  if (cut == cache.end())
    cut = cache
              .emplace(std::make_pair(k, pieces),
                       cut_segment(frame, segments.labels, segments.segments[std::size_t(k)], pieces))
              .first;
  return cut->second;
}

/// The job of `model` around `piece` of segment k (its box, proposal depths over its readings); with
/// `own_targets`, GICP against the piece's own readings, not its neighbour's in the segment.
template <class Backend>
Job piece_job(const Shared<Backend>& sh, int model, int k, const SegmentPiece& piece, bool own_targets) {
  Job job;
  job.model = model, job.label = std::int32_t(k + 1);  // segment: group_segments()
  job.box_xywh = piece.box_xywh;
  job.depths =
      proposal_depths_sorted(piece.depths_m, sh.models[std::size_t(model)].mesh, sh.settings.proposals);
  if (own_targets) job.piece_pixels = piece.pixels;
  return job;
}

/// The scene jobs of `model` on segment k (SceneSettings): none if the segment is too small or too
/// large to hold it, one around the segment's box, or one per model-sized piece of a larger segment
/// (k-means on its readings).
template <class Backend>
void add_scene_jobs(const Shared<Backend>& sh, const RgbdFrame& frame, const FrameSegments& segments, int k,
                    int model, PieceCache& cache, std::vector<Job>& jobs) {
  const SceneSettings& ss = sh.settings.scene;
  const FrameSegment& seg = segments.segments[std::size_t(k)];
  const auto [small_face, large_face] = sh.face_m2[std::size_t(model)];
  if (seg.area_m2 < ss.min_area_fraction * small_face) return;
  if (seg.area_m2 > ss.max_area_faces * large_face) return;  // background for this model
  const int pieces = seg.extent_m > ss.piece_extent_factor * sh.size_m[std::size_t(model)] ||
                             seg.area_m2 > ss.piece_area_faces * large_face
                         ? std::clamp(int(std::ceil(seg.area_m2 / large_face)), 2, std::max(ss.max_pieces, 2))
                         : 1;
  const std::vector<SegmentPiece>& cut = cut_of(frame, segments, k, pieces, cache);
  for (const SegmentPiece& piece : cut) {
    if (piece.depths_m.empty())
      throw InvalidInput("segment " + std::to_string(k + 1), "has no valid depth reading inside it");
    jobs.push_back(piece_job(sh, model, k, piece, cut.size() > 1));
  }
}

/// A segment that some model's size rule cut into pieces (add_scene_jobs) may hold two objects even where
/// a larger model's rule takes it whole (a bowl merged with a distractor behind it): each model searched
/// on such a segment whole also gets a job on each half of it (the segment cut in 2, Job::half) that is
/// large enough to show it (min_area_fraction of its smallest face). Without them the model's one job
/// starts at the merged segment's box and depth, and its smaller same-print copy, cut to the object's
/// piece, was taken for it.
template <class Backend>
void add_half_jobs(const Shared<Backend>& sh, const RgbdFrame& frame, const FrameSegments& segments,
                   PieceCache& cache, std::vector<Job>& jobs) {
  const SceneSettings& ss = sh.settings.scene;
  std::set<int> cut;  // segments some model cut into pieces
  for (const auto& [key, pieces] : cache)
    if (key.second > 1) cut.insert(key.first);
  const std::size_t n = jobs.size();
  for (std::size_t j = 0; j < n; ++j) {
    const int k = jobs[j].label - 1;
    if (!jobs[j].piece_pixels.empty() || !cut.count(k)) continue;
    const std::vector<SegmentPiece>& halves = cut_of(frame, segments, k, 2, cache);
    if (halves.size() < 2) continue;
    const int model = jobs[j].model;
    for (const SegmentPiece& piece : halves) {
      if (piece.depths_m.empty() ||
          piece.area_m2 < ss.min_area_fraction * sh.face_m2[std::size_t(model)].first)
        continue;
      jobs.push_back(piece_job(sh, model, k, piece, true));
      jobs.back().half = true;
    }
  }
}

/// Per job, the segments its object may span: its own and every segment whose centroid lies within the
/// model's size of it and that is no larger than the model (an occluder in front splits an object into
/// such parts). Sets each job's `segment` to its group's index; returns the distinct groups (sorted
/// labels).
template <class Backend>
std::vector<std::vector<std::int32_t>> group_segments(const Shared<Backend>& sh,
                                                      const FrameSegments& segments, std::vector<Job>& jobs) {
  std::map<std::vector<std::int32_t>, std::int32_t> index;
  std::vector<std::vector<std::int32_t>> groups;
  for (Job& job : jobs) {
    const float size = sh.size_m[std::size_t(job.model)];
    const FrameSegment& own = segments.segments[std::size_t(job.label - 1)];
    std::vector<std::int32_t> members;
    for (const FrameSegment& other : segments.segments)
      if (other.label == own.label ||
          (other.extent_m <= size && (other.centroid_cam - own.centroid_cam).norm() <= size))
        members.push_back(other.label);
    auto it = index.find(members);
    if (it == index.end()) {
      it = index.emplace(members, std::int32_t(groups.size())).first;
      groups.push_back(members);
    }
    job.segment = it->second;
  }
  return groups;
}

/// GICP's targets: the groups' clouds, then one cloud per piece job of its piece's readings on the
/// observed grid (Job::target set; a piece without readings there keeps its group's).
inline CloudBatch with_pieces(const ObservedCloudSettings& o, const RgbdFrame& frame,
                              const CloudBatch& groups, std::vector<Job>& jobs) {
  CloudBatch out = groups;
  for (Job& job : jobs) {
    job.target = job.segment;
    if (job.piece_pixels.empty()) continue;
    const std::size_t before = out.size();
    const std::int32_t cloud = std::int32_t(out.num_clouds());
    for (const std::int32_t p : job.piece_pixels) {
      const int u = p % frame.camera.width, v = p / frame.camera.width;
      if (u % o.stride || v % o.stride) continue;
      if (const float d = frame.depth_m(u, v); observed_detail::keep(d, o))
        observed_detail::append_pixel(frame, u, v, d, cloud, out);
    }
    if (out.size() == before) continue;
    out.offsets.push_back(std::int64_t(out.size()));
    job.target = cloud;
  }
  return out;
}

/// One observed cloud per group of segment labels (1..S): the readings on the observed grid whose
/// label is in the group (readings relabelled above S, explained ones, belong to none).
inline CloudBatch group_clouds(const ObservedCloudSettings& o, const RgbdFrame& frame,
                               const LabelImage& labels, const std::vector<std::vector<std::int32_t>>& groups,
                               std::size_t S) {
  CloudBatch out;
  std::vector<std::uint8_t> member(S + 1);
  for (std::size_t g = 0; g < groups.size(); ++g) {
    std::fill(member.begin(), member.end(), 0);
    for (const std::int32_t l : groups[g]) member[std::size_t(l)] = 1;
    for (int v = 0; v < frame.camera.height; v += o.stride)
      for (int u = 0; u < frame.camera.width; u += o.stride) {
        const std::int32_t l = labels(u, v);
        if (l < 1 || std::size_t(l) > S || !member[std::size_t(l)]) continue;
        if (const float d = frame.depth_m(u, v); observed_detail::keep(d, o))
          observed_detail::append_pixel(frame, u, v, d, std::int32_t(g), out);
      }
    out.offsets.push_back(std::int64_t(out.size()));
  }
  return out;
}

/// The observed clouds a set of jobs is searched against, built once for them: groups (group_segments),
/// one cloud per group (J_o's points; group_points its sizes), GICP's targets (with_pieces), both
/// registrations, the cost and the occluders (`labels`' segments 1..S hide nothing of their own jobs).
/// Sets each job's `segment` and `target`.
template <class Backend>
struct JobTargets {
  std::vector<std::vector<std::int32_t>> groups;
  CloudBatch observed;
  std::vector<std::size_t> group_points;
  CloudBatch targets;
  typename Backend::Registration registration;
  std::optional<typename Backend::Registration> first_pass_registration;
  typename Backend::Cost cost;
  Occluders occluders;
  std::vector<std::int32_t> job_cloud, job_label, job_target;

  JobTargets(const Shared<Backend>& sh, const RgbdFrame& frame, const FrameSegments& segments,
             const LabelImage& labels, std::size_t S, std::vector<Job>& jobs)
      : groups(group_segments(sh, segments, jobs)),
        observed(group_clouds(sh.settings.observed, frame, labels, groups, S)),
        group_points(cloud_sizes(observed)),
        targets(with_pieces(sh.settings.observed, frame, observed, jobs)),
        registration(targets),
        first_pass_registration(first_pass_targets(sh, frame, targets)),
        cost(observed),
        occluders{frame.depth_m, labels} {
    for (const Job& j : jobs)
      job_cloud.push_back(j.segment), job_label.push_back(j.label), job_target.push_back(j.target);
  }
  JobTargets(const JobTargets&) = delete;
  JobTargets& operator=(const JobTargets&) = delete;

  Context<Backend> context(const Shared<Backend>& sh, const RgbdFrame& frame) const {
    return {sh,   frame,     occluders, &registration, or_same(first_pass_registration, registration),
            cost, job_cloud, job_label, job_target};
  }

 private:
  static std::vector<std::size_t> cloud_sizes(const CloudBatch& c) {
    std::vector<std::size_t> n;
    for (std::size_t g = 0; g < c.num_clouds(); ++g) n.push_back(c.cloud_size(g));
    return n;
  }
};

}  // namespace sixdof_detail
}  // namespace perch2
