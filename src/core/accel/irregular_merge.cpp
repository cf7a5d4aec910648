// The irregular grid's merging (step 4: aligned neighbours joined while the SAH cost does not
// grow), expansion (step 5: exit boxes grown over cells whose references are a subset) and final
// cell array: IrregularGrid::Builder's last steps (irregular_build.h; irregular.cpp has the first).
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <limits>
#include <vector>

#include "accel/irregular_build.h"
#include "util/cancel.h"

namespace kdgrid {

namespace {

/// Size of the union of two sorted reference lists.
uint32_t count_union(const uint32_t* p, uint32_t n, const uint32_t* q, uint32_t m) {
  uint32_t i = 0, j = 0, c = 0;
  while (i < n && j < m) {
    const uint32_t x = p[i], y = q[j];
    i += x <= y;
    j += y <= x;
    ++c;
  }
  return c + (n - i) + (m - j);
}

/// Writes the sorted union of two sorted lists to out.
void write_union(const uint32_t* p, uint32_t n, const uint32_t* q, uint32_t m, uint32_t* out) {
  uint32_t i = 0, j = 0;
  while (i < n && j < m) {
    const uint32_t x = p[i], y = q[j];
    *out++ = x < y ? x : y;
    i += x <= y;
    j += y <= x;
  }
  while (i < n) *out++ = p[i++];
  while (j < m) *out++ = q[j++];
}

}  // namespace

// Step 4: merging. The cost of a cell is its half surface area (world units) times
// (its number of references + kMergeTraversalCost); two aligned neighbours merge when the
// cost of the union (references = set union) is no larger than the sum of their costs.
double IrregularGrid::Builder::half_area(const int32_t lo[3], const int32_t hi[3]) const {
  const double ex = (hi[0] - lo[0]) * g.vs_[0], ey = (hi[1] - lo[1]) * g.vs_[1],
               ez = (hi[2] - lo[2]) * g.vs_[2];
  return ex * ey + ey * ez + ez * ex;
}

void IrregularGrid::Builder::remap_voxel_map(const std::vector<uint32_t>& new_id) {
  tbb::parallel_for(size_t(0), g.top_.size(), [&](size_t t) {
    if (g.top_[t].leaf) g.top_[t].base = new_id[g.top_[t].base];
  });
  tbb::parallel_for(size_t(0), g.sub_.size(), [&](size_t i) { g.sub_[i] = new_id[g.sub_[i]]; });
}

uint64_t IrregularGrid::Builder::merge_pass(int axis) {
  const size_t n = cells.size();
  const int b = (axis + 1) % 3, c = (axis + 2) % 3;
  require("merge pass", double(n) * 3 * sizeof(uint32_t));
  std::vector<uint32_t> next(n, kNone), prev(n, kNone), ucount(n, 0);
  std::atomic<uint64_t> evaluations{0};
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& rg) {
    check_cancel(params.cancel);
    uint64_t evals = 0;
    for (size_t i = rg.begin(); i < rg.end(); ++i) {
      const BCell& c1 = cells[i];
      if (c1.hi[axis] >= g.res_[axis]) continue;
      int32_t p[3] = {c1.lo[0], c1.lo[1], c1.lo[2]};
      p[axis] = c1.hi[axis];
      const uint32_t j = g.lookup(p);
      const BCell& c2 = cells[j];
      if (c2.lo[axis] != c1.hi[axis] || c2.lo[b] != c1.lo[b] || c2.hi[b] != c1.hi[b] ||
          c2.lo[c] != c1.lo[c] || c2.hi[c] != c1.hi[c])
        continue;
      int32_t ulo[3] = {c1.lo[0], c1.lo[1], c1.lo[2]}, uhi[3] = {c2.hi[0], c2.hi[1], c2.hi[2]};
      const double a1 = half_area(c1.lo, c1.hi), a2 = half_area(c2.lo, c2.hi),
                   au = half_area(ulo, uhi);
      const double apart =
          a1 * (c1.count + kMergeTraversalCost) + a2 * (c2.count + kMergeTraversalCost);
      // The union holds at least max(n1, n2) references: skip the count when even that loses.
      if (au * (std::max(c1.count, c2.count) + kMergeTraversalCost) > apart) continue;
      ++evals;
      const uint32_t nu = count_union(&refs[c1.begin], c1.count, &refs[c2.begin], c2.count);
      if (au * (nu + kMergeTraversalCost) <= apart) {
        next[i] = j;
        ucount[i] = nu;
      }
    }
    evaluations += evals;
  });
  merge_evaluations += evaluations;
  for (size_t i = 0; i < n; ++i)
    if (next[i] != kNone) prev[next[i]] = uint32_t(i);
  // Chains a->b->c->d along the axis merge pairwise (a+b, c+d), as in the paper, so every
  // cell takes part in at most one merge per pass and the result stays balanced.
  std::vector<uint32_t> partner(n, kNone);
  std::vector<uint8_t> kept(n, 1);
  for (size_t i = 0; i < n; ++i) {
    if (prev[i] != kNone || next[i] == kNone) continue;
    bool even = true;
    for (uint32_t k = uint32_t(i); k != kNone; k = next[k], even = !even) {
      if (even) {
        kept[k] = 1;
        partner[k] = next[k];
      } else {
        kept[k] = 0;
      }
    }
  }
  std::vector<uint32_t> new_id(n, kNone);
  uint32_t m = 0;
  for (size_t i = 0; i < n; ++i)
    if (kept[i]) new_id[i] = m++;
  for (size_t i = 0; i < n; ++i)
    if (partner[i] != kNone) new_id[partner[i]] = new_id[i];
  if (m == n) return 0;
  // New cells and references: offsets by a serial scan, unions written in parallel.
  // Chains, ids and the merged cells; the merged references are checked below.
  require("merge pass", double(n) * (6 * sizeof(uint32_t) + 1) + double(m) * sizeof(BCell));
  std::vector<BCell> new_cells(m);
  uint64_t total = 0;
  for (size_t i = 0; i < n; ++i) {
    if (!kept[i]) continue;
    BCell& nc = new_cells[new_id[i]];
    nc = cells[i];
    if (partner[i] != kNone)
      for (int a = 0; a < 3; ++a) nc.hi[a] = cells[partner[i]].hi[a];
    nc.count = partner[i] != kNone ? ucount[i] : cells[i].count;
    nc.begin = uint32_t(total);
    total += nc.count;
  }
  require("merge pass", double(n) * (6 * sizeof(uint32_t) + 1) + double(m) * sizeof(BCell) +
                            double(total) * sizeof(uint32_t));
  std::vector<uint32_t> new_refs(total);
  tbb::parallel_for(size_t(0), n, [&](size_t i) {
    if (!kept[i]) return;
    const BCell& c1 = cells[i];
    uint32_t* out = new_refs.data() + new_cells[new_id[i]].begin;
    if (partner[i] == kNone) {
      std::copy(refs.begin() + c1.begin, refs.begin() + c1.begin + c1.count, out);
    } else {
      const BCell& c2 = cells[partner[i]];
      write_union(&refs[c1.begin], c1.count, &refs[c2.begin], c2.count, out);
    }
  });
  remap_voxel_map(new_id);
  cells.swap(new_cells);
  refs.swap(new_refs);
  return n - m;
}

