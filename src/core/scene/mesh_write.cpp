// PLY and OBJ writers and the extension dispatch of scene/write.h.
#include <algorithm>
#include <bit>
#include <cstdio>
#include <filesystem>
#include <memory>

#include "scene/write.h"
#include "util/atomic_file.h"
#include "util/error.h"

namespace kdgrid {

void write_ply(const Mesh& mesh, const std::string& path) {
  static_assert(sizeof(float) == 4 && sizeof(int32_t) == 4);
  // The binary body is written with the host byte order, which the header declares as
  // little endian: refuse to write a lie on a big-endian machine.
  if constexpr (std::endian::native != std::endian::little)
    throw Error(path + ": the PLY writer supports little-endian hosts only");
  AtomicFile out(path);
  const bool normals = !mesh.normals.empty();
  out.write("ply\nformat binary_little_endian 1.0\ncomment written by kdgrid\n");
  out.write("element vertex " + std::to_string(mesh.num_vertices()) + "\n");
  out.write("property float x\nproperty float y\nproperty float z\n");
  if (normals) out.write("property float nx\nproperty float ny\nproperty float nz\n");
  out.write("element face " + std::to_string(mesh.num_triangles()) + "\n");
  out.write("property list uchar int vertex_indices\nend_header\n");
  std::vector<char> body;
  body.reserve(mesh.num_vertices() * (normals ? 24 : 12) + mesh.num_triangles() * 13);
  auto put = [&](const void* p, size_t n) {
    const char* c = static_cast<const char*>(p);
    body.insert(body.end(), c, c + n);
  };
  for (size_t i = 0; i < mesh.num_vertices(); ++i) {
    put(&mesh.positions[i], 12);
    if (normals) put(&mesh.normals[i], 12);
  }
  for (const auto& t : mesh.triangles) {
    const uint8_t three = 3;
    put(&three, 1);
    for (uint32_t v : t) {
      const int32_t iv = int32_t(v);
      put(&iv, 4);
    }
  }
  out.write(body.data(), body.size());
  out.commit();
}

void write_obj(const Mesh& mesh, const std::string& path) {
  AtomicFile out(path);
  const bool normals = !mesh.normals.empty();
  out.write("# written by kdgrid: " + std::to_string(mesh.num_vertices()) + " vertices, " +
            std::to_string(mesh.num_triangles()) + " triangles\n");
  char line[128];
  // %.9g round-trips every float exactly.
  for (const Vec3& p : mesh.positions) {
    std::snprintf(line, sizeof line, "v %.9g %.9g %.9g\n", p.x, p.y, p.z);
    out.write(line);
  }
  if (normals)
    for (const Vec3& n : mesh.normals) {
      std::snprintf(line, sizeof line, "vn %.9g %.9g %.9g\n", n.x, n.y, n.z);
      out.write(line);
    }
  for (const auto& t : mesh.triangles) {
    if (normals)
      std::snprintf(line, sizeof line, "f %u//%u %u//%u %u//%u\n", t[0] + 1, t[0] + 1, t[1] + 1,
                    t[1] + 1, t[2] + 1, t[2] + 1);
    else
      std::snprintf(line, sizeof line, "f %u %u %u\n", t[0] + 1, t[1] + 1, t[2] + 1);
    out.write(line);
  }
  out.commit();
}

void write_scene(const Scene& scene, const std::string& path) {
  const std::string ext = lower_extension(path);
  if (ext == ".gltf" || ext == ".glb")
    write_gltf(scene, path);
  else if (ext == ".ply")
    write_ply(scene.mesh, path);
  else if (ext == ".obj")
    write_obj(scene.mesh, path);
  else
    throw ParamError(
        path + ": unsupported output format '" + ext +
        "'; kdgrid gen writes .gltf or .glb (with materials, camera, lights), .ply or .obj");
}

}  // namespace kdgrid
