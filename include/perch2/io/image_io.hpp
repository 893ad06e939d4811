// Reading and writing images: 16-bit depth PNGs with a depth scale, 8-bit colour PNG/JPG, label PNGs.
//
// Problems with a file (missing, unreadable, corrupt or truncated bytes, the wrong kind of image) raise
// perch2::FileError naming the file and the reason. Bad arguments or image contents raise InvalidInput.
// Each load_* reads the file and decodes its bytes with the matching decode_*, which also takes bytes from
// memory (e.g. sent by a process that can read the file) and names `path`, where they came from, in errors.
#pragma once

#include <string>

#include "perch2/core/image.hpp"

namespace perch2::io {

/// Loads a 16-bit single-channel PNG depth image and converts it to metres: depth_m = value * metres_per_unit
/// (BOP / LINEMOD / YCB-Video use 0.001 m per unit, i.e. millimetres; BOP scene_camera.json gives
/// "depth_scale" in millimetres per unit, so pass depth_scale * 0.001). 0 stays 0 ("no reading").
/// metres_per_unit must be finite and > 0 (InvalidInput). Any other kind of image raises FileError.
DepthImage load_depth_png(const std::string& path, float metres_per_unit = 0.001f);

/// load_depth_png from the file's bytes; `path` names them in errors.
DepthImage decode_depth_png(const std::string& bytes, const std::string& path,
                            float metres_per_unit = 0.001f);

/// Writes depth (metres) as a 16-bit single-channel PNG: value = round(depth_m / metres_per_unit).
/// Raises InvalidInput for an empty image, a path not ending in ".png", a non-finite or negative depth, or a
/// depth beyond 65535 units (65.535 m at the default 0.001 m per unit); FileError if it cannot be written.
void save_depth_png(const std::string& path, const DepthImage& depth_m, float metres_per_unit = 0.001f);

/// Loads an 8-bit PNG or JPEG colour image (RGB; grey images are replicated to RGB, alpha is dropped).
/// 16-bit images, truncated or corrupt files raise FileError.
ColorImage load_color_image(const std::string& path);

/// load_color_image from the file's bytes; `path` names them in errors.
ColorImage decode_color_image(const std::string& bytes, const std::string& path);

/// Writes an 8-bit RGB image; the format follows the extension (".png" lossless, ".jpg"/".jpeg" quality 95).
/// Raises InvalidInput for an empty image or an unsupported extension, FileError if it cannot be written.
void save_color_image(const std::string& path, const ColorImage& rgb);

/// Loads an 8- or 16-bit single-channel PNG of labels (e.g. a BOP mask_visib image, 0 = background).
LabelImage load_label_png(const std::string& path);

/// load_label_png from the file's bytes; `path` names them in errors.
LabelImage decode_label_png(const std::string& bytes, const std::string& path);

/// The whole file as bytes (for the decode_* functions); FileError if it is missing, a folder or unreadable.
std::string read_file(const std::string& path);

/// Writes labels as a single-channel PNG: 8-bit if every label is <= 255, else 16-bit. Raises InvalidInput
/// for an empty image, a path not ending in ".png" or labels outside [0, 65535]; FileError if it cannot be
/// written.
void save_label_png(const std::string& path, const LabelImage& labels);

}  // namespace perch2::io
