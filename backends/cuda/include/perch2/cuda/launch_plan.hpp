// Host-side launch planning of the Thrust stages: how a batch is split into chunks and work items for a
// System's work-item sizes. The stages launch from these plans; bench_launch_shapes uses them to show the
// launch shapes of a system this machine cannot run (CUDA) next to the ones it measures (thrust_omp).
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "perch2/render/raster.hpp"

namespace perch2::thrust_backend {

/// Device arrays are carved at this alignment (bytes) from one allocation.
inline std::size_t arena_aligned(std::size_t bytes) {
  constexpr std::size_t kAlign = 256;
  return (bytes + kAlign - 1) / kAlign * kAlign;
}

/// Offsets of one segmented domain (vertices, triangles or ROI samples) of a chunk: per hypothesis, its
/// elements and its work items (blocks of `block` elements).
struct HostDomain {
  int block = 1;
  std::vector<std::int64_t> elements{0}, blocks{0};
  void add(std::int64_t n) {
    elements.push_back(elements.back() + n);
    blocks.push_back(blocks.back() + (n + block - 1) / block);
  }
};

/// Reserve for a chunk scan's temporary storage: CUB's decoupled look-back needs ~16 bytes per tile of
/// ~2,000 samples, Thrust's OpenMP scan none; pixels / 16 + 4 KiB bounds both.
inline std::size_t render_scan_temp_bytes(std::int64_t pixels) {
  return arena_aligned(std::size_t(pixels) / 16 + 4096);
}

/// Device bytes of one render chunk's arrays, in the order the renderer carves them: posed vertices and
/// spans, three domains' offsets, z-buffer, resolved samples, visibility flags, slots, the compacted
/// outputs (24 bytes per sample: every ROI sample may be visible) and the per-hypothesis output offsets.
inline std::size_t render_chunk_arena_bytes(std::int64_t vertices, int count, std::int64_t pixels) {
  const auto a = arena_aligned;
  const std::size_t V = std::size_t(vertices), H = std::size_t(count) + 1, P = std::size_t(pixels);
  return a(V * sizeof(PosedPoint)) + a(V * sizeof(GridSpan)) + 6 * a(H * 8) + a(P * sizeof(DepthTriangle)) +
         a(P * sizeof(RenderedSample)) + a(P * 4) + a((P + 1) * 8) + 3 * a(P * sizeof(float)) +
         a(P * sizeof(std::uint32_t)) + 2 * a(P * sizeof(std::int32_t)) + a(H * 8);
}

/// All device working memory of one render chunk: its arrays and the scan's temporaries.
inline std::size_t render_chunk_bytes(std::int64_t vertices, int count, std::int64_t pixels) {
  return render_chunk_arena_bytes(vertices, count, pixels) + render_scan_temp_bytes(pixels);
}

/// Hypotheses [first, first + count) rendered together, with their three domains.
struct RenderChunk {
  int first = 0, count = 0;
  HostDomain vertices, triangles, pixels;
  std::size_t arena_bytes() const {
    return render_chunk_arena_bytes(vertices.elements.back(), count, pixels.elements.back());
  }
};

/// Splits a batch into chunks, each grown while its device memory (render_chunk_bytes) fits budget_bytes
/// (a chunk always holds at least one hypothesis). Per hypothesis: its model's vertex and triangle counts
/// and its ROI sample count; block = System::render_elements_per_item.
inline std::vector<RenderChunk> plan_render_chunks(const std::vector<std::int64_t>& vertices,
                                                   const std::vector<std::int64_t>& triangles,
                                                   const std::vector<std::int64_t>& roi_samples,
                                                   std::size_t budget_bytes, int block) {
  const int n = int(roi_samples.size());
  std::vector<RenderChunk> chunks;
  for (int first = 0; first < n;) {
    RenderChunk ch{first, 0, {block}, {block}, {block}};
    for (int h = first; h < n; ++h) {
      if (ch.count > 0 && render_chunk_bytes(ch.vertices.elements.back() + vertices[h], ch.count + 1,
                                             ch.pixels.elements.back() + roi_samples[h]) > budget_bytes)
        break;
      ch.vertices.add(vertices[h]);
      ch.triangles.add(triangles[h]);
      ch.pixels.add(roi_samples[h]);
      ++ch.count;
    }
    first += ch.count;
    chunks.push_back(std::move(ch));
  }
  return chunks;
}

/// A chunk rendered a whole hypothesis per work item (System::render_whole_hypotheses): hypotheses
/// [first, first + count), their ROI samples, and the scratch sizes of each of `workers` work items.
struct WholeRenderChunk {
  int first = 0, count = 0, workers = 1;
  HostDomain pixels;
  /// Scratch per worker: posed vertices and their blocks, front-facing clusters, z-buffer.
  std::int64_t max_vertices = 0, max_clusters = 0, max_roi = 0;
  std::size_t arena_bytes() const {
    return bytes(workers, max_vertices, max_clusters, max_roi, count, pixels.elements.back());
  }
  /// Carved in this order: worker scratch (posed vertices, spans, z-buffer, front-facing clusters, vertex
  /// blocks); counter; ROI offsets, visible counts, output slots; resolved samples (the compacted outputs are
  /// written to the host batch directly).
  static std::size_t bytes(int workers, std::int64_t max_vertices, std::int64_t max_clusters,
                           std::int64_t max_roi, int count, std::int64_t pixels) {
    const auto a = arena_aligned;
    const std::size_t V = std::size_t(max_vertices), R = std::size_t(max_roi), H = std::size_t(count) + 1,
                      P = std::size_t(pixels), W = std::size_t(workers), C = std::size_t(max_clusters),
                      B = std::size_t(vertex_block_words(int(max_vertices)));
    return a(W * V * sizeof(PosedPoint)) + a(W * V * sizeof(GridSpan)) + a(W * R * sizeof(DepthTriangle)) +
           a(W * C * 4) + a(W * B * 8) + a(8) + 3 * a(H * 8) + a(P * sizeof(RenderedSample));
  }
};

/// Splits a batch into whole-hypothesis chunks, each grown while its arena fits budget_bytes (a chunk
/// always holds at least one hypothesis). Per hypothesis: its model's vertex and cluster counts and its ROI
/// samples.
inline std::vector<WholeRenderChunk> plan_whole_render_chunks(const std::vector<std::int64_t>& vertices,
                                                              const std::vector<std::int64_t>& clusters,
                                                              const std::vector<std::int64_t>& roi_samples,
                                                              std::size_t budget_bytes, int workers) {
  const int n = int(roi_samples.size());
  std::vector<WholeRenderChunk> chunks;
  for (int first = 0; first < n;) {
    WholeRenderChunk ch;
    ch.first = first, ch.workers = workers;
    for (int h = first; h < n; ++h) {
      const std::int64_t V = std::max(ch.max_vertices, vertices[h]),
                         C = std::max(ch.max_clusters, clusters[h]), R = std::max(ch.max_roi, roi_samples[h]);
      if (ch.count > 0 && WholeRenderChunk::bytes(workers, V, C, R, ch.count + 1,
                                                  ch.pixels.elements.back() + roi_samples[h]) > budget_bytes)
        break;
      ch.pixels.add(roi_samples[h]);
      ++ch.count, ch.max_vertices = V, ch.max_clusters = C, ch.max_roi = R;
    }
    first += ch.count;
    chunks.push_back(std::move(ch));
  }
  return chunks;
}

/// Work items of registration's per-iteration pass: each cloud's points in blocks of points_per_item.
inline std::int64_t registration_items(const std::vector<std::int64_t>& cloud_offsets, int points_per_item) {
  std::int64_t items = 0;
  for (std::size_t c = 0; c + 1 < cloud_offsets.size(); ++c)
    items += (cloud_offsets[c + 1] - cloud_offsets[c] + points_per_item - 1) / points_per_item;
  return items;
}

/// kNN I (tiled all-pairs) tiles: `rows` queries x `width` target columns of float distances within the
/// budget (a tile is at least one query row).
struct KnnTiles {
  std::int64_t rows = 1, width = 1;
};
inline KnnTiles plan_knn_tiles(std::int64_t queries, std::int64_t max_segment, std::size_t budget_bytes) {
  const std::int64_t budget = std::max<std::int64_t>(1, std::int64_t(budget_bytes / sizeof(float)));
  KnnTiles t;
  t.width = std::max<std::int64_t>(1, std::min(max_segment, budget));
  t.rows = std::max<std::int64_t>(1, std::min(queries, budget / t.width));
  return t;
}

/// Segmented sorts (kNN radius results per query, grid cells by point index): elements sorted in one work
/// item by rank in a run (segment-aligned; O(run) compares each), then merged by passes that double the
/// sorted runs (one binary search per element), so no work item handles a whole large segment.
constexpr std::int64_t segmented_sort_run = 16;

/// Run widths of the merge passes for a largest segment of max_segment elements (none if it fits one run).
inline std::vector<std::int64_t> segmented_sort_merge_widths(std::int64_t max_segment) {
  std::vector<std::int64_t> widths;
  for (std::int64_t w = segmented_sort_run; w < max_segment; w *= 2) widths.push_back(w);
  return widths;
}

}  // namespace perch2::thrust_backend
