#include "perch2/synth/detections.hpp"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <string>
#include <utility>

#include "noise_field.hpp"

namespace perch2::synth {

namespace {

cv::Mat as_mat(const MaskImage& m) {
  return cv::Mat(m.height, m.width, CV_8U, const_cast<std::uint8_t*>(m.data.data()));
}

/// Grows (shift > 0) or shrinks the mask by `shift` pixels with a smooth random wobble: the new mask is
/// where signed distance (positive inside) + shift + wobble > 0.
MaskImage degrade(const MaskImage& mask, float shift, float wobble, Rng& rng) {
  const cv::Mat m = as_mat(mask);
  cv::Mat inside, outside;
  cv::distanceTransform(m, inside, cv::DIST_L2, 3);
  cv::Mat inv;
  cv::bitwise_not(m, inv);
  cv::distanceTransform(inv, outside, cv::DIST_L2, 3);
  const cv::Mat noise = detail::smooth_noise(mask.width, mask.height, 12, rng);
  MaskImage out(mask.width, mask.height, 0);
  for (int v = 0; v < mask.height; ++v)
    for (int u = 0; u < mask.width; ++u) {
      const float sd = m.at<uchar>(v, u) ? inside.at<float>(v, u) : -outside.at<float>(v, u) + 1.f;
      if (sd + shift + wobble * (2.f * noise.at<float>(v, u) - 1.f) > 0.5f) out(u, v) = 255;
    }
  return out;
}

/// Name before the first '_' ("can" of "can_cola"): models sharing it look alike.
std::string family(const std::string& name) {
  return name.substr(0, name.find('_'));
}

std::array<int, 4> jitter_box(std::array<int, 4> b, float jitter, int W, int H, Rng& rng) {
  float x0 = float(b[0]), y0 = float(b[1]), x1 = float(b[0] + b[2]), y1 = float(b[1] + b[3]);
  const float w = x1 - x0 + 1, h = y1 - y0 + 1;
  x0 += jitter * w * rng.normal(), x1 += jitter * w * rng.normal();
  y0 += jitter * h * rng.normal(), y1 += jitter * h * rng.normal();
  const int ix0 = std::clamp(int(std::lround(std::min(x0, x1))), 0, W - 1);
  const int ix1 = std::clamp(int(std::lround(std::max(x0, x1))), 0, W - 1);
  const int iy0 = std::clamp(int(std::lround(std::min(y0, y1))), 0, H - 1);
  const int iy1 = std::clamp(int(std::lround(std::max(y0, y1))), 0, H - 1);
  return {ix0, iy0, ix1 - ix0, iy1 - iy0};
}

}  // namespace

MaskImage degrade_mask(const MaskImage& visible, const MaskDegradation& d, Rng& rng) {
  const std::pair<const char*, float> sizes[] = {{"boundary_shift_px", d.boundary_shift_px},
                                                 {"boundary_wobble_px", d.boundary_wobble_px},
                                                 {"offset_px", d.offset_px},
                                                 {"blob_size", d.blob_size}};
  for (const auto& [name, v] : sizes)
    if (!(std::isfinite(v) && v >= 0))
      throw InvalidInput(std::string("MaskDegradation::") + name, "must be finite and >= 0");
  for (const auto& [name, p] : {std::pair<const char*, float>{"bleed_probability", d.bleed_probability},
                                {"cut_probability", d.cut_probability}})
    if (!(p >= 0 && p <= 1)) throw InvalidInput(std::string("MaskDegradation::") + name, "must be in [0, 1]");
  const float shift = rng.uniform(-1.f, 1.f) * d.boundary_shift_px;
  const int du = int(std::lround(rng.uniform(-1.f, 1.f) * d.offset_px)),
            dv = int(std::lround(rng.uniform(-1.f, 1.f) * d.offset_px));
  const bool bleed = rng.chance(d.bleed_probability), cut = rng.chance(d.cut_probability);
  MaskImage out = degrade(visible, shift, d.boundary_wobble_px, rng);
  MaskImage moved(out.width, out.height, 0);
  for (int v = 0; v < out.height; ++v)
    for (int u = 0; u < out.width; ++u)
      if (u - du >= 0 && u - du < out.width && v - dv >= 0 && v - dv < out.height)
        moved(u, v) = out(u - du, v - dv);
  out = std::move(moved);
  // A blob on a random pixel of the boundary of the mask so far, sized by its box.
  auto blob = [&](std::uint8_t value) {
    const auto box = mask_bbox(out);
    if (box[0] < 0) return;
    cv::Mat m = as_mat(out), eroded;
    cv::erode(m, eroded, cv::Mat());
    std::vector<cv::Point> boundary;
    for (int v = 0; v < out.height; ++v)
      for (int u = 0; u < out.width; ++u)
        if (out(u, v) && !eroded.at<uchar>(v, u)) boundary.push_back({u, v});
    const cv::Point c = boundary[std::size_t(rng.integer(0, int(boundary.size()) - 1))];
    const int ru = std::max(1, int(std::lround(rng.uniform(0.5f, 1.f) * d.blob_size * float(box[2] + 1))));
    const int rv = std::max(1, int(std::lround(rng.uniform(0.5f, 1.f) * d.blob_size * float(box[3] + 1))));
    cv::ellipse(m, c, {ru, rv}, rng.uniform(0.f, 180.f), 0, 360, value, cv::FILLED);
  };
  if (bleed) blob(255);
  if (cut) blob(0);
  return out;
}

std::vector<std::uint32_t> coco_rle_counts(const MaskImage& mask) {
  std::vector<std::uint32_t> counts;
  bool current = false;  // runs alternate, starting with background
  std::uint32_t run = 0;
  for (int u = 0; u < mask.width; ++u)
    for (int v = 0; v < mask.height; ++v) {
      const bool on = mask(u, v) != 0;
      if (on != current) counts.push_back(run), run = 0, current = on;
      ++run;
    }
  counts.push_back(run);
  return counts;
}

std::string coco_rle_string(const MaskImage& mask) {
  // pycocotools rleToString: runs after the second are stored as differences to the run two before, each
  // value as 5-bit groups (low first) with a continuation bit 0x20, offset by 48 into printable ASCII.
  const std::vector<std::uint32_t> counts = coco_rle_counts(mask);
  std::string s;
  for (std::size_t i = 0; i < counts.size(); ++i) {
    long long x = counts[i];
    if (i > 2) x -= counts[i - 2];
    bool more = true;
    while (more) {
      char c = char(x & 0x1f);
      x >>= 5;
      more = (c & 0x10) ? x != -1 : x != 0;
      if (more) c |= 0x20;
      s.push_back(char(c + 48));
    }
  }
  return s;
}

std::vector<Detection> simulate_detections(const Frame& frame, const std::vector<int>& obj_ids,
                                           const std::vector<ObjectModel>& all_models,
                                           const DetectionSettings& s, Rng& rng) {
  if (obj_ids.size() != frame.masks.size())
    throw InvalidInput("simulate_detections", "need one obj_id per scene object of the frame");
  const int W = frame.camera.width, H = frame.camera.height;
  auto name_of = [&](int obj_id) {
    for (const auto& m : all_models)
      if (m.obj_id == obj_id) return m.name;
    return std::string();
  };
  std::vector<Detection> out;
  const float time_s = s.time_s * std::max(0.f, 1.f + s.time_jitter * rng.normal());
  for (std::size_t k = 0; k < obj_ids.size(); ++k) {
    MaskImage visible(W, H, 0);
    int count = 0;
    for (std::size_t p = 0; p < visible.data.size(); ++p)
      if (frame.visible.data[p] == int(k) + 1) visible.data[p] = 255, ++count;
    const float fraction = frame.px_count_all[k] > 0 ? float(count) / frame.px_count_all[k] : 0.f;
    // Draws happen for every instance so one instance's fate does not shift the others' random streams.
    const float r_miss = float(rng.uniform()), r_conf = float(rng.uniform()), shift = rng.uniform(-1.f, 1.f);
    const float score_noise = rng.normal();
    if (fraction < s.min_visible_fraction) continue;
    if (r_miss < s.miss_probability + s.occluded_miss_probability * (1 - fraction) * (1 - fraction)) continue;
    Detection d;
    d.gt_index = int(k);
    d.category_id = obj_ids[k];
    d.score = std::clamp(s.score_base + s.score_per_visible * fraction + s.score_noise * score_noise, 0.01f,
                         0.999f);
    if (r_conf < s.confusion_probability) {
      std::vector<int> alike;
      for (const auto& m : all_models)
        if (m.obj_id != obj_ids[k] && family(m.name) == family(name_of(obj_ids[k])))
          alike.push_back(m.obj_id);
      if (!alike.empty())
        d.category_id = alike[rng.integer(0, int(alike.size()) - 1)], d.score *= s.confusion_score_factor;
    }
    d.mask = degrade(visible, shift * s.boundary_shift_px, s.boundary_wobble_px, rng);
    const auto box = mask_bbox(d.mask);
    if (box[0] < 0) continue;
    d.bbox = jitter_box(box, s.box_jitter, W, H, rng);
    d.time_s = time_s;
    out.push_back(std::move(d));
  }
  if (rng.chance(s.spurious_probability) && !all_models.empty()) {
    Detection d;
    d.category_id = all_models[rng.integer(0, int(all_models.size()) - 1)].obj_id;
    d.score = rng.uniform(s.spurious_min_score, s.spurious_max_score);
    MaskImage region(W, H, 0);
    int distractors = 0;
    for (int v : frame.visible.data) distractors = std::max(distractors, -v);
    if (distractors > 0) {  // a distractor mistaken for an object
      const int pick = rng.integer(1, distractors);
      for (std::size_t p = 0; p < region.data.size(); ++p)
        if (frame.visible.data[p] == -pick) region.data[p] = 255;
    }
    if (mask_bbox(region)[0] < 0) {  // or a blob of table texture
      cv::Mat m = as_mat(region);
      cv::ellipse(m, {rng.integer(W / 4, 3 * W / 4), rng.integer(H / 4, 3 * H / 4)},
                  {rng.integer(10, W / 10), rng.integer(10, H / 10)}, rng.uniform(0.f, 180.f), 0, 360, 255,
                  cv::FILLED);
    }
    d.mask = degrade(region, rng.uniform(-1.f, 1.f) * s.boundary_shift_px, s.boundary_wobble_px, rng);
    const auto box = mask_bbox(d.mask);
    if (box[0] >= 0) {
      d.bbox = jitter_box(box, s.box_jitter, W, H, rng);
      d.time_s = time_s;
      out.push_back(std::move(d));
    }
  }
  return out;
}

}  // namespace perch2::synth
