// BOP reader on hand-written JSON and small PNGs; detection files and COCO RLE; results CSV.
#include <cmath>
#include <filesystem>
#include <random>
#include <sstream>

#include "bop_fixtures.hpp"
#include "perch2/dataset/bop.hpp"
#include "perch2/dataset/detections.hpp"
#include "perch2/dataset/results.hpp"
#include "test_support.hpp"

using namespace perch2;
using namespace perch2::dataset;
namespace fs = std::filesystem;

namespace {

bool same_pixels(const ColorImage& a, const ColorImage& b) {
  return a.width == b.width && a.height == b.height &&
         std::equal(a.data.begin(), a.data.end(), b.data.begin(),
                    [](const Rgb8& p, const Rgb8& q) { return p.r == q.r && p.g == q.g && p.b == q.b; });
}

template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

/// A 4x3 dataset with one scene, one image, two instances; depth_scale 0.1 mm per unit.
std::string write_small_dataset(const std::string& name, bool with_camera_json = true) {
  const std::string root = test::temp_path(name);
  fs::remove_all(root);
  fs::create_directories(root + "/models");
  fs::create_directories(root + "/test/000002/depth");
  fs::create_directories(root + "/test/000002/rgb");
  fs::create_directories(root + "/test/000002/mask_visib");
  // Model 7 in millimetres: a triangle with a vertex at (100, 0, 0) mm.
  Mesh tri;
  tri.vertices = {{100, 0, 0}, {0, 200, 0}, {0, 0, 300}};
  tri.triangles = {{0, 1, 2}};
  io::save_ply(root + "/models/obj_000007.ply", tri, false);
  test::write_text(root + "/models/models_info.json", R"({
    "7": {"diameter": 250.0, "min_x": 0,
          "symmetries_discrete": [[-1, 0, 0, 10,  0, -1, 0, -20,  0, 0, 1, 0,  0, 0, 0, 1]],
          "symmetries_continuous": [{"axis": [0, 0, 2], "offset": [5, 0, 0]}]},
    "8": {"diameter": 50}})");
  if (with_camera_json)
    test::write_text(
        root + "/camera.json",
        R"({"cx": 1.5, "cy": 1.0, "depth_scale": 0.1, "fx": 500.0, "fy": 501.0, "height": 3, "width": 4})");
  test::write_text(root + "/test/000002/scene_camera.json", R"({
    "5": {"cam_K": [500.0, 0.0, 1.5, 0.0, 501.0, 1.0, 0.0, 0.0, 1.0], "depth_scale": 0.1,
          "cam_R_w2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_w2c": [0, 0, 1000]}})");
  test::write_text(root + "/test/000002/scene_gt.json", R"({
    "5": [{"cam_R_m2c": [1, 0, 0, 0, 0, -1, 0, 1, 0], "cam_t_m2c": [10, -20, 800], "obj_id": 7},
          {"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 900], "obj_id": 8}]})");
  test::write_text(root + "/test/000002/scene_gt_info.json", R"({
    "5": [{"bbox_obj": [0, 0, 2, 3], "bbox_visib": [0, 0, 2, 2], "px_count_all": 6, "px_count_valid": 6,
           "px_count_visib": 4, "visib_fract": 0.6667},
          {"bbox_obj": [2, 0, 2, 3], "bbox_visib": [2, 0, 2, 3], "px_count_all": 6, "px_count_valid": 6,
           "px_count_visib": 6, "visib_fract": 1.0}]})");
  test::write_text(root + "/test_targets_bop19.json",
                   R"([{"im_id": 5, "inst_count": 1, "obj_id": 7, "scene_id": 2}])");
  // Depth: raw 16-bit values written with 1 unit = 0.1 mm = 0.0001 m (so raw 10000 = 1 m).
  DepthImage raw(4, 3, 0.f);
  for (int v = 0; v < 3; ++v)
    for (int u = 0; u < 4; ++u) raw(u, v) = 0.0001f * float(10000 + 1000 * u);  // planar z per column
  raw(3, 2) = 0;                                                                // no reading
  io::save_depth_png(root + "/test/000002/depth/000005.png", raw, 0.0001f);
  ColorImage rgb(4, 3, Rgb8{10, 20, 30});
  io::save_color_image(root + "/test/000002/rgb/000005.png", rgb);
  LabelImage m0(4, 3, 0), m1(4, 3, 0);
  m0(0, 0) = m0(1, 0) = m0(0, 1) = m0(1, 1) = 255;
  for (int v = 0; v < 3; ++v) m1(2, v) = m1(3, v) = 255;
  io::save_label_png(root + "/test/000002/mask_visib/000005_000000.png", m0);
  io::save_label_png(root + "/test/000002/mask_visib/000005_000001.png", m1);
  return root;
}

}  // namespace

