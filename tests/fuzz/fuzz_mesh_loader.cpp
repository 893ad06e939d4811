// libFuzzer target for the mesh loaders: any byte string written as a .ply or .obj file must load or raise
// perch2::FileError / InvalidInput, never crash, hang or leak. Built with -DPERCH2_BUILD_FUZZERS=ON (clang).
//   fuzz_ply CORPUS_DIR -max_len=4096     fuzz_obj CORPUS_DIR -max_len=2048
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <string>

#include "perch2/core/error.hpp"
#include "perch2/io/mesh_io.hpp"

#ifndef PERCH2_FUZZ_EXTENSION
#error "define PERCH2_FUZZ_EXTENSION as \".ply\" or \".obj\""
#endif

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  // The loaders take paths (textures and material libraries are found beside the file).
  static const std::string path = "/tmp/perch2_fuzz_" + std::to_string(getpid()) + PERCH2_FUZZ_EXTENSION;
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return 0;
  std::fwrite(data, 1, size, f);
  std::fclose(f);
  try {
    (void)perch2::io::load_mesh(path);
  } catch (const perch2::FileError&) {
  } catch (const perch2::InvalidInput&) {
  }
  return 0;
}
