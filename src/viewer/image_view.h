// Turning a resolved render into displayable sRGB bytes (shaded or heat map), and writing
// screenshots / heat maps to disk.
#pragma once

#include <cstdint>
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

/// RGBA8, row 0 at the top: tonemapped radiance (Shaded) or the colour ramp (heat modes).
void colorize(const RenderedImage& img, HeatScale scale, HeatRange range, std::vector<uint8_t>& rgba);

/// Writes RGB8 (row 0 at the top) as PNG, byte for byte (write_image would round-trip the
/// bytes through linear floats); returns an error message or "".
std::string write_png(const std::string& path, int w, int h, const std::vector<uint8_t>& rgb);
/// Writes the raw per-pixel counts (the same count in R, G and B) as EXR via write_image.
std::string write_counts_exr(const std::string& path, const RenderedImage& img,
                             const std::string& description);

}  // namespace kdgrid::viewer
