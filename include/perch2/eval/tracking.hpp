// What a tracking run's results say about its losses and its latency, per scene (a video): read from the
// rows `perch2 track` writes (one per tracked object per frame, in the tracker's object order; score 0 while
// lost; time = that frame's update, the first frame's also the start's search). The poses' accuracy over
// every frame is the evaluator's (ADD / ADD-S / ADD(-S) AUC, AR: perch2/eval/evaluator.hpp).
#pragma once

#include <algorithm>
#include <cstdio>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "perch2/dataset/results.hpp"

namespace perch2::eval {

struct SceneTracking {
  int scene_id = 0;
  int frames = 0, objects = 0;  ///< frames (images with rows) and tracks (most rows of one frame)
  int lost_frames = 0;          ///< object-frames lost (score 0)
  int losses = 0;               ///< a track's turns from found to lost (lost from its first frame: one)
  int recoveries = 0;           ///< a track's turns from lost to found
  std::vector<int> frames_to_recover;  ///< per recovery, the frames it was lost
  int never_recovered = 0;             ///< tracks lost at the scene's last frame
  /// Per frame after the first (whose time holds the start's search): the update's seconds, and those
  /// divided by the frame's tracks.
  std::vector<double> frame_s, object_s;
};

/// Rows grouped by scene (ascending), frames by image id; a track is (obj_id, its rank among the frame's
/// rows of that obj_id), so several copies of one model are told apart by the tracker's order.
inline std::vector<SceneTracking> tracking_summary(const std::vector<dataset::PoseEstimate>& rows) {
  std::map<int, std::map<int, std::vector<const dataset::PoseEstimate*>>> by_scene;  // scene -> im -> rows
  for (const auto& r : rows) by_scene[r.scene_id][r.im_id].push_back(&r);
  std::vector<SceneTracking> out;
  for (const auto& [scene, frames] : by_scene) {
    SceneTracking s;
    s.scene_id = scene;
    std::map<std::pair<int, int>, int> lost_since;  // track -> first lost frame index, -1 found
    int f = 0;
    for (const auto& [im, frame_rows] : frames) {
      s.objects = std::max(s.objects, int(frame_rows.size()));
      std::map<int, int> rank;
      for (const dataset::PoseEstimate* r : frame_rows) {
        const std::pair<int, int> track{r->obj_id, rank[r->obj_id]++};
        const bool lost = r->score <= 0;
        s.lost_frames += lost;
        const auto it = lost_since.try_emplace(track, -1).first;
        if (lost && it->second < 0) it->second = f, ++s.losses;
        if (!lost && it->second >= 0) {
          ++s.recoveries, s.frames_to_recover.push_back(f - it->second);
          it->second = -1;
        }
      }
      if (f > 0 && frame_rows.front()->time_s >= 0) {
        s.frame_s.push_back(frame_rows.front()->time_s);
        s.object_s.push_back(frame_rows.front()->time_s / double(frame_rows.size()));
      }
      ++f;
    }
    s.frames = f;
    for (const auto& [track, since] : lost_since) s.never_recovered += since >= 0;
    out.push_back(std::move(s));
  }
  return out;
}

/// The q-quantile (nearest rank) of `v`, 0 when empty.
inline double quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, std::size_t(q * double(v.size())))];
}

/// One line per scene and one for all: frames, tracks, lost object-frames, losses, recoveries (frames to
/// recover median / max), never recovered, latency median / p95 per frame and per object (ms).
inline std::string format_tracking(const std::vector<SceneTracking>& scenes) {
  std::string out =
      "scene   frames tracks  lost  losses recovered (median/max frames) never   ms/frame p50   p95   "
      "ms/object p50   p95\n";
  SceneTracking all;
  auto line = [&](const std::string& name, const SceneTracking& s) {
    std::vector<double> to(s.frames_to_recover.begin(), s.frames_to_recover.end());
    char buf[256];
    std::snprintf(
        buf, sizeof buf, "%-7s %6d %6d %5d %7d %9d (%5.0f/%-5.0f)     %5d %13.1f %5.1f %14.1f %5.1f\n",
        name.c_str(), s.frames, s.objects, s.lost_frames, s.losses, s.recoveries, quantile(to, 0.5),
        quantile(to, 1.0), s.never_recovered, quantile(s.frame_s, 0.5) * 1e3, quantile(s.frame_s, 0.95) * 1e3,
        quantile(s.object_s, 0.5) * 1e3, quantile(s.object_s, 0.95) * 1e3);
    out += buf;
  };
  for (const SceneTracking& s : scenes) {
    line(std::to_string(s.scene_id), s);
    all.frames += s.frames, all.objects += s.objects, all.lost_frames += s.lost_frames;
    all.losses += s.losses, all.recoveries += s.recoveries, all.never_recovered += s.never_recovered;
    all.frames_to_recover.insert(all.frames_to_recover.end(), s.frames_to_recover.begin(),
                                 s.frames_to_recover.end());
    all.frame_s.insert(all.frame_s.end(), s.frame_s.begin(), s.frame_s.end());
    all.object_s.insert(all.object_s.end(), s.object_s.begin(), s.object_s.end());
  }
  line("all", all);
  return out;
}

}  // namespace perch2::eval
