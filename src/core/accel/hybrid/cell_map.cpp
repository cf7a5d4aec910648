#include "accel/hybrid/cell_map.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>

#include "accel/hybrid/build.h"
#include "util/error.h"
#include "util/format.h"

namespace kdgrid::hybrid {

void DenseCellMap::build(const int32_t dims[3], const std::vector<Leaf>& leaves) {
  nx_ = dims[0];
  ny_ = dims[1];
  const uint64_t nx = uint64_t(dims[0]), ny = uint64_t(dims[1]), nz = uint64_t(dims[2]);
  cells_.assign(nx * ny * nz, 0);
  tbb::parallel_for(size_t(0), leaves.size(), [&](size_t li) {
    const Leaf& l = leaves[li];
    for (int32_t z = int32_t(l.lo[2]); z < int32_t(l.hi[2]); ++z)
      for (int32_t y = int32_t(l.lo[1]); y < int32_t(l.hi[1]); ++y) {
        uint32_t* row = cells_.data() + (uint64_t(y) + ny * uint64_t(z)) * nx;
        std::fill(row + int32_t(l.lo[0]), row + int32_t(l.hi[0]), uint32_t(li));
      }
  });
}

namespace {

using B = BrickedCellMap;

struct BrickBudget {
  std::atomic<uint64_t> bytes{0};
  uint64_t limit = ~uint64_t(0);
};

/// Builds (or only counts) the bricks of a tree's map over a grid of dims cells.
class BrickBuilder {
 public:
  BrickBuilder(const std::vector<Node>& nodes, const int32_t dims[3], BrickBudget& budget)
      : nodes_(nodes), budget_(budget) {
    for (int a = 0; a < 3; ++a) dims_[a] = dims[a];
  }

  /// The entry for the region of 4^level cells at (x0, y0, z0), appending bricks to `out`
  /// (nullptr: only count their bytes in the budget). Brick indices are local to `out`.
  uint32_t entry(int32_t x0, int32_t y0, int32_t z0, int level, uint32_t node,
                 std::vector<uint32_t>* out) const {
    static_assert(B::kMaxNodeEntryLeaves >= 2 && B::kMaxNodeEntryDepth >= 1);
    const int64_t side = int64_t(1) << (B::kBrickLog * level);
    const int32_t r0[3] = {x0, y0, z0};
    int32_t r1[3];
    for (int a = 0; a < 3; ++a) {
      if (r0[a] >= dims_[a]) return B::kLeafTag;  // padding beyond the grid: never looked up
      r1[a] = int32_t(std::min<int64_t>(int64_t(r0[a]) + side, dims_[a]));
    }
    while (nodes_[node].axis != 3) {
      const Node& nd = nodes_[node];
      if (r1[nd.axis] <= nd.split)
        node = node + 1;
      else if (r0[nd.axis] >= nd.split)
        node = nd.right;
      else
        break;
    }
    if (nodes_[node].axis == 3) return B::kLeafTag | uint32_t(nodes_[node].split);
    // Crossed by a few splits only, in a region coarser than one brick of cells: keep the node,
    // resolved by a short descent at lookup. Regions of 4^3 cells always refine, so lookups
    // near the geometry end in a leaf entry.
    if (level > 1 &&
        count_region_leaves(node, r0, r1, B::kMaxNodeEntryLeaves + 1, 0) <= B::kMaxNodeEntryLeaves)
      return B::kNodeTag | node;
    // Crossed by many: refine into a brick (level >= 1 here, a single cell is never split).
    const uint64_t bytes = budget_.bytes.fetch_add(B::kBrickEntries * sizeof(uint32_t)) +
                           B::kBrickEntries * sizeof(uint32_t);
    if (out && bytes > budget_.limit)
      throw ParamError("hybrid: the bricked cell matrix of the " + std::to_string(dims_[0]) + "x" +
                       std::to_string(dims_[1]) + "x" + std::to_string(dims_[2]) +
                       " grid exceeds the memory budget of " +
                       format_bytes_iec(double(budget_.limit)) +
                       ": use a larger cell size or 'auto'");
    const int32_t sub = int32_t(side >> B::kBrickLog);
    uint64_t b = 0;
    if (out) {
      b = out->size() / B::kBrickEntries;
      out->resize(out->size() + B::kBrickEntries);
    }
    for (int k = 0; k < B::kBrickSide; ++k)
      for (int j = 0; j < B::kBrickSide; ++j)
        for (int i = 0; i < B::kBrickSide; ++i) {
          const uint32_t e = entry(x0 + i * sub, y0 + j * sub, z0 + k * sub, level - 1, node, out);
          if (out)
            (*out)[b * B::kBrickEntries + uint64_t(i + B::kBrickSide * (j + B::kBrickSide * k))] =
                e;
        }
    return uint32_t(b);
  }

 private:
  /// Leaves of the subtree at `node` that intersect the region [r0, r1), counting up to `limit`;
  /// a path longer than kMaxNodeEntryDepth counts as `limit` (too deep for a node entry).
  int count_region_leaves(uint32_t node, const int32_t r0[3], const int32_t r1[3], int limit,
                          int depth) const {
    if (depth > B::kMaxNodeEntryDepth) return limit;
    const Node& n = nodes_[node];
    if (n.axis == 3) return 1;
    int count = 0;
    if (r0[n.axis] < n.split) count += count_region_leaves(node + 1, r0, r1, limit, depth + 1);
    if (count < limit && r1[n.axis] > n.split)
      count += count_region_leaves(n.right, r0, r1, limit - count, depth + 1);
    return std::min(count, limit);
  }

