// The hybrid's cell -> leaf map: every cell of the grid names the leaf covering it, so a ray
// that leaves a leaf finds the next one by looking up the cell past the exit face. Two forms:
// the paper's dense array (DenseCellMap, BuildParams::hybrid_dense_matrix) and, by default, a
// top array over blocks of cells refined into bricks along the geometry (BrickedCellMap), whose
// memory follows the content rather than the volume (docs/HYBRID.md, "The cell map").
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "accel/hybrid/records.h"
#include "util/cancel.h"

namespace kdgrid::hybrid {

/// The paper's map: one uint32 leaf id per cell, x fastest; 4 bytes per cell of the grid.
class DenseCellMap {
 public:
  /// Bytes the map takes for a grid of dims cells.
  static uint64_t bytes_for(const int32_t dims[3]) {
    return uint64_t(dims[0]) * uint64_t(dims[1]) * uint64_t(dims[2]) * 4;
  }
  /// Fills every cell with the id of the leaf whose box holds it (the leaves' boxes, before
  /// the empty ones are widened, tile the grid).
  void build(const int32_t dims[3], const std::vector<Leaf>& leaves);
  void clear() { cells_.clear(); }
  [[gnu::always_inline]] uint32_t lookup(int32_t x, int32_t y, int32_t z) const {
    return cells_[uint64_t(x) + uint64_t(nx_) * (uint64_t(y) + uint64_t(ny_) * uint64_t(z))];
  }
  /// uint32 entries held.
  uint64_t entries() const { return cells_.size(); }

 private:
  std::vector<uint32_t> cells_;
  int32_t nx_ = 1, ny_ = 1;
};

/// The default map: a dense top array over blocks of 4^k cells whose entries name a leaf (the
/// whole block is that leaf), a 4x4x4 brick of entries one level finer, or a kd node whose
/// short descent resolves a region crossed by a few split planes only. A lookup is at most k
/// dependent loads, plus the descent.
class BrickedCellMap {
 public:
  /// Entries: kLeafTag | leaf id, kNodeTag | kd node index, or a brick index.
  static constexpr uint32_t kLeafTag = 0x80000000u;
  static constexpr uint32_t kNodeTag = 0x40000000u;
  static constexpr uint32_t kTagMask = kLeafTag | kNodeTag;
  /// A region crossed by split planes whose kd subtree, restricted to the region, reaches at
  /// most kMaxNodeEntryLeaves leaves within kMaxNodeEntryDepth levels keeps a kd node entry,
  /// resolved at lookup by a descent of at most that many steps, instead of refining into a
  /// brick. This keeps memory proportional to content: a lone split plane across a huge empty
  /// stadium would otherwise refine every brick it crosses (its area, not content).
  static constexpr int kMaxNodeEntryLeaves = 8;
  static constexpr int kMaxNodeEntryDepth = 16;
  /// The top array's blocks are 4^k cells, k >= 1 the smallest giving at most this many
  /// blocks (1 MiB), so a lookup skips the upper levels (a scan's lookups read one brick level
  /// instead of two; docs/EXPERIMENTS.md, "The cell map").
  static constexpr int kMaxTopEntries = 262144;
  static constexpr int kBrickLog = 2;  ///< 4 cells per brick axis
  static constexpr int kBrickSide = 1 << kBrickLog;
  static constexpr int kBrickEntries = kBrickSide * kBrickSide * kBrickSide;

  /// Sizes the top array for a grid of dims cells (the map stays empty until build()).
  void set_grid(const int32_t dims[3]);
  /// Builds the map of the tree `nodes` (depth-first, Node::split of a leaf its id). Throws
  /// ParamError when the bricks exceed `budget` bytes; polls `cancel` once per top entry.
  void build(const std::vector<Node>& nodes, uint64_t budget, const CancelToken* cancel);
  /// Bytes the map of `nodes` takes (computed, not allocated; exact).
  uint64_t bytes(const std::vector<Node>& nodes) const;
  void clear() {
    bricks_.clear();
    top_.clear();
  }
  /// uint32 entries held (top array and bricks).
  uint64_t entries() const { return bricks_.size() + top_.size(); }
  /// "bricked 4x4x4: top 22x22x17 blocks of 4^3 cells, 5408 bricks" (BuildStats::extra).
  std::string describe() const;

