#include "scene/image_io.h"

#include <OpenImageIO/imageio.h>

#include "accel/guards.h"
#include "util/error.h"
#include "util/input_file.h"
#include "util/memory.h"

namespace kdgrid {

std::vector<uint8_t> to_rgb8(const uint8_t* pixels, size_t count, int channels) {
  std::vector<uint8_t> rgb(count * 3);
  for (size_t i = 0; i < count; ++i) {
    const uint8_t* p = pixels + i * size_t(channels);
    // Grey (+alpha) images replicate the grey value; alpha is dropped.
    const bool grey = channels < 3;
    rgb[3 * i + 0] = p[0];
    rgb[3 * i + 1] = grey ? p[0] : p[1];
    rgb[3 * i + 2] = grey ? p[0] : p[2];
  }
  return rgb;
}

bool texture_fits_budget(int width, int height, int channels, std::string& why) {
  // While decoding: the pixels as read (`channels` bytes each) plus the RGB8 copy.
  const double bytes = double(width) * double(height) * double(channels + 3);
  const uint64_t budget = default_memory_budget_bytes();
  if (bytes <= double(budget)) return true;
  why = std::to_string(width) + "x" + std::to_string(height) + " pixels would take " +
        format_bytes_iec(bytes) + " to decode, above the memory budget of " +
        format_bytes_iec(double(budget)) +
        " (half of the memory available); scale the image down";
  return false;
}

std::optional<Texture> read_texture_file(const std::string& path, std::string& why) {
  try {
    check_input_file(path, "texture");
  } catch (const LoadError& e) {
    why = e.what();
    return std::nullopt;
  }
  auto in = OIIO::ImageInput::open(path);
  if (!in) {
    why = OIIO::geterror();
    if (why.empty()) why = "cannot open";
    return std::nullopt;
  }
  const OIIO::ImageSpec& spec = in->spec();
  const int nch = spec.nchannels;
  if (spec.width <= 0 || spec.height <= 0 || nch <= 0 || spec.depth > 1) {
    why = "unsupported image layout";
    return std::nullopt;
  }
  const int used = std::min(nch, 4);
  // The header gives the size: refuse before decoding what would not fit.
  if (!texture_fits_budget(spec.width, spec.height, used, why)) return std::nullopt;
  std::vector<uint8_t> px(size_t(spec.width) * size_t(spec.height) * size_t(used));
  if (!in->read_image(0, 0, 0, used, OIIO::TypeDesc::UINT8, px.data())) {
    why = in->geterror();
    return std::nullopt;
  }
  Texture t;
  t.width = spec.width;
  t.height = spec.height;
  t.channels = 3;
  t.pixels = to_rgb8(px.data(), size_t(t.width) * size_t(t.height), used);
  // Float images (EXR, HDR) hold linear values; 8-bit colour images are conventionally sRGB.
  t.srgb = !spec.format.is_floating_point();
  t.name = path;
  return t;
}

}  // namespace kdgrid
