// perch2 command-line tool.
//   perch2 demo [--out DIR] [--backend cpu|thrust_omp] [--seed S]    (examples/cli/demo.cpp)
//   perch2 estimate --mode 3dof --dataset DIR --out FILE.csv [...]  (examples/cli/estimate.cpp)
//   perch2 track --dataset DIR --out FILE.csv [...]                  (examples/cli/track.cpp)
//   perch2 render MODEL [--scale S] [--distance M] [--out DIR] [--backend ...]
//   perch2 eval --dataset DIR --results FILE.csv [...]   (examples/cli/eval.cpp)
//   perch2 generate --mode 3dof|6dof [--models DIR] --scenes N [--images-per-scene M] --seed S --out DIR
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>
#include <vector>

#include "cli/commands.hpp"
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
               "  perch2 demo [--out DIR] [--backend cpu|thrust_omp] [--seed S]\n"
               "      estimates the 3-DoF poses of built-in objects on a table; writes DIR/overlay.png\n"
               "  perch2 estimate --mode 3dof --dataset DIR --out FILE.csv [--variant V] (--help for more)\n"
               "      estimates the target objects of a BOP dataset, writes BOP results\n"
               "  perch2 track --dataset DIR --out FILE.csv [--init search|gt] (--help for more)\n"
               "      tracks the objects of each scene (its images are the frames of a video)\n"
               "  perch2 render MODEL.{obj,ply} [--scale S] [--distance M] [--out DIR] [--backend ...]\n"
               "      renders a model from 8 viewpoints at M metres (S scales the file's units to metres)\n"
               "  perch2 eval --dataset DIR --results FILE.csv [--json OUT] (perch2 eval --help for more)\n"
               "  perch2 generate --mode 3dof|6dof [--models DIR] --scenes N [--images-per-scene M] "
               "[--objects N] --seed S "
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

/// Render with the chosen backend.
CloudBatch render(const Args& a, const std::vector<Mesh>& models, const std::vector<Hypothesis>& hyps,
                  const Intrinsics& K, const RenderSettings& s, const Occluders* occ = nullptr) {
  if (a.backend == "cpu") return cpu::Renderer(models).render(hyps, K, s, occ);
  return thrust_omp::Backend::Renderer(models).render(hyps, K, s, occ);
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
  if (argc > 1 && std::string(argv[1]) == "estimate") return run_estimate(argc - 1, argv + 1);
  if (argc > 1 && std::string(argv[1]) == "track") return run_track(argc - 1, argv + 1);
  if (argc > 1 && std::string(argv[1]) == "demo") return run_demo(argc - 1, argv + 1);
  try {
    if (argc > 1 && std::string(argv[1]) == "generate") return run_generate(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "perch2: " << e.what() << "\n";
    return 1;
  }
  const Args a = parse(argc, argv);
  try {
    if (a.command == "render") return run_render(a);
    if (a.command == "-h" || a.command == "--help" || a.command == "help") usage();
    usage("unknown command " + a.command);
  } catch (const std::exception& e) {
    std::cerr << "perch2: " << e.what() << "\n";
    return 1;
  }
}
