// Scene loading: dispatch on the file extension to the glTF, PLY and OBJ readers.
#pragma once

#include <cstdint>
#include <string>

#include "scene/scene.h"

namespace kdgrid {

/// How a scene is loaded.
struct LoadOptions {
  /// Bytes the loader may hold (0: default_memory_budget_bytes(), util/memory.h). The OBJ
  /// reader estimates its peak from the file before parsing and refuses a file above it.
  uint64_t memory_budget = 0;
  /// false: textures are checked from their headers (size, format) but their pixels are not
  /// decoded; each Texture keeps its size and has no pixels (it samples as white). For
  /// commands that report on a scene without rendering it (kdgrid info).
  bool decode_textures = true;
  /// != 1: the scene's coordinates are multiplied by it before finalize() (Scene::scale_by,
  /// `--scale`), so the scale limits of docs/LIMITS.md apply to the scaled scene.
  double scale = 1.0;
};

/// Loads .gltf/.glb (tinygltf), .ply (own reader) or .obj (tinyobjloader), then
/// Scene::finalize(). Throws LoadError naming the file, the problem and the fix.
/// "gen:NAME[:COUNT[:SEED]]" (e.g. gen:landscape:10000000) builds the procedural scene
/// in memory instead (scene/procedural.h), so large test scenes need no file. An allocation
/// that fails while loading is reported as a LoadError naming the file and the memory.
Scene load_scene(const std::string& path, const LoadOptions& options = {});
/// load_scene with the default options but `scale` (LoadOptions::scale).
inline Scene load_scene(const std::string& path, double scale) {
  LoadOptions options;
  options.scale = scale;
  return load_scene(path, options);
}

/// Individual readers; each fills a Scene without finalizing it.
Scene load_ply(const std::string& path);
Scene load_obj(const std::string& path, const LoadOptions& options = {});
Scene load_gltf(const std::string& path, const LoadOptions& options = {});

/// Parses PLY from memory (used by load_ply and the fuzzer); `name` appears in errors.
Scene parse_ply(const char* data, size_t size, const std::string& name);

}  // namespace kdgrid
