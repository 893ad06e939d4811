// Exceptions: every bad input raises one of these, naming the input and the reason.
#pragma once

#include <stdexcept>
#include <string>

namespace perch2 {

/// Invalid argument or data (wrong sizes, NaN depth, empty mask, zero hypotheses...).
struct InvalidInput : std::invalid_argument {
  InvalidInput(const std::string& input, const std::string& reason)
      : std::invalid_argument(input + ": " + reason) {}
};

/// A file that is missing, unreadable, truncated or malformed.
struct FileError : std::runtime_error {
  FileError(const std::string& path, const std::string& reason) : std::runtime_error(path + ": " + reason) {}
};

}  // namespace perch2