TEST_CASE("BopDataset reads hand-written JSON: millimetres to metres, poses, symmetries, targets") {
  const BopDataset d(write_small_dataset("bop_small"));
  REQUIRE(d.models_info().size() == 2);
  const ModelInfo& m = d.model_info(7);
  CHECK(m.diameter_m == doctest::Approx(0.25));
  REQUIRE(m.symmetries_discrete.size() == 1);
  CHECK(m.symmetries_discrete[0].linear()(0, 0) == doctest::Approx(-1));
  CHECK(m.symmetries_discrete[0].translation().x() == doctest::Approx(0.010));   // 10 mm
  CHECK(m.symmetries_discrete[0].translation().y() == doctest::Approx(-0.020));  // -20 mm
  REQUIRE(m.symmetries_continuous.size() == 1);
  CHECK(m.symmetries_continuous[0].axis.z() == doctest::Approx(1));  // normalised
  CHECK(m.symmetries_continuous[0].offset_m.x() == doctest::Approx(0.005));
  CHECK(m.is_symmetric());
  CHECK_FALSE(d.model_info(8).is_symmetric());

  const Mesh mesh = d.load_model(7);
  CHECK(mesh.vertices[0].x() == doctest::Approx(0.1));  // 100 mm
  CHECK(mesh.vertices[2].z() == doctest::Approx(0.3));

  CHECK(d.scene_ids() == std::vector<int>{2});
  const ImageInfo& info = d.info(2, 5);
  CHECK(info.camera.fx == 500.f);
  CHECK(info.camera.fy == 501.f);
  CHECK(info.camera.cx == 1.5f);
  CHECK(info.camera.width == 4);
  CHECK(info.camera.height == 3);
  CHECK(info.depth_scale_mm == doctest::Approx(0.1));
  REQUIRE(info.T_cam_world.has_value());
  CHECK(info.T_cam_world->translation().z() == doctest::Approx(1.0));
  REQUIRE(info.gt.size() == 2);
  CHECK(info.gt[0].obj_id == 7);
  CHECK(info.gt[0].T_cam_obj.translation().isApprox(Eigen::Vector3f(0.010f, -0.020f, 0.8f)));
  CHECK(info.gt[0].T_cam_obj.linear()(1, 2) == doctest::Approx(-1));  // row-major R
  CHECK(info.gt[0].visib_fract == doctest::Approx(0.6667));
  CHECK(info.gt[1].bbox_visib == Eigen::Vector4i(2, 0, 2, 3));
  REQUIRE(d.targets().size() == 1);
  CHECK(d.targets()[0].obj_id == 7);
  CHECK(d.targets()[0].inst_count == 1);
}

TEST_CASE("BopDataset::load_image: depth scale, planar depth, masks, image size without camera.json") {
  for (const bool camera_json : {true, false}) {
    CAPTURE(camera_json);
    const BopDataset d(write_small_dataset(camera_json ? "bop_img_a" : "bop_img_b", camera_json));
    CHECK(d.info(2, 5).camera.width == 4);  // from camera.json or the depth PNG header
    const BopImage im = d.load_image(2, 5);
    CHECK(im.frame.camera.width == 4);
    CHECK(im.frame.camera.height == 3);
    // raw 10000 units * 0.1 mm = 1000 mm = 1 m; z is the same along each column (planar, not ray length).
    CHECK(im.frame.depth_m(0, 0) == doctest::Approx(1.0));
    CHECK(im.frame.depth_m(0, 2) == doctest::Approx(1.0));
    CHECK(im.frame.depth_m(3, 0) == doctest::Approx(1.3));
    CHECK(im.frame.depth_m(3, 2) == 0.f);
    CHECK(im.frame.rgb(1, 1).g == 20);
    REQUIRE(im.masks_visib.size() == 2);
    CHECK(im.masks_visib[0](1, 1) == 1);
    CHECK(im.masks_visib[0](2, 1) == 0);
    const LabelImage labels = im.visible_labels();
    CHECK(labels(0, 0) == 1);
    CHECK(labels(3, 2) == 2);
    CHECK(labels(1, 2) == 0);
    ImageLoadOptions only_depth;
    only_depth.rgb = only_depth.masks_visib = false;
    const BopImage d_only = d.load_image(2, 5, only_depth);
    CHECK(d_only.frame.rgb.empty());
    CHECK(d_only.masks_visib.empty());
  }
}

