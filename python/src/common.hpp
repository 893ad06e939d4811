// Shared pieces of the nanobind bindings: docstrings from the C++ headers, numpy conversions with errors
// that name the argument, poses as 4x4 arrays, and the run-time choice of backend.
#pragma once

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/array.h>
#include <nanobind/stl/map.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "perch2/core/camera.hpp"
#include "perch2/core/cloud.hpp"
#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/cpu/backend.hpp"
#include "perch2/cuda/backend.hpp"

namespace nb = nanobind;
namespace perch2 {
struct SixDofModel;
}

namespace perch2_py {

// ---- docstrings -------------------------------------------------------------------------------------

/// The C++ comment of a declaration ("TabletopSettings.xy_step_m", "file:perch2/search/sixdof.hpp"), as
/// extracted from the headers at build time (python/tools/header_docs.py); "" if it has none.
const char* doc(const char* key);

/// Binds a settings/result field read-write with its C++ comment as the docstring. Type is the struct's
/// unqualified name (the docstring key), so every new C++ field is one line here.
#define PERCH2_RW(cls, Type, field) cls.def_rw(#field, &Type::field, perch2_py::doc(#Type "." #field))
#define PERCH2_RO(cls, Type, field) cls.def_ro(#field, &Type::field, perch2_py::doc(#Type "." #field))
#define PERCH2_ENUM(e, Type, item) e.value(#item, Type::item, perch2_py::doc(#Type "." #item))

// ---- numpy in -----------------------------------------------------------------------------------------

using AnyArray = nb::ndarray<nb::ro, nb::device::cpu>;

/// `obj` as an array on the CPU (anything numpy.asarray accepts); InvalidInput naming `name` otherwise.
AnyArray as_array(nb::handle obj, const std::string& name);

/// numpy's name of an array's element type ("float32", "uint16", ...).
std::string dtype_name(const AnyArray& a);
/// "(480, 640)"
std::string shape_text(const AnyArray& a);

template <class T>
bool has_dtype(const AnyArray& a) {
  return a.dtype() == nb::dtype<T>();
}

/// Copies an array of any strides into contiguous storage (row-major), converting each element to Out.
/// The element type must be In (checked by the caller).
template <class In, class Out>
void copy_elements(const AnyArray& a, Out* out) {
  const std::size_t n = a.size();
  const std::size_t nd = a.ndim();
  bool contiguous = true;
  std::int64_t expect = 1;
  for (std::size_t d = nd; d-- > 0;) {
    if (a.shape(d) != 1 && a.stride(d) != expect) contiguous = false;
    expect *= std::int64_t(a.shape(d));
  }
  const auto* base = static_cast<const In*>(a.data());
  if (contiguous) {
    for (std::size_t i = 0; i < n; ++i) out[i] = Out(base[i]);
    return;
  }
  std::vector<std::size_t> idx(nd, 0);
  for (std::size_t i = 0; i < n; ++i) {
    std::int64_t off = 0;
    for (std::size_t d = 0; d < nd; ++d) off += std::int64_t(idx[d]) * a.stride(d);
    out[i] = Out(base[off]);
    for (std::size_t d = nd; d-- > 0;) {
      if (++idx[d] < a.shape(d)) break;
      idx[d] = 0;
    }
  }
}

/// A float array of shape (n, cols) (or (cols,) as n = 1 when allow_1d) from float32 or float64 input.
std::vector<float> float_rows(nb::handle obj, const std::string& name, std::size_t cols, std::size_t* rows,
                              bool allow_1d = false);
/// A 1-D integer array (any integer dtype, values must fit int32) of length n (n = -1: any).
std::vector<std::int32_t> int_vector(nb::handle obj, const std::string& name, long n = -1);

/// Depth in metres from a float32 (metres) or uint16 (units of depth_scale_m metres) H x W array. Always a
/// copy into C++ storage (perch2's images own their pixels); NaN or negative values are rejected later by
/// the frame's validation with the pixel named.
perch2::DepthImage depth_from(nb::handle obj, const std::string& name, std::optional<float> depth_scale_m);
/// 8-bit sRGB from a uint8 H x W x 3 array (copy); None -> empty image.
perch2::ColorImage rgb_from(nb::handle obj, const std::string& name);
/// A mask (bool or uint8, non-zero = inside) H x W (copy).
perch2::Image<std::uint8_t> mask_from(nb::handle obj, const std::string& name);
/// Labels (any integer dtype, values fit int32) H x W (copy).
perch2::LabelImage labels_from(nb::handle obj, const std::string& name);

/// Intrinsics from a perch2.Intrinsics or a 3 x 3 matrix K (then width x height must be given).
perch2::Intrinsics intrinsics_from(nb::handle obj, const std::string& name, int width, int height);

/// A pose from a 4 x 4 array (float32 or float64, last row 0 0 0 1); InvalidInput naming `name` otherwise.
perch2::Pose pose_from(nb::handle obj, const std::string& name);
/// Poses from an (n, 4, 4) or (4, 4) array (n = 1).
std::vector<perch2::Pose> poses_from(nb::handle obj, const std::string& name);

/// A frame from numpy arrays: depth (float32 metres or uint16 with depth_scale_m), rgb (uint8 HxWx3 or
/// None), K (3x3 or perch2.Intrinsics); sizes checked against each other, values validated.
perch2::RgbdFrame frame_from(nb::handle depth, nb::handle rgb, nb::handle K,
                             std::optional<float> depth_scale_m);

// ---- numpy out ----------------------------------------------------------------------------------------

/// A writable numpy view of C++ storage kept alive by `owner` (a Python object holding it).
template <class T>
nb::ndarray<nb::numpy, T> view(T* data, std::initializer_list<std::size_t> shape, nb::handle owner) {
  return nb::ndarray<nb::numpy, T>(data, shape, owner);
}

/// A numpy array that owns `values` (moved to the heap, freed with the array): no copy of the elements.
template <class T>
nb::ndarray<nb::numpy, T> owned(std::vector<T>&& values, std::initializer_list<std::size_t> shape) {
  auto* heap = new std::vector<T>(std::move(values));
  nb::capsule free_it(heap, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
  return nb::ndarray<nb::numpy, T>(heap->data(), shape, free_it);
}

/// A pose as a new 4 x 4 float32 array (row-major).
nb::ndarray<nb::numpy, float> pose_array(const perch2::Pose& T);
/// Poses as a new (n, 4, 4) float32 array.
nb::ndarray<nb::numpy, float> poses_array(const std::vector<perch2::Pose>& T);

/// A read-write Eigen::Vector3f field as a 3-array property that accepts any array-like of 3 numbers.
template <class T>
void vec3_rw(nb::class_<T>& cls, const char* name, Eigen::Vector3f T::*field, const char* docstring) {
  cls.def_prop_rw(
      name,
      [field](const T& x) {
        return owned(std::vector<float>{(x.*field).x(), (x.*field).y(), (x.*field).z()}, {3});
      },
      [field, name](T& x, nb::handle v) {
        std::size_t n = 0;
        const std::vector<float> a = float_rows(v, name, 3, &n, true);
        if (n != 1) throw perch2::InvalidInput(name, "must be 3 numbers");
        x.*field = Eigen::Vector3f(a[0], a[1], a[2]);
      },
      nb::rv_policy::move, docstring);
}
#define PERCH2_VEC3(cls, Type, field) \
  perch2_py::vec3_rw(cls, #field, &Type::field, perch2_py::doc(#Type "." #field))

// ---- backends -----------------------------------------------------------------------------------------

#if PERCH2_PY_HAVE_CUDA
#define PERCH2_PY_CUDA_ALT(x) , x
#else
#define PERCH2_PY_CUDA_ALT(x)
#endif

enum class BackendId { Cpu, ThrustOmp, Cuda };

/// "cpu" | "thrust_omp" | "cuda"; InvalidInput naming the argument otherwise (and for "cuda" in a build
/// without nvcc).
BackendId parse_backend(const std::string& name);
const char* backend_name(BackendId b);
/// The backend names this build has, e.g. ["cpu", "thrust_omp"].
std::vector<std::string> backends_built();

/// One C++ object per backend, chosen at run time: PerBackend<Of>::Variant holds an Of<cpu::Backend>,
/// Of<thrust_omp::Backend> or (nvcc builds) Of<cuda::Backend>. Calls on one object are serialised by its
/// mutex (the Thrust backend's stages keep workspaces between calls), taken after the GIL is released.
template <template <class> class Of>
struct PerBackend {
  using Variant = std::variant<std::unique_ptr<Of<perch2::cpu::Backend>>,
                               std::unique_ptr<Of<perch2::thrust_omp::Backend>> PERCH2_PY_CUDA_ALT(
                                   std::unique_ptr<Of<perch2::cuda::Backend>>)>;

  BackendId backend = BackendId::ThrustOmp;
  Variant impl;
  std::unique_ptr<std::mutex> mutex = std::make_unique<std::mutex>();

  template <class... Args>
  PerBackend(const std::string& backend_name, Args&&... args) : backend(parse_backend(backend_name)) {
    switch (backend) {
      case BackendId::Cpu:
        impl = std::make_unique<Of<perch2::cpu::Backend>>(std::forward<Args>(args)...);
        break;
      case BackendId::ThrustOmp:
        impl = std::make_unique<Of<perch2::thrust_omp::Backend>>(std::forward<Args>(args)...);
        break;
      case BackendId::Cuda:
#if PERCH2_PY_HAVE_CUDA
        impl = std::make_unique<Of<perch2::cuda::Backend>>(std::forward<Args>(args)...);
#endif
        break;
    }
  }

  /// f(object) with the GIL released and the object's mutex held.
  template <class F>
  auto call(F&& f) const {
    nb::gil_scoped_release release;
    std::lock_guard<std::mutex> lock(*mutex);
    return std::visit([&](const auto& p) { return f(*p); }, impl);
  }
  /// f(object) with the GIL held (quick accessors).
  template <class F>
  decltype(auto) with(F&& f) const {
    return std::visit([&](const auto& p) -> decltype(auto) { return f(*p); }, impl);
  }
};

// ---- the areas, one file each ---------------------------------------------------------------------------

void bind_core(nb::module_& m);        // errors, camera, meshes, frames, clouds (core.cpp)
void bind_stages(nb::module_& m);      // Renderer, KnnIndex, Registration, Cost (stages.cpp)
void bind_dataset(nb::module_& m);     // BOP reader, detections, results CSV (dataset.cpp)
void bind_estimators(nb::module_& m);  // TabletopEstimator, SixDofEstimator, BOP 6-DoF glue (estimators.cpp)
void bind_runner(nb::module_& m);      // BopRunner: per-image BOP estimation, either mode (runner.cpp)
void bind_eval(nb::module_& m);        // evaluation (eval.cpp)
void bind_track(nb::module_& m);       // Tracker over RGB-D streams (track.cpp)

/// SixDofEstimator's and Tracker's models: perch2.SixDofModel or perch2.Mesh (no symmetries) values.
std::vector<perch2::SixDofModel> sixdof_models(nb::handle models);

}  // namespace perch2_py
