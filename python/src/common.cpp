#include "common.hpp"

#include <cmath>
#include <limits>
#include <string_view>
#include <unordered_map>

#include "perch2_docs.hpp"  // generated at build time from the headers
#if PERCH2_PY_HAVE_CUDA
#include "perch2/cuda/device.hpp"
#endif

namespace perch2_py {

using perch2::InvalidInput;

const char* doc(const char* key) {
  static const auto* table = [] {
    auto* t = new std::unordered_map<std::string_view, const char*>;
    for (const DocEntry& e : kDocEntries) t->emplace(e.key, e.text);
    return t;
  }();
  const auto it = table->find(key);
  return it == table->end() ? "" : it->second;
}

AnyArray as_array(nb::handle obj, const std::string& name) {
  if (obj.is_none()) throw InvalidInput(name, "is None; an array is needed");
  AnyArray a;
  if (nb::try_cast(obj, a, false)) return a;
  // Lists, tuples, numpy scalars, ...: through numpy.asarray (a copy, as numpy makes it).
  nb::object converted;
  try {
    converted = nb::module_::import_("numpy").attr("asarray")(obj);
  } catch (const nb::python_error&) {
    throw InvalidInput(name, "cannot be converted to an array (got " +
                                 std::string(nb::str(nb::handle(obj.type())).c_str()) + ")");
  }
  if (!nb::try_cast(converted, a, false))
    throw InvalidInput(name,
                       "must be an array on the CPU (numpy, or anything with __dlpack__ on the CPU); got " +
                           std::string(nb::str(nb::handle(obj.type())).c_str()));
  return a;
}

std::string dtype_name(const AnyArray& a) {
  const nb::dlpack::dtype d = a.dtype();
  const auto code = nb::dlpack::dtype_code(d.code);
  std::string kind = code == nb::dlpack::dtype_code::Int       ? "int"
                     : code == nb::dlpack::dtype_code::UInt    ? "uint"
                     : code == nb::dlpack::dtype_code::Float   ? "float"
                     : code == nb::dlpack::dtype_code::Bool    ? "bool"
                     : code == nb::dlpack::dtype_code::Complex ? "complex"
                                                               : "other";
  return kind == "bool" ? kind : kind + std::to_string(d.bits);
}

std::string shape_text(const AnyArray& a) {
  std::string s = "(";
  for (std::size_t d = 0; d < a.ndim(); ++d) s += (d ? ", " : "") + std::to_string(a.shape(d));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

namespace {

bool is_float(const AnyArray& a) {
  return has_dtype<float>(a) || has_dtype<double>(a);
}

bool is_integer(const AnyArray& a) {
  const auto c = nb::dlpack::dtype_code(a.dtype().code);
  return c == nb::dlpack::dtype_code::Int || c == nb::dlpack::dtype_code::UInt;
}

template <class Out>
void copy_any_integer(const AnyArray& a, Out* out) {
  const auto c = nb::dlpack::dtype_code(a.dtype().code);
  const bool u = c == nb::dlpack::dtype_code::UInt;
  switch (a.dtype().bits) {
    case 8:
      return u ? copy_elements<std::uint8_t>(a, out) : copy_elements<std::int8_t>(a, out);
    case 16:
      return u ? copy_elements<std::uint16_t>(a, out) : copy_elements<std::int16_t>(a, out);
    case 32:
      return u ? copy_elements<std::uint32_t>(a, out) : copy_elements<std::int32_t>(a, out);
    default:
      return u ? copy_elements<std::uint64_t>(a, out) : copy_elements<std::int64_t>(a, out);
  }
}

/// Integers as int64 (any integer dtype), for range checks before narrowing.
std::vector<std::int64_t> integers(const AnyArray& a, const std::string& name) {
  if (!is_integer(a)) throw InvalidInput(name, "must hold integers, got " + dtype_name(a));
  std::vector<std::int64_t> v(a.size());
  copy_any_integer(a, v.data());
  return v;
}

void check_hw(const AnyArray& a, const std::string& name, const char* what) {
  if (a.ndim() != 2)
    throw InvalidInput(name,
                       std::string("must be an H x W array (") + what + "), got shape " + shape_text(a));
  if (a.shape(0) == 0 || a.shape(1) == 0) throw InvalidInput(name, "is empty, shape " + shape_text(a));
  if (a.shape(0) > 1000000 || a.shape(1) > 1000000)
    throw InvalidInput(name, "is too large: " + shape_text(a));
}

}  // namespace

std::vector<float> float_rows(nb::handle obj, const std::string& name, std::size_t cols, std::size_t* rows,
                              bool allow_1d) {
  const AnyArray a = as_array(obj, name);
  if (!is_float(a) && !is_integer(a))
    throw InvalidInput(name, "must hold real numbers, got " + dtype_name(a));
  const bool one = allow_1d && a.ndim() == 1 && a.shape(0) == cols;
  if (!one && !(a.ndim() == 2 && a.shape(1) == cols))
    throw InvalidInput(name, "must have shape (n, " + std::to_string(cols) + "), got " + shape_text(a));
  *rows = one ? 1 : a.shape(0);
  std::vector<float> out(a.size());
  if (has_dtype<float>(a)) {
    copy_elements<float>(a, out.data());
  } else if (has_dtype<double>(a)) {
    copy_elements<double>(a, out.data());
  } else {
    std::vector<std::int64_t> v(a.size());
    copy_any_integer(a, v.data());
    for (std::size_t i = 0; i < v.size(); ++i) out[i] = float(v[i]);
  }
  return out;
}

std::vector<std::int32_t> int_vector(nb::handle obj, const std::string& name, long n) {
  const AnyArray a = as_array(obj, name);
  if (a.ndim() != 1) throw InvalidInput(name, "must be a 1-D array, got shape " + shape_text(a));
  if (n >= 0 && a.shape(0) != std::size_t(n))
    throw InvalidInput(name,
                       "must have " + std::to_string(n) + " entries, got " + std::to_string(a.shape(0)));
  std::vector<std::int32_t> out;
  for (const std::int64_t v : integers(a, name)) {
    if (v < std::numeric_limits<std::int32_t>::min() || v > std::numeric_limits<std::int32_t>::max())
      throw InvalidInput(name, "value " + std::to_string(v) + " does not fit in int32");
    out.push_back(std::int32_t(v));
  }
  return out;
}

perch2::DepthImage depth_from(nb::handle obj, const std::string& name, std::optional<float> depth_scale_m) {
  const AnyArray a = as_array(obj, name);
  check_hw(a, name, "depth");
  perch2::DepthImage out(int(a.shape(1)), int(a.shape(0)));
  if (has_dtype<float>(a)) {
    if (depth_scale_m)
      throw InvalidInput("depth_scale_m", "applies to uint16 depth only; float32 depth is already in metres");
    copy_elements<float>(a, out.data.data());
  } else if (has_dtype<std::uint16_t>(a)) {
    if (!depth_scale_m)
      throw InvalidInput(name, "is uint16: pass depth_scale_m (metres per unit, e.g. 0.001 for millimetres)");
    const float s = *depth_scale_m;
    if (!(std::isfinite(s) && s > 0)) throw InvalidInput("depth_scale_m", "must be finite and > 0");
    std::vector<std::uint16_t> raw(a.size());
    copy_elements<std::uint16_t>(a, raw.data());
    for (std::size_t i = 0; i < raw.size(); ++i) out.data[i] = float(raw[i]) * s;
  } else {
    throw InvalidInput(name, "must be float32 (metres) or uint16 (with depth_scale_m), got " + dtype_name(a) +
                                 (has_dtype<double>(a) ? " (use depth.astype(numpy.float32))" : ""));
  }
  return out;
}

perch2::ColorImage rgb_from(nb::handle obj, const std::string& name) {
  if (obj.is_none()) return {};
  const AnyArray a = as_array(obj, name);
  if (!has_dtype<std::uint8_t>(a))
    throw InvalidInput(name, "must be uint8 (8-bit sRGB), got " + dtype_name(a));
  if (a.ndim() != 3 || a.shape(2) != 3)
    throw InvalidInput(name, "must be an H x W x 3 array (RGB), got shape " + shape_text(a));
  if (a.shape(0) == 0 || a.shape(1) == 0) throw InvalidInput(name, "is empty, shape " + shape_text(a));
  perch2::ColorImage out(int(a.shape(1)), int(a.shape(0)));
  static_assert(sizeof(perch2::Rgb8) == 3, "Rgb8 is packed");
  copy_elements<std::uint8_t>(a, reinterpret_cast<std::uint8_t*>(out.data.data()));
  return out;
}

perch2::Image<std::uint8_t> mask_from(nb::handle obj, const std::string& name) {
  const AnyArray a = as_array(obj, name);
  if (!(has_dtype<bool>(a) || has_dtype<std::uint8_t>(a)))
    throw InvalidInput(name, "must be a bool or uint8 mask (non-zero = inside), got " + dtype_name(a));
  check_hw(a, name, "mask");
  perch2::Image<std::uint8_t> out(int(a.shape(1)), int(a.shape(0)));
  copy_elements<std::uint8_t>(a, out.data.data());  // bool is one byte, 0 or 1
  return out;
}

perch2::LabelImage labels_from(nb::handle obj, const std::string& name) {
  const AnyArray a = as_array(obj, name);
  check_hw(a, name, "labels");
  const std::vector<std::int64_t> v = integers(a, name);
  perch2::LabelImage out(int(a.shape(1)), int(a.shape(0)));
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (v[i] < std::numeric_limits<std::int32_t>::min() || v[i] > std::numeric_limits<std::int32_t>::max())
      throw InvalidInput(name, "label " + std::to_string(v[i]) + " does not fit in int32");
    out.data[i] = std::int32_t(v[i]);
  }
  return out;
}

perch2::Intrinsics intrinsics_from(nb::handle obj, const std::string& name, int width, int height) {
  perch2::Intrinsics K;
  if (nb::try_cast(obj, K, false)) return K;
  std::size_t rows = 0;
  const std::vector<float> m =
      float_rows(obj, name + " (3 x 3 camera matrix or perch2.Intrinsics)", 3, &rows);
  if (rows != 3) throw InvalidInput(name, "must be a 3 x 3 camera matrix or a perch2.Intrinsics");
  if (m[1] != 0.f || m[3] != 0.f || m[6] != 0.f || m[7] != 0.f || m[8] != 1.f)
    throw InvalidInput(name, "must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)");
  K.fx = m[0], K.cx = m[2], K.fy = m[4], K.cy = m[5], K.width = width, K.height = height;
  K.validate(name);
  return K;
}

perch2::Pose pose_from(nb::handle obj, const std::string& name) {
  const AnyArray a = as_array(obj, name);
  if (a.ndim() != 2 || a.shape(0) != 4 || a.shape(1) != 4)
    throw InvalidInput(name, "must be a 4 x 4 pose, got shape " + shape_text(a));
  std::size_t rows = 0;
  const std::vector<float> m = float_rows(obj, name, 4, &rows);
  if (m[12] != 0.f || m[13] != 0.f || m[14] != 0.f || m[15] != 1.f)
    throw InvalidInput(name, "must be a rigid transform: its last row must be [0, 0, 0, 1]");
  perch2::Pose T = perch2::Pose::Identity();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) T.matrix()(r, c) = m[std::size_t(4 * r + c)];
  if (!perch2::is_valid_pose(T))
    throw InvalidInput(name, "is not a finite rigid transform (R orthonormal, det +1)");
  return T;
}