TEST_CASE("load_image reads gray/ when there is no rgb/ (grey cameras, e.g. ITODD)") {
  const std::string root = write_small_dataset("bop_gray");
  fs::remove_all(root + "/test/000002/rgb");
  fs::create_directories(root + "/test/000002/gray");
  LabelImage grey(4, 3, 77);
  io::save_label_png(root + "/test/000002/gray/000005.png", grey);
  const BopImage im = BopDataset(root).load_image(2, 5);
  CHECK(im.frame.rgb(2, 1).r == 77);
  CHECK(im.frame.rgb(2, 1).b == 77);
}

TEST_CASE("bop24 targets (images only) set detection: nothing is taken from the ground truth") {
  const std::string root = write_small_dataset("bop_t24");
  fs::remove(root + "/test_targets_bop19.json");
  test::write_text(root + "/test_targets_bop24.json", R"([{"im_id": 5, "scene_id": 2}])");
  const BopDataset d(root);
  CHECK(d.targets_path().find("bop24") != std::string::npos);
  CHECK(d.target_task() == TargetTask::Detection);
  CHECK(d.targets().empty());  // not the annotated objects and counts: a detector is not told them
  CHECK(d.target_images() == std::vector<std::pair<int, int>>{{2, 5}});
  CHECK(run_images(d) == std::vector<std::pair<int, int>>{{2, 5}});
  CHECK(d.info(2, 5).gt.size() == 2);  // the evaluator's view: the ground truth is read

  // An estimator's view: the ground truth is not read, and need not exist.
  DatasetOptions no_gt;
  no_gt.ground_truth = false;
  CHECK(BopDataset(root, no_gt).info(2, 5).gt.empty());
  fs::remove(root + "/test/000002/scene_gt.json");
  fs::remove(root + "/test/000002/scene_gt_info.json");
  fs::remove_all(root + "/test/000002/mask_visib");
  const BopDataset blind(root, no_gt);
  CHECK(run_images(blind) == std::vector<std::pair<int, int>>{{2, 5}});
  ImageLoadOptions all_parts;
  all_parts.masks = true;
  const BopImage im = blind.load_image(2, 5, all_parts);
  CHECK(im.masks_visib.empty());
  CHECK(im.frame.depth_m.width == im.frame.camera.width);

  test::write_text(
      root + "/test_targets_bop24.json",
      R"([{"im_id": 5, "scene_id": 2}, {"im_id": 5, "scene_id": 2, "obj_id": 7, "inst_count": 1}])");
  CHECK(error_of([&] { BopDataset mixed(root, no_gt); }).find("mixes image-only") != std::string::npos);
  test::write_text(root + "/test_targets_bop24.json", R"([{"im_id": 6, "scene_id": 2}])");
  std::string e;
  try {
    BopDataset bad(root);
  } catch (const FileError& err) {
    e = err.what();
  }
  CHECK(e.find("test_targets_bop24.json") != std::string::npos);
  CHECK(e.find("image 6") != std::string::npos);
}

