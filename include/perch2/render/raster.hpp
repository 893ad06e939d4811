// Device-callable rasterisation kernels shared by every backend (the algorithm text lives once).
//
// Homogeneous rasterisation (Olano & Greer 1997): each triangle (a, b, c) in the camera frame gets three
// edge planes through the camera centre; a pixel ray d = (x, y, 1) hits the triangle iff it lies on the
// inner side of all three. No screen-space clipping is needed: triangles crossing the near plane are
// handled per sample (z >= near).
//
// Conditioning. Scanned models have millimetre triangles a metre away, so every quantity is formed from
// vertex-relative (edge) vectors, never from triple products of the ~1 m position vectors, whose
// cancellation cost up to 3% of the depth in float:
// - edge plane of edge (p, q): p x (q - p) (= p x q), with (p, q) ordered canonically by coordinates, so the
//   two triangles sharing an edge compute the same bits with opposite signs (watertight: a sample on a
//   shared edge is covered by at least one of them);
// - plane normal N = (b - a) x (c - a); depth along d: z = (N . a) / (N . d);
// - barycentrics of the hit p = z d from q = p - a: w_b = (q x e2) . N / |N|^2, w_c = (e1 x q) . N / |N|^2.
//
// The kernels, by concern, under render/raster/ (each includes what it uses):
// - common.hpp: the SSE2 switch, PERCH2_HD_FORCE_INLINE, small branch-free integer helpers;
// - mesh_view.hpp: MeshView, triangle clusters and vertex blocks, cluster culling;
// - grid.hpp: stride-grid geometry (GridRoi, GridRays, grid_cover, model_roi, GridSpan), the z-buffer word;
// - pose_vertices.hpp: vertex posing (VertexPoser, pose_vertices, pose_vertex_blocks);
// - triangle.hpp: triangle set-up and sampling (edge planes, watertightness), covers_exactly in double;
// - shade.hpp: barycentrics, texturing and shading;
// - screen.hpp: candidate triangles from grid spans and the image-space pre-test (ScreenTriangle);
// - rasterize.hpp: the triangle-run rasteriser (rasterize_triangle_run, rasterize_triangles);
// - resolve.hpp: occluder test, resolve pass, shading of resolved samples;
// - render_hypothesis.hpp: one hypothesis start to end in one thread.
#pragma once

#include "perch2/render/raster/common.hpp"
#include "perch2/render/raster/grid.hpp"
#include "perch2/render/raster/mesh_view.hpp"
#include "perch2/render/raster/pose_vertices.hpp"
#include "perch2/render/raster/rasterize.hpp"
#include "perch2/render/raster/render_hypothesis.hpp"
#include "perch2/render/raster/resolve.hpp"
#include "perch2/render/raster/screen.hpp"
#include "perch2/render/raster/shade.hpp"
#include "perch2/render/raster/triangle.hpp"
