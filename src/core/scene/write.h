// Scene writers: what `kdgrid gen` produces. Triangle order is preserved by every writer, so
// hit indices (docs/RAYSETS.md) agree between the generated file and the scene it came from.
#pragma once

#include <string>

#include "scene/scene.h"

namespace kdgrid {

/// Self-contained glTF 2.0 (.gltf with the buffer embedded as a data URI): mesh (positions,
/// normals and uvs when present), materials (baseColor, metallic, roughness, emissive with
/// KHR_materials_emissive_strength above 1, KHR_materials_transmission, KHR_materials_ior),
/// the camera and KHR_lights_punctual lights. Consecutive triangles with the same material
/// become one primitive, in mesh order. Textures are not written. A path ending in .glb gets
/// the binary container (GLB) instead. Throws Error naming the path.
void write_gltf(const Scene& scene, const std::string& path);

/// Binary little-endian PLY: vertex x y z (and nx ny nz when the mesh has normals), face
/// vertex_indices as uchar count + int indices. Geometry only.
void write_ply(const Mesh& mesh, const std::string& path);

/// Wavefront OBJ: v, vn (when present) and f lines. Geometry only.
void write_obj(const Mesh& mesh, const std::string& path);

/// Dispatches on the extension (.gltf, .glb, .ply, .obj); ParamError listing them otherwise.
/// Every writer goes through AtomicFile (util/atomic_file.h): the file is replaced whole or
/// not at all.
void write_scene(const Scene& scene, const std::string& path);

}  // namespace kdgrid