void IrregularGrid::Builder::merge() {
  for (int round = 0; round < kMergeMaxRounds; ++round) {
    const uint64_t before = cells.size();
    uint64_t removed = 0;
    for (int axis = 0; axis < 3; ++axis) {
      check_cancel(params.cancel);
      removed += merge_pass(axis);
    }
    ++merge_rounds;
    if (double(removed) < std::max(kMergeStopFraction * double(before), double(kMergeMinCells)))
      break;
  }
}

// Step 5: expansion. A face of a cell's exit box moves one layer of neighbouring cells
// outwards when every voxel of that layer belongs to cells whose references are a subset of
// this cell's (so a ray inside the grown box can only meet triangles already tested). The
// six faces take turns, one layer each, for kExpansionRounds rounds (the paper's fixed
// iteration count, which keeps the cost linear in the cells: without it an unmerged empty
// cell would sweep the whole empty space around it). A face that failed is not retried:
// growing other faces only adds voxels to its layer, so it cannot succeed later.
bool IrregularGrid::Builder::subset_of(const BCell& small, const BCell& big) const {
  if (small.count == 0) return true;
  if (small.count > big.count) return false;
  return std::includes(refs.begin() + big.begin, refs.begin() + big.begin + big.count,
                       refs.begin() + small.begin, refs.begin() + small.begin + small.count);
}

