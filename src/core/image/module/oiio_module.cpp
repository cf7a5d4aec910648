// kdgrid-image-oiio.so: image_module.h's Api over OpenImageIO. Built as its own shared module,
// linked to OpenImageIO and nothing of kdgrid, and loaded by image_io.cpp on first use.
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include "image/image_module.h"

namespace kdgrid::image_module {

namespace {

/// A Reader over an OpenImageIO input, with the memory it reads from when there is one.
class OiioReader final : public Reader {
 public:
  OiioReader(std::unique_ptr<OIIO::ImageInput> in,
             std::unique_ptr<OIIO::Filesystem::IOMemReader> source)
      : source_(std::move(source)), in_(std::move(in)) {
    const OIIO::ImageSpec& spec = in_->spec();
    header_.width = spec.width;
    header_.height = spec.height;
    header_.depth = spec.depth;
    header_.channels = spec.nchannels;
    header_.floating = spec.format.is_floating_point();
    for (const OIIO::ParamValue& p : spec.extra_attribs)
      if (p.type() == OIIO::TypeDesc::STRING)
        header_.strings.emplace_back(p.name().string(), p.get_string());
  }
  ~OiioReader() override { in_->close(); }

  const Header& header() const override { return header_; }

  bool read(int channels, bool as_float, void* out, std::string& error) override {
    const OIIO::TypeDesc type = as_float ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::UINT8;
    // libjpeg reports a truncated JPEG as a warning, fills the missing rows with grey and
    // succeeds; OpenImageIO keeps the warning as an error message, so it fails here too.
    if (in_->read_image(0, 0, 0, channels, type, out) && !in_->has_error()) return true;
    error = in_->geterror();
    return false;
  }

 private:
  std::unique_ptr<OIIO::Filesystem::IOMemReader> source_;  // outlives in_, which reads it
  std::unique_ptr<OIIO::ImageInput> in_;
  Header header_;
};

std::unique_ptr<Reader> open_file(const std::string& path, std::string& error) {
  auto in = OIIO::ImageInput::open(path);
  if (!in) {
    error = OIIO::geterror();
    return nullptr;
  }
  return std::make_unique<OiioReader>(std::move(in), nullptr);
}

std::unique_ptr<Reader> open_memory(const std::string& format, const unsigned char* bytes,
                                    size_t size, std::string& error) {
  auto source = std::make_unique<OIIO::Filesystem::IOMemReader>(bytes, size);
  auto in = OIIO::ImageInput::open(format, nullptr, source.get());
  if (!in) {
    error = OIIO::geterror();
    return nullptr;
  }
  return std::make_unique<OiioReader>(std::move(in), std::move(source));
}

bool encode(const std::string& format, int width, int height, bool as_float, const void* pixels,
            const Attributes& attributes, std::vector<unsigned char>& out, std::string& error) {
  const OIIO::TypeDesc type = as_float ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::UINT8;
  OIIO::ImageSpec spec(width, height, 3, type);
  for (const auto& [name, value] : attributes) spec.attribute(name, value);
  auto writer = OIIO::ImageOutput::create(format);
  if (!writer) {
    error = "cannot create an image writer: " + OIIO::geterror();
    return false;
  }
  OIIO::Filesystem::IOVecOutput sink(out);
  writer->set_ioproxy(&sink);
  if (!writer->open(format, spec)) {
    error = "cannot start encoding the image: " + writer->geterror();
    return false;
  }
  bool ok = writer->write_image(type, pixels);
  std::string why = ok ? "" : writer->geterror();
  if (!writer->close() && ok) {
    ok = false;
    why = writer->geterror();
  }
  if (!ok) error = "encoding the image failed: " + why;
  return ok;
}

constexpr Api kApi{open_file, open_memory, encode};

}  // namespace

}  // namespace kdgrid::image_module

extern "C" [[gnu::visibility("default")]] const kdgrid::image_module::Api*
kdgrid_image_module_api() {
  return &kdgrid::image_module::kApi;
}
