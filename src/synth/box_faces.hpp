// The six faces of an axis-aligned box centred at the origin (internal to perch2::synth).
#pragma once

namespace perch2::synth::detail {

/// Corners of each face as signs of (x, y, z) half-sizes, ordered bottom-left, bottom-right, top-right,
/// top-left as seen from outside (side faces: up = +z; top: up = +y; bottom: seen from below, up = +y).
/// Faces: -y (front), +x, +y (back), -x, +z, -z. Triangles (0, 1, 2) and (0, 2, 3) wind outward.
inline constexpr float kBoxFaces[6][4][3] = {{{-1, -1, -1}, {1, -1, -1}, {1, -1, 1}, {-1, -1, 1}},
                                             {{1, -1, -1}, {1, 1, -1}, {1, 1, 1}, {1, -1, 1}},
                                             {{1, 1, -1}, {-1, 1, -1}, {-1, 1, 1}, {1, 1, 1}},
                                             {{-1, 1, -1}, {-1, -1, -1}, {-1, -1, 1}, {-1, 1, 1}},
                                             {{-1, -1, 1}, {1, -1, 1}, {1, 1, 1}, {-1, 1, 1}},
                                             {{1, -1, -1}, {-1, -1, -1}, {-1, 1, -1}, {1, 1, -1}}};

}  // namespace perch2::synth::detail