std::vector<perch2::Pose> poses_from(nb::handle obj, const std::string& name) {
  const AnyArray a = as_array(obj, name);
  if (a.ndim() == 2) return {pose_from(obj, name)};
  if (a.ndim() != 3 || a.shape(1) != 4 || a.shape(2) != 4)
    throw InvalidInput(name, "must have shape (n, 4, 4) or (4, 4), got " + shape_text(a));
  if (!is_float(a)) throw InvalidInput(name, "must be float32 or float64 poses, got " + dtype_name(a));
  std::vector<float> m(a.size());
  if (has_dtype<float>(a))
    copy_elements<float>(a, m.data());
  else
    copy_elements<double>(a, m.data());
  std::vector<perch2::Pose> out(a.shape(0), perch2::Pose::Identity());
  for (std::size_t k = 0; k < out.size(); ++k) {
    const float* p = m.data() + 16 * k;
    const std::string who = name + "[" + std::to_string(k) + "]";
    if (p[12] != 0.f || p[13] != 0.f || p[14] != 0.f || p[15] != 1.f)
      throw InvalidInput(who, "must be a rigid transform: its last row must be [0, 0, 0, 1]");
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) out[k].matrix()(r, c) = p[4 * r + c];
    if (!perch2::is_valid_pose(out[k])) throw InvalidInput(who, "is not a finite rigid transform");
  }
  return out;
}

