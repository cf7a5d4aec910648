// A triangle mesh: the only geometry kdgrid's accelerators see.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "math/vec.h"

namespace kdgrid {

/// Indexed triangle mesh in world space. Triangle i is the i-th face of the source file
/// after fan triangulation (docs/RAYSETS.md), so hit indices are comparable across tools.
struct Mesh {
  std::vector<Vec3> positions;
  std::vector<std::array<uint32_t, 3>> triangles;
  /// Per-vertex shading normals; empty, or the same size as positions.
  std::vector<Vec3> normals;
  /// Per-vertex texture coordinates (u, v); empty, or the same size as positions.
  std::vector<std::array<float, 2>> uvs;
  /// Per-triangle material index into Scene::materials; empty means material 0.
  std::vector<uint32_t> material_ids;

  size_t num_triangles() const { return triangles.size(); }
  size_t num_vertices() const { return positions.size(); }

  /// The three corners of triangle i.
  std::array<Vec3, 3> corners(size_t i) const {
    const auto& t = triangles[i];
    return {positions[t[0]], positions[t[1]], positions[t[2]]};
  }
  Box3 triangle_bounds(size_t i) const {
    Box3 b;
    for (const Vec3& p : corners(i)) b.grow(p);
    return b;
  }
  Box3 bounds() const;
  /// Unnormalised geometric normal of triangle i (cross(v1-v0, v2-v0)).
  Vec3 geometric_normal(size_t i) const {
    const auto c = corners(i);
    return cross(c[1] - c[0], c[2] - c[0]);
  }
  uint32_t material_of(size_t i) const { return material_ids.empty() ? 0 : material_ids[i]; }

  /// Appends another mesh, offsetting its indices; material ids are offset by mat_offset.
  void append(const Mesh& other, uint32_t mat_offset = 0);

  /// Throws LoadError naming `source` if any index is out of range or any position is
  /// NaN/inf, or if the mesh has no triangles.
  void validate(const std::string& source) const;

  /// Bytes held by the mesh arrays (what a structure that references the mesh reuses).
  size_t memory_bytes() const;
};

}  // namespace kdgrid
