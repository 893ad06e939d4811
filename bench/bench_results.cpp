// What streaming results costs a run (perch2::dataset::ResultsWriter): one image's rows appended (5 rows, one
// write(2) plus its .done record), with and without fsync(2) per image, and resuming from a 10,000-image
// file (50,000 rows: read, check, keep). Medians of 5 runs; the files go to --dir (default /tmp).
// Usage: bench_results [--dir DIR]
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "bench_support.hpp"
#include "perch2/dataset/results.hpp"

using namespace perch2;

namespace {

std::vector<dataset::PoseEstimate> image_rows(int scene_id, int im_id) {
  std::vector<dataset::PoseEstimate> rows(5);
  for (std::size_t k = 0; k < rows.size(); ++k) {
    rows[k].scene_id = scene_id, rows[k].im_id = im_id, rows[k].obj_id = int(k) + 1, rows[k].time_s = 1.5;
    rows[k].T_cam_obj = Eigen::Translation3f(0.1f, -0.05f, 0.8f) *
                        Eigen::AngleAxisf(0.3f * float(k), Eigen::Vector3f::UnitX());
  }
  return rows;
}

/// Seconds per write_image over `images` images into a new file.
double write_seconds(const std::string& path, int images, bool fsync) {
  dataset::ResultsWriter w(path, {false, fsync});
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < images; ++i) w.write_image(1 + i / 1000, i % 1000, image_rows(1 + i / 1000, i % 1000));
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / images;
}

}  // namespace

int main(int argc, char** argv) try {
  std::string dir = "/tmp";
  for (int k = 1; k + 1 < argc; k += 2)
    if (std::string(argv[k]) == "--dir") dir = argv[k + 1];
  const std::string path = dir + "/perch2_bench_results.csv";
  std::vector<double> plain, synced, resume;
  for (int run = 0; run < 5; ++run) {
    plain.push_back(write_seconds(path, 2000, false));
    synced.push_back(write_seconds(path, 100, true));
  }
  write_seconds(path, 10000, false);
  for (int run = 0; run < 5; ++run) {
    const auto t0 = std::chrono::steady_clock::now();
    const dataset::ResultsWriter w(path, {true, false});
    resume.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    if (w.done().size() != 10000) throw InvalidInput(path, "resume kept " + std::to_string(w.done().size()));
  }
  std::printf("bench_results: %s, files in %s\n", bench::cpu_model().c_str(), dir.c_str());
  std::printf("  write_image (5 rows)          %8.1f us per image (median of 5 x 2000 images)\n",
              1e6 * bench::median(plain));
  std::printf("  write_image (5 rows) + fsync  %8.1f us per image (median of 5 x 100 images)\n",
              1e6 * bench::median(synced));
  std::printf("  resume of 10,000 images       %8.1f ms (50,000 rows; median of 5)\n",
              1e3 * bench::median(resume));
  std::filesystem::remove(path);
  std::filesystem::remove(path + ".done");
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_results: %s\n", e.what());
  return 1;
}