TEST_CASE("BopDataset: a malformed scene entry costs only its image, named with its file and key") {
  const std::string root = write_small_dataset("bop_bad");
  const std::string gt = root + "/test/000002/scene_gt.json";
  // Each bad scene_gt.json: the dataset opens, image (2, 5) is bad, info() and load_image() name the file
  // and the key, and the targets file still lists the image (a run reports it rather than losing it).
  auto bad_image_error = [&](const std::string& scene_gt) {
    test::write_text(gt, scene_gt);
    const BopDataset d(root);
    CHECK_FALSE(d.has_image(2, 5));
    CHECK(d.image_ids().empty());
    REQUIRE(d.bad_image(2, 5) != nullptr);
    CHECK(d.bad_image(2, 5)->path == gt);
    CHECK(d.target_images() == std::vector<std::pair<int, int>>{{2, 5}});
    CHECK_THROWS_AS(d.load_image(2, 5), FileError);
    const std::string e = error_of([&] { d.info(2, 5); });
    CHECK(e.rfind(gt + ": ", 0) == 0);
    return e;
  };
  CHECK(bad_image_error(R"({"5": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "obj_id": 7}]})")
            .find("image 5 instance 0: missing key \"cam_t_m2c\"") != std::string::npos);
  CHECK(bad_image_error(
            R"({"5": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 1], "obj_id": 99}]})")
            .find("obj_id 99") != std::string::npos);
  CHECK(bad_image_error(
            R"({"5": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 2], "cam_t_m2c": [0, 0, 1], "obj_id": 7}]})")
            .find("not a rotation") != std::string::npos);
  CHECK(bad_image_error(R"({"5": [ )").find("malformed JSON") != std::string::npos);  // the whole file
  fs::remove(gt);
  fs::remove(root + "/test/000002/scene_gt_info.json");
  fs::remove(root + "/test/000002/depth/000005.png");
  std::string e = error_of([&] {
    BopDataset d(root);
    d.load_image(2, 5);
  });
  CHECK(e.find("depth/000005.png") != std::string::npos);
  // Without scene_camera.json the scene's images are unknown: a target of it is a bad image naming the file.
  fs::remove(root + "/test/000002/scene_camera.json");
  const BopDataset no_camera(root);
  CHECK(no_camera.warnings().size() == 1);
  e = error_of([&] { no_camera.info(2, 5); });
  CAPTURE(e);
  CHECK(e.find("scene_camera.json") != std::string::npos);
  CHECK(e.find("image 5 (listed in the targets file) is not in the scene's JSON") != std::string::npos);
  CHECK(e.find("cannot open") != std::string::npos);
  // Dataset-level problems still fail at once.
  CHECK(error_of([&] { BopDataset d(root + "/nowhere"); }).find("nowhere") != std::string::npos);
  fs::remove(root + "/models/models_info.json");
  CHECK(error_of([&] { BopDataset d(root); }).find("models_info.json") != std::string::npos);
}

TEST_CASE("BopDataset: the other images of a scene with a bad entry are unaffected, stray keys warn") {
  const std::string root = write_small_dataset("bop_bad_one");
  const std::string scene = root + "/test/000002";
  test::write_text(scene + "/scene_camera.json", R"({
    "5": {"cam_K": [500.0, 0.0, 1.5, 0.0, 501.0, 1.0, 0.0, 0.0, 1.0], "depth_scale": 0.1},
    "6": {"cam_K": [500.0, 0.0, 1.5, 0.0, 501.0, 1.0, 0.0, 0.0, 1.0], "depth_scale": 0.1},
    "7": {"cam_K": [500.0, 1.0, 1.5, 0.0, 501.0, 1.0, 0.0, 0.0, 1.0]},
    "x": {}})");
  test::write_text(scene + "/scene_gt.json", R"({
    "5": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 900], "obj_id": 8}],
    "6": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, "far"], "obj_id": 8}],
    "9": []})");
  fs::remove(scene + "/scene_gt_info.json");
  fs::remove(scene + "/mask_visib/000005_000001.png");
  test::write_text(root + "/test_targets_bop19.json",
                   R"([{"im_id": 5, "inst_count": 1, "obj_id": 8, "scene_id": 2},
    {"im_id": 6, "inst_count": 1, "obj_id": 8, "scene_id": 2}, {"im_id": 7, "inst_count": 1, "obj_id": 8, "scene_id": 2}])");
  const BopDataset d(root);
  CHECK(d.image_ids() == std::vector<std::pair<int, int>>{{2, 5}});
  CHECK(d.load_image(2, 5).masks_visib.size() == 1);
  CHECK(d.bad_images().size() == 2);
  CHECK(error_of([&] { d.info(2, 6); }).find("scene_gt.json: image 6 instance 0") != std::string::npos);
  CHECK(error_of([&] { d.info(2, 7); }).find("scene_camera.json: image 7 cam_K: expected") !=
        std::string::npos);
  CHECK(d.targets().size() == 3);  // bop19 targets of bad images are kept: the run reports the images
  CHECK(d.target_images().size() == 3);
  CHECK(run_images(d) == std::vector<std::pair<int, int>>{{2, 5}, {2, 6}, {2, 7}});  // bad ones included
  CHECK(run_images(d, 3, 9).empty());
  REQUIRE(d.warnings().size() == 2);  // the key "x", the entry for image 9 (in no scene_camera.json entry)
  CHECK(d.warnings()[0].find("\"x\"") != std::string::npos);
  CHECK(d.warnings()[1].find("image 9 is not in scene_camera.json") != std::string::npos);
  // A target of an image no scene has, in a scene without problems, is the targets file's error.
  const std::string root2 = write_small_dataset("bop_bad_target");
  test::write_text(root2 + "/test_targets_bop19.json",
                   R"([{"im_id": 8, "inst_count": 1, "obj_id": 7, "scene_id": 2}])");
  CHECK(error_of([&] { BopDataset bad(root2); }).find("image 8 is not in the split") != std::string::npos);
}

