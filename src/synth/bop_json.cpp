#include "bop_json.hpp"

#include <filesystem>
#include <fstream>

#include "perch2/core/error.hpp"

namespace perch2::synth::detail {

void make_folder(const std::string& path) {
  std::error_code ec;
  std::filesystem::create_directories(path, ec);
  if (ec) throw FileError(path, "cannot create the folder: " + ec.message());
}

void write_bop_json(const std::string& path, const nlohmann::ordered_json& content) {
  std::ofstream f(path);
  const bool object = content.is_object();
  f << (object ? "{" : "[");
  bool first = true;
  for (auto it = content.begin(); it != content.end(); ++it) {
    f << (first ? "\n  " : ",\n  ");
    if (object) f << nlohmann::ordered_json(it.key()).dump() << ": ";
    f << it.value().dump();
    first = false;
  }
  f << (first ? "" : "\n") << (object ? "}" : "]") << "\n";
  if (!f) throw FileError(path, "cannot be written");
}

}  // namespace perch2::synth::detail
