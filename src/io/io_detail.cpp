// File helpers shared by the perch2::io sources.
#include "io_detail.hpp"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <fstream>

#include "perch2/io/image_io.hpp"

namespace perch2::io::detail {

namespace fs = std::filesystem;

std::string read_file_bytes(const std::string& path) {
  std::error_code ec;
  const auto status = fs::status(path, ec);
  if (ec || !fs::exists(status)) throw FileError(path, "file not found");
  if (fs::is_directory(status)) throw FileError(path, "is a folder, not a file");
  std::ifstream f(path, std::ios::binary);
  if (!f) throw FileError(path, std::string("cannot be opened for reading (") + std::strerror(errno) + ")");
  f.seekg(0, std::ios::end);
  const std::streamoff size = f.tellg();
  if (size < 0) throw FileError(path, "cannot be read (its size is unknown)");
  f.seekg(0, std::ios::beg);
  std::string bytes(std::size_t(size), '\0');
  if (size > 0 && !f.read(bytes.data(), size)) throw FileError(path, "read error");
  return bytes;
}

void write_file_bytes(const std::string& path, const void* data, std::size_t size) {
  const fs::path p(path);
  std::error_code ec;
  if (p.has_parent_path() && !fs::is_directory(p.parent_path(), ec))
    throw FileError(path, "cannot be written: folder '" + p.parent_path().string() + "' does not exist");
  if (fs::is_directory(p, ec)) throw FileError(path, "cannot be written: it is a folder");
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) throw FileError(path, std::string("cannot be opened for writing (") + std::strerror(errno) + ")");
  f.write(static_cast<const char*>(data), std::streamsize(size));
  f.close();
  if (!f) throw FileError(path, "write error (disk full?)");
}

std::string lower_extension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

ColorImage load_texture(const std::string& mesh_path, const fs::path& folder, std::string name,
                        const std::string& named_by) {
  fs::path p = fs::path(name).is_absolute() ? fs::path(name) : folder / name;
  std::error_code ec;
  if (!fs::is_regular_file(p, ec) && name.find('\\') != std::string::npos) {
    // Files exported on Windows may name the texture with backslashes.
    std::replace(name.begin(), name.end(), '\\', '/');
    p = fs::path(name).is_absolute() ? fs::path(name) : folder / name;
  }
  if (!fs::is_regular_file(p, ec))
    throw FileError(mesh_path, "texture '" + name + "' named by " + named_by + " not found (looked for '" +
                                   p.string() + "')");
  return load_color_image(p.string());
}

}  // namespace perch2::io::detail
