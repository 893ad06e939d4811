// Pins the searches' behaviour while their code moves: the poses and scores that `perch2 estimate` gives on
// small generated sets (3-DoF; 6-DoF with ground-truth masks, with simulated detections and with no masks),
// on both CPU backends, must equal bit for bit the listing checked in as tests/search_digest.txt.
//
// Every value is written as a hexadecimal float (%a), so a difference in the last bit shows, and the first
// line that differs names the case, the backend, the image and the object. The thread count is fixed (2):
// parallel reductions then add in the same order on any machine.
//
// A change that is meant to move results regenerates the listing (and says why in its commit):
//   PERCH2_WRITE_SEARCH_DIGEST=1 ./build/tests/test_search_digest
#include <omp.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <sstream>

#include "perch2/dataset/runner.hpp"
#include "perch2/synth/synth.hpp"
#include "test_support.hpp"

using namespace perch2;
using namespace perch2::dataset;
namespace fs = std::filesystem;

namespace {

const std::string kDigestPath = std::string(PERCH2_TEST_SOURCE_DIR) + "/search_digest.txt";

/// One scene, two images, 4-5 objects (6-DoF: with detections_synth.json), generated once per mode.
std::string digest_dataset(synth::Mode mode) {
  const std::string dir = test::temp_path(mode == synth::Mode::ThreeDof ? "digest_3dof" : "digest_6dof");
  if (fs::exists(dir + "/test_targets_bop19.json")) return dir;
  synth::DatasetSettings s;
  s.num_scenes = 1, s.images_per_scene = 2, s.seed = 41;
  s.scene.mode = mode;
  s.scene.min_objects = 4, s.scene.max_objects = 5;
  synth::generate_dataset(synth::builtin_models(), s, dir);
  return dir;
}

std::string hex(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%a", v);
  return buf;
}

/// The listing of one run: a line per row (case, backend, scene, image, object, score, R row-major, t).
void list_run(const std::string& name, const std::string& root, RunOptions options, int max_images,
              std::ostringstream& out) {
  const BopRunner runner(BopDataset(root), options);
  int n = 0;
  for (const auto& [scene, im] : runner.images()) {
    if (n++ == max_images) break;
    const ImageResult r = runner.estimate(scene, im);
    out << name << ' ' << backend_name(options.backend) << " scene " << scene << " im " << im << ": "
        << r.rows.size() << " rows, " << r.missing << " missing\n";
    for (const PoseEstimate& row : r.rows) {
      out << "  obj " << row.obj_id << " score " << hex(row.score) << " T";
      const Eigen::Matrix4d T = row.T_cam_obj.matrix().cast<double>();
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 4; ++j) out << ' ' << hex(T(i, j));
      out << '\n';
    }
  }
}

std::string listing() {
  std::ostringstream out;
  const std::string root3 = digest_dataset(synth::Mode::ThreeDof);
  const std::string root6 = digest_dataset(synth::Mode::SixDof);
  for (const BackendKind backend : {BackendKind::Cpu, BackendKind::ThrustOmp}) {
    RunOptions o;
    o.backend = backend;
    o.mode = RunMode::Tabletop;
    list_run("3dof", root3, o, 2, out);
    o.mode = RunMode::SixDof;
    o.masks = "gt";
    list_run("6dof-gt", root6, o, 2, out);
    o.masks = root6 + "/detections_synth.json";
    list_run("6dof-detections", root6, o, 2, out);
    o.masks = "none";
    list_run("6dof-none", root6, o, 1, out);
  }
  return out.str();
}

}  // namespace

TEST_CASE("the searches' poses and scores on generated sets equal tests/search_digest.txt bit for bit") {
  omp_set_num_threads(2);
  const std::string now = listing();
  if (std::getenv("PERCH2_WRITE_SEARCH_DIGEST")) {
    test::write_file(kDigestPath, now);
    MESSAGE("wrote " << kDigestPath);
    return;
  }
  const std::string expected = test::read_file(kDigestPath);
  REQUIRE_MESSAGE(!expected.empty(), kDigestPath << " is missing or empty");
  std::istringstream a(now), b(expected);
  std::string line_now, line_expected, context;
  for (int line = 1; std::getline(b, line_expected); ++line) {
    if (line_expected.rfind("  ", 0) != 0) context = line_expected;
    const bool more = bool(std::getline(a, line_now));
    CAPTURE(context);
    CAPTURE(line);
    REQUIRE_MESSAGE(more, "the run ends before the digest's line " << line);
    REQUIRE(line_now == line_expected);
  }
  CHECK_MESSAGE(!std::getline(a, line_now), "the run lists more than the digest: " << line_now);
}
