// What a hybrid build at given parameters would make, before it runs: the auto rule's density
// floor and caps, HybridEstimate (GridKdHybrid::estimate, estimate.cpp) and the constants of its
// model of the build's bytes and seconds. The build refuses parameters whose estimate does not
// fit the memory budget or BuildParams::hybrid_max_build_seconds; the viewer shows it.
#pragma once

#include <cstdint>
#include <string>

#include "accel/hybrid/records.h"

namespace kdgrid {

/// Auto rule density floor: at least this many cells per triangle, so that scenes mixing huge
/// and tiny triangles (Sponza) still get a useful grid.
constexpr double kHybridAutoCellsPerTriangle = 16.0;
/// Auto rule cap on cells along one axis (per-node binning arrays, lookup depth).
constexpr int64_t kHybridAutoMaxAxisCells = 2048;
/// Auto rule cap on the total cell count with leaf subtrees: the subtrees resolve the geometry,
/// and a small grid keeps lookups in the caches and references few; a coarser cap saves memory
/// but costs rays of scenes like Sponza (docs/HYBRID.md, "The cell size"; docs/EXPERIMENTS.md).
constexpr double kHybridAutoMaxCells = double(uint64_t(1) << 16);
/// Auto rule cap with plain leaves (BuildParams::hybrid_subtree_min = 0), whose cells must stay
/// about a triangle wide: the per-cell binning and the dense matrix (2^24 cells: 64 MiB) bound it.
constexpr double kHybridAutoMaxCellsPlain = double(uint64_t(1) << 24);
/// Explicit cell sizes may give at most this many cells along one axis (int32 coordinates,
/// at most 12 brick levels).
constexpr int64_t kHybridMaxAxisCells = int64_t(1) << 24;

/// What a hybrid build at given parameters would make, from the mesh alone (O(triangles), no
/// allocation beyond one float per triangle): GridKdHybrid::estimate. The viewer shows it before a
/// build; GridKdHybrid::build refuses parameters whose estimate does not fit, with the estimate and
/// suggested_cell in the message.
struct HybridEstimate {
  double cell = 0;       ///< the cell size the build would use (the auto rule resolved)
  double auto_cell = 0;  ///< the auto rule's size for this mesh and these parameters
  std::string rule;      ///< how the cell size was chosen (BuildStats::extra "auto rule")
  double dims[3] = {1, 1, 1};
  double cells = 1;
  /// Peak bytes of the build, estimated: the cell matrix (dense: 4 bytes a cell; bricked:
  /// 256-byte bricks along the surface, about kHybridBricksPerArea x area / (4 cells)^2), the
  /// per-cell binning
  /// arrays, the empty-leaf table, and the tree (kHybridBytesPerTriangle a triangle).
  double bytes = 0;
  /// The built structure's bytes (BuildStats::bytes), estimated: bytes less what the build
  /// frees before it returns (the binning arrays, the empty-leaf table).
  double structure_bytes = 0;
  /// Build time in seconds on BuildParams::threads threads at the rates kHybridSecondsPer*: an
  /// order of magnitude, for the refusal and the viewer. It follows the cell size: the matrix,
  /// the binning and the empty-leaf table grow with the cells, the subtrees with the triangles
  /// a cell holds.
  double seconds = 0;
  uint64_t budget = 0;       ///< the memory budget it was checked against
  double seconds_limit = 0;  ///< BuildParams::hybrid_max_build_seconds (0 = none)
  bool fits = true;          ///< bytes within the budget and seconds within the limit
  /// When !fits: the smallest cell size (two significant digits, rounded up) whose estimate
  /// fits; 0 when even one cell does not.
  double suggested_cell = 0;
  /// "a 88x87x68 grid (5.21e+05 cells), about 15 MiB and under a second to build".
  std::string describe() const;
  /// Why the size does not fit, with the estimate and the fix (the build's ParamError text).
  std::string refusal() const;
};

/// Estimate model constants (see HybridEstimate), fitted to the build phases that `kdgrid
/// render --threads 1 --stats-json` reports, rounded towards the slow side, and the bytes a
/// triangle of the finest cells the suite's scenes were built at (docs/EXPERIMENTS.md, "The
/// build estimate", has the figures).
constexpr double kHybridBricksPerArea = 4.5;  ///< bricks per (4-cell)^2 of triangle area
/// Tree, leaves, subtrees and triangle groups, a triangle.
constexpr double kHybridBytesPerTriangle = hybrid::kSharedCorners ? 150 : 300;
constexpr double kHybridSecondsPerBrick = 2.5e-6;     ///< matrix construction, one thread
constexpr double kHybridSecondsPerTriangle = 3.5e-6;  ///< tree and subtrees, one thread
constexpr double kHybridSecondsPerBinOp = 1e-9;       ///< one per-cell binning entry
/// One entry of the empty-leaf table (hybrid_expand_empty): a cell of the grid, one thread.
constexpr double kHybridSecondsPerExpandEntry = 1.5e-8;
/// The leaf subtrees' extra work, a fraction of kHybridSecondsPerTriangle per triangle per
/// level, where cells coarser than the triangles leave many triangles a leaf (one cell: the
/// whole scene in one subtree).
constexpr double kHybridSubtreeLevelShare = 0.04;

}  // namespace kdgrid