  [[gnu::always_inline]] uint32_t lookup(int32_t x, int32_t y, int32_t z, const Node* nodes) const {
    // Strides instead of nested products: the two multiplies run in parallel.
    uint32_t e = top_[uint64_t(uint32_t(x) >> top_shift_) +
                      top_stride_[0] * uint64_t(uint32_t(y) >> top_shift_) +
                      top_stride_[1] * uint64_t(uint32_t(z) >> top_shift_)];
    int shift = top_shift_ - kBrickLog;
    while (!(e & kTagMask)) {
      const uint32_t local = ((uint32_t(x) >> shift) & (kBrickSide - 1)) |
                             (((uint32_t(y) >> shift) & (kBrickSide - 1)) << kBrickLog) |
                             (((uint32_t(z) >> shift) & (kBrickSide - 1)) << (2 * kBrickLog));
      e = bricks_[uint64_t(e) * kBrickEntries + local];
      shift -= kBrickLog;
    }
    if (e & kLeafTag) return e & ~kTagMask;
    // A sparse region: finish with a short kd descent from the stored node.
    const int32_t c[3] = {x, y, z};
    const Node* n = nodes + (e & ~kTagMask);
    while (n->axis != 3) n = c[n->axis] < n->split ? n + 1 : nodes + n->right;
    return uint32_t(n->split);
  }

 private:
  int top_shift_ = kBrickLog;  ///< log2 of the top blocks' side in cells
  int32_t top_dims_[3] = {1, 1, 1};
  uint64_t top_stride_[2] = {1, 1};  ///< top array strides of y and z
  int32_t dims_[3] = {1, 1, 1};      ///< the grid's cells per axis
  std::vector<uint32_t> bricks_;     ///< kBrickEntries per brick
  std::vector<uint32_t> top_;        ///< entries of the top blocks
};

/// The map a build selected (BuildParams::hybrid_dense_matrix): one predicted branch per lookup.
class CellMap {
 public:
  /// Empties the map and selects its form.
  void reset(bool dense) {
    dense_ = dense;
    dense_map_.clear();
    bricked_.clear();
  }
  /// Sizes the map for a grid of dims cells (both forms' layout: matrix_bytes reports either).
  void set_grid(const int32_t dims[3]) { bricked_.set_grid(dims); }
  /// Builds the selected map from the tree (`leaves` with their kd boxes, before widening).
  void build(const int32_t dims[3], const std::vector<Node>& nodes, const std::vector<Leaf>& leaves,
             uint64_t budget, const CancelToken* cancel) {
    if (dense_)
      dense_map_.build(dims, leaves);
    else
      bricked_.build(nodes, budget, cancel);
  }
  /// The leaf of cell (x, y, z), which must lie inside the grid; `nodes` is the tree the map
  /// was built from (the bricked map's node entries).
  [[gnu::always_inline]] uint32_t lookup(int32_t x, int32_t y, int32_t z, const Node* nodes) const {
    if (dense_) return dense_map_.lookup(x, y, z);
    return bricked_.lookup(x, y, z, nodes);
  }
  bool dense() const { return dense_; }
  const BrickedCellMap& bricked() const { return bricked_; }
  /// uint32 entries held by both forms (one of them is empty).
  uint64_t entries() const { return dense_map_.entries() + bricked_.entries(); }

 private:
  bool dense_ = false;
  DenseCellMap dense_map_;
  BrickedCellMap bricked_;
};

}  // namespace kdgrid::hybrid
