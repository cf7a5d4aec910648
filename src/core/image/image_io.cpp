#include "image/image_io.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>

#include "util/atomic_file.h"
#include "util/error.h"
#include "util/format.h"
#include "util/input_file.h"
#include "util/memory.h"

namespace kdgrid {

namespace {

float srgb_to_linear(float c) {
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}

constexpr const char* kMetaPrefix = "kdgrid:";

/// Error unless `bytes` decode as a `width` x `height` image (header only) and, for PNG, end
/// in the IEND chunk that closes every complete PNG.
void verify_encoded_image(const std::string& path, const std::string& format_name,
                          const std::vector<unsigned char>& bytes, int width, int height) {
  static const unsigned char kIend[12] = {0, 0, 0, 0, 'I', 'E', 'N', 'D', 0xAE, 0x42, 0x60, 0x82};
  const bool png = lower_extension(format_name) == ".png";
  if (png && (bytes.size() < 12 || std::memcmp(bytes.data() + bytes.size() - 12, kIend, 12) != 0))
    throw Error(path + ": the PNG encoder produced an incomplete image (" +
                std::to_string(bytes.size()) + " bytes, no IEND chunk); the file was not changed");
  OIIO::Filesystem::IOMemReader reader(bytes.data(), bytes.size());
  auto in = OIIO::ImageInput::open(format_name, nullptr, &reader);
  if (!in || in->spec().width != width || in->spec().height != height)
    throw Error(path + ": the encoded image does not read back as " + std::to_string(width) + "x" +
                std::to_string(height) + (in ? "" : " (" + OIIO::geterror() + ")") +
                "; the file was not changed");
  in->close();
}

}  // namespace

void check_image_extension(const std::string& path) {
  const std::string ext = lower_extension(path);
  if (ext != ".png" && ext != ".exr")
    throw ParamError(path + ": unsupported image format '" + ext +
                     "'; kdgrid writes .png (8-bit sRGB) and .exr (linear float)");
}

void tonemap_srgb8(const std::vector<float>& rgb, std::vector<uint8_t>& out, float exposure) {
  out.resize(rgb.size());
  for (size_t i = 0; i < rgb.size(); ++i) {
    float c = rgb[i] * exposure;
    c = (c == c) ? std::min(1.0f, std::max(0.0f, c)) : 0.0f;  // NaN -> black
    const float s = c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
    out[i] = static_cast<uint8_t>(std::lround(s * 255.0f));
  }
}

namespace {

/// Encodes `pixels` (3 channels of `type`, row 0 at the top) as `spec` in memory (OpenImageIO's
/// PNG writer does not report a failed write to a file), checks the encoding by decoding its
/// header back, then writes it through AtomicFile, whose writes and close are all checked: a
/// full disk leaves the old image in place.
void encode_and_write(const std::string& path, const OIIO::ImageSpec& spec, OIIO::TypeDesc type,
                      const void* pixels) {
  using namespace OIIO;
  const bool png = lower_extension(path) == ".png";
  const std::string format_name = png ? "x.png" : "x.exr";  // picks the encoder
  auto out = ImageOutput::create(format_name);
  if (!out) throw Error(path + ": cannot create an image writer: " + OIIO::geterror());
  std::vector<unsigned char> encoded;
  Filesystem::IOVecOutput sink(encoded);
  out->set_ioproxy(&sink);
  if (!out->open(format_name, spec))
    throw Error(path + ": cannot start encoding the image: " + out->geterror());
  bool ok = out->write_image(type, pixels);
  std::string err = ok ? "" : out->geterror();
  if (!out->close() && ok) {
    ok = false;
    err = out->geterror();
  }
  if (!ok) throw Error(path + ": encoding the image failed: " + err + "; the file was not changed");
  verify_encoded_image(path, format_name, encoded, spec.width, spec.height);
  write_file_atomically(
      path, std::string_view(reinterpret_cast<const char*>(encoded.data()), encoded.size()));
}

}  // namespace

void write_image(const std::string& path, int width, int height, const std::vector<float>& rgb,
                 const std::map<std::string, std::string>& metadata) {
  using namespace OIIO;
  check_image_extension(path);
  if (width < 1 || height < 1 || rgb.size() != size_t(width) * size_t(height) * 3)
    throw ParamError(path + ": image data does not match " + std::to_string(width) + "x" +
                     std::to_string(height) + " RGB");
  const bool png = lower_extension(path) == ".png";
  ImageSpec spec(width, height, 3, png ? TypeDesc::UINT8 : TypeDesc::FLOAT);
  for (const auto& [key, value] : metadata) spec.attribute(kMetaPrefix + key, value);
  if (!png) spec.attribute("compression", "zip");
  if (png) {
    std::vector<uint8_t> bytes;
    tonemap_srgb8(rgb, bytes);
    encode_and_write(path, spec, TypeDesc::UINT8, bytes.data());
  } else {
    encode_and_write(path, spec, TypeDesc::FLOAT, rgb.data());
  }
}

void write_png_rgb8(const std::string& path, int width, int height,
                    const std::vector<uint8_t>& rgb) {
  using namespace OIIO;
  if (lower_extension(path) != ".png")
    throw ParamError(path + ": a screenshot is a PNG; name the file with the .png extension");
  if (width < 1 || height < 1 || rgb.size() != size_t(width) * size_t(height) * 3)
    throw ParamError(path + ": image data does not match " + std::to_string(width) + "x" +
                     std::to_string(height) + " RGB");
  encode_and_write(path, ImageSpec(width, height, 3, TypeDesc::UINT8), TypeDesc::UINT8, rgb.data());
}

ImageRGB read_image(const std::string& path) {
  using namespace OIIO;
  auto in = ImageInput::open(path);
  if (!in) throw LoadError(path + ": cannot read image: " + OIIO::geterror());
  const ImageSpec& spec = in->spec();
  const int nc = spec.nchannels;
  std::vector<float> data(size_t(spec.width) * spec.height * nc);
  if (!in->read_image(0, 0, 0, nc, TypeDesc::FLOAT, data.data()))
    throw LoadError(path + ": cannot read image pixels: " + in->geterror());
  ImageRGB img;
  img.width = spec.width;
  img.height = spec.height;
  img.rgb.resize(size_t(spec.width) * spec.height * 3);
  // Integer formats hold display (sRGB) values; float formats (EXR) hold linear ones.
  const bool linearise = !spec.format.is_floating_point();
  for (size_t i = 0; i < size_t(spec.width) * spec.height; ++i)
    for (int ch = 0; ch < 3; ++ch) {
      const float v = data[i * nc + std::min(ch, nc - 1)];
      img.rgb[i * 3 + ch] = linearise ? srgb_to_linear(v) : v;
    }
  for (const ParamValue& p : spec.extra_attribs) {
    const std::string name = p.name().string();
    if (name.rfind(kMetaPrefix, 0) == 0 && p.type() == TypeDesc::STRING)
      img.metadata[name.substr(std::string(kMetaPrefix).size())] = p.get_string();
  }
  in->close();
  return img;
}

double rmse(const ImageRGB& a, const ImageRGB& b) {
  if (a.width != b.width || a.height != b.height || a.rgb.size() != b.rgb.size())
    throw ParamError("cannot compare images of different sizes: " + std::to_string(a.width) + "x" +
                     std::to_string(a.height) + " and " + std::to_string(b.width) + "x" +
                     std::to_string(b.height));
  if (a.rgb.empty()) return 0.0;
  double sum = 0.0;
  for (size_t i = 0; i < a.rgb.size(); ++i) {
    const double d = double(a.rgb[i]) - double(b.rgb[i]);
    sum += d * d;
  }
  return std::sqrt(sum / double(a.rgb.size()));
}

ImageDifference srgb8_difference(const std::vector<uint8_t>& a, const std::vector<uint8_t>& b,
                                 int tolerance) {
  if (a.size() != b.size() || a.size() % 3 != 0)
    throw ParamError("cannot compare 8-bit images of " + std::to_string(a.size()) + " and " +
                     std::to_string(b.size()) + " bytes");
  ImageDifference d;
  if (a.empty()) return d;
  uint64_t differing = 0, sum = 0;
  for (size_t i = 0; i < a.size(); i += 3) {
    int most = 0;
    for (size_t c = i; c < i + 3; ++c) {
      const int e = std::abs(int(a[c]) - int(b[c]));
      most = std::max(most, e);
      sum += uint64_t(e);
    }
    differing += most > tolerance ? 1 : 0;
  }
  d.pixels_differing = double(differing) / double(a.size() / 3);
  d.mean_abs = double(sum) / (255.0 * double(a.size()));
  return d;
}

// ---- textures -------------------------------------------------------------------------
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

bool texture_size_ok(int width, int height, int channels, std::string& why) {
  const std::string size = std::to_string(width) + "x" + std::to_string(height) + " pixels";
  // While decoding: the pixels as read (`channels` bytes each) plus the RGB8 copy.
  const double bytes = double(width) * double(height) * double(channels + 3);
  const uint64_t budget = default_memory_budget_bytes();
  if (bytes > double(budget)) {
    why = size + " would take " + format_bytes_iec(bytes) +
          " to decode, above the memory budget of " + format_bytes_iec(double(budget)) +
          " (half of the memory available); scale the image down";
    return false;
  }
  if (width > kMaxTextureSide || height > kMaxTextureSide) {
    why = size + ": above the limit of " + std::to_string(kMaxTextureSide) +
          " a side (docs/LIMITS.md); scale the image down";
    return false;
  }
  return true;
}

namespace {

/// The texture of the image `in` has opened (its header read); see read_texture_file.
std::optional<Texture> read_texture(OIIO::ImageInput& in, const std::string& name, std::string& why,
                                    bool decode) {
  const OIIO::ImageSpec spec = in.spec();
  const int nch = spec.nchannels;
  if (spec.width <= 0 || spec.height <= 0 || nch <= 0 || spec.depth > 1) {
    why = "unsupported image layout";
    return std::nullopt;
  }
  const int used = std::min(nch, 4);
  // The header gives the size: refuse before decoding what would not fit.
  if (!texture_size_ok(spec.width, spec.height, used, why)) return std::nullopt;
  Texture t;
  t.width = spec.width;
  t.height = spec.height;
  t.channels = 3;
  // Float images (EXR, HDR) hold linear values; 8-bit colour images are conventionally sRGB.
  t.srgb = !spec.format.is_floating_point();
  t.name = name;
  if (!decode) return t;
  std::vector<uint8_t> px(size_t(spec.width) * size_t(spec.height) * size_t(used));
  // libjpeg reports a truncated JPEG as a warning, fills the missing rows with grey and
  // succeeds; OpenImageIO keeps the warning as an error message: either way the texture is
  // refused, as a truncated PNG is.
  const bool ok = in.read_image(0, 0, 0, used, OIIO::TypeDesc::UINT8, px.data());
  if (!ok || in.has_error()) {
    why = in.geterror();
    while (!why.empty() && (why.back() == '\n' || why.back() == ' ')) why.pop_back();
    std::replace(why.begin(), why.end(), '\n', ' ');
    why = "cannot decode the pixels (" + printable(why.empty() ? "unknown error" : why, 200) +
          "); the file is truncated or corrupt";
    return std::nullopt;
  }
  t.pixels = to_rgb8(px.data(), size_t(t.width) * size_t(t.height), used);
  return t;
}

}  // namespace

std::optional<Texture> read_texture_file(const std::string& path, std::string& why, bool decode) {
  try {
    check_input_file(path, "texture");
  } catch (const LoadError& e) {
    why = e.what();
    return std::nullopt;
  }
  auto in = OIIO::ImageInput::open(path);
  if (!in) {
    why = printable(OIIO::geterror(), 200);
    if (why.empty()) why = "cannot open";
    return std::nullopt;
  }
  return read_texture(*in, path, why, decode);
}

std::optional<Texture> decode_texture(const unsigned char* bytes, size_t size,
                                      const std::string& name, std::string& why, bool decode) {
  const bool png = size >= 8 && std::memcmp(bytes, "\x89PNG", 4) == 0;
  const bool jpeg = size >= 3 && bytes[0] == 0xFF && bytes[1] == 0xD8;
  if (!png && !jpeg) {
    why = "neither PNG nor JPEG";
    return std::nullopt;
  }
  const std::string format = png ? "x.png" : "x.jpg";
  OIIO::Filesystem::IOMemReader reader(bytes, size);
  auto in = OIIO::ImageInput::open(format, nullptr, &reader);
  if (!in) {
    why = "cannot decode (" + printable(OIIO::geterror(), 200) + ")";
    return std::nullopt;
  }
  return read_texture(*in, name, why, decode);
}

}  // namespace kdgrid