TEST_CASE("decode_image from the files' bytes equals load_image, bad bytes name their file") {
  const std::string root = write_small_dataset("bop_bytes");
  const BopDataset d(root);
  ImageLoadOptions all;
  all.masks = true;
  fs::create_directories(root + "/test/000002/mask");
  for (const char* m : {"000005_000000.png", "000005_000001.png"})
    fs::copy_file(root + "/test/000002/mask_visib/" + m, root + "/test/000002/mask/" + m);
  const ImageFiles files = d.read_image_files(2, 5, all);
  REQUIRE(files.depth);
  CHECK(files.depth->path == root + "/test/000002/depth/000005.png");
  CHECK(files.depth->bytes == test::read_file(files.depth->path));
  const BopImage from_bytes = decode_image(d.info(2, 5), files);
  const BopImage from_files = d.load_image(2, 5, all);
  // ... and both as the io loaders read each file on its own (depth_scale 0.1 mm per unit).
  CHECK(from_bytes.frame.depth_m.data ==
        io::load_depth_png(files.depth->path, d.info(2, 5).depth_scale_mm * 0.001f).data);
  CHECK(from_bytes.frame.depth_m.data == from_files.frame.depth_m.data);
  CHECK(same_pixels(from_bytes.frame.rgb, io::load_color_image(files.rgb->path)));
  CHECK(same_pixels(from_bytes.frame.rgb, from_files.frame.rgb));
  REQUIRE(from_bytes.masks_visib.size() == 2);
  REQUIRE(from_bytes.masks.size() == 2);
  for (std::size_t g = 0; g < 2; ++g) {
    CHECK(from_bytes.masks_visib[g].data == from_files.masks_visib[g].data);
    CHECK(from_bytes.masks[g].data == from_files.masks[g].data);
  }
  CHECK(from_bytes.frame.camera.width == 4);
  // A JPEG colour image from bytes.
  ColorImage rgb(4, 3, Rgb8{200, 100, 50});
  const std::string jpg = test::temp_path("bytes.jpg");
  io::save_color_image(jpg, rgb);
  ImageFiles with_jpg = files;
  with_jpg.rgb = FileBytes{"sent/000005.jpg", test::read_file(jpg)};
  CHECK(same_pixels(decode_image(d.info(2, 5), with_jpg).frame.rgb, io::load_color_image(jpg)));
  // Truncated, wrong-size and missing inputs: FileError naming where the bytes came from.
  ImageFiles bad = files;
  bad.depth->bytes.resize(bad.depth->bytes.size() / 2);
  CHECK(error_of([&] { decode_image(d.info(2, 5), bad); }) ==
        files.depth->path + ": truncated PNG (no IEND chunk at the end)");
  bad = files;
  bad.masks_visib[1].bytes = with_jpg.rgb->bytes;
  CHECK(error_of([&] { decode_image(d.info(2, 5), bad); }) ==
        files.masks_visib[1].path + ": not a PNG file (a PNG is required)");
  bad = files;
  bad.masks_visib.pop_back();
  CHECK_THROWS_AS(decode_image(d.info(2, 5), bad), InvalidInput);
  bad = files;
  ColorImage wide(5, 3, Rgb8{1, 2, 3});
  io::save_color_image(jpg, wide);
  bad.rgb = FileBytes{"wide.jpg", test::read_file(jpg)};
  CHECK(error_of([&] { decode_image(d.info(2, 5), bad); }).find("wide.jpg: image is 5x3") == 0);
  fs::remove(root + "/test/000002/mask/000005_000001.png");
  CHECK(error_of([&] { d.read_image_files(2, 5, all); }) ==
        root + "/test/000002/mask/000005_000001.png: file not found");
}

