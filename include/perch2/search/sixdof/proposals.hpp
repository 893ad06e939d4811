// Jobs and their proposals. estimate() makes one job per instance: its model, its trimmed mask's
// proposal depths (from its nearest reading to its farthest plus half the object's thickness, every
// proposals.depth_step_m) and its box (the mask's if none was given). propose() turns every job into
// hypotheses: rotations (viewpoints x in-plane angles, de-duplicated under the model's symmetries) x depths
// on the ray through the box centre (perch2/search/proposals.hpp), and bounds each job's rendered points for
// the chunk sizes.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "perch2/search/proposals.hpp"
#include "perch2/search/sixdof/context.hpp"

namespace perch2 {
namespace sixdof_detail {

/// One job per instance: its model's proposals around its box, refined against its own segment (cloud k,
/// label k + 1 in `labels`, the trimmed masks).
template <class Backend>
std::vector<Job> instance_jobs(const Shared<Backend>& sh, const RgbdFrame& frame,
                               const std::vector<SixDofInstance>& instances, const LabelImage& labels) {
  const SixDofSettings& s = sh.settings;
  std::vector<Job> jobs;
  for (std::size_t k = 0; k < instances.size(); ++k) {
    const SixDofInstance& in = instances[k];
    Image<std::uint8_t> trimmed(labels.width, labels.height, 0);  // the mask after trimming
    for (std::size_t i = 0; i < labels.data.size(); ++i) trimmed.data[i] = labels.data[i] == int(k + 1);
    Job job;
    job.model = in.model, job.segment = std::int32_t(k), job.label = std::int32_t(k + 1);
    job.depths = proposal_depths(frame.depth_m, trimmed, sh.models[std::size_t(in.model)].mesh, s.proposals,
                                 "instances[" + std::to_string(k) + "] mask");
    job.box_xywh = in.box_xywh;
    if (job.box_xywh[2] < 0 || job.box_xywh[3] < 0) job.box_xywh = mask_box(in.mask);
    jobs.push_back(std::move(job));
  }
  return jobs;
}

/// Every job's proposals (Hypothesis::label = job + 1; rotations from `proposals`), job by job; fills the
/// per-job counts of `result` and points_estimate (per job: a bound on its rendered points at the finest
/// stride, for the chunk sizes).
template <class Backend>
std::vector<Hypothesis> propose(const Context<Backend>& ctx, const std::vector<Job>& jobs,
                                const ProposalSettings& proposals, std::vector<std::size_t>& points_estimate,
                                SixDofResult& result) {
  const SixDofSettings& s = ctx.shared.settings;
  const std::size_t K = jobs.size();
  auto t = Clock::now();
  std::vector<Hypothesis> hyps;
  points_estimate.clear();
  std::map<int, std::vector<Eigen::Matrix3f>> rotations_of;  // per model
  for (std::size_t k = 0; k < K; ++k) {
    const Job& job = jobs[k];
    const SixDofModel& model = ctx.shared.models[std::size_t(job.model)];
    std::vector<Eigen::Matrix3f> aligned;
    if (std::isfinite(job.image_axis_rad))
      aligned =
          aligned_rotation_proposals(proposals, model.symmetries,
                                     ctx.shared.surface_moments[std::size_t(job.model)], job.image_axis_rad);
    auto it = rotations_of.find(job.model);
    if (aligned.empty() && it == rotations_of.end())
      it = rotations_of.emplace(job.model, rotation_proposals(proposals, model.symmetries)).first;
    const std::vector<Eigen::Matrix3f>& rotations = aligned.empty() ? it->second : aligned;
    const auto poses = pose_proposals(ctx.frame.camera, box_centre_px(job.box_xywh), rotations, job.depths);
    for (const auto& T : poses) hyps.push_back({job.model, T, std::int32_t(k + 1)});
    result.rotations.push_back(rotations.size());
    result.depths.push_back(job.depths.size());
    result.hypotheses.push_back(poses.size());
    // The object's image at the nearest depth covers at most its diameter's projection, squared.
    const float px = ctx.frame.camera.fx * ctx.shared.diameter[std::size_t(job.model)] /
                     std::max(job.depths.front(), 1e-3f);
    const int stride = std::min({s.render.stride, s.second_pass_stride, s.score_stride});
    points_estimate.push_back(std::size_t(px * px / float(stride * stride)) + 1);
  }
  result.hypotheses_total += hyps.size();
  result.timings.proposals += seconds_since(t);
  return hyps;
}

}  // namespace sixdof_detail
}  // namespace perch2
