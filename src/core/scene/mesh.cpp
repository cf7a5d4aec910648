#include "scene/mesh.h"

#include <cmath>

#include "util/error.h"

namespace kdgrid {

Box3 Mesh::bounds() const {
  Box3 b;
  for (const auto& t : triangles)
    for (uint32_t v : t) b.grow(positions[v]);
  return b;
}

void Mesh::append(const Mesh& other, uint32_t mat_offset) {
  const uint32_t base = static_cast<uint32_t>(positions.size());
  const size_t old_tris = triangles.size();
  const bool had_normals = !normals.empty() || positions.empty();
  const bool had_uvs = !uvs.empty() || positions.empty();
  positions.insert(positions.end(), other.positions.begin(), other.positions.end());
  // Keep normals/uvs aligned with positions: fill gaps with defaults when only one side has them.
  if (!other.normals.empty() || !normals.empty()) {
    if (!had_normals) normals.resize(base, Vec3(0, 0, 0));
    if (other.normals.empty())
      normals.resize(positions.size(), Vec3(0, 0, 0));
    else
      normals.insert(normals.end(), other.normals.begin(), other.normals.end());
  }
  if (!other.uvs.empty() || !uvs.empty()) {
    if (!had_uvs) uvs.resize(base, {0.f, 0.f});
    if (other.uvs.empty())
      uvs.resize(positions.size(), {0.f, 0.f});
    else
      uvs.insert(uvs.end(), other.uvs.begin(), other.uvs.end());
  }
  for (const auto& t : other.triangles)
    triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
  if (!other.material_ids.empty() || mat_offset != 0 || !material_ids.empty()) {
    material_ids.resize(old_tris, 0);
    for (size_t i = 0; i < other.triangles.size(); ++i)
      material_ids.push_back(other.material_of(i) + mat_offset);
  }
}

void Mesh::validate(const std::string& source) const {
  if (triangles.empty())
    throw LoadError(source +
                    ": the scene has no triangles (nothing to render); check that the "
                    "file holds faces and not only points or lines");
  for (size_t i = 0; i < positions.size(); ++i) {
    const Vec3& p = positions[i];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      throw LoadError(source + ": vertex " + std::to_string(i) +
                      " has a NaN or infinite coordinate; fix or remove that vertex");
  }
  const size_t nv = positions.size();
  for (size_t i = 0; i < triangles.size(); ++i)
    for (uint32_t v : triangles[i])
      if (v >= nv)
        throw LoadError(source + ": triangle " + std::to_string(i) + " references vertex " +
                        std::to_string(v) + " but the file has " + std::to_string(nv) +
                        " vertices");
  if (!normals.empty() && normals.size() != nv)
    throw LoadError(source + ": normal count differs from vertex count");
  if (!uvs.empty() && uvs.size() != nv)
    throw LoadError(source + ": texture coordinate count differs from vertex count");
}

size_t Mesh::memory_bytes() const {
  return positions.capacity() * sizeof(Vec3) + triangles.capacity() * sizeof(triangles[0]) +
         normals.capacity() * sizeof(Vec3) + uvs.capacity() * sizeof(uvs[0]) +
         material_ids.capacity() * sizeof(uint32_t);
}

}  // namespace kdgrid
