// Segmented sort for the Thrust stages (private to the backend's .inl files): sorts each segment
// [offsets[s], offsets[s + 1]) of paired arrays (a, b) by less(a_i, b_i, a_j, b_j), with a bounded amount of
// work per work item whatever the segment sizes (a GPU thread must never sort a whole large segment alone).
//
// Pass 1 sorts runs of segmented_sort_run elements (aligned to each segment's start): each element counts the
// run's elements before it (O(run) per element). Merge passes then double the sorted runs: each element
// finds its place in the merge of its run and the neighbouring run by one binary search (O(log width) per
// element). ceil(log2(largest segment / run)) merge passes; none when every segment fits one run. Equal
// elements keep their order (stable). Only for_each over raw pointers: the same text runs on the OpenMP
// system (thrust::sort's OpenMP version reads through device references, which UBSan reports) and is
// deterministic on both.
#pragma once

#include <thrust/copy.h>
#include <thrust/execution_policy.h>
#include <thrust/for_each.h>
#include <thrust/iterator/counting_iterator.h>
#include <cuda/atomic>

#include <cstdint>
#include <string>

#include "perch2/core/segments.hpp"
#include "perch2/cuda/launch_plan.hpp"
#include "perch2/cuda/system.hpp"

namespace perch2::thrust_backend {

namespace segsort_detail {

/// Element i's segment range and the first element of its aligned run of `width` elements.
struct RunOf {
  std::int64_t seg_begin, seg_end, run_begin;
};
template <class Offset>
PERCH2_HD inline RunOf run_of(const Offset* offsets, int num_segments, std::int64_t i, std::int64_t width) {
  const int s = find_segment(offsets, num_segments, Offset(i));
  const std::int64_t o = offsets[s], e = offsets[s + 1];
  return {o, e, o + (i - o) / width * width};
}

/// One pass over every element i, reading (a, b) and writing (a_out, b_out).
///   merge == false (pass 1): i's rank within its run of `width` elements (stable), written at that rank.
///   merge == true: runs [base, base + width) and [base + width, base + 2 width) of a segment (cut at its
///   end) become one sorted run; i's place = its rank in its own run + the other run's elements before it
///   (ties: the left run's elements first).
template <class Offset, class A, class B, class Less>
struct SortPass {
  const Offset* offsets;
  int num_segments;
  std::int64_t width;
  bool merge;
  const A* a;
  const B* b;
  A* a_out;
  B* b_out;
  Less less;

