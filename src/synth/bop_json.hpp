// Output helpers (internal to perch2::synth). JSON files laid out as bop_toolkit's inout.save_json writes
// them (internal to perch2::synth): one line per top-level entry, each value compact, so 20,000-image scene
// files stay small and diffable.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

namespace perch2::synth::detail {

/// Creates a folder and its parents; FileError naming it if that fails (e.g. a file is in the way).
void make_folder(const std::string& path);

/// Writes an object or array; FileError if the file cannot be written.
void write_bop_json(const std::string& path, const nlohmann::ordered_json& content);

}  // namespace perch2::synth::detail
