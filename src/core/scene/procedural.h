// Procedural scenes: test and benchmark geometry built in code (`kdgrid gen NAME`).
// Each generator is deterministic for its parameters; random ones use their own seeded
// generator (splitmix64), so the same seed gives the same file on every platform.
//
//   cornell            Cornell-style box 2 x 2 x 2 (x in [-1,1], y in [0,2], z in [-1,1], open
//                      at z = +1): red left wall, green right wall, white floor, ceiling and
//                      back; a square emissive ceiling panel with a point light just below it;
//                      a mirror sphere (metallic 1, roughness 0) at the back left and a glass
//                      sphere (transmission 1, ior 1.5) front right; camera looking in from +z.
//                      level = sphere subdivision (default 3: 1280 triangles per sphere).
//   teapot-in-stadium  A dense closed torus (count triangles, default 20000, ~2.7 units wide)
//                      at the origin inside a huge box (12 triangles, 3000 units wide, ~1100x
//                      larger): the classic case where uniform grids waste their cells.
//   thin-triangles     count (default 10000) long thin triangles (length 0.5..2, width
//                      1e-4..1e-3) with random centres in [-1,1]^3 and random directions; seed.
//   coplanar-quads     count (default 2000) axis-aligned quads lying exactly in four shared
//                      planes (z = 0, z = 3, x = 0, y = 1.5); half are unit quads on the
//                      integer lattice (corners on integer coordinates), half random
//                      overlapping rectangles in the same planes; seed.
//   interior           a 20 x 5 x 14 room placed off the origin and turned 0.3 rad about +y:
//                      count floor tiles (default 560) on an exactly coincident slab split
//                      along the other diagonal, a rug 4e-6 above the floor, walls facing in
//                      with coincident plaster layers split differently, two windows, four
//                      columns and a table whose bottoms lie in the floor's plane, a light
//                      outside the windows and a camera inside. Coincident and near-coincident
//                      surfaces, as architecture exports have them.
//   duplicates         count (default 2000) random base triangles, each emitted twice with the
//                      same vertex indices, and every fourth once more shifted by a tiny amount
//                      (alternately 1 ULP per coordinate and 1e-6 along the normal); seed.
//   soup               count (default 10000) random triangles (corners within 0.1 of a
//                      random centre in [-1,1]^3); seed.
//   sphere             closed icosphere of radius 1, level subdivisions (default 4: 20*4^level
//                      triangles), with smooth normals.
//   torus              closed torus, major radius 1, minor radius 0.35, about count triangles
//                      (default 5000), with smooth normals.
//   landscape          exactly count triangles (default 1M; 10M is the big-scene test of
//                      scripts/big-scene.sh): a 2000 x 2000 fBm height-field terrain (heights
//                      about -40..260, a ridged range towards +z) with ~35% of the triangles in
//                      clusters of icospheres and tori sitting on it (one in ten floating
//                      30..150 units up), a fence strip that makes the count exact, a sun and an
//                      overview camera. Dense clusters, smooth slopes and empty sky: a test of
//                      how each structure copes with scale, not a flat sheet; seed.
//
// Generators fill mesh, materials, and where sensible lights and a camera; they do not call
// Scene::finalize() (do that before rendering).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "scene/scene.h"

namespace kdgrid {

struct ProceduralParams {
  /// Triangle/quad count of generators that take one; 0 = that generator's default.
  int count = 0;
  /// Seed of the random generators (same seed, same scene).
  uint64_t seed = 1;
  /// Subdivision level of generators that take one (cornell, sphere); -1 = default.
  int level = -1;
};

struct ProceduralInfo {
  std::string name;
  std::string description;  ///< one line, shown by `kdgrid gen --help`
};

/// All generator names with a one-line description, in a stable order.
std::vector<ProceduralInfo> procedural_generators();

/// Builds the named scene. Throws ParamError for an unknown name (listing the valid ones)
/// or parameters out of range (count < 0 or too large, level out of 0..8).
Scene generate_scene(const std::string& name, const ProceduralParams& params = {});

// ---- building blocks (also used by tests) -----------------------------------------------

/// Closed icosphere: 20 * 4^level triangles, outward winding, smooth normals.
Mesh make_icosphere(int level, const Vec3& center = Vec3(0.0f), float radius = 1.0f);
/// Closed torus in the xz plane: 2 * major * minor triangles, outward winding, smooth normals.
Mesh make_torus(int major_segments, int minor_segments, float major_radius = 1.0f,
                float minor_radius = 0.35f, const Vec3& center = Vec3(0.0f));
/// Axis-aligned box of 12 triangles with per-face normals; outward unless `inward`.
/// rotation_y (radians) turns it about its centre's vertical axis.
Mesh make_box(const Vec3& center, const Vec3& half_extent, float rotation_y = 0.0f,
              bool inward = false);

}  // namespace kdgrid
