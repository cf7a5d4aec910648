// Scene loading: dispatch on the file extension to the glTF, PLY and OBJ readers.
#pragma once

#include <string>

#include "scene/scene.h"

namespace kdgrid {

/// Loads .gltf/.glb (tinygltf), .ply (own reader) or .obj (tinyobjloader), then
/// Scene::finalize(). Throws LoadError naming the file, the problem and the fix.
/// "gen:NAME[:COUNT[:SEED]]" (e.g. gen:landscape:10000000) builds the procedural scene
/// in memory instead (scene/procedural.h), so large test scenes need no file.
Scene load_scene(const std::string& path);

/// Individual readers; each fills a Scene without finalizing it.
Scene load_ply(const std::string& path);
Scene load_obj(const std::string& path);
Scene load_gltf(const std::string& path);

/// Parses PLY from memory (used by load_ply and the fuzzer); `name` appears in errors.
Scene parse_ply(const char* data, size_t size, const std::string& name);

}  // namespace kdgrid
