// The hybrid's records: the tree's nodes, the leaves the walk steps over, the leaves' kd boxes
// and the leaves' triangle groups (accel/hybrid/hybrid.h holds them; docs/HYBRID.md explains them).
#pragma once

#include <cstdint>

#include "accel/triangle_wide.h"
#include "math/vec.h"

namespace kdgrid::hybrid {

/// Tree node, kept for the cell map's node entries, its construction and split walks
/// (for_each_split); leaves point into the leaf array.
struct Node {
  int32_t split;   ///< interior: the split boundary (cell index); leaf: leaf id
  uint32_t right;  ///< interior: index of the right child (left child = this + 1)
  uint32_t axis;   ///< 0..2 interior, 3 leaf
};

/// Leaf: an integer cell box [lo, hi), its first triangle group (TriGroup) and its triangle
/// count. 64 bytes.
/// The box is the one the walk steps over: the kd leaf's box, or for an empty leaf that
/// box widened over empty cells (widen.cpp).
struct alignas(64) Leaf {
  /// The step box in cells: whole numbers, held as doubles so that the walk's exit reads
  /// them with no conversion (7 per step; one cache line per leaf all the same). lo and hi
  /// each start a 32-byte half of the line, so that the walk reads each as four lanes (the
  /// fourth: first/count's bits after lo, `pad` after hi; see leaf_exit in walk.h).
  double lo[3];
  uint32_t first, count;
  double hi[3];
  double pad;
};

/// Leaf::count bit: `first` is the root of the leaf's kd subtree in the subtree node array (whose
/// leaves hold their first group and triangle count) and the low bits count the triangles the
/// leaf references.
constexpr uint32_t kSubtreeFlag = 0x80000000u;

/// A leaf's kd box (an empty leaf's before widening): the kd boxes tile the grid, so a cell
/// inside one names its leaf (the next-leaf cache's check, walk.h).
struct KdBox {
  /// x, y, z and a fourth lane that every cell passes (INT32_MIN, INT32_MAX; a walk's lane 3 is 0).
  alignas(16) int32_t lo[4];
  int32_t hi[4];
};

/// A leaf's triangles, kWideLanes of them by lane (the wide test reads each coordinate of a
/// corner as one vector), with the mesh's index of each. A leaf of n triangles owns
/// ceil(n / kWideLanes) consecutive groups, in its references' order; its last group repeats the
/// leaf's last triangle in the lanes left over. A triangle referenced by several leaves is
/// copied into each.
struct TriGroup {
  WideTriangles<kWideLanes> tri;
  uint32_t prim[kWideLanes];
};

}  // namespace kdgrid::hybrid
