// Internals shared by the hybrid's build files (build.cpp, tree.cpp, widen.cpp, estimate.cpp,
// cell_map.cpp); not part of the structure's interface, which is hybrid.h.
#pragma once

#include <array>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "accel/hybrid/records.h"
#include "accel/params.h"
#include "scene/mesh.h"
#include "util/cancel.h"
#include "util/format.h"

namespace kdgrid::hybrid {

/// A triangle reference during the build: its inclusive integer cell range in the node.
struct Ref {
  uint32_t prim;
  int32_t lo[3], hi[3];
};

/// The distinct corners of a shared-corner group (records.h, "Triangle groups"), compared by
/// their bits, in the order the lanes first name them.
struct CornerSet {
  uint32_t bits[kMaxGroupCorners + 3][3];
  uint32_t key[kMaxGroupCorners + 3];  ///< a hash of bits, compared first
  uint32_t size = 0;

  /// A corner's bits and their hash.
  struct Corner {
    uint32_t b[3], h;
    explicit Corner(const Vec3& v) {
      std::memcpy(b, &v, sizeof b);
      h = b[0] * 0x9e3779b1u ^ b[1] * 0x85ebca77u ^ b[2] * 0xc2b2ae3du;
    }
    bool operator==(const Corner& o) const {
      return h == o.h && b[0] == o.b[0] && b[1] == o.b[1] && b[2] == o.b[2];
    }
  };
  /// The index of corner c in the set, or size where the set does not hold it.
  uint32_t find(const Corner& c) const {
    uint32_t i = 0;
    while (i < size &&
           (key[i] != c.h || bits[i][0] != c.b[0] || bits[i][1] != c.b[1] || bits[i][2] != c.b[2]))
      ++i;
    return i;
  }

  /// The corners of a triangle that the set does not hold (each counted once).
  uint32_t fresh(const std::array<Vec3, 3>& c) const {
    const Corner k[3] = {Corner(c[0]), Corner(c[1]), Corner(c[2])};
    uint32_t count = 0;
    for (int a = 0; a < 3; ++a) {
      bool seen = find(k[a]) < size;
      for (int j = 0; j < a && !seen; ++j) seen = k[j] == k[a];
      count += !seen;
    }
    return count;
  }

  /// Adds the corners of a triangle and sets their indices in the set, if the set then holds
  /// at most kMaxGroupCorners corners; else leaves it as it was and returns false.
  bool add(const std::array<Vec3, 3>& c, uint8_t index[3]) {
    const uint32_t before = size;
    for (int k = 0; k < 3; ++k) {
      const Corner v(c[k]);
      const uint32_t i = find(v);
      if (i == size) {
        key[size] = v.h;
        std::memcpy(bits[size++], v.b, sizeof v.b);
      }
      index[k] = uint8_t(i);
    }
    if (size <= kMaxGroupCorners) return true;
    size = before;
    return false;
  }
};

/// Cells per axis of a grid of cell size `cell` over a box of extent `ext`: at least 1, as doubles.
void dims_for(const double ext[3], double cell, double out[3]);
/// The scene box's low corner and extent, over the triangles' vertices (a point at 0 without
/// triangles).
void scene_box(const Mesh& mesh, double origin[3], double ext[3]);
/// The auto rule (hybrid.h; docs/HYBRID.md, "The cell size"); `rule` describes each step taken.
double auto_cell_size(const Mesh& mesh, const BuildParams& params, const double ext[3],
                      uint64_t budget, std::string& rule);
/// The cell size a build uses: params.cell_size (at most the scene's extent), or the auto rule;
/// `rule` says which (BuildStats::extra "auto rule").
double choose_cell_size(const Mesh& mesh, const BuildParams& params, const double ext[3],
                        uint64_t budget, std::string& rule);

/// Widens every empty leaf's box over the empty cells around it (docs/HYBRID.md, "Widened
/// empty leaves"), in a grid of dims cells; returns the BuildStats text. Skipped when its
/// table of occupied cells exceeds `budget` bytes or GridKdHybrid::kMaxExpandEntries entries.
/// Upper bound of the bytes a build at cell size `cell` over grid dims `d` from `origin` holds at
/// once (tree.cpp): a triangle is referenced by disjoint leaves, each covering at least one cell
/// of its cell range, so the top tree holds at most the sum of the triangles' cell counts; the
/// leaf subtrees, the groups, the matrix and the empty-leaf table follow from that, the depth
/// limits and the cell count (the object itself is not included).
double worst_case_bytes(const Mesh& mesh, const double origin[3], double cell, const double d[3],
                        const BuildParams& params, int threads);

std::string widen_empty_leaves(std::vector<Leaf>& leaves, const int32_t dims[3], uint64_t budget,
                               const CancelToken* cancel);

}  // namespace kdgrid::hybrid
