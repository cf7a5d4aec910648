#include "scene/load.h"

#include <algorithm>
#include <filesystem>

#include "util/error.h"
#include "util/paths.h"

namespace kdgrid {

Scene load_scene(const std::string& given) {
  // A path that does not exist as given is looked up in the shared scenes directory.
  const std::string path = resolve_scene_path(given);
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(path, ec))
    throw LoadError(path + ": no such file; check the path (shared scenes are found relative to "
                           "$KDGRID_SCENES or ../shared/scenes)");
  if (fs::is_directory(path, ec))
    throw LoadError(path + ": is a directory; give a scene file (.gltf .glb .ply .obj)");
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  Scene s;
  if (ext == ".ply")
    s = load_ply(path);
  else if (ext == ".obj")
    s = load_obj(path);
  else if (ext == ".gltf" || ext == ".glb")
    s = load_gltf(path);
  else
    throw LoadError(path + ": unknown scene format '" + ext +
                    "'; kdgrid reads .gltf, .glb, .ply and .obj");
  s.source = path;
  s.finalize();
  return s;
}

}  // namespace kdgrid
