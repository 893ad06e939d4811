// perch2 command-line tool.
//   perch2 demo [--out DIR] [--backend cpu|thrust_omp] [--stride N]
//   perch2 render MODEL [--scale S] [--distance M] [--out DIR] [--backend ...]
//   perch2 eval --dataset DIR --results FILE.csv [...]   (examples/cli/eval.cpp)
//   perch2 generate --mode 3dof|6dof [--models DIR] --scenes N [--images-per-scene M] --seed S --out DIR
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>
#include <vector>

#include "cli/commands.hpp"
#include "demo_scene.hpp"
#include "perch2/cpu/backend.hpp"
#include "perch2/cuda/backend.hpp"
#include "perch2/io/io.hpp"

using namespace perch2;

namespace {

struct Args {
  std::string command, model, out = "perch2_out", backend = "thrust_omp";
  int stride = 4;
  float scale = 1.f, distance_m = 0.5f;
};

[[noreturn]] void usage(const std::string& error = "") {
  if (!error.empty()) std::cerr << "perch2: " << error << "\n\n";
  std::cerr << "usage:\n"
               "  perch2 demo [--out DIR] [--backend cpu|thrust_omp] [--stride N]\n"
               "      renders the built-in table scene and 3-DoF pose hypotheses; writes PNGs to DIR\n"
               "  perch2 render MODEL.{obj,ply} [--scale S] [--distance M] [--out DIR] [--backend ...]\n"
               "      renders a model from 8 viewpoints at M metres (S scales the file's units to metres)\n"
               "  perch2 eval --dataset DIR --results FILE.csv [--json OUT] (perch2 eval --help for more)\n";
               "  perch2 generate --mode 3dof|6dof [--models DIR] --scenes N [--images-per-scene M] --seed S "
               "--out DIR\n"
               "      writes a synthetic BOP dataset (built-in or DIR's models) with degraded detections\n";
  std::exit(error.empty() ? 0 : 2);
}

Args parse(int argc, char** argv) {
  Args a;
  if (argc < 2) usage("missing command");
  a.command = argv[1];
  for (int k = 2; k < argc; ++k) {
    const std::string s = argv[k];
    auto value = [&]() -> std::string {
      if (k + 1 >= argc) usage(s + " needs a value");
      return argv[++k];
    };
    try {
      if (s == "--out")
        a.out = value();
      else if (s == "--backend")
        a.backend = value();
      else if (s == "--stride")
        a.stride = std::stoi(value());
      else if (s == "--scale")
        a.scale = std::stof(value());
      else if (s == "--distance")
        a.distance_m = std::stof(value());
      else if (s == "-h" || s == "--help")
        usage();
      else if (s.rfind("--", 0) != 0 && a.model.empty())
        a.model = s;
      else
        usage("unknown argument " + s);
    } catch (const std::logic_error&) {
      usage("bad number for " + s);
    }
  }
  if (a.backend != "cpu" && a.backend != "thrust_omp") usage("unknown backend " + a.backend);
  return a;
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

/// Render with the chosen backend.
CloudBatch render(const Args& a, const std::vector<Mesh>& models, const std::vector<Hypothesis>& hyps,
                  const Intrinsics& K, const RenderSettings& s, const Occluders* occ = nullptr) {
  if (a.backend == "cpu") return cpu::Renderer(models).render(hyps, K, s, occ);
  return thrust_omp::Backend::Renderer(models).render(hyps, K, s, occ);
}

/// Composite clouds into one frame, nearest point per pixel (full-resolution pixels).
RgbdFrame composite(const CloudBatch& c, const Intrinsics& K) {
  RgbdFrame f{K, DepthImage(K.width, K.height, 0.f), ColorImage(K.width, K.height, Rgb8{0, 0, 0})};
  for (std::size_t i = 0; i < c.size(); ++i) {
    float& d = f.depth_m.data[c.pixel[i]];
    if (d == 0.f || c.z[i] < d) d = c.z[i], f.rgb.data[c.pixel[i]] = unpack_rgb(c.rgb[i]);
  }
  return f;
}

/// Depth as a picture: near = bright, far = dark, no reading = black.
ColorImage depth_picture(const DepthImage& depth_m) {
  float lo = 1e9f, hi = 0.f;
  for (float d : depth_m.data)
    if (d > 0) lo = std::min(lo, d), hi = std::max(hi, d);
  ColorImage out(depth_m.width, depth_m.height, Rgb8{0, 0, 0});
  for (std::size_t k = 0; k < depth_m.data.size(); ++k) {
    const float d = depth_m.data[k];
    if (d <= 0) continue;
    const float t = hi > lo ? (d - lo) / (hi - lo) : 0.f;
    out.data[k] = {std::uint8_t(255 * (1 - t)), std::uint8_t(200 * (1 - t) + 30), std::uint8_t(80 + 120 * t)};
  }
  return out;
}

/// Tiles of the first `count` clouds, each drawn on the stride grid.
ColorImage contact_sheet(const CloudBatch& c, const Intrinsics& K, int stride, int columns, int count) {
  const int tw = K.grid_width(stride), th = K.grid_height(stride);
  const int rows = (count + columns - 1) / columns;
  ColorImage sheet(columns * tw, rows * th, Rgb8{30, 30, 30});
  for (int h = 0; h < count && std::size_t(h) < c.num_clouds(); ++h)
    for (auto i = c.offsets[h]; i < c.offsets[h + 1]; ++i) {
      const int u = (c.pixel[i] % K.width) / stride, v = (c.pixel[i] / K.width) / stride;
      sheet((h % columns) * tw + u, (h / columns) * th + v) = unpack_rgb(c.rgb[i]);
    }
  return sheet;
}

int run_demo(const Args& a) {
  const demo::Scene scene = demo::make_scene();
  const Intrinsics& K = scene.camera;
  std::filesystem::create_directories(a.out);

  // 1. The observed frame: every model at its true pose, full resolution, composited.
  std::vector<Hypothesis> truth;
  for (std::size_t m = 0; m < scene.models.size(); ++m)
    truth.push_back({int(m), scene.T_cam_table * scene.T_table_obj[m]});
  RenderSettings full;
  full.stride = 1;
  const RgbdFrame observed = composite(render(a, scene.models, truth, K, full), K);
  io::save_color_image(a.out + "/scene_rgb.png", observed.rgb);
  io::save_depth_png(a.out + "/scene_depth.png", observed.depth_m);  // 16-bit, millimetres
  io::save_color_image(a.out + "/scene_depth_view.png", depth_picture(observed.depth_m));

  // 2. 3-DoF hypotheses for the can (paper defaults: 0.08 m, 22.5 deg), occluded by the observed depth.
  std::vector<Hypothesis> hyps;
  const float kPi = 3.14159265f;
  for (float y = -0.16f; y <= 0.32f + 1e-4f; y += 0.08f)
    for (float x = -0.32f; x <= 0.32f + 1e-4f; x += 0.08f)
      for (int k = 0; k < 16; ++k) hyps.push_back({1, scene.T_cam_table * demo::on_table(x, y, k * kPi / 8)});
  RenderSettings s;
  s.stride = a.stride;
  Occluders occ;
  occ.depth_m = observed.depth_m;
  const std::vector<Mesh> can{scene.models[1]};
  for (auto& h : hyps) h.model = 0;
  CloudBatch batch;
  std::vector<double> times;
  for (int run = 0; run < 3; ++run) {
    const auto t0 = std::chrono::steady_clock::now();
    batch = render(a, can, hyps, K, s, &occ);
    times.push_back(seconds_since(t0));
  }
  std::sort(times.begin(), times.end());
  std::vector<Hypothesis> every_14th;
  CloudBatch sheet_batch;
  for (std::size_t h = 0; h < hyps.size(); h += 14) every_14th.push_back(hyps[h]);
  sheet_batch = render(a, can, every_14th, K, s, &occ);
  io::save_color_image(a.out + "/hypotheses.png", contact_sheet(sheet_batch, K, s.stride, 8, 64));

  std::printf("perch2 demo (backend %s)\n", a.backend.c_str());
  std::printf("  scene: %zu models, %dx%d camera, %zu visible pixels\n", scene.models.size(), K.width,
              K.height,
              std::size_t(std::count_if(observed.depth_m.data.begin(), observed.depth_m.data.end(),
                                        [](float d) { return d > 0; })));
  std::printf(
      "  rendered %zu 3-DoF hypotheses of the can at stride %d with occluders: %zu points, "
      "%.1f ms (median of 3) = %.0f hypotheses/s\n",
      hyps.size(), s.stride, batch.size(), 1e3 * times[1], double(hyps.size()) / times[1]);
  std::printf("  wrote %s/scene_rgb.png, scene_depth.png (16-bit mm), scene_depth_view.png, hypotheses.png\n",
              a.out.c_str());
  return 0;
}

int run_render(const Args& a) {
  if (a.model.empty()) usage("render needs a MODEL file");
  io::MeshLoadOptions options;
  options.scale = a.scale;
  const Mesh mesh = io::load_mesh(a.model, options);
  const Intrinsics K{615.f, 615.f, 319.5f, 239.5f, 640, 480};
  const Eigen::Vector3f centre = mesh.bounds().center();
  std::vector<Hypothesis> views;
  for (int k = 0; k < 8; ++k) {
    Pose T = Pose::Identity();
    T.linear() = (Eigen::AngleAxisf(0.5f, Eigen::Vector3f::UnitX()) *
                  Eigen::AngleAxisf(k * 3.14159265f / 4, Eigen::Vector3f::UnitY()))
                     .toRotationMatrix();
    T.translation() = Eigen::Vector3f(0, 0, a.distance_m) - T.linear() * centre;
    views.push_back({0, T});
  }
  RenderSettings s;
  s.stride = a.stride;
  const CloudBatch c = render(a, {mesh}, views, K, s);
  std::filesystem::create_directories(a.out);
  io::save_color_image(a.out + "/views.png", contact_sheet(c, K, s.stride, 4, 8));
  std::printf(
      "%s: %zu vertices, %zu triangles, %s; rendered 8 views at stride %d: %zu points -> %s/views.png\n",
      a.model.c_str(), mesh.vertices.size(), mesh.triangles.size(),
      mesh.has_texture()         ? "textured"
      : mesh.has_vertex_colors() ? "vertex colours"
                                 : "untextured",
      s.stride, c.size(), a.out.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc > 1 && std::string(argv[1]) == "eval") return run_eval(argc - 1, argv + 1);
  try {
    if (argc > 1 && std::string(argv[1]) == "generate") return run_generate(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "perch2: " << e.what() << "\n";
    return 1;
  }
  const Args a = parse(argc, argv);
  try {
    if (a.command == "demo") return run_demo(a);
    if (a.command == "render") return run_render(a);
    if (a.command == "-h" || a.command == "--help" || a.command == "help") usage();
    usage("unknown command " + a.command);
  } catch (const std::exception& e) {
    std::cerr << "perch2: " << e.what() << "\n";
    return 1;
  }
}
