// PLY and OBJ writers and the extension dispatch of scene/write.h.
#include <algorithm>
#include <bit>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>

#include "scene/write.h"
#include "util/error.h"

namespace kdgrid {

namespace {

std::ofstream open_for_writing(const std::string& path, bool binary) {
  std::ofstream out(path, binary ? std::ios::binary : std::ios::out);
  if (!out)
    throw Error(path +
                ": cannot open for writing; check that the directory exists and is writable");
  return out;
}

void finish(std::ofstream& out, const std::string& path) {
  out.flush();
  if (!out) throw Error(path + ": writing failed (disk full?)");
}

}  // namespace

void write_ply(const Mesh& mesh, const std::string& path) {
  static_assert(sizeof(float) == 4 && sizeof(int32_t) == 4);
  // The binary body is written with the host byte order, which the header declares as
  // little endian: refuse to write a lie on a big-endian machine.
  if constexpr (std::endian::native != std::endian::little)
    throw Error(path + ": the PLY writer supports little-endian hosts only");
  auto out = open_for_writing(path, true);
  const bool normals = !mesh.normals.empty();
  out << "ply\nformat binary_little_endian 1.0\ncomment written by kdgrid\n";
  out << "element vertex " << mesh.num_vertices() << "\n";
  out << "property float x\nproperty float y\nproperty float z\n";
  if (normals) out << "property float nx\nproperty float ny\nproperty float nz\n";
  out << "element face " << mesh.num_triangles() << "\n";
  out << "property list uchar int vertex_indices\nend_header\n";
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
  out.write(body.data(), std::streamsize(body.size()));
  finish(out, path);
}

void write_obj(const Mesh& mesh, const std::string& path) {
  auto out = open_for_writing(path, false);
  const bool normals = !mesh.normals.empty();
  out << "# written by kdgrid: " << mesh.num_vertices() << " vertices, " << mesh.num_triangles()
      << " triangles\n";
  char line[128];
  // %.9g round-trips every float exactly.
  for (const Vec3& p : mesh.positions) {
    std::snprintf(line, sizeof line, "v %.9g %.9g %.9g\n", p.x, p.y, p.z);
    out << line;
  }
  if (normals)
    for (const Vec3& n : mesh.normals) {
      std::snprintf(line, sizeof line, "vn %.9g %.9g %.9g\n", n.x, n.y, n.z);
      out << line;
    }
  for (const auto& t : mesh.triangles) {
    if (normals)
      std::snprintf(line, sizeof line, "f %u//%u %u//%u %u//%u\n", t[0] + 1, t[0] + 1, t[1] + 1,
                    t[1] + 1, t[2] + 1, t[2] + 1);
    else
      std::snprintf(line, sizeof line, "f %u %u %u\n", t[0] + 1, t[1] + 1, t[2] + 1);
    out << line;
  }
  finish(out, path);
}

void write_scene(const Scene& scene, const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  if (ext == ".gltf")
    write_gltf(scene, path);
  else if (ext == ".ply")
    write_ply(scene.mesh, path);
  else if (ext == ".obj")
    write_obj(scene.mesh, path);
  else
    throw ParamError(path + ": unsupported output format '" + ext +
                     "'; kdgrid gen writes .gltf (with materials, camera, lights), .ply or .obj");
}

}  // namespace kdgrid
