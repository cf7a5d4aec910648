// The interface between kdgrid and its image module, kdgrid-image-oiio.so: the OpenImageIO
// calls that image_io.cpp makes, built as a shared module that kdgrid loads the first time it
// reads or writes an image. OpenImageIO brings about 260 shared libraries (codecs, OpenCV,
// OpenVDB, ...) whose loading and relocation would otherwise be the start-up of every kdgrid
// process, also of the many that never touch an image (a scene's statistics, a benchmark, a
// test). Only standard types cross the boundary; both sides are built by the same compiler.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace kdgrid::image_module {

/// String attributes of an image (name, value), in the order they are written or were read.
using Attributes = std::vector<std::pair<std::string, std::string>>;

/// An image's header as its reader gives it.
struct Header {
  int width = 0, height = 0, depth = 1, channels = 0;
  bool floating = false;  ///< float pixels (EXR, HDR), which hold linear values
  Attributes strings;     ///< its string attributes
};

/// An open image: its header, then its pixels.
class Reader {
 public:
  virtual ~Reader() = default;
  virtual const Header& header() const = 0;
  /// Reads channels [0, channels) of every pixel, as 8-bit values or floats, into `out`. False
  /// with `error` set when the data end early or are corrupt, also when the codec only warned.
  virtual bool read(int channels, bool as_float, void* out, std::string& error) = 0;
};

/// What the module offers.
struct Api {
  /// Opens the image file `path`; nullptr with `error` set when it cannot.
  std::unique_ptr<Reader> (*open_file)(const std::string& path, std::string& error);
  /// Opens an encoded image in memory, decoded by the codec that `format` names as a file name
  /// would ("x.png"); nullptr with `error` set when it cannot.
  std::unique_ptr<Reader> (*open_memory)(const std::string& format, const unsigned char* bytes,
                                         size_t size, std::string& error);
  /// Encodes `width` x `height` pixels of 3 channels (8-bit or float, row 0 at the top) with
  /// `attributes` into `out`, as the codec that `format` names ("x.png", "x.exr"). False with
  /// `error` set (what failed and the codec's message) when it cannot.
  bool (*encode)(const std::string& format, int width, int height, bool as_float,
                 const void* pixels, const Attributes& attributes, std::vector<unsigned char>& out,
                 std::string& error);
};

/// The module's file name, and the one symbol kdgrid looks up in it.
inline constexpr const char* kFileName = "kdgrid-image-oiio.so";
inline constexpr const char* kEntryPoint = "kdgrid_image_module_api";

}  // namespace kdgrid::image_module

/// The module's entry point: its Api, valid for the life of the process.
extern "C" const kdgrid::image_module::Api* kdgrid_image_module_api();
