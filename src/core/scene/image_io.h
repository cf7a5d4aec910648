// Reading image files into textures for the OBJ and glTF loaders (OpenImageIO).
#pragma once

#include <optional>
#include <string>

#include "scene/scene.h"

namespace kdgrid {

/// Reads an image file (PNG, JPEG, TGA, EXR, ... whatever OpenImageIO reads) as an RGB8
/// texture. 8-bit images are taken as sRGB, float images as linear. Returns nullopt and sets
/// `why` when the file cannot be read, so callers can warn and go on untextured.
std::optional<Texture> read_texture_file(const std::string& path, std::string& why);

/// Converts interleaved 8-bit pixels with `channels` channels (1-4) to RGB8.
std::vector<uint8_t> to_rgb8(const uint8_t* pixels, size_t count, int channels);

}  // namespace kdgrid
