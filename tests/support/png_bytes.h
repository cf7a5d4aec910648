// PNG files written byte by byte, for tests of what the texture readers do with a header
// alone (the size a decoder would allocate for) and no pixel data.
#pragma once

#include <cstdint>
#include <string>

namespace kdgrid::test {

inline uint32_t crc32(const std::string& bytes) {
  uint32_t c = 0xFFFFFFFFu;
  for (unsigned char b : bytes) {
    c ^= b;
    for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
  }
  return ~c;
}

inline std::string be32(uint32_t v) {
  return {char(v >> 24), char(v >> 16), char(v >> 8), char(v)};
}

inline std::string png_chunk(const std::string& type, const std::string& data) {
  return be32(uint32_t(data.size())) + type + data + be32(crc32(type + data));
}

/// A PNG whose header says `w` x `h` RGB pixels, with no pixel data: the header is all a
/// reader needs to know what decoding would cost.
inline std::string png_header_only(uint32_t w, uint32_t h) {
  const std::string ihdr = be32(w) + be32(h) + std::string("\x08\x02\x00\x00\x00", 5);
  return std::string("\x89PNG\r\n\x1a\n", 8) + png_chunk("IHDR", ihdr) + png_chunk("IDAT", "") +
         png_chunk("IEND", "");
}

}  // namespace kdgrid::test
