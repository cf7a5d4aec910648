// Widened empty leaves (BuildParams::hybrid_expand_empty): each empty leaf's step box grown
// over the empty cells around it, so that a ray crosses empty space in fewer steps. The
// leaves' kd boxes, the cell map and the triangle tests are unchanged; only Leaf::lo/hi of
// empty leaves move.
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <string>
#include <vector>

#include "accel/hybrid/build.h"
#include "accel/hybrid/hybrid.h"

namespace kdgrid::hybrid {

std::string widen_empty_leaves(std::vector<Leaf>& leaves, const int32_t dims[3], uint64_t budget,
                               const CancelToken* cancel) {
  constexpr uint64_t kMaxExpandEntries = GridKdHybrid::kMaxExpandEntries;
  const int64_t nx = dims[0], ny = dims[1], nz = dims[2];
  const uint64_t entries = uint64_t(nx + 1) * uint64_t(ny + 1) * uint64_t(nz + 1);
  if (entries > kMaxExpandEntries || entries * sizeof(uint32_t) > budget)
    return "skipped: its table of occupied cells would take " +
           format_bytes_iec(double(entries) * 4.0) +
           (entries > kMaxExpandEntries
                ? " (more than " + std::to_string(kMaxExpandEntries) + " cells)"
                : ", above the memory left in the budget") +
           "; steps use the kd leaf boxes";
  // sat(x, y, z) = the number of occupied cells (cells of leaves with triangles) in
  // [0, x) x [0, y) x [0, z): any box's count in 8 loads (a summed-volume table).
  const int64_t sx = nx + 1, sxy = (nx + 1) * (ny + 1);
  std::vector<uint32_t> sat(entries, 0);
  auto at = [&](int64_t x, int64_t y, int64_t z) -> uint32_t& {
    return sat[uint64_t(x + sx * y + sxy * z)];
  };
  tbb::parallel_for(size_t(0), leaves.size(), [&](size_t i) {
    const Leaf& l = leaves[i];
    if (l.count == 0) return;  // leaves partition the grid: the writes are disjoint
    for (int32_t z = int32_t(l.lo[2]); z < int32_t(l.hi[2]); ++z)
      for (int32_t y = int32_t(l.lo[1]); y < int32_t(l.hi[1]); ++y)
        for (int32_t x = int32_t(l.lo[0]); x < int32_t(l.hi[0]); ++x) at(x + 1, y + 1, z + 1) = 1;
  });
  tbb::parallel_for(int64_t(1), nz + 1, [&](int64_t z) {
    check_cancel(cancel);  // one slice of the table
    for (int64_t y = 1; y <= ny; ++y)
      for (int64_t x = 1; x <= nx; ++x) at(x, y, z) += at(x - 1, y, z);
    for (int64_t y = 1; y <= ny; ++y)
      for (int64_t x = 1; x <= nx; ++x) at(x, y, z) += at(x, y - 1, z);
  });
  tbb::parallel_for(int64_t(1), ny + 1, [&](int64_t y) {
    for (int64_t z = 1; z <= nz; ++z)
      for (int64_t x = 1; x <= nx; ++x) at(x, y, z) += at(x, y, z - 1);
  });
  auto occupied = [&](const int32_t lo[3], const int32_t hi[3]) {
    const int64_t x0 = lo[0], y0 = lo[1], z0 = lo[2], x1 = hi[0], y1 = hi[1], z1 = hi[2];
    return int64_t(at(x1, y1, z1)) - at(x0, y1, z1) - at(x1, y0, z1) - at(x1, y1, z0) +
               at(x0, y0, z1) + at(x0, y1, z0) + at(x1, y0, z0) - at(x0, y0, z0) !=
           0;
  };
  // Each empty leaf's box grows face by face, in rounds, by the most (at most its current
  // extent, so it stays roughly cubic) that keeps it free of occupied cells; binary search
  // per face. Leaves with triangles keep their kd boxes. Read-only table: deterministic.
  std::atomic<uint64_t> widened{0}, cells_before{0}, cells_after{0};
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, leaves.size()), [&](const tbb::blocked_range<size_t>& r) {
        check_cancel(cancel);
        uint64_t w = 0, before = 0, after = 0;
        for (size_t i = r.begin(); i != r.end(); ++i) {
          Leaf& l = leaves[i];
          if (l.count != 0) continue;
          int32_t lo[3], hi[3];
          for (int a = 0; a < 3; ++a) {
            lo[a] = int32_t(l.lo[a]);
            hi[a] = int32_t(l.hi[a]);
          }
          for (bool grew = true; grew;) {
            grew = false;
            for (int a = 0; a < 3; ++a)
              for (int up = 0; up < 2; ++up) {
                const int32_t room = up ? dims[a] - hi[a] : lo[a];
                int32_t best = 0, k0 = 1, k1 = std::min(room, hi[a] - lo[a]);
                while (k0 <= k1) {  // the largest k in [1, k1] whose slab is free
                  const int32_t k = k0 + (k1 - k0) / 2;
                  int32_t slo[3] = {lo[0], lo[1], lo[2]}, shi[3] = {hi[0], hi[1], hi[2]};
                  if (up) {
                    slo[a] = hi[a];
                    shi[a] = hi[a] + k;
                  } else {
                    shi[a] = lo[a];
                    slo[a] = lo[a] - k;
                  }
                  if (occupied(slo, shi)) {
                    k1 = k - 1;
                  } else {
                    best = k;
                    k0 = k + 1;
                  }
                }
                if (best) {
                  grew = true;
                  (up ? hi[a] : lo[a]) += up ? best : -best;
                }
              }
          }
          const uint64_t v0 = uint64_t(l.hi[0] - l.lo[0]) * uint64_t(l.hi[1] - l.lo[1]) *
                              uint64_t(l.hi[2] - l.lo[2]);
          const uint64_t v1 =
              uint64_t(hi[0] - lo[0]) * uint64_t(hi[1] - lo[1]) * uint64_t(hi[2] - lo[2]);
          w += v1 > v0;
          before += v0;
          after += v1;
          for (int a = 0; a < 3; ++a) {
            l.lo[a] = lo[a];
            l.hi[a] = hi[a];
          }
        }
        widened += w;
        cells_before += before;
        cells_after += after;
      });
  return std::to_string(widened.load()) +
         " empty leaves widened over empty cells (step boxes hold " +
         format_double("%.2f", double(cells_after.load()) /
                                   double(std::max<uint64_t>(1, cells_before.load()))) +
         "x the cells of the kd leaf boxes; table " + format_bytes_iec(double(entries) * 4.0) +
         ", freed)";
}

}  // namespace kdgrid::hybrid
