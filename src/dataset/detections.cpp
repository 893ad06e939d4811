#include "perch2/dataset/detections.hpp"

#include "json_util.hpp"

namespace perch2::dataset {

using namespace detail;

Rle rle_encode(const Mask& mask) {
  Rle r;
  r.height = mask.height, r.width = mask.width;
  // Column-major scan (maskApi.c rleEncode): counts alternate 0-runs and 1-runs, starting with 0s.
  std::uint8_t current = 0;
  std::uint32_t run = 0;
  for (int u = 0; u < mask.width; ++u)
    for (int v = 0; v < mask.height; ++v) {
      const std::uint8_t bit = mask(u, v) != 0;
      if (bit != current) r.counts.push_back(run), run = 0, current = bit;
      ++run;
    }
  r.counts.push_back(run);
  return r;
}

Mask rle_decode(const Rle& rle) {
  if (rle.height < 0 || rle.width < 0) throw InvalidInput("RLE", "negative size");
  Mask m(rle.width, rle.height, 0);
  const std::uint64_t n = std::uint64_t(rle.width) * std::uint64_t(rle.height);
  std::uint64_t pos = 0;
  std::uint8_t value = 0;
  for (const std::uint32_t c : rle.counts) {
    if (pos + c > n)
      throw InvalidInput("RLE", "runs cover more than the " + std::to_string(rle.height) + "x" +
                                    std::to_string(rle.width) + " image");
    for (std::uint64_t k = pos; k < pos + c; ++k) {
      // Column-major index k -> pixel (u = k / height, v = k % height).
      m(int(k / std::uint64_t(rle.height)), int(k % std::uint64_t(rle.height))) = value;
    }
    pos += c;
    value ^= 1;
  }
  if (pos != n)
    throw InvalidInput("RLE", "runs cover " + std::to_string(pos) + " of " + std::to_string(n) + " pixels");
  return m;
}

std::string rle_to_string(const Rle& rle) {
  // maskApi.c rleToString: "similar to LEB128 but using 6 bits/char and ascii chars 48-111". From the
  // fourth count on (i > 2), the difference to the count two before is written (may be negative).
  std::string s;
  for (std::size_t i = 0; i < rle.counts.size(); ++i) {
    long long x = rle.counts[i];
    if (i > 2) x -= static_cast<long long>(rle.counts[i - 2]);
    bool more = true;
    while (more) {
      char c = char(x & 0x1f);
      x >>= 5;  // arithmetic shift, as in maskApi.c (long)
      more = (c & 0x10) ? x != -1 : x != 0;
      if (more) c |= 0x20;
      s.push_back(char(c + 48));
    }
  }
  return s;
}

Rle rle_from_string(const std::string& counts, int height, int width) {
  Rle r;
  r.height = height, r.width = width;
  std::size_t p = 0;
  while (p < counts.size()) {
    long long x = 0;
    int k = 0;
    bool more = true;
    while (more) {
      if (p >= counts.size()) throw InvalidInput("RLE string", "ends inside a count");
      const int c = int(static_cast<unsigned char>(counts[p])) - 48;
      if (c < 0 || c > 63)
        throw InvalidInput("RLE string", "character outside '0'..'o' at " + std::to_string(p));
      if (k >= 12) throw InvalidInput("RLE string", "count too long at " + std::to_string(p));
      x |= static_cast<long long>(c & 0x1f) << (5 * k);
      more = (c & 0x20) != 0;
      ++p, ++k;
      if (!more && (c & 0x10)) x |= static_cast<long long>(~0ULL << (5 * k));  // sign-extend
    }
    if (r.counts.size() > 2) x += static_cast<long long>(r.counts[r.counts.size() - 2]);
    if (x < 0 || x > 0xffffffffLL) throw InvalidInput("RLE string", "count out of range");
    r.counts.push_back(std::uint32_t(x));
  }
  return r;
}

namespace {

Rle parse_segmentation(const json& seg, const std::string& path, const std::string& where) {
  const auto size = numbers(member(seg, "size", path, where), 2, path, where + " size");
  const int h = int(size[0]), w = int(size[1]);
  if (h < 0 || w < 0 || h != size[0] || w != size[1])
    throw FileError(path, where + " size: expected [height, width] as non-negative integers");
  const json& counts = member(seg, "counts", path, where);
  Rle r;
  try {
    if (counts.is_string()) {
      r = rle_from_string(counts.get<std::string>(), h, w);
    } else if (counts.is_array()) {
      r.height = h, r.width = w;
      for (std::size_t k = 0; k < counts.size(); ++k) {
        const int c = integer(counts[k], path, where + " counts[" + std::to_string(k) + "]");
        if (c < 0) throw FileError(path, where + " counts: negative run");
        r.counts.push_back(std::uint32_t(c));
      }
    } else {
      throw FileError(path, where + " counts: expected a list of runs or an RLE string");
    }
    rle_decode(r);  // validates the run total
  } catch (const InvalidInput& e) {
    throw FileError(path, where + " segmentation: " + e.what());
  }
  return r;
}

}  // namespace

std::vector<Detection> load_detections(const std::string& path) {
  const json j = read_json(path);
  if (!j.is_array()) throw FileError(path, "expected a JSON list of detections");
  std::vector<Detection> out;
  out.reserve(j.size());
  for (std::size_t k = 0; k < j.size(); ++k) {
    const std::string where = "detection " + std::to_string(k);
    const json& e = j[k];
    Detection d;
    d.scene_id = integer(member(e, "scene_id", path, where), path, where + " scene_id");
    d.image_id = integer(member(e, "image_id", path, where), path, where + " image_id");
    d.category_id = integer(member(e, "category_id", path, where), path, where + " category_id");
    d.score = float(number(member(e, "score", path, where), path, where + " score"));
    const auto b = numbers(member(e, "bbox", path, where), 4, path, where + " bbox");
    for (int c = 0; c < 4; ++c) d.bbox[c] = float(b[c]);
    if (e.contains("segmentation")) d.segmentation = parse_segmentation(e["segmentation"], path, where);
    if (e.contains("time")) d.time_s = number(e["time"], path, where + " time");
    out.push_back(std::move(d));
  }
  return out;
}

void save_detections(const std::string& path, const std::vector<Detection>& detections, bool compressed) {
  json list = json::array();
  for (const auto& d : detections) {
    json e = {{"scene_id", d.scene_id}, {"image_id", d.image_id}, {"category_id", d.category_id},
              {"score", d.score},       {"bbox", d.bbox},         {"time", d.time_s}};
    if (d.has_mask()) {
      json counts = compressed ? json(rle_to_string(d.segmentation)) : json(d.segmentation.counts);
      e["segmentation"] = {{"size", {d.segmentation.height, d.segmentation.width}}, {"counts", counts}};
    }
    list.push_back(std::move(e));
  }
  write_json(path, list, -1);
}

std::map<std::pair<int, int>, std::vector<std::size_t>> detections_by_image(
    const std::vector<Detection>& dets) {
  std::map<std::pair<int, int>, std::vector<std::size_t>> out;
  for (std::size_t k = 0; k < dets.size(); ++k) out[{dets[k].scene_id, dets[k].image_id}].push_back(k);
  return out;
}

}  // namespace perch2::dataset