TEST_CASE("COCO RLE: hand-encoded masks, string codec, round trips") {
  // 3 rows x 4 columns; column-major: col0 = 0 1 1, col1 = 1 1 0, col2 = 0 0 0, col3 = 0 0 1
  Mask m(4, 3, 0);
  m(0, 1) = m(0, 2) = m(1, 0) = m(1, 1) = m(3, 2) = 1;
  const Rle r = rle_encode(m);
  CHECK(r.height == 3);
  CHECK(r.width == 4);
  CHECK(r.counts == std::vector<std::uint32_t>{1, 4, 6, 1});
  // By hand (maskApi.c rleToString): 1 -> '1', 4 -> '4', 6 -> '6', then 1 - 4 = -3: 5 bits 11101 = 29, the
  // rest is -1 and bit 4 is set, so one char 29 + 48 = 'M'.
  CHECK(rle_to_string(r) == "146M");
  // 100 = 0b11'00100: low 5 bits 4 with continuation (4 | 32) + 48 = 'T', then 3 -> '3'.
  CHECK(rle_to_string(Rle{10, 10, {100}}) == "T3");
  CHECK(rle_from_string("T3", 10, 10).counts == std::vector<std::uint32_t>{100});
  CHECK(rle_from_string("146M", 3, 4).counts == r.counts);
  const Mask back = rle_decode(rle_from_string("146M", 3, 4));
  CHECK(back.data == m.data);
  // A mask starting with 1 has an empty first 0-run.
  Mask full(2, 2, 1);
  CHECK(rle_encode(full).counts == std::vector<std::uint32_t>{0, 4});
  // Random masks round-trip through both forms.
  std::mt19937 rng(7);
  for (int trial = 0; trial < 20; ++trial) {
    Mask rnd(37, 23, 0);
    std::bernoulli_distribution on(trial % 2 ? 0.5 : 0.05);
    for (auto& px : rnd.data) px = on(rng);
    const Rle e = rle_encode(rnd);
    CHECK(rle_decode(rle_from_string(rle_to_string(e), 23, 37)).data == rnd.data);
    CHECK(rle_decode(e).data == rnd.data);
  }
  CHECK_THROWS_AS(rle_decode(Rle{3, 4, {1, 4}}), InvalidInput);        // covers 5 of 12 pixels
  CHECK_THROWS_AS(rle_decode(Rle{3, 4, {1, 4, 6, 2}}), InvalidInput);  // covers 13
  CHECK_THROWS_AS(rle_from_string("1T", 3, 4), InvalidInput);          // ends inside a count
  CHECK_THROWS_AS(rle_from_string("1~", 3, 4), InvalidInput);          // outside '0'..'o'
}

TEST_CASE("Detection files: list and string counts decode to the same mask, detections stay apart") {
  const std::string path = test::temp_path("dets.json");
  test::write_text(path, R"([
    {"scene_id": 1, "image_id": 4, "category_id": 5, "score": 0.9, "bbox": [0, 0, 2, 3], "time": 0.5,
     "segmentation": {"size": [3, 4], "counts": [1, 4, 6, 1]}},
    {"scene_id": 1, "image_id": 4, "category_id": 5, "score": 0.4, "bbox": [1, 0, 3, 3], "time": 0.5,
     "segmentation": {"size": [3, 4], "counts": "146M"}},
    {"scene_id": 2, "image_id": 0, "category_id": 6, "score": 0.7, "bbox": [1, 2, 3, 4], "time": 0.1}])");
  const auto dets = load_detections(path);
  REQUIRE(dets.size() == 3);
  CHECK(dets[0].mask().data == dets[1].mask().data);
  CHECK(dets[0].mask()(0, 1) == 1);
  CHECK(dets[1].bbox[2] == 3.f);
  CHECK_FALSE(dets[2].has_mask());
  const auto by_image = detections_by_image(dets);
  CHECK(by_image.at({1, 4}).size() == 2);
  // Writing and reading back keeps everything (compressed and uncompressed).
  for (const bool compressed : {true, false}) {
    const std::string out = test::temp_path(compressed ? "dets_c.json" : "dets_u.json");
    save_detections(out, dets, compressed);
    const auto again = load_detections(out);
    REQUIRE(again.size() == 3);
    CHECK(again[1].mask().data == dets[1].mask().data);
    CHECK(again[0].score == doctest::Approx(0.9));
    CHECK(again[2].category_id == 6);
  }
  test::write_text(path, R"([{"scene_id": 1, "image_id": 4, "category_id": 5, "score": 0.9, "bbox": [0, 0, 2],
                              "time": 0.5}])");
  CHECK(error_of([&] { load_detections(path); }).find("detection 0 bbox") != std::string::npos);
  test::write_text(path,
                   R"([{"scene_id": 1, "image_id": 4, "category_id": 5, "score": 0.9, "bbox": [0, 0, 2, 3],
                              "segmentation": {"size": [3, 4], "counts": [1, 4]}}])");
  CHECK(error_of([&] { load_detections(path); }).find("segmentation") != std::string::npos);
}

