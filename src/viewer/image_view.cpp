#include "viewer/image_view.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "image/image_io.h"
#include "viewer/overlay.h"

namespace kdgrid::viewer {

HeatRange heat_range(const RenderedImage& img, HeatScale scale, float fixed_lo, float fixed_hi) {
  if (scale == HeatScale::Fixed) return {fixed_lo, std::max(fixed_hi, fixed_lo + 1e-6f)};
  HeatRange r{kInf, -kInf};
  for (size_t i = 0; i < img.rgb.size(); i += 3) {
    r.lo = std::min(r.lo, img.rgb[i]);
    r.hi = std::max(r.hi, img.rgb[i]);
  }
  if (!(r.lo <= r.hi)) return {0, 1};
  if (r.hi == r.lo) r.hi = r.lo + 1;
  return r;
}

float heat_position(float count, HeatRange r, HeatScale scale) {
  if (scale == HeatScale::Log)
    return std::log1p(std::max(count - r.lo, 0.0f)) / std::log1p(r.hi - r.lo);
  return (count - r.lo) / (r.hi - r.lo);
}

SrgbEncoder::SrgbEncoder() {
  // The byte tonemap_srgb8 gives one value: the encoder is defined by it, not by a copy of
  // its formula.
  std::vector<float> one(1);
  std::vector<uint8_t> byte;
  const auto encode = [&](float c) {
    one[0] = c;
    tonemap_srgb8(one, byte);
    return int(byte[0]);
  };
  const auto bits = [](float f) {
    uint32_t u;
    std::memcpy(&u, &f, sizeof u);
    return u;
  };
  const auto from_bits = [](uint32_t u) {
    float f;
    std::memcpy(&f, &u, sizeof f);
    return f;
  };
  // Non-negative floats order like their bit patterns, so bisect on those: the smallest
  // value in [0, 1] that encodes to k or more.
  thresholds_[0] = 0.0f;
  for (int k = 1; k < 256; ++k) {
    uint32_t lo = bits(0.0f), hi = bits(1.0f);  // encode(hi) = 255 >= k
    while (lo < hi) {
      const uint32_t mid = lo + (hi - lo) / 2;
      if (encode(from_bits(mid)) >= k)
        hi = mid;
      else
        lo = mid + 1;
    }
    thresholds_[k] = from_bits(lo);
  }
  thresholds_[256] = kInf;  // byte 255 never steps up
  for (uint32_t e = 0; e <= (kOne >> kShift); ++e) {
    const uint32_t first = e << kShift, last = std::min(first + ((1u << kShift) - 1), kOne);
    const int lo = encode(from_bits(first)), hi = encode(from_bits(last));
    if (hi - lo > 1) throw std::logic_error("SrgbEncoder: table entry spans more than two bytes");
    lut_[e] = uint8_t(lo);
  }
}

void colorize(const RenderedImage& img, HeatScale scale, HeatRange range,
              std::vector<uint8_t>& rgba) {
  const size_t n = size_t(img.width) * size_t(img.height);
  rgba.resize(n * 4);
  if (img.mode == RenderMode::Shaded) {
    static const SrgbEncoder encoder;  // thread-safe one-time set-up (a few ms)
    for (size_t i = 0; i < n; ++i) {
      rgba[i * 4 + 0] = encoder(img.rgb[i * 3 + 0]);
      rgba[i * 4 + 1] = encoder(img.rgb[i * 3 + 1]);
      rgba[i * 4 + 2] = encoder(img.rgb[i * 3 + 2]);
      rgba[i * 4 + 3] = 255;
    }
    return;
  }
  // The ramp's bytes at kRampSteps + 1 even positions: a pixel's byte differs from its exact
  // ramp colour by at most one, and costs a table read instead of a ramp and three roundings.
  static constexpr int kRampSteps = 4096;
  static const std::vector<uint32_t> table = [] {
    std::vector<uint32_t> t(kRampSteps + 1);
    for (int k = 0; k <= kRampSteps; ++k) {
      const Color c = ramp(float(k) / kRampSteps);
      const uint8_t px[4] = {uint8_t(std::lround(c.r * 255)), uint8_t(std::lround(c.g * 255)),
                             uint8_t(std::lround(c.b * 255)), 255};
      std::memcpy(&t[size_t(k)], px, 4);
    }
    return t;
  }();
  for (size_t i = 0; i < n; ++i) {
    const float t = heat_position(img.rgb[i * 3], range, scale);
    const int k = t > 0.0f ? int(std::min(t, 1.0f) * kRampSteps + 0.5f) : 0;  // NaN -> 0
    std::memcpy(&rgba[i * 4], &table[size_t(k)], 4);
  }
}

std::string write_png(const std::string& path, int w, int h, const std::vector<uint8_t>& rgb) {
  try {
    write_png_rgb8(path, w, h, rgb);
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

std::string write_counts_exr(const std::string& path, const RenderedImage& img,
                             const std::string& description) {
  try {
    write_image(path, img.width, img.height, img.rgb,
                {{"description", description}, {"samples", std::to_string(img.samples)}});
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

}  // namespace kdgrid::viewer
