// Turning a resolved render into displayable sRGB bytes (shaded or heat map), and writing
// screenshots / heat maps to disk.
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "viewer/render_worker.h"
#include "viewer/settings.h"

namespace kdgrid::viewer {

struct HeatRange {
  float lo = 0, hi = 1;  ///< counts mapped to the two ends of the ramp
};

/// Counts range used for the heat map: data min/max (Auto, Log) or the fixed one.
HeatRange heat_range(const RenderedImage& img, HeatScale scale, float fixed_lo, float fixed_hi);
/// Position 0..1 on the colour ramp for `count` (log scale maps log1p(count - lo)).
float heat_position(float count, HeatRange r, HeatScale scale);

/// Linear radiance to the sRGB byte tonemap_srgb8 (exposure 1) gives, bit for bit, without a
/// pow per channel: the UI thread colours every new pass. A table indexed by the top bits of the
/// float (2^14 consecutive floats per entry, so entries are finest near 0 where sRGB is steepest)
/// holds the byte of the entry's smallest value; one comparison with the next byte's threshold (the
/// smallest value that tonemap_srgb8 maps to it, found by bisection through tonemap_srgb8 itself)
/// finishes. The constructor checks that no entry spans more than two bytes.
class SrgbEncoder {
 public:
  SrgbEncoder();
  uint8_t operator()(float c) const {
    c = c > 0.0f ? std::min(c, 1.0f) : 0.0f;  // NaN, negatives and -0 -> black, as tonemap_srgb8
    uint32_t u;
    std::memcpy(&u, &c, sizeof u);
    const int k = lut_[u >> kShift];
    return uint8_t(k + (c >= thresholds_[k + 1]));
  }

 private:
  static constexpr int kShift = 14;
  static constexpr uint32_t kOne = 0x3f800000u;  ///< bits of 1.0f
  float thresholds_[257];
  uint8_t lut_[(kOne >> kShift) + 1];
};

/// RGBA8, row 0 at the top: tonemapped radiance (Shaded) or the colour ramp (heat modes).
void colorize(const RenderedImage& img, HeatScale scale, HeatRange range,
              std::vector<uint8_t>& rgba);

/// Writes RGB8 (row 0 at the top) as PNG, byte for byte, through the atomic writer
/// (write_png_rgb8: a failed write leaves the old file as it was); returns an error message or
/// "".
std::string write_png(const std::string& path, int w, int h, const std::vector<uint8_t>& rgb);
/// Writes the raw per-pixel counts (the same count in R, G and B) as EXR via write_image.
std::string write_counts_exr(const std::string& path, const RenderedImage& img,
                             const std::string& description);

}  // namespace kdgrid::viewer
