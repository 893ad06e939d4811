// BopRunner (perch2/dataset/runner.hpp) on tiny generated datasets, both modes: an image estimated from its
// files' bytes gives the rows of the image loaded from the dataset; bad images throw ImageError naming the
// image, the file and the reason.
#include <filesystem>

#include "perch2/dataset/runner.hpp"
#include "perch2/synth/synth.hpp"
#include "test_support.hpp"

using namespace perch2;
using namespace perch2::dataset;
namespace fs = std::filesystem;

namespace {

/// One scene, one image, one object (seed 5), generated once per mode.
std::string tiny_dataset(synth::Mode mode) {
  const std::string dir = test::temp_path(mode == synth::Mode::ThreeDof ? "runner_3dof" : "runner_6dof");
  if (fs::exists(dir + "/test_targets_bop19.json")) return dir;
  synth::DatasetSettings s;
  s.num_scenes = 1, s.images_per_scene = 1, s.seed = 5;
  s.scene.mode = mode;
  s.scene.min_objects = s.scene.max_objects = 1;
  synth::generate_dataset(synth::builtin_models(), s, dir);
  return dir;
}

void check_same_rows(const ImageResult& a, const ImageResult& b) {
  REQUIRE(a.rows.size() == b.rows.size());
  for (std::size_t k = 0; k < a.rows.size(); ++k) {
    CHECK(a.rows[k].obj_id == b.rows[k].obj_id);
    CHECK(a.rows[k].score == b.rows[k].score);
    CHECK(a.rows[k].T_cam_obj.matrix() == b.rows[k].T_cam_obj.matrix());
  }
}

}  // namespace

TEST_CASE("BopRunner: both modes, from the dataset and from the files' bytes, bad images are ImageErrors") {
  for (const auto mode : {synth::Mode::ThreeDof, synth::Mode::SixDof}) {
    const std::string root = tiny_dataset(mode);
    RunOptions options;
    options.mode = mode == synth::Mode::ThreeDof ? RunMode::Tabletop : RunMode::SixDof;
    options.backend = BackendKind::Cpu;
    CAPTURE(mode_name(options.mode));
    const BopRunner runner(BopDataset(root), options);  // holds its own copy of the dataset's index
    const auto images = runner.images();
    REQUIRE(images.size() == 1);
    const auto [scene, im] = images.front();
    const ImageResult from_dataset = runner.estimate(scene, im);
    CHECK(from_dataset.scene_id == scene);
    CHECK(from_dataset.requested == 1);
    REQUIRE(from_dataset.rows.size() == 1);
    CHECK(from_dataset.rows[0].obj_id == runner.obj_ids()[std::size_t(from_dataset.row_models[0])]);
    CHECK(from_dataset.stages.back().first == "total");
    CHECK(from_dataset.rows[0].time_s == from_dataset.seconds);
    CHECK((options.mode == RunMode::Tabletop ? from_dataset.tabletop.has_value()
                                             : from_dataset.sixdof.has_value()));

    CHECK(runner.images() == run_images(BopDataset(root)));
    CHECK(load_options(options).masks_visib == (options.mode == RunMode::SixDof));
    const ImageFiles paths = runner.image_files(scene, im);
    REQUIRE(paths.depth);
    CHECK(paths.depth->bytes.empty());
    CHECK(paths.masks_visib.size() == (options.mode == RunMode::SixDof ? 1u : 0u));  // gt masks for 6-DoF
    ImageFiles files = read_files(paths);
    check_same_rows(runner.estimate(scene, im, files), from_dataset);

    // Bad bytes: the image's error, naming the file the bytes came from.
    files.depth->bytes.resize(files.depth->bytes.size() / 2);
    try {
      runner.estimate(scene, im, files);
      FAIL("no ImageError for a truncated depth PNG");
    } catch (const ImageError& e) {
      CHECK(e.scene_id == scene);
      CHECK(e.im_id == im);
      CHECK(e.reason == files.depth->path + ": truncated PNG (no IEND chunk at the end)");
      CHECK(std::string(e.what()).rfind("scene 1 image 0: ", 0) == 0);
    }
    CHECK_THROWS_AS(runner.estimate(scene, im + 1), ImageError);  // not in the split
  }
  // A missing mask (6-DoF, ground-truth masks) costs the image, from the dataset.
  const std::string root = tiny_dataset(synth::Mode::SixDof);
  RunOptions six;
  six.mode = RunMode::SixDof, six.backend = BackendKind::Cpu;
  const BopRunner runner(BopDataset(root), six);
  const std::string mask = root + "/test/000001/mask_visib/000000_000000.png";
  const std::string saved = test::read_file(mask);
  fs::remove(mask);
  const std::string e = [&] {
    try {
      runner.estimate(1, 0);
    } catch (const ImageError& err) {
      return err.reason;
    }
    return std::string();
  }();
  test::write_file(mask, saved);
  CHECK(e == mask + ": file not found");
}

TEST_CASE("BopRunner: dataset-level problems fail when it is built") {
  const std::string root = tiny_dataset(synth::Mode::SixDof);
  RunOptions options;
  options.mode = RunMode::SixDof;
  options.masks = root + "/no_detections.json";
  CHECK_THROWS_WITH_AS(BopRunner(BopDataset(root), options), doctest::Contains("no_detections.json"),
                       FileError);
  CHECK_THROWS_WITH_AS(BopRunner(BopDataset(root), RunOptions{}, {99}), doctest::Contains("obj_id 99"),
                       InvalidInput);
  CHECK_THROWS_WITH_AS(parse_mode("4dof"), doctest::Contains("'4dof'"), InvalidInput);
  CHECK_THROWS_WITH_AS(parse_backend("gpu"), doctest::Contains("'gpu'"), InvalidInput);
  CHECK_THROWS_WITH_AS(parse_variant("perch9"), doctest::Contains("'perch9'"), InvalidInput);
}
