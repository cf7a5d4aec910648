#include "image/image_io.h"

#include <dlfcn.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <mutex>

#include "image/image_module.h"
#include "util/atomic_file.h"
#include "util/error.h"
#include "util/format.h"
#include "util/input_file.h"
#include "util/memory.h"
#include "util/paths.h"

namespace kdgrid {

namespace {

namespace fs = std::filesystem;

#ifndef KDGRID_IMAGE_MODULE_FROM_BIN
#define KDGRID_IMAGE_MODULE_FROM_BIN "../lib/kdgrid"
#endif

/// Where the image module may be, in order: beside the executable, where `cmake --install`
/// puts it for PREFIX/bin (KDGRID_IMAGE_MODULE_FROM_BIN, relative), and for an executable in a
/// build tree (build/PRESET/src/cli, build/PRESET/tests, ...) the build tree's top, the
/// nearest of its ancestors that holds a CMakeCache.txt.
std::vector<fs::path> image_module_candidates() {
  const fs::path exe = executable_dir();
  std::vector<fs::path> out;
  if (exe.empty()) return out;
  out.push_back(exe / image_module::kFileName);
  out.push_back(exe / KDGRID_IMAGE_MODULE_FROM_BIN / image_module::kFileName);
  std::error_code ec;
  fs::path dir = exe;
  for (int up = 0; up < 4 && dir != dir.parent_path(); ++up, dir = dir.parent_path())
    if (fs::exists(dir / "CMakeCache.txt", ec)) {
      out.push_back(dir / image_module::kFileName);
      break;
    }
  return out;
}

/// The image module's Api, loaded on first use and kept for the life of the process. Throws
/// Error naming where it looked when no candidate loads.
const image_module::Api& image_api() {
  static std::mutex mutex;
  static const image_module::Api* api = nullptr;
  const std::lock_guard lock(mutex);
  if (api) return *api;
  std::string tried;
  for (const fs::path& candidate : image_module_candidates()) {
    std::error_code ec;
    if (!fs::exists(candidate, ec)) continue;
    void* module = dlopen(candidate.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!module) {
      const char* why = dlerror();
      tried +=
          (tried.empty() ? ": " : "; ") + candidate.string() + ": " + (why ? why : "cannot load");
      continue;
    }
    using Entry = const image_module::Api* (*)();
    auto entry = reinterpret_cast<Entry>(dlsym(module, image_module::kEntryPoint));
    if (entry && (api = entry())) return *api;
    tried +=
        (tried.empty() ? ": " : "; ") + candidate.string() + ": no " + image_module::kEntryPoint;
  }
  const std::string module =
      std::string("kdgrid's image module ") + image_module::kFileName + " (OpenImageIO)";
  if (tried.empty())
    throw Error("cannot read or write images: " + module +
                " is neither beside the executable, in " KDGRID_IMAGE_MODULE_FROM_BIN
                " from it, nor at the top of its build tree; reinstall or rebuild kdgrid");
  throw Error("cannot read or write images: " + module + " does not load" + tried);
}

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
  std::string why;
  const auto in = image_api().open_memory(format_name, bytes.data(), bytes.size(), why);
  if (!in || in->header().width != width || in->header().height != height)
    throw Error(path + ": the encoded image does not read back as " + std::to_string(width) + "x" +
                std::to_string(height) + (in ? "" : " (" + why + ")") +
                "; the file was not changed");
}

}  // namespace

void check_image_extension(const std::string& path) {
  const std::string ext = lower_extension(path);
  if (ext != ".png" && ext != ".exr")
    throw ParamError(path + ": unsupported image format '" + ext +
                     "'; kdgrid writes .png (8-bit sRGB) and .exr (linear float)");
}

void require_image_module() {
  image_api();
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

/// Encodes `pixels` (3 channels, floats or 8-bit, row 0 at the top) with `attributes` in memory
/// (OpenImageIO's PNG writer does not report a failed write to a file), checks the encoding by
/// decoding its header back, then writes it through AtomicFile, whose writes and close are all
/// checked: a full disk leaves the old image in place.
void encode_and_write(const std::string& path, int width, int height, bool as_float,
                      const void* pixels, const image_module::Attributes& attributes = {}) {
  const bool png = lower_extension(path) == ".png";
  const std::string format_name = png ? "x.png" : "x.exr";  // picks the encoder
  std::vector<unsigned char> encoded;
  std::string why;
  if (!image_api().encode(format_name, width, height, as_float, pixels, attributes, encoded, why))
    throw Error(path + ": " + why + "; the file was not changed");
  verify_encoded_image(path, format_name, encoded, width, height);
  write_file_atomically(
      path, std::string_view(reinterpret_cast<const char*>(encoded.data()), encoded.size()));
}

}  // namespace