bool IrregularGrid::Builder::grow_face(const BCell& self, std::array<int32_t, 6>& box, int axis,
                                       bool positive) const {
  int32_t* lo = box.data();
  int32_t* hi = box.data() + 3;
  const int32_t layer = positive ? hi[axis] : lo[axis] - 1;
  if (layer < 0 || layer >= g.res_[axis]) return false;
  const int b = (axis + 1) % 3, c = (axis + 2) % 3;
  int32_t depth = std::numeric_limits<int32_t>::max();
  int32_t p[3];
  p[axis] = layer;
  // Walk the layer cell by cell: along b by each cell's extent; rows along c advance to
  // the nearest end of the cells met in the row, since the row looks the same until then.
  for (int32_t w = lo[c]; w < hi[c];) {
    int32_t row_end = hi[c];
    for (int32_t u = lo[b]; u < hi[b];) {
      p[b] = u;
      p[c] = w;
      const BCell& n = cells[g.lookup(p)];
      if (!subset_of(n, self)) return false;
      depth = std::min(depth, positive ? n.hi[axis] - layer : layer + 1 - n.lo[axis]);
      row_end = std::min(row_end, n.hi[c]);
      u = n.hi[b];
    }
    w = row_end;
  }
  if (positive)
    hi[axis] += depth;
  else
    lo[axis] -= depth;
  return true;
}

void IrregularGrid::Builder::expand() {
  const size_t n = cells.size();
  require("cell expansion", double(n) * sizeof(exit_boxes[0]));
  exit_boxes.resize(n);
  for (size_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) {
      exit_boxes[i][a] = cells[i].lo[a];
      exit_boxes[i][3 + a] = cells[i].hi[a];
    }
  if (!params.irregular_expand) return;
  std::atomic<uint64_t> grown{0};
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& rg) {
    check_cancel(params.cancel);
    uint64_t local = 0;
    for (size_t i = rg.begin(); i < rg.end(); ++i) {
      bool open[6] = {true, true, true, true, true, true};
      bool grew = false;
      for (int round = 0; round < kExpansionRounds; ++round) {
        bool any = false;
        for (int f = 0; f < 6; ++f) {
          if (!open[f]) continue;
          open[f] = grow_face(cells[i], exit_boxes[i], f >> 1, f & 1);
          any |= open[f];
        }
        if (!any) break;
        grew = true;
      }
      local += grew;
    }
    grown += local;
  });
  expanded_cells = grown;
}

void IrregularGrid::Builder::finish() {
  const size_t n = cells.size();
  require("final cell array", double(n) * (sizeof(IrregularGrid::Cell) + sizeof(g.own_boxes_[0])));
  g.cells_.resize(n);
  g.own_boxes_.resize(n);
  for (size_t i = 0; i < n; ++i) {
    IrregularGrid::Cell& c = g.cells_[i];
    for (int a = 0; a < 3; ++a) {
      c.lo[a] = exit_boxes[i][a];
      c.hi[a] = exit_boxes[i][3 + a];
      g.own_boxes_[i][a] = cells[i].lo[a];
      g.own_boxes_[i][3 + a] = cells[i].hi[a];
    }
    c.begin = cells[i].begin;
    c.end = cells[i].begin + cells[i].count;
  }
  g.refs_.swap(refs);
}

}  // namespace kdgrid
