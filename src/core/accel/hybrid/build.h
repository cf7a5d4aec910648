// Internals shared by the hybrid's build files (build.cpp, tree.cpp, widen.cpp, estimate.cpp,
// cell_map.cpp); not part of the structure's interface, which is hybrid.h.
#pragma once

#include <cstdint>
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
std::string widen_empty_leaves(std::vector<Leaf>& leaves, const int32_t dims[3], uint64_t budget,
                               const CancelToken* cancel);

}  // namespace kdgrid::hybrid
