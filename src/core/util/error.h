// Errors that reach the user. Every message names the file or parameter, the problem and,
// where there is one, the fix (docs/DESIGN.md, "Errors"). The CLI prints what() and exits non-zero.
#pragma once

#include <cstdio>
#include <stdexcept>
#include <string>
#include <string_view>

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

/// `s` for an error message: at most `max` bytes (then "..."), with every byte that would cut
/// or garble the message (NUL, control characters, bytes above 126) written as \xNN.
inline std::string printable(std::string_view s, size_t max = 40) {
  std::string out;
  for (size_t i = 0; i < s.size() && i < max; ++i) {
    const unsigned char c = static_cast<unsigned char>(s[i]);
    if (c >= 32 && c < 127) {
      out += char(c);
    } else {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02X", c);
      out += buf;
    }
  }
  if (s.size() > max) out += "...";
  return out;
}

}  // namespace kdgrid