TEST_CASE("Results CSV: round trip in mm, shards concatenate, bad rows name file:line") {
  PoseEstimate a;
  a.scene_id = 1, a.im_id = 2, a.obj_id = 3, a.score = 0.75, a.time_s = 1.25;
  a.T_cam_obj = Eigen::Translation3f(0.01f, -0.02f, 0.5f) *
                Eigen::AngleAxisf(0.3f, Eigen::Vector3f(1, 2, 3).normalized());
  PoseEstimate b = a;
  b.im_id = 3, b.obj_id = 4, b.score = 0.5;
  std::ostringstream s;
  write_results_csv(s, {a});
  const std::string text = s.str();
  CHECK(text.rfind("scene_id,im_id,obj_id,score,R,t,time\n1,2,3,0.75,", 0) == 0);
  CHECK(text.find(",10 -20 500,1.25") != std::string::npos);  // t in millimetres

  const std::string path = test::temp_path("results.csv");
  fs::remove(path);
  save_results_csv(path, {a}, true);  // shard 1 creates the file with a header
  save_results_csv(path, {b}, true);  // shard 2 appends rows only
  const std::string both = test::read_file(path);
  CHECK(both.find("scene_id") == both.rfind("scene_id"));  // one header
  auto rows = load_results_csv(path);
  REQUIRE(rows.size() == 2);
  CHECK(rows[0].T_cam_obj.isApprox(a.T_cam_obj, 1e-6f));
  CHECK(rows[1].obj_id == 4);
  CHECK(rows[1].line == 3);
  // Concatenating two complete files (each with a header) is valid too.
  test::write_text(path, text + text);
  CHECK(load_results_csv(path).size() == 2);

  const std::string good = "1,2,3,0.5,1 0 0 0 1 0 0 0 1,0 0 500,0.1\n";
  auto fails_at_line_2 = [&](const std::string& bad_row, const std::string& reason) {
    test::write_text(path, std::string(kBopResultsHeader) + "\n" + bad_row + "\n" + good);
    const std::string e = error_of([&] { load_results_csv(path); });
    CAPTURE(e);
    CHECK(e.find(path + ":2") != std::string::npos);
    CHECK(e.find(reason) != std::string::npos);
  };
  fails_at_line_2("1,2,3,0.5,1 0 0 0 1 0 0 0 1,0 0 500", "7 comma-separated");
  fails_at_line_2("1,2,3,0.5,1 0 0 0 1 0 0 0 1,0 0 500,0.1,9", "7 comma-separated");
  fails_at_line_2("1,2,x,0.5,1 0 0 0 1 0 0 0 1,0 0 500,0.1", "obj_id");
  fails_at_line_2("1,2,3,nan,1 0 0 0 1 0 0 0 1,0 0 500,0.1", "score");
  fails_at_line_2("1,2,3,0.5,1 0 0 0 1 0 0 0 1,0 inf 500,0.1", "t must be");
  fails_at_line_2("1,2,3,0.5,1 0 0 0 1 0 0 0,0 0 500,0.1", "R must be");
  fails_at_line_2("1,2,3,0.5,2 0 0 0 1 0 0 0 1,0 0 500,0.1", "not a rotation");
  fails_at_line_2("1,2,3,0.5,1 0 0 0 1 0 0 0 1,0 0 500,1e999", "time");
  CHECK(error_of([&] { load_results_csv(path + ".missing"); }).find(".missing") != std::string::npos);
}

TEST_CASE("Results CSV: a torn last line is named (file:line) and can be dropped") {
  const std::string path = test::temp_path("torn.csv");
  const std::string good = "1,2,3,0.5,1 0 0 0 1 0 0 0 1,0 0 500,0.1\n";
  test::write_text(path, std::string(kBopResultsHeader) + "\n" + good + "1,2,4,0.5,1 0 0 0 1");
  const std::string e = error_of([&] { load_results_csv(path); });
  CHECK(e.find(path + ":3: torn last line") == 0);
  CHECK(e.find("expected 7 comma-separated fields") != std::string::npos);
  int torn = -1;
  CHECK(load_results_csv(path, true, &torn).size() == 1);
  CHECK(torn == 3);
  CHECK(completed_images(path) == std::map<std::pair<int, int>, int>{{{1, 2}, 1}});
  // The same bad line with its newline is a malformed file, not a torn one; a good last line needs none.
  test::write_text(path, std::string(kBopResultsHeader) + "\n" + good + "1,2,4,0.5,1 0 0 0 1\n" + good);
  CHECK(error_of([&] { load_results_csv(path, true); }).find(path + ":3: expected 7") == 0);
  test::write_text(path, std::string(kBopResultsHeader) + "\n" + good + good.substr(0, good.size() - 1));
  CHECK(load_results_csv(path, false, &torn).size() == 2);
  CHECK(torn == 0);
}