  const std::vector<Node>& nodes_;
  int32_t dims_[3];
  BrickBudget& budget_;
};

}  // namespace

void BrickedCellMap::set_grid(const int32_t dims[3]) {
  for (int a = 0; a < 3; ++a) dims_[a] = dims[a];
  // Top array over blocks of 4^k cells: the smallest k >= 1 giving at most kMaxTopEntries.
  int top_level = 1;
  auto top_count = [&](int k) {
    double c = 1;
    for (int a = 0; a < 3; ++a)
      c *= std::ceil(double(dims[a]) / double(int64_t(1) << (kBrickLog * k)));
    return c;
  };
  while (top_count(top_level) > double(kMaxTopEntries)) ++top_level;
  top_shift_ = kBrickLog * top_level;
  for (int a = 0; a < 3; ++a)
    top_dims_[a] = int32_t((int64_t(dims[a]) + (int64_t(1) << top_shift_) - 1) >> top_shift_);
  top_stride_[0] = uint64_t(top_dims_[0]);
  top_stride_[1] = uint64_t(top_dims_[0]) * uint64_t(top_dims_[1]);
}

void BrickedCellMap::build(const std::vector<Node>& nodes, uint64_t budget,
                           const CancelToken* cancel) {
  // Each top entry's bricks are built independently (in parallel) into their own arrays,
  // then concatenated in top-entry order with brick indices relocated: deterministic.
  const uint64_t ntop = uint64_t(top_dims_[0]) * uint64_t(top_dims_[1]) * uint64_t(top_dims_[2]);
  top_.assign(ntop, kLeafTag);
  BrickBudget bb;
  bb.limit = budget > ntop * 4 ? budget - ntop * 4 : 0;
  const BrickBuilder builder(nodes, dims_, bb);
  std::vector<std::vector<uint32_t>> parts(ntop);
  const int top_level = top_shift_ / kBrickLog;
  tbb::parallel_for(uint64_t(0), ntop, [&](uint64_t i) {
    check_cancel(cancel);  // one top entry's bricks: a small part of the matrix
    const int32_t tx = int32_t(i % uint64_t(top_dims_[0]));
    const int32_t ty = int32_t((i / uint64_t(top_dims_[0])) % uint64_t(top_dims_[1]));
    const int32_t tz = int32_t(i / (uint64_t(top_dims_[0]) * uint64_t(top_dims_[1])));
    top_[i] = builder.entry(tx << top_shift_, ty << top_shift_, tz << top_shift_, top_level, 0,
                            &parts[i]);
  });
  uint64_t total = 0;
  std::vector<uint64_t> first(ntop);
  for (uint64_t i = 0; i < ntop; ++i) {
    first[i] = total / kBrickEntries;
    total += parts[i].size();
  }
  if (total / kBrickEntries >= kNodeTag)
    throw ParamError(
        "hybrid: the bricked cell matrix needs more than 2^30 bricks: use a larger cell size");
  bricks_.resize(total);
  tbb::parallel_for(uint64_t(0), ntop, [&](uint64_t i) {
    const uint32_t off = uint32_t(first[i]);
    uint32_t* dst = bricks_.data() + uint64_t(off) * kBrickEntries;
    for (uint32_t e : parts[i]) *dst++ = (e & kTagMask) ? e : e + off;
    if (!(top_[i] & kTagMask)) top_[i] += off;
    std::vector<uint32_t>().swap(parts[i]);
  });
}

uint64_t BrickedCellMap::bytes(const std::vector<Node>& nodes) const {
  if (nodes.empty()) return 0;
  const uint64_t ntop = uint64_t(top_dims_[0]) * uint64_t(top_dims_[1]) * uint64_t(top_dims_[2]);
  BrickBudget bb;
  const BrickBuilder builder(nodes, dims_, bb);
  for (uint64_t i = 0; i < ntop; ++i) {
    const int32_t tx = int32_t(i % uint64_t(top_dims_[0]));
    const int32_t ty = int32_t((i / uint64_t(top_dims_[0])) % uint64_t(top_dims_[1]));
    const int32_t tz = int32_t(i / (uint64_t(top_dims_[0]) * uint64_t(top_dims_[1])));
    builder.entry(tx << top_shift_, ty << top_shift_, tz << top_shift_, top_shift_ / kBrickLog, 0,
                  nullptr);
  }
  return bb.bytes.load() + ntop * sizeof(uint32_t);
}

std::string BrickedCellMap::describe() const {
  return "bricked 4x4x4: top " + std::to_string(top_dims_[0]) + "x" + std::to_string(top_dims_[1]) +
         "x" + std::to_string(top_dims_[2]) + " blocks of " + std::to_string(1 << top_shift_) +
         "^3 cells, " + std::to_string(bricks_.size() / kBrickEntries) + " bricks";
}

}  // namespace kdgrid::hybrid
