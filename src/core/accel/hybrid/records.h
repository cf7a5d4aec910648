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

/// Leaf: an integer cell box [lo, hi), where its triangle groups start (a float offset into
/// GridKdHybrid::groups_, "Triangle groups" below) and its triangle count. 64 bytes.
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

/// Triangle groups. A leaf's triangles are stored as consecutive groups of kWideLanes lanes, the
/// last one holding what is left (n lanes): a group holds, for each corner k and axis a, the
/// lanes' coordinates one after the other (lane i's at float (3k + a) stride + i), then the
/// lanes' mesh indices (as uint32, at 9 stride + i). With AVX-512 masked loads read a group of
/// n lanes, so it is stored with stride n and rounded up to whole 64-byte lines (no padding
/// lanes); without them every group has stride kWideLanes and its last lanes repeat the leaf's
/// last triangle. A triangle referenced by several leaves is copied into each.
#if defined(__AVX512F__)
constexpr bool kCompactGroups = kWideLanes == 16;
#else
constexpr bool kCompactGroups = false;
#endif
/// Floats a lane takes: nine corner coordinates and the mesh's index.
constexpr uint32_t kGroupLaneFloats = 10;
/// The stride of a group of n lanes.
constexpr uint32_t group_stride(uint32_t n) {
  return kCompactGroups ? n : uint32_t(kWideLanes);
}
/// The floats a group of n lanes occupies (a full group: kGroupLaneFloats * kWideLanes).
constexpr uint32_t group_floats(uint32_t n) {
  return kCompactGroups ? (kGroupLaneFloats * n + 15) / 16 * 16
                        : kGroupLaneFloats * uint32_t(kWideLanes);
}
static_assert(group_floats(kWideLanes) == kGroupLaneFloats * kWideLanes);
/// 64 bytes of group storage (the array is 64-byte aligned).
struct alignas(64) GroupLine {
  float f[16];
};

}  // namespace kdgrid::hybrid