TEST_CASE(
    "ResultsWriter: rows appended per image, zero-row images recorded, resume drops what is unfinished") {
  const std::string path = test::temp_path("stream.csv");
  fs::remove(path);
  fs::remove(path + ".done");
  auto row = [](int im, int obj) {
    PoseEstimate e;
    e.scene_id = 1, e.im_id = im, e.obj_id = obj, e.score = 0.5, e.time_s = 0.25;
    e.T_cam_obj.translation() = Eigen::Vector3f(0.01f * float(obj), 0.f, 0.5f);
    return e;
  };
  std::string after_three;
  {
    ResultsWriter w(path, {});
    w.write_image(1, 0, {row(0, 3), row(0, 4)});
    CHECK(load_results_csv(path).size() == 2);  // on disk at once, before the writer closes
    w.write_image(1, 1, {});                    // nothing found: still done
    w.write_image(1, 2, {row(2, 3)});
    CHECK_THROWS_AS(w.write_image(1, 2, {row(2, 3)}), InvalidInput);  // once only
    CHECK_THROWS_AS(w.write_image(1, 3, {row(2, 3)}), InvalidInput);  // a row of another image
    CHECK(w.is_done(1, 1));
    CHECK_FALSE(w.is_done(1, 3));
    after_three = test::read_file(path);
  }
  const std::map<std::pair<int, int>, int> three{{{1, 0}, 2}, {{1, 1}, 0}, {{1, 2}, 1}};
  CHECK(completed_images(path) == three);
  CHECK(load_results_csv(path).size() == 3);

  // A crash while image 3 was written: one of its rows (no done record) and a torn line.
  std::ostringstream partial;
  write_results_csv(partial, {row(3, 3)}, false);
  test::write_text(path, after_three + partial.str() + "1,3,4,0.5,1 0 0");
  CHECK(completed_images(path) == three);
  {
    ResultsWriter w(path, {true, false});
    CHECK(w.done() == three);
    REQUIRE(w.resume_notes().size() == 3);
    CHECK(w.resume_notes()[0].find("3 complete images (3 rows) kept") != std::string::npos);
    CHECK(w.resume_notes()[1].find(path + ":6: dropped: torn last line") == 0);
    CHECK(w.resume_notes()[2].find(path + ":5: dropped: a row of scene 1 image 3") == 0);
    CHECK(test::read_file(path) == after_three);  // the finished images' lines, byte for byte
    w.write_image(1, 3, {row(3, 3), row(3, 4)});
  }
  CHECK(load_results_csv(path).size() == 5);
  CHECK(completed_images(path).size() == 4);
  // Without the .done record (a CSV from elsewhere): every image with rows counts; zero-row ones cannot.
  fs::remove(path + ".done");
  CHECK(completed_images(path).size() == 3);
  {
    ResultsWriter w(path, {true, false});
    CHECK(w.done().size() == 3);
    CHECK(w.resume_notes().back().find(".done not found") != std::string::npos);
  }
  CHECK(completed_images(path).size() == 3);  // and the writer recorded them
  // One writer at a time: a second one (another run on the same output) fails, naming the file.
  {
    ResultsWriter first(path, {true, false});
    CHECK(error_of([&] {
            ResultsWriter second(path, {true, false});
          }) == path + ": is being written by another process (its .done file is locked)");
  }
  { ResultsWriter again(path, {true, false}); }  // free once the first is gone
  // A fresh (non-resume) writer replaces the file; resume of a missing file starts one.
  { ResultsWriter w(path, {}); }
  CHECK(load_results_csv(path).empty());
  CHECK(completed_images(path).empty());
  fs::remove(path);
  { ResultsWriter w(path, {true, false}); }
  CHECK(test::read_file(path) == std::string(kBopResultsHeader) + "\n");
  // Bad records and unwritable places are the file's errors.
  test::write_text(path + ".done", "scene_id,im_id,rows\n1,0\n1,1,0\n");
  CHECK(error_of([&] { ResultsWriter w(path, {true, false}); }).find(path + ".done:2: expected") == 0);
  CHECK(error_of([&] {
          ResultsWriter w(test::temp_path("no_such_dir/r.csv"), {});
        }).find("no_such_dir/r.csv: cannot be written") != std::string::npos);
}
