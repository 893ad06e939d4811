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

TEST_CASE("BopDataset::load_image: depth scale, planar depth, masks; image size without camera.json") {
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

TEST_CASE("bop24 targets (images only) make every annotated object of the image a target") {
  const std::string root = write_small_dataset("bop_t24");
  fs::remove(root + "/test_targets_bop19.json");
  test::write_text(root + "/test_targets_bop24.json", R"([{"im_id": 5, "scene_id": 2}])");
  const BopDataset d(root);
  CHECK(d.targets_path().find("bop24") != std::string::npos);
  REQUIRE(d.targets().size() == 2);
  CHECK(d.targets()[0].obj_id == 7);
  CHECK(d.targets()[1].obj_id == 8);
  CHECK(d.targets()[1].inst_count == 1);
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

TEST_CASE("BopDataset rejects missing and malformed files, naming them") {
  const std::string root = write_small_dataset("bop_bad");
  const std::string gt = root + "/test/000002/scene_gt.json";
  test::write_text(gt, R"({"5": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "obj_id": 7}]})");
  std::string e = error_of([&] { BopDataset d(root); });
  CHECK(e.find("scene_gt.json") != std::string::npos);
  CHECK(e.find("cam_t_m2c") != std::string::npos);
  test::write_text(
      gt, R"({"5": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 1], "obj_id": 99}]})");
  e = error_of([&] { BopDataset d(root); });
  CHECK(e.find("obj_id 99") != std::string::npos);
  test::write_text(
      gt, R"({"5": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 2], "cam_t_m2c": [0, 0, 1], "obj_id": 7}]})");
  e = error_of([&] { BopDataset d(root); });
  CHECK(e.find("not a rotation") != std::string::npos);
  test::write_text(gt, R"({"5": [ )");
  e = error_of([&] { BopDataset d(root); });
  CHECK(e.find("malformed JSON") != std::string::npos);
  fs::remove(gt);
  fs::remove(root + "/test/000002/scene_gt_info.json");
  fs::remove(root + "/test/000002/depth/000005.png");
  e = error_of([&] {
    BopDataset d(root);
    d.load_image(2, 5);
  });
  CHECK(e.find("depth/000005.png") != std::string::npos);
  fs::remove(root + "/test/000002/scene_camera.json");
  e = error_of([&] { BopDataset d(root); });
  CHECK(e.find("scene_camera.json") != std::string::npos);
  CHECK(error_of([&] { BopDataset d(root + "/nowhere"); }).find("nowhere") != std::string::npos);
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

TEST_CASE("Detection files: list and string counts decode to the same mask; detections stay apart") {
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
