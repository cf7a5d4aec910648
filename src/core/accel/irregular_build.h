// The irregular grid's build (IrregularGrid::Builder): its scratch state and its steps, which
// irregular.cpp (the driver, the top level and the subdivision) and irregular_merge.cpp (merging,
// expansion and the final cell array) define. Included by those two files only.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "accel/guards.h"
#include "accel/irregular.h"
#include "scene/scene.h"

namespace kdgrid {

/// The build, step by step, with its scratch state. A nested class so it can fill the
/// grid's private members directly.
struct IrregularGrid::Builder {
  static constexpr uint32_t kNone = 0xFFFFFFFFu;

  /// A cell during the build: its own box on the lattice [lo, hi) and its sorted references.
  struct BCell {
    int32_t lo[3], hi[3];
    uint32_t begin, count;
  };

  IrregularGrid& g;
  const Mesh& mesh;
  const BuildParams& params;
  const uint64_t budget;
  std::vector<uint32_t> valid;  ///< triangles with finite corners and valid indices
  std::vector<BCell> cells;
  std::vector<uint32_t> refs;
  std::vector<std::array<int32_t, 6>> exit_boxes;
  double top_vs[3] = {1, 1, 1};  ///< top cell size
  uint64_t cells_before_merge = 0, cells_after_merge = 0, expanded_cells = 0;
  uint64_t merge_rounds = 0, merge_evaluations = 0;
  double peak = 0;  ///< the most require() saw held and asked for

  Builder(IrregularGrid& grid, const Mesh& m, const BuildParams& p)
      : g(grid), mesh(m), params(p), budget(effective_memory_budget(p)) {}

  /// Bytes the build holds now in its long-lived arrays (capacity, not size).
  double held_bytes() const {
    return double(valid.capacity() * sizeof(uint32_t) + cells.capacity() * sizeof(BCell) +
                  refs.capacity() * sizeof(uint32_t) +
                  exit_boxes.capacity() * sizeof(exit_boxes[0]) +
                  g.top_.capacity() * sizeof(TopEntry) + g.sub_.capacity() * sizeof(uint32_t));
  }

  /// Throws ParamError when `extra` more bytes on top of held_bytes() exceed the budget:
  /// checked before each phase allocates, so the build stops at the budget on scenes whose
  /// triangles cross far more cells than the estimate before building assumed.
  void require(const char* phase, double extra);

  Vec3d corner(uint32_t tri, int k) const { return Vec3d(mesh.positions[mesh.triangles[tri][k]]); }

  /// Conservative padding of boxes in the overlap test: a small fraction of the cell plus
  /// float rounding of the coordinates, so triangles that touch a cell face within float
  /// precision are referenced on both sides (the traversal and triangle tests run in float).
  double pad(int a, double cell_size) const {
    const double mag = std::max(std::fabs(g.lo_[a]), std::fabs(g.hi_[a]));
    return cell_size * 1e-5 + mag * 0x1p-20;
  }

  /// The steps in order (irregular.cpp).
  void run();

  // ---- steps 1 and 2 (irregular.cpp) ----
  void collect_valid_triangles();
  void set_up_box_and_top_resolution();
  /// Range of cells (of size cs, origin o, count res) overlapped by [mn, mx] on one axis.
  static void cell_range(double mn, double mx, double o, double cs, int32_t res, int32_t& lo,
                         int32_t& hi);
  /// Calls fn(cell) for each cell of a uniform grid (origin o, cell size cs, resolution res)
  /// that triangle tri overlaps, by bounding box then exact overlap.
  template <class Fn>
  void for_each_overlapped_cell(uint32_t tri, const double o[3], const double cs[3],
                                const int32_t res[3], const double padding[3], Fn&& fn) const;
  void assign_top_references(std::vector<uint32_t>& count, std::vector<uint32_t>& begin,
                             std::vector<uint32_t>& top_refs);
  /// Each top cell's sub-level (log2 of its sub-resolution) per axis.
  using SubLogs = std::vector<std::array<uint8_t, 3>>;
  /// A non-empty top cell's sub-cells: references per sub-cell, and the references sorted by
  /// sub-cell, then triangle.
  struct SubOut {
    std::vector<uint32_t> count;
    std::vector<uint32_t> refs;
  };
  void subdivide(const std::vector<uint32_t>& count, const std::vector<uint32_t>& begin,
                 const std::vector<uint32_t>& top_refs);
  SubLogs sub_levels(const std::vector<uint32_t>& count, const std::vector<uint32_t>& begin,
                     const std::vector<uint32_t>& top_refs) const;
  void set_lattice(const SubLogs& logs, size_t top_refs);
  std::vector<SubOut> sub_references(const std::vector<uint32_t>& count,
                                     const std::vector<uint32_t>& begin,
                                     const std::vector<uint32_t>& top_refs,
                                     const SubLogs& logs) const;
  void assemble_cells(const std::vector<uint32_t>& count, const SubLogs& logs,
                      std::vector<SubOut>& outs);

  // ---- steps 4 and 5 (irregular_merge.cpp) ----
  double half_area(const int32_t lo[3], const int32_t hi[3]) const;
  /// Rewrites every cell id in the voxel map through new_id.
  void remap_voxel_map(const std::vector<uint32_t>& new_id);
  /// One merge pass along `axis`; returns the number of cells removed.
  uint64_t merge_pass(int axis);
  void merge();
  bool subset_of(const BCell& small, const BCell& big) const;
  /// Tries to move face (axis, dir) of box outwards by one layer of cells.
  bool grow_face(const BCell& self, std::array<int32_t, 6>& box, int axis, bool positive) const;
  void expand();
  void finish();
};

}  // namespace kdgrid
