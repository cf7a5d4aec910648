// Image files: PNG (tone-mapped 8-bit sRGB) for looking at, EXR (linear float) for comparing.
// OpenImageIO does the encoding; it stays a private dependency of kdgrid_core.
#pragma once

#include <map>
#include <string>
#include <vector>

namespace kdgrid {

/// A linear float RGB image, row 0 at the top, 3 floats per pixel.
struct ImageRGB {
  int width = 0, height = 0;
  std::vector<float> rgb;
  /// String attributes found in the file (EXR/PNG metadata written by write_image).
  std::map<std::string, std::string> metadata;
};

/// Writes `rgb` (width*height*3 linear floats) to `path`, chosen by extension:
/// .png -> tone-mapped 8-bit sRGB (tonemap_srgb8, exposure 1), .exr -> linear float RGB.
/// Each metadata entry is stored as a string attribute "kdgrid:<key>" (e.g. samples, seconds,
/// accelerator, scene). The file is written to a temporary name in the same directory and
/// renamed, so readers never see a half-written image. Throws ParamError for an unsupported
/// extension and Error naming the path and the OpenImageIO message when writing fails.
void write_image(const std::string& path, int width, int height, const std::vector<float>& rgb,
                 const std::map<std::string, std::string>& metadata = {});

/// Throws ParamError unless `path` ends in an extension write_image supports (.png, .exr).
void check_image_extension(const std::string& path);

/// Reads any image OpenImageIO understands into linear float RGB (8-bit sRGB files are
/// linearised; grey is replicated, alpha dropped). Throws LoadError naming the path.
ImageRGB read_image(const std::string& path);

/// Root-mean-square difference over all channels of two images of the same size.
/// Throws ParamError if the sizes differ.
double rmse(const ImageRGB& a, const ImageRGB& b);

}  // namespace kdgrid
