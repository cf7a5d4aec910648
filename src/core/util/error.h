// Errors that reach the user. Every message names the file or parameter, the problem and,
// where there is one, the fix (docs/DESIGN.md, "Errors"). The CLI prints what() and exits non-zero.
#pragma once

#include <stdexcept>
#include <string>

namespace kdgrid {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
};

/// Input files that cannot be read or parsed.
class LoadError : public Error {
 public:
  using Error::Error;
};

/// Parameters out of their valid range (cell size, resolution, spp, ...).
class ParamError : public Error {
 public:
  using Error::Error;
};

}  // namespace kdgrid
