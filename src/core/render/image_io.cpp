#include "render/image_io.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "render/renderer.h"
#include "util/atomic_file.h"
#include "util/error.h"

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
    throw Error(path + ": the encoded image does not read back as " + std::to_string(width) +
                "x" + std::to_string(height) + (in ? "" : " (" + OIIO::geterror() + ")") +
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

void write_image(const std::string& path, int width, int height, const std::vector<float>& rgb,
                 const std::map<std::string, std::string>& metadata) {
  using namespace OIIO;
  check_image_extension(path);
  if (width < 1 || height < 1 || rgb.size() != size_t(width) * size_t(height) * 3)
    throw ParamError(path + ": image data does not match " + std::to_string(width) + "x" +
                     std::to_string(height) + " RGB");
  const bool png = lower_extension(path) == ".png";

  // Encoded in memory (OpenImageIO's PNG writer does not report a failed write to a file),
  // checked by decoding the header back, then written through AtomicFile, whose writes and
  // close are all checked: a full disk leaves the old image in place.
  ImageSpec spec(width, height, 3, png ? TypeDesc::UINT8 : TypeDesc::FLOAT);
  for (const auto& [key, value] : metadata) spec.attribute(kMetaPrefix + key, value);
  if (!png) spec.attribute("compression", "zip");

  const std::string format_name = png ? "x.png" : "x.exr";  // picks the encoder
  auto out = ImageOutput::create(format_name);
  if (!out) throw Error(path + ": cannot create an image writer: " + OIIO::geterror());
  std::vector<unsigned char> encoded;
  Filesystem::IOVecOutput sink(encoded);
  out->set_ioproxy(&sink);
  if (!out->open(format_name, spec))
    throw Error(path + ": cannot start encoding the image: " + out->geterror());
  bool ok;
  if (png) {
    std::vector<uint8_t> bytes;
    tonemap_srgb8(rgb, bytes);
    ok = out->write_image(TypeDesc::UINT8, bytes.data());
  } else {
    ok = out->write_image(TypeDesc::FLOAT, rgb.data());
  }
  std::string err = ok ? "" : out->geterror();
  if (!out->close() && ok) {
    ok = false;
    err = out->geterror();
  }
  if (!ok) throw Error(path + ": encoding the image failed: " + err + "; the file was not changed");
  verify_encoded_image(path, format_name, encoded, width, height);
  write_file_atomically(path, std::string_view(reinterpret_cast<const char*>(encoded.data()),
                                               encoded.size()));
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

}  // namespace kdgrid
