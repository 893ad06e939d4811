// Errors, camera intrinsics, meshes, RGB-D frames, point-cloud batches and the observed cloud.
#include <cmath>

#include "common.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/observed.hpp"
#include "perch2/io/mesh_io.hpp"

namespace perch2_py {

using namespace perch2;

namespace {

/// Vertex colours from uint8 (0..255) or float (0..1) arrays of shape (n, 3) or (n, 4) (alpha dropped).
std::vector<Rgb8> colors_from(nb::handle obj, std::size_t n, const std::string& name) {
  const AnyArray a = as_array(obj, name);
  if (a.ndim() != 2 || a.shape(0) != n || (a.shape(1) != 3 && a.shape(1) != 4))
    throw InvalidInput(name, "must have shape (" + std::to_string(n) + ", 3) or (" + std::to_string(n) +
                                 ", 4) (one RGB or RGBA colour per vertex), got " + shape_text(a));
  const std::size_t ch = a.shape(1);
  std::vector<float> v(a.size());
  bool unit = false;
  if (has_dtype<std::uint8_t>(a)) {
    copy_elements<std::uint8_t>(a, v.data());
  } else if (has_dtype<float>(a) || has_dtype<double>(a)) {
    has_dtype<float>(a) ? copy_elements<float>(a, v.data()) : copy_elements<double>(a, v.data());
    unit = true;
  } else {
    throw InvalidInput(name, "must be uint8 (0..255) or float (0..1), got " + dtype_name(a));
  }
  std::vector<Rgb8> out(n);
  for (std::size_t i = 0; i < n; ++i) {
    std::uint8_t c[3];
    for (int k = 0; k < 3; ++k) {
      const float x = v[i * ch + std::size_t(k)];
      if (unit && !(x >= 0.f && x <= 1.f)) throw InvalidInput(name, "float colours must lie in [0, 1]");
      c[k] = std::uint8_t(unit ? std::lround(x * 255.f) : x);
    }
    out[i] = {c[0], c[1], c[2]};
  }
  return out;
}

Mesh make_mesh(nb::handle vertices, nb::handle faces, nb::handle colors, nb::handle uv, nb::handle texture,
               const std::string& name, std::optional<std::array<int, 3>> base_color) {
  Mesh m;
  m.name = name;
  std::size_t n = 0;
  const std::vector<float> v = float_rows(vertices, "vertices", 3, &n);
  m.vertices.resize(n);
  for (std::size_t i = 0; i < n; ++i) m.vertices[i] = {v[3 * i], v[3 * i + 1], v[3 * i + 2]};
  const AnyArray f = as_array(faces, "faces");
  if (f.ndim() != 2 || f.shape(1) != 3)
    throw InvalidInput("faces", "must have shape (m, 3) (vertex indices per triangle), got " + shape_text(f));
  std::vector<std::int32_t> idx = int_vector(nb::module_::import_("numpy").attr("ravel")(faces), "faces");
  m.triangles.resize(f.shape(0));
  for (std::size_t t = 0; t < m.triangles.size(); ++t)
    m.triangles[t] = {idx[3 * t], idx[3 * t + 1], idx[3 * t + 2]};
  if (!colors.is_none()) m.vertex_colors = colors_from(colors, n, "colors");
  if (!uv.is_none()) {
    const AnyArray a = as_array(uv, "uv");
    std::size_t rows = 0;
    if (a.ndim() == 3 && a.shape(0) == m.triangles.size() && a.shape(1) == 3 && a.shape(2) == 2) {
      const std::vector<float> c = float_rows(
          nb::module_::import_("numpy").attr("reshape")(uv, nb::make_tuple(-1, 2)), "uv", 2, &rows);
      for (std::size_t i = 0; i < rows; ++i) m.corner_uvs.emplace_back(c[2 * i], c[2 * i + 1]);
    } else if (a.ndim() == 2 && a.shape(0) == n && a.shape(1) == 2) {
      const std::vector<float> c = float_rows(uv, "uv", 2, &rows);
      for (const auto& t : m.triangles)
        for (int k = 0; k < 3; ++k) {
          if (t[k] < 0 || std::size_t(t[k]) >= n) break;  // validate() names the bad index
          m.corner_uvs.emplace_back(c[2 * std::size_t(t[k])], c[2 * std::size_t(t[k]) + 1]);
        }
    } else {
      throw InvalidInput("uv", "must be per vertex (" + std::to_string(n) + ", 2) or per triangle corner (" +
                                   std::to_string(m.triangles.size()) + ", 3, 2), got " + shape_text(a));
    }
  }
  if (!texture.is_none()) m.texture = rgb_from(texture, "texture");
  if (base_color) {
    for (int c : *base_color)
      if (c < 0 || c > 255) throw InvalidInput("base_color", "components must be in 0..255");
    m.base_color = {std::uint8_t((*base_color)[0]), std::uint8_t((*base_color)[1]),
                    std::uint8_t((*base_color)[2])};
  }
  m.validate();
  return m;
}

/// A CloudBatch from arrays; missing per-point arrays get their neutral values.
CloudBatch make_cloud(nb::handle points, nb::handle offsets, nb::handle rgb, nb::handle pixel) {
  CloudBatch c;
  std::size_t n = 0;
  const std::vector<float> p = float_rows(points, "points", 3, &n);
  c.resize(n);
  for (std::size_t i = 0; i < n; ++i) c.x[i] = p[3 * i], c.y[i] = p[3 * i + 1], c.z[i] = p[3 * i + 2];
  if (offsets.is_none()) {
    c.offsets = {0, std::int64_t(n)};
  } else {
    const std::vector<std::int32_t> o = int_vector(offsets, "offsets");
    c.offsets.assign(o.begin(), o.end());
  }
  if (!rgb.is_none()) {
    const std::vector<std::int32_t> v = int_vector(rgb, "rgb", long(n));
    for (std::size_t i = 0; i < n; ++i) c.rgb[i] = std::uint32_t(v[i]);
  }
  if (!pixel.is_none())
    c.pixel = int_vector(pixel, "pixel", long(n));
  else
    std::fill(c.pixel.begin(), c.pixel.end(), -1);
  c.validate("points/offsets");
  for (std::size_t k = 0; k + 1 < c.offsets.size(); ++k)
    for (auto i = c.offsets[k]; i < c.offsets[k + 1]; ++i) c.cloud[std::size_t(i)] = std::int32_t(k);
  return c;
}

template <class T>
nb::object vector_view(nb::handle self, std::vector<T>& v) {
  return nb::cast(view(v.data(), {v.size()}, self));
}

}  // namespace

void bind_core(nb::module_& m) {
  nb::exception<InvalidInput>(m, "InvalidInput", PyExc_ValueError);
  nb::exception<FileError>(m, "FileError", PyExc_OSError);
  m.attr("InvalidInput").attr("__doc__") = doc("InvalidInput");
  m.attr("FileError").attr("__doc__") = doc("FileError");
  m.def("backends", &backends_built,
        "The backend names this build of perch2 has (\"cuda\" only in nvcc builds).");

  nb::class_<Intrinsics> K(m, "Intrinsics", doc("file:perch2/core/camera.hpp"));
  K.def(nb::init<>())
      .def(
          "__init__",
          [](Intrinsics* self, float fx, float fy, float cx, float cy, int width, int height) {
            new (self) Intrinsics{fx, fy, cx, cy, width, height};
            self->validate("Intrinsics");
          },
          nb::arg("fx"), nb::arg("fy"), nb::arg("cx"), nb::arg("cy"), nb::arg("width"), nb::arg("height"))
      .def_static(
          "from_matrix",
          [](nb::handle Km, int width, int height) { return intrinsics_from(Km, "K", width, height); },
          nb::arg("K"), nb::arg("width"), nb::arg("height"),
          "From a 3 x 3 camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] and the image size in pixels.")
      .def_prop_ro(
          "K",
          [](const Intrinsics& k) {
            return owned(std::vector<float>{k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1}, {3, 3});
          },
          nb::rv_policy::move, "The 3 x 3 camera matrix (a new array).")
      .def("at_stride", &Intrinsics::at_stride, nb::arg("stride"), doc("Intrinsics.grid_width"))
      .def("validate", &Intrinsics::validate, nb::arg("name") = "camera intrinsics",
           doc("Intrinsics.validate"))
      .def("__repr__", [](const Intrinsics& k) {
        return "Intrinsics(fx=" + std::to_string(k.fx) + ", fy=" + std::to_string(k.fy) +
               ", cx=" + std::to_string(k.cx) + ", cy=" + std::to_string(k.cy) +
               ", width=" + std::to_string(k.width) + ", height=" + std::to_string(k.height) + ")";
      });
  PERCH2_RW(K, Intrinsics, fx);
  PERCH2_RW(K, Intrinsics, fy);
  PERCH2_RW(K, Intrinsics, cx);
  PERCH2_RW(K, Intrinsics, cy);
  K.def_rw("width", &Intrinsics::width, "image width, pixels");
  K.def_rw("height", &Intrinsics::height, "image height, pixels");

  const std::string mesh_doc =
      std::string(doc("file:perch2/core/mesh.hpp")) +
      "\n\nFrom arrays (every input is copied into the mesh):\n"
      "  vertices (n, 3) float, metres; faces (m, 3) integer vertex indices (counter-clockwise "
      "seen from outside);\n"
      "  colors (n, 3|4) uint8 0..255 or float 0..1 (alpha dropped); uv per vertex (n, 2) or "
      "per triangle corner (m, 3, 2),\n"
      "  OBJ convention (v = 0 at the image bottom), with texture (h, w, 3) uint8.\n"
      "trimesh:  perch2.Mesh(t.vertices, t.faces, colors=t.visual.vertex_colors)\n"
      "Open3D:   perch2.Mesh(np.asarray(o.vertices), np.asarray(o.triangles), "
      "colors=np.asarray(o.vertex_colors))\n"
      "The array properties (vertices, faces, colors, corner_uvs, texture) are views of the "
      "mesh's storage (no copy).";
  nb::class_<Mesh> M(m, "Mesh", mesh_doc.c_str());
  M.def(
       "__init__",
       [](Mesh* self, nb::handle vertices, nb::handle faces, nb::handle colors, nb::handle uv,
          nb::handle texture, const std::string& name, std::optional<std::array<int, 3>> base_color) {
         new (self) Mesh(make_mesh(vertices, faces, colors, uv, texture, name, base_color));
       },
       nb::arg("vertices"), nb::arg("faces"), nb::arg("colors").none() = nb::none(),
       nb::arg("uv").none() = nb::none(), nb::arg("texture").none() = nb::none(), nb::arg("name") = "",
       nb::arg("base_color").none() = nb::none())
      .def_prop_ro(
          "vertices",
          [](nb::handle self) {
            Mesh& me = nb::cast<Mesh&>(self);
            return view(reinterpret_cast<float*>(me.vertices.data()), {me.vertices.size(), 3}, self);
          },
          doc("Mesh.vertices"))
      .def_prop_ro(
          "faces",
          [](nb::handle self) {
            Mesh& me = nb::cast<Mesh&>(self);
            return view(reinterpret_cast<std::int32_t*>(me.triangles.data()), {me.triangles.size(), 3}, self);
          },
          doc("Mesh.triangles"))
      .def_prop_ro(
          "colors",
          [](nb::handle self) -> nb::object {
            Mesh& me = nb::cast<Mesh&>(self);
            if (me.vertex_colors.empty()) return nb::none();
            return nb::cast(view(reinterpret_cast<std::uint8_t*>(me.vertex_colors.data()),
                                 {me.vertex_colors.size(), 3}, self));
          },
          doc("Mesh.vertex_colors"))
      .def_prop_ro(
          "corner_uvs",
          [](nb::handle self) -> nb::object {
            Mesh& me = nb::cast<Mesh&>(self);
            if (me.corner_uvs.empty()) return nb::none();
            return nb::cast(
                view(reinterpret_cast<float*>(me.corner_uvs.data()), {me.corner_uvs.size() / 3, 3, 2}, self));
          },
          doc("Mesh.corner_uvs"))
      .def_prop_ro(
          "texture",
          [](nb::handle self) -> nb::object {
            Mesh& me = nb::cast<Mesh&>(self);
            if (me.texture.empty()) return nb::none();
            return nb::cast(view(reinterpret_cast<std::uint8_t*>(me.texture.data.data()),
                                 {std::size_t(me.texture.height), std::size_t(me.texture.width), 3}, self));
          },
          doc("Mesh.texture"))
      .def_prop_rw(
          "base_color",
          [](const Mesh& me) {
            return std::array<int, 3>{me.base_color.r, me.base_color.g, me.base_color.b};
          },
          [](Mesh& me, std::array<int, 3> c) {
            for (int v : c)
              if (v < 0 || v > 255) throw InvalidInput("base_color", "components must be in 0..255");
            me.base_color = {std::uint8_t(c[0]), std::uint8_t(c[1]), std::uint8_t(c[2])};
          },
          doc("Mesh.base_color"))
      .def("has_texture", &Mesh::has_texture)
      .def("has_vertex_colors", &Mesh::has_vertex_colors)
      .def("validate", &Mesh::validate, doc("Mesh.validate"))
      .def(
          "bounds",
          [](const Mesh& me) {
            const auto b = me.bounds();
            return std::make_pair(std::array<float, 3>{b.min().x(), b.min().y(), b.min().z()},
                                  std::array<float, 3>{b.max().x(), b.max().y(), b.max().z()});
          },
          doc("Mesh.bounds"))
      .def("__repr__", [](const Mesh& me) {
        return "Mesh('" + me.name + "', " + std::to_string(me.vertices.size()) + " vertices, " +
               std::to_string(me.triangles.size()) + " triangles" + (me.has_texture() ? ", textured" : "") +
               (me.has_vertex_colors() ? ", vertex colours" : "") + ")";
      });
  PERCH2_RW(M, Mesh, name);

  m.def(
      "load_mesh",
      [](const std::string& path, float scale) {
        nb::gil_scoped_release release;
        return io::load_mesh(path, {scale});
      },
      nb::arg("path"), nb::arg("scale") = 1.f,
      (std::string(doc("load_mesh")) + "\n\nscale: " + doc("MeshLoadOptions.scale")).c_str());
  m.def(
      "save_ply",
      [](const std::string& path, const Mesh& mesh, bool binary) {
        nb::gil_scoped_release release;
        io::save_ply(path, mesh, binary);
      },
      nb::arg("path"), nb::arg("mesh"), nb::arg("binary") = true, doc("save_ply"));

  nb::class_<RgbdFrame> F(
      m, "RgbdFrame",
      "One registered RGB-D frame: depth (metres, 0 = no reading), optional colour, the camera.\n\n"
      "RgbdFrame(depth, rgb=None, K=..., depth_scale_m=None): depth float32 metres H x W, or uint16 in units "
      "of\n"
      "depth_scale_m metres; rgb uint8 H x W x 3; K a 3 x 3 camera matrix or a perch2.Intrinsics. The "
      "arrays\n"
      "are copied once into the frame (perch2's images own their pixels; a 640 x 480 frame takes well under\n"
      "5 ms, see bench/bench_python.py); depth_m and rgb are then views of the frame's storage, and passing\n"
      "the frame to an estimator copies nothing.");
  F.def(
       "__init__",
       [](RgbdFrame* self, nb::handle depth, nb::handle rgb, nb::handle K,
          std::optional<float> depth_scale_m) {
         new (self) RgbdFrame(frame_from(depth, rgb, K, depth_scale_m));
       },
       nb::arg("depth"), nb::arg("rgb").none() = nb::none(), nb::arg("K"),
       nb::arg("depth_scale_m").none() = nb::none())
      .def_rw("camera", &RgbdFrame::camera, "intrinsics (with the image size)")
      .def_prop_ro(
          "depth_m",
          [](nb::handle self) -> nb::object {
            RgbdFrame& f = nb::cast<RgbdFrame&>(self);
            if (f.depth_m.empty()) return nb::none();
            return nb::cast(view(f.depth_m.data.data(),
                                 {std::size_t(f.depth_m.height), std::size_t(f.depth_m.width)}, self));
          },
          "depth in metres, H x W float32 (a view of the frame's storage), 0 = no reading")
      .def_prop_ro(
          "rgb",
          [](nb::handle self) -> nb::object {
            RgbdFrame& f = nb::cast<RgbdFrame&>(self);
            if (f.rgb.empty()) return nb::none();
            return nb::cast(view(reinterpret_cast<std::uint8_t*>(f.rgb.data.data()),
                                 {std::size_t(f.rgb.height), std::size_t(f.rgb.width), 3}, self));
          },
          "colour, H x W x 3 uint8 sRGB (a view of the frame's storage), or None")
      .def("validate", &RgbdFrame::validate, nb::arg("name") = "RGB-D frame");

  nb::class_<CloudBatch> C(
      m, "CloudBatch",
      "Point clouds (one per hypothesis) in one structure-of-arrays batch: cloud c holds points\n"
      "[offsets[c], offsets[c+1]), camera frame, metres.\n\n"
      "CloudBatch(points, offsets=None, rgb=None, pixel=None): points (n, 3) float (copied); offsets int\n"
      "(num_clouds + 1; default one cloud); rgb packed 0xRRGGBB per point (default 0); pixel v * width + u\n"
      "(default -1). The array properties x, y, z, rgb, pixel, cloud and offsets are views of the batch's "
      "C++\n"
      "storage (no copy; writable; valid while the batch lives, which they keep alive); `points` is a new\n"
      "(n, 3) array. Stages take a CloudBatch without copying it in Python.");
  C.def(nb::init<>())
      .def(
          "__init__",
          [](CloudBatch* self, nb::handle points, nb::handle offsets, nb::handle rgb, nb::handle pixel) {
            new (self) CloudBatch(make_cloud(points, offsets, rgb, pixel));
          },
          nb::arg("points"), nb::arg("offsets").none() = nb::none(), nb::arg("rgb").none() = nb::none(),
          nb::arg("pixel").none() = nb::none())
      .def_prop_ro(
          "x", [](nb::handle s) { return vector_view(s, nb::cast<CloudBatch&>(s).x); }, "x, metres (view)")
      .def_prop_ro(
          "y", [](nb::handle s) { return vector_view(s, nb::cast<CloudBatch&>(s).y); }, "y, metres (view)")
      .def_prop_ro(
          "z", [](nb::handle s) { return vector_view(s, nb::cast<CloudBatch&>(s).z); }, "z, metres (view)")
      .def_prop_ro(
          "rgb", [](nb::handle s) { return vector_view(s, nb::cast<CloudBatch&>(s).rgb); },
          doc("CloudBatch.rgb"))
      .def_prop_ro(
          "pixel", [](nb::handle s) { return vector_view(s, nb::cast<CloudBatch&>(s).pixel); },
          doc("CloudBatch.pixel"))
      .def_prop_ro(
          "cloud", [](nb::handle s) { return vector_view(s, nb::cast<CloudBatch&>(s).cloud); },
          doc("CloudBatch.cloud"))
      .def_prop_ro(
          "offsets", [](nb::handle s) { return vector_view(s, nb::cast<CloudBatch&>(s).offsets); },
          doc("CloudBatch.offsets"))
      .def_prop_ro(
          "points",
          [](const CloudBatch& c) {
            std::vector<float> p(3 * c.size());
            for (std::size_t i = 0; i < c.size(); ++i)
              p[3 * i] = c.x[i], p[3 * i + 1] = c.y[i], p[3 * i + 2] = c.z[i];
            return owned(std::move(p), {c.size(), 3});
          },
          nb::rv_policy::move, "(n, 3) float32 points (a new array: x, y, z are stored apart)")
      .def("__len__", &CloudBatch::size)
      .def("num_clouds", &CloudBatch::num_clouds)
      .def("cloud_size",
           [](const CloudBatch& c, std::size_t k) {
             if (k >= c.num_clouds())
               throw InvalidInput("cloud", "index " + std::to_string(k) + " out of range");
             return c.cloud_size(k);
           })
      .def("validate", &CloudBatch::validate, nb::arg("name") = "cloud batch", doc("CloudBatch.validate"))
      .def("__repr__", [](const CloudBatch& c) {
        return "CloudBatch(" + std::to_string(c.size()) + " points in " + std::to_string(c.num_clouds()) +
               " clouds)";
      });

  nb::class_<ObservedCloudSettings> O(m, "ObservedCloudSettings", doc("ObservedCloudSettings"));
  O.def(nb::init<>());
  PERCH2_RW(O, ObservedCloudSettings, stride);
  PERCH2_RW(O, ObservedCloudSettings, min_depth_m);
  PERCH2_RW(O, ObservedCloudSettings, max_depth_m);

  m.def(
      "observed_cloud",
      [](const RgbdFrame& f, const ObservedCloudSettings& s) {
        nb::gil_scoped_release release;
        return observed_cloud(f, s);
      },
      nb::arg("frame"), nb::arg("settings") = ObservedCloudSettings{}, doc("observed_cloud"));
  m.def(
      "observed_segments",
      [](const RgbdFrame& f, nb::handle labels, nb::handle segment_labels, const ObservedCloudSettings& s) {
        const LabelImage l = labels_from(labels, "labels");
        const std::vector<std::int32_t> seg = int_vector(segment_labels, "segment_labels");
        nb::gil_scoped_release release;
        return observed_segments(f, l, seg, s);
      },
      nb::arg("frame"), nb::arg("labels"), nb::arg("segment_labels"),
      nb::arg("settings") = ObservedCloudSettings{}, doc("observed_segments"));
}

}  // namespace perch2_py
