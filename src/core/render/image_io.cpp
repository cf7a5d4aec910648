#include "render/image_io.h"

#include <OpenImageIO/imageio.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>

#include "render/renderer.h"
#include "util/error.h"

namespace kdgrid {

namespace {

std::string lower_extension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  return ext;
}

float srgb_to_linear(float c) {
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}

constexpr const char* kMetaPrefix = "kdgrid:";

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

  // Temporary file beside the target (same filesystem, so the rename is atomic) keeping the
  // extension, from which OpenImageIO picks the format.
  namespace fs = std::filesystem;
  static std::atomic<unsigned> counter{0};
  const fs::path target(path);
  std::string tmp_name = ".";  // built stepwise: GCC 12 warns falsely on "." + std::string
  tmp_name += target.stem().string();
  tmp_name += ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter++);
  tmp_name += target.extension().string();
  const fs::path tmp = target.parent_path() / tmp_name;

  ImageSpec spec(width, height, 3, png ? TypeDesc::UINT8 : TypeDesc::FLOAT);
  for (const auto& [key, value] : metadata) spec.attribute(kMetaPrefix + key, value);
  if (!png) spec.attribute("compression", "zip");

  auto out = ImageOutput::create(tmp.string());
  if (!out) throw Error(path + ": cannot create an image writer: " + OIIO::geterror());
  if (!out->open(tmp.string(), spec))
    throw Error(path + ": cannot open for writing (" + out->geterror() +
                "); check that the directory exists and is writable");
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
  if (!ok) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw Error(path + ": writing the image failed: " + err);
  }
  std::error_code ec;
  fs::rename(tmp, target, ec);
  if (ec) {
    fs::remove(tmp, ec);
    throw Error(path + ": cannot move the finished image into place: " + ec.message());
  }
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
