// Reading a glTF 2.0 file (load_gltf): the .glb header checked field by field, tinygltf's file
// callbacks (buffers and images from the scene's folder only, images decoded by OpenImageIO), the
// required extensions, and tinygltf's errors and warnings in a few plain lines; gltf.cpp turns the
// parsed model into the Scene.
#include <tiny_gltf.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "image/image_io.h"
#include "scene/gltf_scene.h"
#include "scene/load.h"
#include "util/error.h"
#include "util/format.h"
#include "util/input_file.h"

namespace kdgrid {

namespace {

std::string lower_ext(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

uint32_t le32(const std::string& d, size_t at) {
  return uint32_t(uint8_t(d[at])) | uint32_t(uint8_t(d[at + 1])) << 8 |
         uint32_t(uint8_t(d[at + 2])) << 16 | uint32_t(uint8_t(d[at + 3])) << 24;
}

/// Checks the 12-byte GLB header and the chunk headers, naming the field that is wrong
/// (tinygltf says only "Invalid glTF binary").
void check_glb_header(const std::string& d, const std::string& path) {
  auto fail = [&](const std::string& problem) {
    throw LoadError(path + ": broken .glb: " + problem);
  };
  const size_t size = d.size();
  if (size < 12)
    fail("the file has " + std::to_string(size) + " bytes, fewer than the 12-byte header");
  if (d.compare(0, 4, "glTF") != 0)
    fail("bytes 0-3 are '" + printable(std::string_view(d).substr(0, 4)) +
         "', not the magic 'glTF'" + (d[0] == '{' ? " (this is JSON: rename it to .gltf)" : ""));
  if (le32(d, 4) != 2)
    fail("header version (bytes 4-7) is " + std::to_string(le32(d, 4)) +
         "; kdgrid reads glTF 2 binaries");
  const uint64_t length = le32(d, 8);
  if (length > size)
    throw LoadError(path + ": truncated .glb: its header length (bytes 8-11) says " +
                    std::to_string(length) + " bytes but the file has " + std::to_string(size));
  if (length != size)
    fail("header length (bytes 8-11) says " + std::to_string(length) + " bytes but the file has " +
         std::to_string(size) + ": bytes follow the end");
  size_t at = 12;
  for (int chunk = 0; at < size; ++chunk) {
    const std::string which = chunk == 0 ? "first (JSON) chunk" : "chunk " + std::to_string(chunk);
    if (size - at < 8)
      fail(which + " header at byte " + std::to_string(at) + " needs 8 bytes, only " +
           std::to_string(size - at) + " remain");
    const uint64_t len = le32(d, at), type = le32(d, at + 4);
    if (len > size - at - 8)
      fail(which + " length (bytes " + std::to_string(at) + "-" + std::to_string(at + 3) + ") is " +
           std::to_string(len) + " but only " + std::to_string(size - at - 8) +
           " bytes follow its header");
    if (chunk == 0 && type != 0x4E4F534Au)
      fail(which + " type (bytes 16-19) is '" + printable(std::string_view(d).substr(16, 4)) +
           "', not 'JSON'");
    if (chunk == 0) {
      // The JSON text ends in '}', padded with spaces: a length that ends elsewhere is wrong
      // (what follows would be read as the next chunk's header, from inside the JSON).
      size_t last = at + 8 + size_t(len);
      while (last > at + 8 && (d[last - 1] == ' ' || d[last - 1] == '\0')) --last;
      if (last == at + 8 || d[last - 1] != '}')
        fail("the JSON chunk length (bytes 12-15) is " + std::to_string(len) +
             ", which does not end at the end of the JSON text (its last byte there is '" +
             printable(std::string_view(d).substr(last > at + 8 ? last - 1 : at + 8, 1)) +
             "', not '}'); the JSON chunk length is wrong: re-export the file");
    }
    if (chunk == 1 && type != 0x004E4942u)
      fail(which + " type (bytes " + std::to_string(at + 4) + "-" + std::to_string(at + 7) +
           ") is '" + printable(std::string_view(d).substr(at + 4, 4)) + "', not 'BIN'");
    at += 8 + size_t(len);
  }
  if (size == 12) fail("the header is followed by no JSON chunk");
}

/// What the file callbacks need: the scene's folder, outside which nothing is read.
struct GltfFiles {
  std::filesystem::path folder;
  bool decode_textures = true;  // LoadOptions::decode_textures
};

/// tinygltf's reader of buffer and image files: inside the scene's folder only (a URI of
/// ../../etc/passwd must not read, or reveal the size of, files elsewhere), regular files of
/// bounded size only (util/input_file.h).
bool read_scene_file(std::vector<unsigned char>* out, std::string* err, const std::string& file,
                     void* user) {
  namespace fs = std::filesystem;
  const auto* files = static_cast<const GltfFiles*>(user);
  std::error_code ec;
  const fs::path full = fs::weakly_canonical(fs::absolute(file), ec);
  const auto rel = full.lexically_relative(files->folder);
  if (ec || rel.empty() || *rel.begin() == "..") {
    if (err)
      *err += "the URI points outside the scene's folder " + files->folder.string() +
              "; kdgrid reads buffers and images from that folder (and below) only: copy the "
              "file there";
    return false;
  }
  try {
    const std::string text = read_input_file(file, "glTF buffer or image");
    out->assign(text.begin(), text.end());
  } catch (const LoadError& e) {
    if (err) *err += e.what();
    return false;
  }
  return true;
}

bool refuse_write(std::string* err, const std::string&, const std::vector<unsigned char>&, void*) {
  if (err) *err += "kdgrid does not write files while loading";
  return false;
}

/// Decodes a glTF image (PNG or JPEG bytes from a file, a data URI or a buffer view) with
/// OpenImageIO into RGB8 (image/image_io.h, decode_texture): the header is read first and an
/// image above the texture limits is refused before decoding (stb_image, tinygltf's default,
/// has neither check nor a useful message for large images). `user` points to GltfFiles.
bool decode_image(tinygltf::Image* image, const int index, std::string*, std::string* warn, int,
                  int, const unsigned char* bytes, int size, void* user) {
  const bool decode = static_cast<const GltfFiles*>(user)->decode_textures;
  std::string why;
  auto tex = decode_texture(bytes, size_t(std::max(size, 0)), image->name, why, decode);
  if (!tex) {
    // An unusable image is a warning: the texture is dropped, not the scene.
    if (warn)
      *warn += "image " + std::to_string(index) + ": " + why + "; material left untextured\n";
    return true;
  }
  image->width = tex->width;
  image->height = tex->height;
  image->component = 3;
  image->bits = 8;
  image->pixel_type = TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE;
  image->image = std::move(tex->pixels);
  return true;
}

/// The extensions kdgrid reads (GltfBuilder, gltf.cpp): a file that requires any other one
/// (extensionsRequired) cannot be shown as its author meant, so it is refused; an extension
/// that is only used (extensionsUsed) is ignored, as glTF allows.
void check_required_extensions(const tinygltf::Model& model, const std::string& path) {
  static const char* const kRead[] = {
      "KHR_lights_punctual", "KHR_materials_emissive_strength", "KHR_materials_ior",
      "KHR_materials_transmission",
      // Positions, normals and uvs of any component type (AccessorReader::component).
      "KHR_mesh_quantization"};
  for (const std::string& req : model.extensionsRequired) {
    if (std::find(std::begin(kRead), std::end(kRead), req) != std::end(kRead)) continue;
    std::string known;
    for (const char* k : kRead) known += std::string(known.empty() ? "" : ", ") + k;
    throw LoadError(path + ": requires the glTF extension '" + printable(req, 80) +
                    "' (extensionsRequired), which kdgrid does not read (it reads " + known +
                    "); re-export the file without it");
  }
}

/// Prints tinygltf's warnings, one line each, cut to a few hundred bytes; at most ten (a file
/// of many broken images would otherwise print a line for each).
void print_warnings(const std::string& path, const std::string& text) {
  size_t start = 0, printed = 0, suppressed = 0;
  while (start < text.size()) {
    size_t end = text.find('\n', start);
    if (end == std::string::npos) end = text.size();
    if (end > start && ++printed <= 10)
      std::fprintf(stderr, "%s: warning: %s\n", path.c_str(),
                   printable(std::string_view(text).substr(start, end - start), 300).c_str());
    else if (end > start)
      ++suppressed;
    start = end + 1;
  }
  if (suppressed > 0)
    std::fprintf(stderr, "%s: warning: (%zu further warnings suppressed)\n", path.c_str(),
                 suppressed);
}

}  // namespace

Scene load_gltf(const std::string& path, const LoadOptions& options) {
  namespace fs = std::filesystem;
  const bool binary = lower_ext(path) == ".glb";
  const std::string data = read_input_file(path);
  if (binary) check_glb_header(data, path);
  GltfFiles files;
  std::error_code ec;
  files.folder = fs::weakly_canonical(fs::absolute(fs::path(path)).parent_path(), ec);
  files.decode_textures = options.decode_textures;
  tinygltf::TinyGLTF loader;
  loader.SetFsCallbacks(
      {&tinygltf::FileExists, &tinygltf::ExpandFilePath, &read_scene_file, &refuse_write, &files});
  loader.SetImageLoader(&decode_image, &files);
  tinygltf::Model model;
  std::string err, warn;
  const std::string base_dir = fs::path(path).parent_path().string();
  const bool ok =
      binary ? loader.LoadBinaryFromMemory(&model, &err, &warn,
                                           reinterpret_cast<const unsigned char*>(data.data()),
                                           unsigned(data.size()), base_dir)
             : loader.LoadASCIIFromString(&model, &err, &warn, data.data(), unsigned(data.size()),
                                          base_dir);
  if (!ok) {
    std::string e = err.empty() ? warn : err;
    while (!e.empty() && (e.back() == '\n' || e.back() == ' ')) e.pop_back();
    std::replace(e.begin(), e.end(), '\n', ' ');
    // tinygltf's own words for a stride outside 4..252 speak of multiples of 4 only.
    const std::string bad_stride =
        "Invalid `byteStride' value. `byteStride' must be the multiple of 4 : ";
    const size_t at = e.find(bad_stride);
    if (at != std::string::npos)
      throw LoadError(path + ": a buffer view has byteStride " +
                      printable(std::string_view(e).substr(at + bad_stride.size()), 24) +
                      "; glTF allows a multiple of 4 from 4 to 252 (or none, for tightly packed "
                      "elements): re-export the file");
    // tinygltf quotes the file's text (a data: URI of megabytes): cut to a few hundred bytes.
    throw LoadError(path +
                    ": cannot parse glTF: " + (e.empty() ? "unknown error" : printable(e, 400)));
  }
  print_warnings(path, warn);
  check_required_extensions(model, path);
  Scene scene;
  gltf_to_scene(model, path, options.decode_textures, scene);
  return scene;
}

}  // namespace kdgrid