  PERCH2_HD void operator()(std::int64_t i) const {
    if (merge)
      merge_runs(i);
    else
      sort_run(i);
  }
  PERCH2_HD void sort_run(std::int64_t i) const {
    const RunOf r = run_of(offsets, num_segments, i, width);
    const std::int64_t last = r.run_begin + width < r.seg_end ? r.run_begin + width : r.seg_end;
    const A ai = a[i];
    const B bi = b[i];
    std::int64_t rank = 0;
    for (std::int64_t j = r.run_begin; j < last; ++j)
      rank += (less(a[j], b[j], ai, bi) || (j < i && !less(ai, bi, a[j], b[j]))) ? 1 : 0;
    a_out[r.run_begin + rank] = ai;
    b_out[r.run_begin + rank] = bi;
  }
  PERCH2_HD void merge_runs(std::int64_t i) const {
    const RunOf r = run_of(offsets, num_segments, i, 2 * width);
    const std::int64_t base = r.run_begin;
    const std::int64_t mid = base + width < r.seg_end ? base + width : r.seg_end;
    const std::int64_t end = base + 2 * width < r.seg_end ? base + 2 * width : r.seg_end;
    const A ai = a[i];
    const B bi = b[i];
    const bool left = i < mid;
    std::int64_t lo = left ? mid : base, hi = left ? end : mid;  // search the other run
    while (lo < hi) {
      const std::int64_t m = lo + (hi - lo) / 2;
      // Left elements go after the right run's smaller ones; right elements after the left run's
      // smaller-or-equal ones.
      const bool before = left ? less(a[m], b[m], ai, bi) : !less(ai, bi, a[m], b[m]);
      if (before)
        lo = m + 1;
      else
        hi = m;
    }
    const std::int64_t pos = left ? (i - base) + (lo - mid) : (i - mid) + (lo - base);
    a_out[base + pos] = ai;
    b_out[base + pos] = bi;
  }
};

/// Largest segment size, by atomic maximum (a compare-exchange loop: Debian's libcu++ has no fetch_max).
template <class Offset>
struct MaxSegment {
  const Offset* offsets;
  std::int64_t* max_size;
  PERCH2_HD void operator()(std::int64_t s) const {
    const std::int64_t n = std::int64_t(offsets[s + 1]) - std::int64_t(offsets[s]);
    cuda::atomic_ref<std::int64_t, cuda::thread_scope_device> m(*max_size);
    std::int64_t seen = m.load(cuda::memory_order_relaxed);
    while (n > seen && !m.compare_exchange_weak(seen, n, cuda::memory_order_relaxed)) {
    }
  }
};

}  // namespace segsort_detail

/// Largest segment of num_segments + 1 device offsets (one pass and one scalar to the host). `scalar` is
/// one element of device memory.
template <class Offset>
std::int64_t max_segment_size(const Offset* offsets, std::int64_t num_segments, std::int64_t* scalar,
                              LaunchShape& shape, const std::string& name) {
  if (num_segments <= 0) return 0;
  thrust::fill_n(thrust::device, scalar, 1, std::int64_t(0));
  thrust::for_each(thrust::device, thrust::counting_iterator<std::int64_t>(0),
                   thrust::counting_iterator<std::int64_t>(num_segments),
                   segsort_detail::MaxSegment<Offset>{offsets, scalar});
  shape.launch(name, 1, num_segments);
  std::int64_t out = 0;
  thrust::copy_n(thrust::device_pointer_cast(scalar), 1, &out);
  return out;
}

/// Sorts every segment of (a, b) (n elements, num_segments + 1 device offsets, the largest segment
/// max_segment elements) in place; a_tmp and b_tmp are n-element scratch arrays. less(a_i, b_i, a_j, b_j)
/// is a strict weak order. Records its passes in `shape` as name + "_runs" / "_merge" / "_copy".
template <class Offset, class A, class B, class Less>
void segmented_sort(const Offset* offsets, int num_segments, std::int64_t n, std::int64_t max_segment, A* a,
                    B* b, A* a_tmp, B* b_tmp, Less less, LaunchShape& shape, const std::string& name) {
  using namespace segsort_detail;
  if (n == 0 || max_segment <= 1) return;
  const thrust::counting_iterator<std::int64_t> first(0);
  const std::int64_t run = segmented_sort_run;
  using Pass = SortPass<Offset, A, B, Less>;
  thrust::for_each(thrust::device, first, first + n,
                   Pass{offsets, num_segments, run, false, a, b, a_tmp, b_tmp, less});
  shape.launch(name + "_runs", 1, n);
  bool in_tmp = true;
  for (const std::int64_t width : segmented_sort_merge_widths(max_segment)) {
    const A* ai = in_tmp ? a_tmp : a;
    const B* bi = in_tmp ? b_tmp : b;
    thrust::for_each(
        thrust::device, first, first + n,
        Pass{offsets, num_segments, width, true, ai, bi, in_tmp ? a : a_tmp, in_tmp ? b : b_tmp, less});
    shape.launch(name + "_merge", 1, n);
    in_tmp = !in_tmp;
  }
  if (in_tmp) {
    thrust::copy(thrust::device, a_tmp, a_tmp + n, a);
    thrust::copy(thrust::device, b_tmp, b_tmp + n, b);
    shape.launch(name + "_copy", 1, n);
  }
}

}  // namespace perch2::thrust_backend
