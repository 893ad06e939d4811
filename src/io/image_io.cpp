// Depth, colour and label images through OpenCV's codecs (decoded from and encoded to memory, so that every
// file-system problem is reported by perch2 with its reason).
#include "perch2/io/image_io.hpp"

#include <algorithm>
#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "io_detail.hpp"

namespace perch2::io {

namespace {

enum class Codec { Png, Jpeg, Other };

Codec sniff(const std::string& bytes) {
  static const char png_magic[8] = {'\x89', 'P', 'N', 'G', '\r', '\n', '\x1a', '\n'};
  if (bytes.size() >= 8 && std::equal(png_magic, png_magic + 8, bytes.begin())) return Codec::Png;
  if (bytes.size() >= 3 && bytes[0] == '\xff' && bytes[1] == '\xd8' && bytes[2] == '\xff') return Codec::Jpeg;
  return Codec::Other;
}

/// libpng and libjpeg decode truncated files into partly blank images with only a warning: check the end.
void check_complete(const std::string& path, const std::string& bytes, Codec codec) {
  if (codec == Codec::Png) {
    // The last chunk is IEND (type + 4-byte CRC).
    const std::size_t iend = bytes.rfind("IEND");
    if (iend == std::string::npos || iend + 8 > bytes.size())
      throw FileError(path, "truncated PNG (no IEND chunk at the end)");
  } else if (codec == Codec::Jpeg) {
    // The entropy-coded data after the last start-of-scan marker (FF DA) cannot contain FF D9 (end of image)
    // except as the real end, so an EOI after the last SOS means the main image is complete.
    const std::size_t sos = bytes.rfind("\xff\xda");
    const std::size_t eoi = bytes.rfind("\xff\xd9");
    if (sos == std::string::npos || eoi == std::string::npos || eoi < sos)
      throw FileError(path, "truncated JPEG (no end-of-image marker after the image data)");
  }
}

std::string describe(const cv::Mat& m) {
  const int depth = m.depth();
  const std::string bits = depth == CV_8U    ? "8-bit"
                           : depth == CV_16U ? "16-bit"
                           : depth == CV_32F ? "float"
                                             : "unusual";
  return bits + " " + std::to_string(m.channels()) + "-channel " + std::to_string(m.cols) + "x" +
         std::to_string(m.rows);
}

/// Decodes an image file's bytes as stored (no conversions); `path` names them in errors.
cv::Mat decode(const std::string& bytes, const std::string& path, bool png_only) {
  if (bytes.empty()) throw FileError(path, "empty file");
  const Codec codec = sniff(bytes);
  if (codec == Codec::Other) throw FileError(path, png_only ? "not a PNG file" : "not a PNG or JPEG file");
  if (png_only && codec != Codec::Png) throw FileError(path, "not a PNG file (a PNG is required)");
  check_complete(path, bytes, codec);
  cv::Mat image;
  try {
    const cv::Mat buffer(1, int(bytes.size()), CV_8U, const_cast<char*>(bytes.data()));
    image = cv::imdecode(buffer, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    throw FileError(path, std::string("corrupt image data (") + e.what() + ")");
  }
  if (image.empty() || image.cols <= 0 || image.rows <= 0)
    throw FileError(path, std::string("corrupt ") + (codec == Codec::Png ? "PNG" : "JPEG") +
                              " data (the image could not be decoded)");
  return image;
}

void check_png_path(const std::string& path, const std::string& what) {
  if (detail::lower_extension(path) != ".png")
    throw InvalidInput(path, what + " must be written as PNG (the path must end in .png)");
}

void encode_and_write(const std::string& path, const cv::Mat& image, const std::string& ext,
                      const std::vector<int>& params = {}) {
  std::vector<uchar> buffer;
  bool ok = false;
  try {
    ok = cv::imencode(ext, image, buffer, params);
  } catch (const cv::Exception& e) {
    throw FileError(path, std::string("could not be encoded (") + e.what() + ")");
  }
  if (!ok) throw FileError(path, "could not be encoded as " + ext);
  detail::write_file_bytes(path, buffer.data(), buffer.size());
}

template <class T>
void check_not_empty(const Image<T>& image, const std::string& path, const std::string& what) {
  if (image.empty() || image.width <= 0 || image.height <= 0)
    throw InvalidInput(path, "cannot write an empty " + what + " image");
  check_size(image, image.width, image.height, path);
}

}  // namespace

std::string read_file(const std::string& path) {
  return detail::read_file_bytes(path);
}

DepthImage load_depth_png(const std::string& path, float metres_per_unit) {
  return decode_depth_png(detail::read_file_bytes(path), path, metres_per_unit);
}

DepthImage decode_depth_png(const std::string& bytes, const std::string& path, float metres_per_unit) {
  if (!std::isfinite(metres_per_unit) || metres_per_unit <= 0)
    throw InvalidInput("metres_per_unit", "must be finite and > 0, got " + std::to_string(metres_per_unit));
  const cv::Mat m = decode(bytes, path, true);
  if (m.type() != CV_16UC1)
    throw FileError(path, "expected a 16-bit single-channel depth PNG, got a " + describe(m) + " image");
  DepthImage depth(m.cols, m.rows);
  for (int v = 0; v < m.rows; ++v) {
    const std::uint16_t* row = m.ptr<std::uint16_t>(v);
    for (int u = 0; u < m.cols; ++u) depth(u, v) = float(row[u]) * metres_per_unit;
  }
  return depth;
}

void save_depth_png(const std::string& path, const DepthImage& depth_m, float metres_per_unit) {
  if (!std::isfinite(metres_per_unit) || metres_per_unit <= 0)
    throw InvalidInput("metres_per_unit", "must be finite and > 0, got " + std::to_string(metres_per_unit));
  check_not_empty(depth_m, path, "depth");
  check_png_path(path, "depth");
  cv::Mat m(depth_m.height, depth_m.width, CV_16UC1);
  for (int v = 0; v < m.rows; ++v) {
    std::uint16_t* row = m.ptr<std::uint16_t>(v);
    for (int u = 0; u < m.cols; ++u) {
      const float d = depth_m(u, v);
      const std::string where = " at pixel (" + std::to_string(u) + ", " + std::to_string(v) + ")";
      if (!std::isfinite(d) || d < 0)
        throw InvalidInput(path,
                           "depth" + where + " is " + std::to_string(d) + "; it must be finite and >= 0");
      const double units = std::nearbyint(double(d) / double(metres_per_unit));
      if (units > 65535.0)
        throw InvalidInput(path, "depth" + where + " is " + std::to_string(d) +
                                     " m = " + std::to_string(units) + " units of " +
                                     std::to_string(metres_per_unit) + " m, beyond the 16-bit maximum 65535");
      row[u] = std::uint16_t(units);
    }
  }
  encode_and_write(path, m, ".png");
}

ColorImage load_color_image(const std::string& path) {
  return decode_color_image(detail::read_file_bytes(path), path);
}

ColorImage decode_color_image(const std::string& bytes, const std::string& path) {
  const cv::Mat m = decode(bytes, path, false);
  if (m.depth() != CV_8U)
    throw FileError(path, "expected an 8-bit colour image, got a " + describe(m) + " image");
  const int channels = m.channels();
  if (channels != 1 && channels != 3 && channels != 4)
    throw FileError(path, "expected a grey, RGB or RGBA image, got a " + describe(m) + " image");
  // OpenCV stores BGR(A): convert while copying (no intermediate image: textures are 4096x4096).
  ColorImage image(m.cols, m.rows);
  for (int v = 0; v < m.rows; ++v) {
    const std::uint8_t* row = m.ptr<std::uint8_t>(v);
    Rgb8* out = &image(0, v);
    if (channels == 1)
      for (int u = 0; u < m.cols; ++u) out[u] = Rgb8{row[u], row[u], row[u]};
    else
      for (int u = 0; u < m.cols; ++u) {
        const std::uint8_t* p = row + channels * u;
        out[u] = Rgb8{p[2], p[1], p[0]};
      }
  }
  return image;
}

void save_color_image(const std::string& path, const ColorImage& rgb) {
  check_not_empty(rgb, path, "colour");
  const std::string ext = detail::lower_extension(path);
  std::vector<int> params;
  if (ext == ".jpg" || ext == ".jpeg")
    params = {cv::IMWRITE_JPEG_QUALITY, 95};
  else if (ext != ".png")
    throw InvalidInput(path, "colour images are written as .png, .jpg or .jpeg, not '" + ext + "'");
  cv::Mat bgr(rgb.height, rgb.width, CV_8UC3);
  for (int v = 0; v < bgr.rows; ++v) {
    cv::Vec3b* row = bgr.ptr<cv::Vec3b>(v);
    for (int u = 0; u < bgr.cols; ++u) {
      const Rgb8 c = rgb(u, v);
      row[u] = cv::Vec3b(c.b, c.g, c.r);
    }
  }
  encode_and_write(path, bgr, ext, params);
}

LabelImage load_label_png(const std::string& path) {
  return decode_label_png(detail::read_file_bytes(path), path);
}

LabelImage decode_label_png(const std::string& bytes, const std::string& path) {
  const cv::Mat m = decode(bytes, path, true);
  if (m.type() != CV_8UC1 && m.type() != CV_16UC1)
    throw FileError(path,
                    "expected an 8- or 16-bit single-channel label PNG, got a " + describe(m) + " image");
  LabelImage labels(m.cols, m.rows);
  for (int v = 0; v < m.rows; ++v) {
    if (m.depth() == CV_8U) {
      const std::uint8_t* row = m.ptr<std::uint8_t>(v);
      for (int u = 0; u < m.cols; ++u) labels(u, v) = row[u];
    } else {
      const std::uint16_t* row = m.ptr<std::uint16_t>(v);
      for (int u = 0; u < m.cols; ++u) labels(u, v) = row[u];
    }
  }
  return labels;
}

void save_label_png(const std::string& path, const LabelImage& labels) {
  check_not_empty(labels, path, "label");
  check_png_path(path, "labels");
  std::int32_t max_label = 0;
  for (std::size_t i = 0; i < labels.data.size(); ++i) {
    const std::int32_t l = labels.data[i];
    if (l < 0 || l > 65535)
      throw InvalidInput(path, "label " + std::to_string(l) + " at pixel (" +
                                   std::to_string(i % labels.width) + ", " +
                                   std::to_string(i / labels.width) + ") is outside [0, 65535]");
    max_label = std::max(max_label, l);
  }
  cv::Mat m(labels.height, labels.width, max_label <= 255 ? CV_8UC1 : CV_16UC1);
  for (int v = 0; v < m.rows; ++v)
    for (int u = 0; u < m.cols; ++u) {
      if (m.depth() == CV_8U)
        m.at<std::uint8_t>(v, u) = std::uint8_t(labels(u, v));
      else
        m.at<std::uint16_t>(v, u) = std::uint16_t(labels(u, v));
    }
  encode_and_write(path, m, ".png");
}

}  // namespace perch2::io
