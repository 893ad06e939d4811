// Segmented arrays: element ranges [offsets[s], offsets[s+1]) per segment (hypothesis, cloud, ...).
#pragma once

#include <cstdint>

#include "perch2/core/device.hpp"

namespace perch2 {

/// The segment holding element `index`, given num_segments + 1 non-decreasing offsets: the last segment
/// starting at or before `index` (so empty segments are skipped). Branchless binary search: the probes
/// compile to conditional moves, so a thread mapping elements to segments pays no mispredictions.
template <class Offset>
PERCH2_HD inline int find_segment(const Offset* offsets, int num_segments, Offset index) {
  int lo = 0, len = num_segments;  // invariant: offsets[lo] <= index, answer in [lo, lo + len)
  while (len > 1) {
    const int half = len / 2;
    lo = offsets[lo + half] <= index ? lo + half : lo;
    len -= half;
  }
  return lo;
}

}  // namespace perch2

namespace perch2 {

/// Work item `item` of a segmented domain cut into blocks of `block` elements per segment: its segment
/// and its segment-local element range [begin, end). One search per block instead of per element.
struct BlockRange {
  int segment;
  std::int64_t begin, end;
};

PERCH2_HD inline BlockRange block_range(const std::int64_t* block_offsets,
                                        const std::int64_t* element_offsets, int num_segments,
                                        std::int64_t item, int block) {
  const int s = find_segment(block_offsets, num_segments, item);
  const std::int64_t begin = (item - block_offsets[s]) * block;
  const std::int64_t size = element_offsets[s + 1] - element_offsets[s];
  return {s, begin, begin + block < size ? begin + block : size};
}

}  // namespace perch2

namespace perch2 {

/// In-place heap sort of the positions [0, n) of a segment (device-callable: O(n log n) in one thread, no
/// extra memory, so a segment that happens to be large, e.g. a grid cell of coincident points, cannot cost
/// O(n^2)). less(a, b) compares and swap(a, b) exchanges the elements at positions a and b.
template <class Less, class Swap>
PERCH2_HD inline void heap_sort(std::int64_t n, Less less, Swap swap) {
  auto sift = [&](std::int64_t root, std::int64_t size) {
    while (true) {
      std::int64_t child = 2 * root + 1;
      if (child >= size) return;
      if (child + 1 < size && less(child, child + 1)) ++child;
      if (!less(root, child)) return;
      swap(root, child);
      root = child;
    }
  };
  for (std::int64_t r = n / 2 - 1; r >= 0; --r) sift(r, n);
  for (std::int64_t end = n - 1; end > 0; --end) {
    swap(0, end);
    sift(0, end);
  }
}

}  // namespace perch2
