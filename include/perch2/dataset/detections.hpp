// Detection files in the BOP / COCO results format (the BOP challenge's default detections):
//   [{"scene_id": 1, "image_id": 3, "category_id": 5, "score": 0.93, "bbox": [x, y, w, h],
//     "segmentation": {"size": [h, w], "counts": [...] or "string"}, "time": 0.12}, ...]
// category_id is the BOP obj_id; bbox is in pixels (top-left corner, width, height); time in seconds.
//
// Masks are run-length encoded as COCO does (pycocotools/common/maskApi.c): runs over the mask in
// column-major order (down each column, then the next column), alternating 0-runs and 1-runs, starting with
// a (possibly empty) 0-run. `counts` is either that list of integers ("uncompressed RLE") or COCO's compact
// string (rleToString: each count, or for the 4th count on its difference to the count two before, written
// as 5-bit groups with a continuation bit in ASCII 48..111).
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "perch2/dataset/bop.hpp"

namespace perch2::dataset {

struct Rle {
  int height = 0, width = 0;
  std::vector<std::uint32_t> counts;  ///< alternating 0/1 run lengths, column-major, starting with 0s
};

/// Encodes a mask (any non-zero value is inside) exactly as pycocotools' rleEncode.
Rle rle_encode(const Mask& mask);
/// Decodes to a width x height mask. InvalidInput if the runs do not sum to height * width.
Mask rle_decode(const Rle& rle);
/// COCO's compressed string of the counts (maskApi.c rleToString).
std::string rle_to_string(const Rle& rle);
/// Parses COCO's compressed string (maskApi.c rleFrString). InvalidInput on characters outside 48..111, a
/// truncated last count, or a negative count.
Rle rle_from_string(const std::string& counts, int height, int width);

struct Detection {
  int scene_id = 0, image_id = 0, category_id = 0;  ///< category_id = BOP obj_id
  float score = 0;
  std::array<float, 4> bbox{};  ///< x, y, width, height in pixels
  Rle segmentation;             ///< height = width = 0 when the detection has no mask
  double time_s = -1;           ///< seconds spent on the image (-1 if not given)
  bool has_mask() const { return segmentation.height > 0 && segmentation.width > 0; }
  Mask mask() const { return rle_decode(segmentation); }
};

/// Reads a detection file (counts as a list or a string). FileError naming the file and the entry on any
/// problem (missing key, non-finite number, runs that do not cover the image).
std::vector<Detection> load_detections(const std::string& path);

/// Writes a detection file; masks as compressed strings (compressed = true) or count lists.
void save_detections(const std::string& path, const std::vector<Detection>& detections,
                     bool compressed = true);

/// Indices of the detections of each (scene_id, image_id), in file order (several detections of one
/// category in one image stay separate entries).
std::map<std::pair<int, int>, std::vector<std::size_t>> detections_by_image(
    const std::vector<Detection>& dets);

}  // namespace perch2::dataset
