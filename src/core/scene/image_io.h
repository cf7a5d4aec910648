// Reading image files into textures for the OBJ and glTF loaders (OpenImageIO).
#pragma once

#include <optional>
#include <string>

#include "scene/scene.h"

namespace kdgrid {

/// Reads an image file (PNG, JPEG, TGA, EXR, ... whatever OpenImageIO reads) as an RGB8
/// texture. 8-bit images are taken as sRGB, float images as linear. Returns nullopt and sets
/// `why` when the file cannot be read, so callers can warn and go on untextured: also when it
/// is not a regular file (util/input_file.h) or its header gives a size whose decoding would
/// exceed the memory budget (checked before any pixel is read).
std::optional<Texture> read_texture_file(const std::string& path, std::string& why);

/// True when a `width` x `height` image of `channels` 8-bit channels can be decoded within
/// the default memory budget (util/memory.h); else false with `why` naming the sizes.
bool texture_fits_budget(int width, int height, int channels, std::string& why);

/// Converts interleaved 8-bit pixels with `channels` channels (1-4) to RGB8.
std::vector<uint8_t> to_rgb8(const uint8_t* pixels, size_t count, int channels);

}  // namespace kdgrid
