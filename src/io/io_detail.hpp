// Helpers shared by the perch2::io sources (not installed).
#pragma once

#include <charconv>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "perch2/core/error.hpp"
#include "perch2/core/image.hpp"

namespace perch2::io::detail {

/// The whole file as bytes; FileError if it is missing, a folder, or unreadable.
std::string read_file_bytes(const std::string& path);

/// Writes bytes to a file; FileError if the folder is missing or the write fails.
void write_file_bytes(const std::string& path, const void* data, std::size_t size);

/// Lower-case extension with its dot (".png"), or "".
std::string lower_extension(const std::string& path);

/// Loads the texture `name` (relative to `folder` unless absolute) for the mesh file `mesh_path`; `named_by`
/// says where the name came from. Missing file -> FileError on mesh_path; a bad image -> FileError on it.
ColorImage load_texture(const std::string& mesh_path, const std::filesystem::path& folder, std::string name,
                        const std::string& named_by);

inline bool is_space(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v';
}

/// Next whitespace-separated token of `line` from `pos` (empty when none); advances `pos`.
inline std::string_view next_token(std::string_view line, std::size_t& pos) {
  while (pos < line.size() && is_space(line[pos])) ++pos;
  const std::size_t start = pos;
  while (pos < line.size() && !is_space(line[pos])) ++pos;
  return line.substr(start, pos - start);
}

/// Parses the whole token as a double (a leading '+' is allowed); false if it is not a number.
inline bool parse_double(std::string_view token, double& value) {
  if (!token.empty() && token[0] == '+') token.remove_prefix(1);
  if (token.empty()) return false;
  const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
  return ec == std::errc() && end == token.data() + token.size();
}

/// Parses the whole token as a 64-bit integer (a leading '+' is allowed).
inline bool parse_int(std::string_view token, std::int64_t& value) {
  if (!token.empty() && token[0] == '+') token.remove_prefix(1);
  if (token.empty()) return false;
  const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
  return ec == std::errc() && end == token.data() + token.size();
}

/// Quotes a token for an error message (shortened if long).
inline std::string quote(std::string_view token) {
  std::string s(token.substr(0, 40));
  if (token.size() > 40) s += "...";
  return "'" + s + "'";
}

/// Checks MeshLoadOptions::scale.
inline void check_scale(float scale) {
  if (!std::isfinite(scale) || scale <= 0)
    throw InvalidInput("MeshLoadOptions::scale", "must be finite and > 0, got " + std::to_string(scale));
}

}  // namespace perch2::io::detail
