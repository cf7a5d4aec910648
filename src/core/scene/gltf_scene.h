// The glTF loader's two halves: load_gltf (gltf_file.cpp) reads and checks the file through
// tinygltf, gltf_to_scene (gltf.cpp) turns the parsed model into a Scene. Included by those two
// files only.
#pragma once

#include <string>

#include "scene/scene.h"

namespace tinygltf {
class Model;
}

namespace kdgrid {

/// The default scene of `model` (parsed from the file `path`, which messages name) into
/// `scene`: its node tree flattened into one world-space mesh, its materials, textures
/// (decoded when decode_textures), lights and camera. Throws LoadError on broken content.
void gltf_to_scene(const tinygltf::Model& model, const std::string& path, bool decode_textures,
                   Scene& scene);

}  // namespace kdgrid