perch2::RgbdFrame frame_from(nb::handle depth, nb::handle rgb, nb::handle K,
                             std::optional<float> depth_scale_m) {
  perch2::RgbdFrame f;
  f.depth_m = depth_from(depth, "depth", depth_scale_m);
  f.camera = intrinsics_from(K, "K", f.depth_m.width, f.depth_m.height);
  if (f.camera.width != f.depth_m.width || f.camera.height != f.depth_m.height)
    throw InvalidInput("depth", "is " + std::to_string(f.depth_m.width) + " x " +
                                    std::to_string(f.depth_m.height) + " (W x H) but K is for " +
                                    std::to_string(f.camera.width) + " x " + std::to_string(f.camera.height));
  f.rgb = rgb_from(rgb, "rgb");
  if (!f.rgb.empty() && (f.rgb.width != f.depth_m.width || f.rgb.height != f.depth_m.height))
    throw InvalidInput("rgb", "is " + std::to_string(f.rgb.width) + " x " + std::to_string(f.rgb.height) +
                                  " (W x H) but depth is " + std::to_string(f.depth_m.width) + " x " +
                                  std::to_string(f.depth_m.height));
  perch2::check_depth_values(f.depth_m, "depth");
  return f;
}

nb::ndarray<nb::numpy, float> pose_array(const perch2::Pose& T) {
  std::vector<float> m(16);
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) m[std::size_t(4 * r + c)] = T.matrix()(r, c);
  return owned(std::move(m), {4, 4});
}

