// A simulated instance detector: ground-truth visible masks degraded the way a real detector's are
// (boundaries grown or shrunk by a few pixels and wobbly, jittered boxes, scores that fall with occlusion,
// missed instances, class confusions between look-alikes, spurious detections on distractors), and the
// BOP/COCO detection JSON they are written in.
#pragma once

#include <array>
#include <string>
#include <vector>

#include "perch2/core/export.hpp"
#include "perch2/synth/sensor.hpp"

namespace perch2::synth {

struct DetectionSettings {
  float min_visible_fraction = 0.05f;       ///< less visible instances are never detected
  float miss_probability = 0.03f;           ///< chance of missing a fully visible instance
  float occluded_miss_probability = 0.35f;  ///< added miss chance, times (1 - visible fraction)^2
  float boundary_shift_px = 3.f;            ///< boundary grows or shrinks by up to this, pixels (uniform +-)
  float boundary_wobble_px = 2.f;           ///< amplitude of the smooth random boundary displacement, pixels
  float box_jitter = 0.03f;                 ///< box sides move by normal noise of this times the box size
  float confusion_probability = 0.05f;      ///< a look-alike's label (same name before '_', e.g. can_*)
  float spurious_probability = 0.3f;    ///< chance per image of one detection on a distractor (or the table)
  float score_base = 0.55f;             ///< score of a barely visible true detection (before noise)
  float score_per_visible = 0.4f;       ///< added score times the visible fraction
  float score_noise = 0.08f;            ///< sigma of the score noise
  float confusion_score_factor = 0.7f;  ///< a confused label's score is multiplied by this
  float spurious_min_score = 0.1f, spurious_max_score = 0.6f;  ///< uniform score of a spurious detection
  float time_jitter = 0.1f;                                    ///< relative sigma of the per-image time
  float time_s = 0.05f;                                        ///< detector time written per image, seconds
};

struct Detection {
  int scene_id = 0, image_id = 0, category_id = 0;  ///< category_id = BOP obj_id
  float score = 0;
  std::array<int, 4> bbox{};  ///< x, y, w, h in pixels, w = x_max - x_min (BOP's calc_2d_bbox)
  MaskImage mask;
  float time_s = 0;
  int gt_index = -1;  ///< the scene_gt instance it came from, -1 for a spurious detection
};

/// Detections of one frame. `obj_ids[k]` and `names[k]` belong to scene object k; `all_models` lets a
/// confusion or a spurious detection pick another class.
PERCH2_API std::vector<Detection> simulate_detections(const Frame& frame, const std::vector<int>& obj_ids,
                                                      const std::vector<ObjectModel>& all_models,
                                                      const DetectionSettings& settings, Rng& rng);

/// What degrade_mask() does to a visible mask: the errors of a real instance detector's masks, to measure
/// how much they cost on data that has only exact masks (e.g. real frames with ground-truth mask_visib).
struct MaskDegradation {
  float boundary_shift_px = 3.f;   ///< the boundary grows or shrinks by up to this (uniform +-), pixels
  float boundary_wobble_px = 2.f;  ///< amplitude of a smooth random boundary displacement, pixels
  float offset_px = 2.f;           ///< the whole mask moves by up to this in u and in v (uniform +-), pixels
  /// Chance that the mask bleeds: a blob centred on a random boundary pixel is added (onto the table, a
  /// neighbour or the background next to the object).
  float bleed_probability = 0.35f;
  float cut_probability = 0.35f;  ///< chance that a blob centred on a random boundary pixel is cut away
  /// A bleed or cut blob is an ellipse whose radii are uniform in [0.5, 1] x this x the mask box's width
  /// and height (independently), at a random angle.
  float blob_size = 0.3f;
};

/// `visible` (non-zero = inside) degraded as `d` says (boundary, offset, bleed, cut, in that order). May
/// return an empty mask when `visible` is tiny.
PERCH2_API MaskImage degrade_mask(const MaskImage& visible, const MaskDegradation& d, Rng& rng);

/// COCO run-length encoding (column-major runs, starting with background) as pycocotools' compressed string.
PERCH2_API std::string coco_rle_string(const MaskImage& mask);
/// The same runs as a list (COCO's uncompressed form).
PERCH2_API std::vector<std::uint32_t> coco_rle_counts(const MaskImage& mask);

// Bounding boxes of masks: perch2::mask_bbox (perch2/core/image.hpp).

}  // namespace perch2::synth
