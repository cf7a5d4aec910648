#include "scene/load.h"

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <new>
#include <vector>

#include "scene/procedural.h"
#include "util/error.h"
#include "util/input_file.h"
#include "util/memory.h"
#include "util/paths.h"

namespace kdgrid {

namespace {

/// "gen:NAME[:COUNT[:SEED]]": a procedural scene built in memory, no file involved.
Scene generate_from_spec(const std::string& spec, double scale) {
  std::vector<std::string> parts;
  size_t start = 4;
  while (true) {
    const size_t colon = spec.find(':', start);
    parts.push_back(spec.substr(start, colon == std::string::npos ? colon : colon - start));
    if (colon == std::string::npos) break;
    start = colon + 1;
  }
  auto number = [&](size_t i, const char* what) -> uint64_t {
    const std::string& t = parts[i];
    char* end = nullptr;
    const unsigned long long v = std::strtoull(t.c_str(), &end, 10);
    if (t.empty() || t[0] == '-' || *end != '\0')
      throw LoadError(spec + ": " + what + " '" + t + "' is not a whole number; write gen:NAME" +
                      "[:COUNT[:SEED]], e.g. gen:landscape:10000000");
    return v;
  };
  if (parts.empty() || parts[0].empty() || parts.size() > 3)
    throw LoadError(spec + ": write gen:NAME[:COUNT[:SEED]], e.g. gen:landscape:10000000 " +
                    "(names: kdgrid gen --help)");
  ProceduralParams p;
  if (parts.size() > 1) {
    const uint64_t c = number(1, "count");
    if (c > uint64_t(std::numeric_limits<int>::max()))
      throw LoadError(spec + ": count " + parts[1] + " is too large");
    p.count = int(c);
  }
  if (parts.size() > 2) p.seed = number(2, "seed");
  Scene s = generate_scene(parts[0], p);
  s.source = spec;
  s.scale_by(scale, "--scale");
  s.finalize();
  return s;
}

}  // namespace

Scene load_scene(const std::string& given, const LoadOptions& options) {
  if (given.rfind("gen:", 0) == 0) return generate_from_spec(given, options.scale);
  // A path that does not exist as given is looked up in the shared scenes directory.
  const std::string path = resolve_scene_path(given);
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(path, ec))
    throw LoadError(path +
                    ": no such file; check the path (shared scenes are found relative to "
                    "$KDGRID_SCENES or ../shared/scenes)");
  if (fs::is_directory(path, ec))
    throw LoadError(path + ": is a directory; give a scene file (.gltf .glb .ply .obj)");
  check_input_file(path);  // a FIFO or device blocks or never ends; a huge file cannot fit
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  if (ext != ".ply" && ext != ".obj" && ext != ".gltf" && ext != ".glb")
    throw LoadError(path + ": unknown scene format '" + printable(ext) +
                    "'; kdgrid reads .gltf, .glb, .ply and .obj");
  try {
    Scene s = ext == ".ply"   ? load_ply(path)
              : ext == ".obj" ? load_obj(path, options)
                              : load_gltf(path, options);
    s.source = path;
    s.scale_by(options.scale, "--scale");
    s.finalize();
    return s;
  } catch (const std::bad_alloc&) {
    throw LoadError(path + ": " + out_of_memory_message() +
                    " while loading it: use a smaller scene or run with more memory");
  }
}

}  // namespace kdgrid
