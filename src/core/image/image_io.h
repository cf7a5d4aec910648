// Image files through OpenImageIO (a private dependency of kdgrid_core): rendered images out
// as PNG (tone-mapped 8-bit sRGB) for looking at and EXR (linear float) for comparing, images
// back in for comparisons, and texture files in for the OBJ and glTF loaders.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "scene/scene.h"

namespace kdgrid {

/// A linear float RGB image, row 0 at the top, 3 floats per pixel.
struct ImageRGB {
  int width = 0, height = 0;
  std::vector<float> rgb;
  /// String attributes found in the file (EXR/PNG metadata written by write_image).
  std::map<std::string, std::string> metadata;
};

/// Maps linear RGB to 8-bit sRGB with a simple exposure + clamp (PNG output, viewer).
void tonemap_srgb8(const std::vector<float>& rgb, std::vector<uint8_t>& out, float exposure = 1.0f);

/// Writes `rgb` (width*height*3 linear floats) to `path`, chosen by extension:
/// .png -> tone-mapped 8-bit sRGB (tonemap_srgb8, exposure 1), .exr -> linear float RGB.
/// Each metadata entry is stored as a string attribute "kdgrid:<key>" (e.g. samples, seconds,
/// accelerator, scene). The file is written to a temporary name in the same directory and
/// renamed, so readers never see a half-written image. Throws ParamError for an unsupported
/// extension and Error naming the path and the OpenImageIO message when writing fails.
void write_image(const std::string& path, int width, int height, const std::vector<float>& rgb,
                 const std::map<std::string, std::string>& metadata = {});

/// Writes 8-bit RGB bytes (width*height*3, row 0 at the top) as a PNG, byte for byte, encoded
/// and checked in memory and written through the atomic writer as write_image does. Throws
/// ParamError unless `path` ends in .png, Error naming the path when encoding or writing fails
/// (the old file is then unchanged).
void write_png_rgb8(const std::string& path, int width, int height,
                    const std::vector<uint8_t>& rgb);

/// Throws ParamError unless `path` ends in an extension write_image supports (.png, .exr).
void check_image_extension(const std::string& path);

/// Loads the image module (image_module.h) that reads and writes images, as the first image
/// read or write would; throws Error naming where it looked when it cannot. A command that will
/// write an image calls it before its work: a missing module is then said at once, and the
/// module's libraries, whose static set-up does not survive a failed allocation, are never
/// loaded by a process that its build has left short of memory.
void require_image_module();

/// Reads any image OpenImageIO understands into linear float RGB (8-bit sRGB files are
/// linearised; grey is replicated, alpha dropped). Throws LoadError naming the path.
ImageRGB read_image(const std::string& path);

/// Root-mean-square difference over all channels of two images of the same size.
/// Throws ParamError if the sizes differ.
double rmse(const ImageRGB& a, const ImageRGB& b);

/// How two 8-bit RGB images (3 bytes per pixel, as written to PNG) differ: the fraction of
/// pixels with any channel apart by more than `tolerance` levels, and the mean absolute
/// difference over all channels in units of full scale (1 level = 1/255). Throws ParamError
/// if the sizes differ.
struct ImageDifference {
  double pixels_differing = 0;
  double mean_abs = 0;
};
ImageDifference srgb8_difference(const std::vector<uint8_t>& a, const std::vector<uint8_t>& b,
                                 int tolerance = 0);

// ---- textures -------------------------------------------------------------------------

/// Largest width or height of a texture that is decoded: the largest texture GPUs load
/// (GL_MAX_TEXTURE_SIZE is 16384 on most), far above what a render at the resolutions kdgrid
/// is used for can show. A larger image costs seconds and gigabytes to decode (40000 x 40000
/// is 4.8 GB as RGB8) from a file of a few megabytes; it is refused from its header.
constexpr int kMaxTextureSide = 16384;

/// Reads an image file (PNG, JPEG, TGA, EXR, ... whatever OpenImageIO reads) as an RGB8
/// texture. 8-bit images are taken as sRGB, float images as linear. Returns nullopt and sets
/// `why` when the file cannot be read, so callers can warn and go on untextured: also when it
/// is not a regular file (util/input_file.h), when its header gives a size that
/// texture_size_ok refuses (checked before any pixel is read), and when its data ends early
/// (a truncated PNG or JPEG). With `decode` false only the header is read: the Texture has its
/// size and no pixels.
std::optional<Texture> read_texture_file(const std::string& path, std::string& why,
                                         bool decode = true);

/// True when a `width` x `height` image of `channels` 8-bit channels can be decoded within
/// the default memory budget (util/memory.h) and neither side exceeds kMaxTextureSide; else
/// false with `why` naming the sizes and the fix.
bool texture_size_ok(int width, int height, int channels, std::string& why);

/// read_texture_file for an encoded image in memory (`size` bytes, e.g. a glTF buffer view);
/// `name` is the texture's name. The format is recognised from the bytes.
std::optional<Texture> decode_texture(const unsigned char* bytes, size_t size,
                                      const std::string& name, std::string& why,
                                      bool decode = true);

/// Converts interleaved 8-bit pixels with `channels` channels (1-4) to RGB8.
std::vector<uint8_t> to_rgb8(const uint8_t* pixels, size_t count, int channels);

}  // namespace kdgrid