nb::ndarray<nb::numpy, float> poses_array(const std::vector<perch2::Pose>& T) {
  std::vector<float> m(16 * T.size());
  for (std::size_t k = 0; k < T.size(); ++k)
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) m[16 * k + std::size_t(4 * r + c)] = T[k].matrix()(r, c);
  return owned(std::move(m), {T.size(), 4, 4});
}

BackendId parse_backend(const std::string& name) {
  if (name == "cpu") return BackendId::Cpu;
  if (name == "thrust_omp") return BackendId::ThrustOmp;
  if (name == "cuda") {
#if PERCH2_PY_HAVE_CUDA
    // Without a usable GPU the CUDA runtime would fail on the first allocation (a MemoryError): say why here.
    if (perch2::cuda::device_count() == 0)
      throw InvalidInput("backend", "'cuda': " + perch2::cuda::device_summary());
    return BackendId::Cuda;
#else
    throw InvalidInput("backend",
                       "'cuda': perch2 was built without CUDA (no nvcc at build time; rebuild with nvcc "
                       "and PERCH2_WITH_CUDA=ON); built backends: cpu, thrust_omp");
#endif
  }
  std::string built;
  for (const auto& b : backends_built()) built += (built.empty() ? "" : "|") + b;
  throw InvalidInput("backend", "unknown backend '" + name + "' (" + built + ")");
}

const char* backend_name(BackendId b) {
  return b == BackendId::Cpu ? "cpu" : b == BackendId::ThrustOmp ? "thrust_omp" : "cuda";
}

std::vector<std::string> backends_built() {
#if PERCH2_PY_HAVE_CUDA
  return {"cpu", "thrust_omp", "cuda"};
#else
  return {"cpu", "thrust_omp"};
#endif
}

}  // namespace perch2_py