void write_image(const std::string& path, int width, int height, const std::vector<float>& rgb,
                 const std::map<std::string, std::string>& metadata) {
  check_image_extension(path);
  if (width < 1 || height < 1 || rgb.size() != size_t(width) * size_t(height) * 3)
    throw ParamError(path + ": image data does not match " + std::to_string(width) + "x" +
                     std::to_string(height) + " RGB");
  const bool png = lower_extension(path) == ".png";
  image_module::Attributes attributes;
  for (const auto& [key, value] : metadata) attributes.emplace_back(kMetaPrefix + key, value);
  if (png) {
    std::vector<uint8_t> bytes;
    tonemap_srgb8(rgb, bytes);
    encode_and_write(path, width, height, false, bytes.data(), attributes);
  } else {
    attributes.emplace_back("compression", "zip");
    encode_and_write(path, width, height, true, rgb.data(), attributes);
  }
}

void write_png_rgb8(const std::string& path, int width, int height,
                    const std::vector<uint8_t>& rgb) {
  if (lower_extension(path) != ".png")
    throw ParamError(path + ": a screenshot is a PNG; name the file with the .png extension");
  if (width < 1 || height < 1 || rgb.size() != size_t(width) * size_t(height) * 3)
    throw ParamError(path + ": image data does not match " + std::to_string(width) + "x" +
                     std::to_string(height) + " RGB");
  encode_and_write(path, width, height, false, rgb.data());
}

ImageRGB read_image(const std::string& path) {
  std::string why;
  const auto in = image_api().open_file(path, why);
  if (!in) throw LoadError(path + ": cannot read image: " + why);
  const image_module::Header& spec = in->header();
  const int nc = spec.channels;
  if (spec.width <= 0 || spec.height <= 0 || nc <= 0 || spec.depth > 1)
    throw LoadError(path + ": cannot read image: unsupported image layout");
  std::vector<float> data(size_t(spec.width) * spec.height * nc);
  if (!in->read(nc, true, data.data(), why))
    throw LoadError(path + ": cannot read image pixels: " + why);
  ImageRGB img;
  img.width = spec.width;
  img.height = spec.height;
  img.rgb.resize(size_t(spec.width) * spec.height * 3);
  // Integer formats hold display (sRGB) values; float formats (EXR) hold linear ones.
  const bool linearise = !spec.floating;
  for (size_t i = 0; i < size_t(spec.width) * spec.height; ++i)
    for (int ch = 0; ch < 3; ++ch) {
      const float v = data[i * nc + std::min(ch, nc - 1)];
      img.rgb[i * 3 + ch] = linearise ? srgb_to_linear(v) : v;
    }
  for (const auto& [name, value] : spec.strings)
    if (name.rfind(kMetaPrefix, 0) == 0)
      img.metadata[name.substr(std::string(kMetaPrefix).size())] = value;
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
std::optional<Texture> read_texture(image_module::Reader& in, const std::string& name,
                                    std::string& why, bool decode) {
  const image_module::Header& spec = in.header();
  const int nch = spec.channels;
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
  t.srgb = !spec.floating;
  t.name = name;
  if (!decode) return t;
  std::vector<uint8_t> px(size_t(spec.width) * size_t(spec.height) * size_t(used));
  // A truncated JPEG, which libjpeg only warns of, is refused as a truncated PNG is.
  if (!in.read(used, false, px.data(), why)) {
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
  try {
    const auto in = image_api().open_file(path, why);
    if (in) return read_texture(*in, path, why, decode);
  } catch (const Error& e) {
    why = e.what();
    return std::nullopt;
  }
  why = printable(why, 200);
  if (why.empty()) why = "cannot open";
  return std::nullopt;
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
  try {
    const auto in = image_api().open_memory(format, bytes, size, why);
    if (in) return read_texture(*in, name, why, decode);
  } catch (const Error& e) {
    why = e.what();
    return std::nullopt;
  }
  why = "cannot decode (" + printable(why, 200) + ")";
  return std::nullopt;
}

}  // namespace kdgrid
