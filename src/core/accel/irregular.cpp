// The irregular grid's build driver (IrregularGrid::build), its top level (step 1: the grid
// box, the top resolution, the top cells' references) and its subdivision (step 2: the
// sub-levels, the lattice, the sub-cells' references, the cells and voxel map); irregular.h
// describes the structure, irregular_merge.cpp the merging and expansion.
#include "accel/irregular.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/task_arena.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <functional>
#include <limits>
#include <string>

#include "accel/guards.h"
#include "accel/irregular_build.h"
#include "scene/scene.h"
#include "util/cancel.h"
#include "util/error.h"

namespace kdgrid {

namespace {

/// Separating-axis test of a triangle against a box given by centre and half size, in double
/// (Akenine-Möller's 13 axes: the 3 box axes, the triangle normal and the 9 edge/axis cross
/// products). Touching counts as overlapping, so references are conservative.
bool triangle_overlaps_box(const Vec3d& a, const Vec3d& b, const Vec3d& c, const double ctr[3],
                           const double half[3]) {
  const Vec3d cc(ctr[0], ctr[1], ctr[2]);
  const Vec3d v[3] = {a - cc, b - cc, c - cc};
  for (int k = 0; k < 3; ++k) {
    const double mn = std::min({v[0][k], v[1][k], v[2][k]});
    const double mx = std::max({v[0][k], v[1][k], v[2][k]});
    if (mn > half[k] || mx < -half[k]) return false;
  }
  auto separated = [&](const Vec3d& axis) {
    const double p0 = dot(axis, v[0]), p1 = dot(axis, v[1]), p2 = dot(axis, v[2]);
    const double r =
        half[0] * std::fabs(axis.x) + half[1] * std::fabs(axis.y) + half[2] * std::fabs(axis.z);
    return std::min({p0, p1, p2}) > r || std::max({p0, p1, p2}) < -r;
  };
  const Vec3d e[3] = {v[1] - v[0], v[2] - v[1], v[0] - v[2]};
  if (separated(cross(e[0], e[1]))) return false;
  for (const Vec3d& ed : e) {
    if (separated(Vec3d(0.0, -ed.z, ed.y))) return false;  // x x edge
    if (separated(Vec3d(ed.z, 0.0, -ed.x))) return false;  // y x edge
    if (separated(Vec3d(-ed.y, ed.x, 0.0))) return false;  // z x edge
  }
  return true;
}

std::string format_bytes(double b) {
  return format_bytes_iec(b);
}

std::string format_res(const int32_t r[3]) {
  return std::to_string(r[0]) + "x" + std::to_string(r[1]) + "x" + std::to_string(r[2]);
}

}  // namespace

void IrregularGrid::Builder::require(const char* phase, double extra) {
  const double need = held_bytes() + extra;
  peak = std::max(peak, need);
  if (need > double(budget))
    throw ParamError(std::string("irregular: the ") + phase + " needs " + format_bytes_iec(extra) +
                     " more on top of the " + format_bytes_iec(held_bytes()) + " held (" +
                     std::to_string(cells.size()) + " cells, " + std::to_string(refs.size()) +
                     " references over " + std::to_string(valid.size()) +
                     " triangles), above the memory budget of " + format_bytes_iec(double(budget)) +
                     "; lower --irregular-sub-density or --irregular-top-density, or raise "
                     "--memory-budget-mb (0 = half of the memory available) if the machine has "
                     "the memory");
}

void IrregularGrid::Builder::run() {
  collect_valid_triangles();
  if (valid.empty()) return;
  set_up_box_and_top_resolution();
  std::vector<uint32_t> top_count, top_begin, top_refs;
  assign_top_references(top_count, top_begin, top_refs);
  subdivide(top_count, top_begin, top_refs);
  check_cancel(params.cancel);
  cells_before_merge = cells.size();
  if (params.irregular_merge) merge();
  cells_after_merge = cells.size();
  check_cancel(params.cancel);
  expand();
  check_cancel(params.cancel);
  finish();
}

void IrregularGrid::Builder::collect_valid_triangles() {
  const size_t nv = mesh.positions.size();
  for (uint32_t i = 0; i < uint32_t(mesh.triangles.size()); ++i) {
    const auto& t = mesh.triangles[i];
    if (t[0] >= nv || t[1] >= nv || t[2] >= nv) continue;
    if (!is_finite(mesh.positions[t[0]]) || !is_finite(mesh.positions[t[1]]) ||
        !is_finite(mesh.positions[t[2]]))
      continue;
    valid.push_back(i);
  }
}

// Step 1: the grid box and the top-level resolution.
void IrregularGrid::Builder::set_up_box_and_top_resolution() {
  double blo[3] = {kInf, kInf, kInf}, bhi[3] = {-kInf, -kInf, -kInf};
  for (uint32_t t : valid)
    for (int k = 0; k < 3; ++k) {
      const Vec3 p = mesh.positions[mesh.triangles[t][k]];
      for (int a = 0; a < 3; ++a) {
        blo[a] = std::min(blo[a], double(p[a]));
        bhi[a] = std::max(bhi[a], double(p[a]));
      }
    }
  const double max_ext = std::max({bhi[0] - blo[0], bhi[1] - blo[1], bhi[2] - blo[2]});
  // Pad so that geometry on the box faces is strictly inside, then give flat axes a minimum
  // thickness (1e-3 of the largest extent) so the density rule has a volume to work with.
  for (int a = 0; a < 3; ++a) {
    const double mag = std::max(std::fabs(blo[a]), std::fabs(bhi[a]));
    const double p = max_ext * 1e-5 + mag * 0x1p-20 + 1e-30;
    g.lo_[a] = blo[a] - p;
    g.hi_[a] = bhi[a] + p;
  }
  double ext[3], big = 0;
  for (int a = 0; a < 3; ++a) big = std::max(big, g.hi_[a] - g.lo_[a]);
  for (int a = 0; a < 3; ++a) {
    if (g.hi_[a] - g.lo_[a] < 1e-3 * big) {
      const double c = 0.5 * (g.lo_[a] + g.hi_[a]);
      g.lo_[a] = c - 0.5e-3 * big;
      g.hi_[a] = c + 0.5e-3 * big;
    }
    ext[a] = g.hi_[a] - g.lo_[a];
  }
  // Cleary's / Wald et al.'s rule: cells = density * N with cubic cells shaped by the box:
  // resolution_a = round(extent_a * cbrt(density * N / volume)), at least 1.
  const double n = double(valid.size());
  const double k = std::cbrt(double(params.irregular_top_density) * n / (ext[0] * ext[1] * ext[2]));
  double r[3], top_cells = 1;
  for (int a = 0; a < 3; ++a) {
    r[a] = std::max(1.0, std::round(ext[a] * k));
    top_cells *= r[a];
  }
  // Work guard (accel/guards.h): halve the resolution while the references pile up.
  for (;;) {
    const int32_t res[3] = {int32_t(std::min(r[0], 1e9)), int32_t(std::min(r[1], 1e9)),
                            int32_t(std::min(r[2], 1e9))};
    if (res[0] == 1 && res[1] == 1 && res[2] == 1) break;
    const double cs[3] = {ext[0] / r[0], ext[1] / r[1], ext[2] / r[2]};
    const double estimated = tbb::parallel_reduce(
        tbb::blocked_range<size_t>(0, valid.size(), 4096), 0.0,
        [&](const tbb::blocked_range<size_t>& rg, double sum) {
          check_cancel(params.cancel);
          return sum +
                 estimate_grid_references(mesh, valid.data(), rg.begin(), rg.end(), g.lo_, cs, res);
        },
        std::plus<double>());
    if (!grid_references_pile_up(estimated, n, top_cells)) break;
    top_cells = 1;
    for (int a = 0; a < 3; ++a) {
      r[a] = std::max(1.0, std::floor(r[a] / 2));
      top_cells *= r[a];
    }
  }
  // Every top cell costs at least its voxel-map entry and one build cell.
  const double need = top_cells * double(sizeof(TopEntry) + sizeof(BCell) + sizeof(Cell));
  if (need > double(budget) || std::max({r[0], r[1], r[2]}) > double(1 << 24))
    throw ParamError("irregular_top_density = " + std::to_string(params.irregular_top_density) +
                     " asks for " + std::to_string(uint64_t(std::min(top_cells, 1e19))) +
                     " top-level cells (about " + format_bytes(need) +
                     "), beyond the memory budget of " + format_bytes(double(budget)) +
                     " or the lattice limit of 2^24 cells per axis: lower --irregular-top-density "
                     "(default 0.12), or raise --memory-budget-mb (0 = half of physical "
                     "memory) if the machine has the memory");
  for (int a = 0; a < 3; ++a) {
    g.top_res_[a] = int32_t(r[a]);
    top_vs[a] = ext[a] / r[a];
  }
}

void IrregularGrid::Builder::cell_range(double mn, double mx, double o, double cs, int32_t res,
                                        int32_t& lo, int32_t& hi) {
  const double flo = std::floor((mn - o) / cs), fhi = std::floor((mx - o) / cs);
  lo = int32_t(std::clamp(flo, 0.0, double(res - 1)));
  hi = int32_t(std::clamp(fhi, 0.0, double(res - 1)));
}

template <class Fn>
void IrregularGrid::Builder::for_each_overlapped_cell(uint32_t tri, const double o[3],
                                                      const double cs[3], const int32_t res[3],
                                                      const double padding[3], Fn&& fn) const {
  const Vec3d a = corner(tri, 0), b = corner(tri, 1), c = corner(tri, 2);
  int32_t lo[3], hi[3];
  for (int k = 0; k < 3; ++k)
    cell_range(std::min({a[k], b[k], c[k]}) - padding[k], std::max({a[k], b[k], c[k]}) + padding[k],
               o[k], cs[k], res[k], lo[k], hi[k]);
  const bool single = lo[0] == hi[0] && lo[1] == hi[1] && lo[2] == hi[2];
  double half[3], ctr[3];
  for (int k = 0; k < 3; ++k) half[k] = 0.5 * cs[k] + padding[k];
  for (int32_t z = lo[2]; z <= hi[2]; ++z)
    for (int32_t y = lo[1]; y <= hi[1]; ++y)
      for (int32_t x = lo[0]; x <= hi[0]; ++x) {
        if (!single) {
          ctr[0] = o[0] + (x + 0.5) * cs[0];
          ctr[1] = o[1] + (y + 0.5) * cs[1];
          ctr[2] = o[2] + (z + 0.5) * cs[2];
          if (!triangle_overlaps_box(a, b, c, ctr, half)) continue;
        }
        fn(x, y, z);
      }
}

// Step 1b: references of the top cells, sorted by cell then triangle.
void IrregularGrid::Builder::assign_top_references(std::vector<uint32_t>& count,
                                                   std::vector<uint32_t>& begin,
                                                   std::vector<uint32_t>& top_refs) {
  const int32_t* r = g.top_res_;
  const size_t num_top = size_t(r[0]) * r[1] * r[2];
  double padding[3];
  for (int a = 0; a < 3; ++a) padding[a] = pad(a, top_vs[a]);
  // Parallel over chunks of triangles; each chunk lists (cell, triangle) pairs in triangle
  // order, so a stable counting sort by cell keeps every cell's list sorted by triangle.
  constexpr size_t kChunk = 2048;
  const size_t num_chunks = (valid.size() + kChunk - 1) / kChunk;
  std::vector<std::vector<std::pair<uint32_t, uint32_t>>> pairs(num_chunks);
  // The (cell, triangle) pairs are the first allocation that grows with the references, whose
  // number is unknown until they are listed: stop listing once they pass the budget.
  std::atomic<uint64_t> listed{0};
  std::atomic<bool> over{false};
  tbb::parallel_for(size_t(0), num_chunks, [&](size_t ch) {
    check_cancel(params.cancel);
    if (over.load(std::memory_order_relaxed)) return;
    auto& out = pairs[ch];
    const size_t end = std::min(valid.size(), (ch + 1) * kChunk);
    for (size_t i = ch * kChunk; i < end; ++i) {
      const uint32_t tri = valid[i];
      for_each_overlapped_cell(tri, g.lo_, top_vs, r, padding,
                               [&](int32_t x, int32_t y, int32_t z) {
                                 out.emplace_back(uint32_t((size_t(z) * r[1] + y) * r[0] + x), tri);
                               });
    }
    const uint64_t total_pairs = listed.fetch_add(out.capacity()) + out.capacity();
    // Pairs now, and later the sorted references (4 bytes) and the per-cell counts.
    if (double(total_pairs) * (sizeof(out[0]) + sizeof(uint32_t)) > double(budget))
      over.store(true);
  });
  if (over.load()) {
    const double seen = double(listed.load());
    for (auto& v : pairs) std::vector<std::pair<uint32_t, uint32_t>>().swap(v);
    throw ParamError("irregular: the top-level cells' references outgrew the memory budget of " +
                     format_bytes(double(budget)) + " (" +
                     format_bytes(seen * (sizeof(pairs[0][0]) + sizeof(uint32_t))) + " for the " +
                     std::to_string(uint64_t(seen)) + " listed before stopping, over " +
                     std::to_string(valid.size()) +
                     " triangles): triangles crossing very many cells; lower "
                     "--irregular-top-density, or raise --memory-budget-mb (0 = half of physical "
                     "memory) if the machine has the memory");
  }
  count.assign(num_top, 0);
  size_t total = 0;
  for (const auto& v : pairs) {
    total += v.size();
    for (const auto& p : v) ++count[p.first];
  }
  if (total >= kNone)
    throw ParamError("irregular grid: more than 2^32 references; lower irregular_top_density");
  begin.assign(num_top + 1, 0);
  for (size_t i = 0; i < num_top; ++i) begin[i + 1] = begin[i] + count[i];
  top_refs.resize(total);
  std::vector<uint32_t> fill(begin.begin(), begin.end() - 1);
  for (auto& v : pairs) {
    for (const auto& p : v) top_refs[fill[p.first]++] = p.second;
    std::vector<std::pair<uint32_t, uint32_t>>().swap(v);
  }
}

// Step 2: subdivide every non-empty top cell with sub_density cells per reference, per-axis
// resolution rounded to a power of two; assemble cells and the two-level voxel map.
void IrregularGrid::Builder::subdivide(const std::vector<uint32_t>& count,
                                       const std::vector<uint32_t>& begin,
                                       const std::vector<uint32_t>& top_refs) {
  const SubLogs logs = sub_levels(count, begin, top_refs);
  set_lattice(logs, top_refs.size());
  std::vector<SubOut> outs = sub_references(count, begin, top_refs, logs);
  assemble_cells(count, logs, outs);
}

// Step 2a: each top cell's sub-resolution (log2 per axis), halved while its references pile up.
IrregularGrid::Builder::SubLogs IrregularGrid::Builder::sub_levels(
    const std::vector<uint32_t>& count, const std::vector<uint32_t>& begin,
    const std::vector<uint32_t>& top_refs) const {
  const int32_t* r = g.top_res_;
  const size_t num_top = count.size();
  SubLogs logs(num_top, {0, 0, 0});
  const double top_volume = top_vs[0] * top_vs[1] * top_vs[2];
  tbb::parallel_for(size_t(0), num_top, [&](size_t t) {
    if (count[t] == 0) return;
    const double k = std::cbrt(double(params.irregular_sub_density) * count[t] / top_volume);
    int l[3];
    for (int a = 0; a < 3; ++a) {
      const double d = top_vs[a] * k;
      l[a] = d <= 1.0 ? 0 : std::min(kMaxSubLog, int(std::lround(std::log2(d))));
    }
    // Work guard (accel/guards.h): halve the sub-resolution while the cell's references
    // pile up (its triangles coincide or cover it many times over).
    const int32_t tc[3] = {int32_t(t % r[0]), int32_t((t / r[0]) % r[1]),
                           int32_t(t / (size_t(r[0]) * r[1]))};
    while (l[0] + l[1] + l[2] > 0) {
      check_cancel(params.cancel);
      double o[3], cs[3];
      int32_t sres[3];
      for (int a = 0; a < 3; ++a) {
        o[a] = g.lo_[a] + double(tc[a]) * top_vs[a];
        sres[a] = 1 << l[a];
        cs[a] = top_vs[a] / double(sres[a]);
      }
      const double estimated = estimate_grid_references(mesh, top_refs.data(), begin[t],
                                                        begin[t] + count[t], o, cs, sres);
      if (!grid_references_pile_up(estimated, count[t], double(sres[0]) * sres[1] * sres[2])) break;
      for (int a = 0; a < 3; ++a) l[a] = std::max(0, l[a] - 1);
    }
    for (int a = 0; a < 3; ++a) logs[t][a] = uint8_t(l[a]);
  });
  return logs;
}

// Step 2b: the lattice (the top resolution times 2^shift, shift the largest sub-level), once
// its cells are known to fit the budget.
void IrregularGrid::Builder::set_lattice(const SubLogs& logs, size_t top_refs) {
  const int32_t* r = g.top_res_;
  int shift = 0;
  double sub_cells = 0;
  for (size_t t = 0; t < logs.size(); ++t) {
    int total_log = 0;
    for (int a = 0; a < 3; ++a) {
      shift = std::max(shift, int(logs[t][a]));
      total_log += logs[t][a];
    }
    sub_cells += double(uint64_t(1) << total_log);
  }
  const double need = sub_cells * double(sizeof(uint32_t) + sizeof(BCell) + sizeof(Cell) + 24) +
                      double(top_refs) * 3.0 * sizeof(uint32_t);
  if (need > double(budget) || sub_cells >= double(kNone))
    throw ParamError(
        "irregular_sub_density = " + std::to_string(params.irregular_sub_density) + " asks for " +
        std::to_string(uint64_t(sub_cells)) + " cells (about " + format_bytes(need) + ") over " +
        std::to_string(valid.size()) + " triangles, beyond the memory budget of " +
        format_bytes(double(budget)) +
        ": lower --irregular-sub-density (default 2.4), or raise --memory-budget-mb (0 "
        "= half of the memory available) if the machine has the memory");
  g.shift_ = shift;
  for (int a = 0; a < 3; ++a) {
    g.res_[a] = r[a] << shift;
    g.vs_[a] = (g.hi_[a] - g.lo_[a]) / double(g.res_[a]);
    g.inv_vs_[a] = 1.0 / g.vs_[a];
  }
}

// Step 2c: per non-empty top cell, in parallel: the references of each of its sub-cells.
std::vector<IrregularGrid::Builder::SubOut> IrregularGrid::Builder::sub_references(
    const std::vector<uint32_t>& count, const std::vector<uint32_t>& begin,
    const std::vector<uint32_t>& top_refs, const SubLogs& logs) const {
  const int32_t* r = g.top_res_;
  const int shift = g.shift_;
  std::vector<uint32_t> nonempty;
  for (size_t t = 0; t < count.size(); ++t)
    if (count[t] > 0) nonempty.push_back(uint32_t(t));
  std::vector<SubOut> outs(nonempty.size());
  tbb::parallel_for(size_t(0), nonempty.size(), [&](size_t idx) {
    check_cancel(params.cancel);
    const uint32_t t = nonempty[idx];
    const auto& l = logs[t];
    const int32_t tx = int32_t(t % r[0]), ty = int32_t((t / r[0]) % r[1]),
                  tz = int32_t(t / (size_t(r[0]) * r[1]));
    const int32_t sres[3] = {1 << l[0], 1 << l[1], 1 << l[2]};
    const size_t nsub = size_t(sres[0]) * sres[1] * sres[2];
    SubOut& out = outs[idx];
    if (nsub == 1) {
      out.count.assign(1, count[t]);
      out.refs.assign(top_refs.begin() + begin[t], top_refs.begin() + begin[t] + count[t]);
      return;
    }
    double o[3], cs[3], padding[3];
    const int32_t tc[3] = {tx, ty, tz};
    for (int a = 0; a < 3; ++a) {
      o[a] = g.lo_[a] + double(tc[a] << shift) * g.vs_[a];
      cs[a] = double(1 << (shift - l[a])) * g.vs_[a];
      padding[a] = pad(a, cs[a]);
    }
    std::vector<std::pair<uint32_t, uint32_t>> pairs;
    for (uint32_t i = begin[t]; i < begin[t] + count[t]; ++i) {
      const uint32_t tri = top_refs[i];
      for_each_overlapped_cell(tri, o, cs, sres, padding, [&](int32_t x, int32_t y, int32_t z) {
        pairs.emplace_back(uint32_t((size_t(z) * sres[1] + y) * sres[0] + x), tri);
      });
    }
    out.count.assign(nsub, 0);
    for (const auto& p : pairs) ++out.count[p.first];
    std::vector<uint32_t> fill(nsub, 0);
    for (size_t s = 1; s < nsub; ++s) fill[s] = fill[s - 1] + out.count[s - 1];
    out.refs.resize(pairs.size());
    for (const auto& p : pairs) out.refs[fill[p.first]++] = p.second;
  });
  return outs;
}

// Step 2d: the cells in top-cell order, and the voxel map; empty top cells are one cell and
// one map entry.
void IrregularGrid::Builder::assemble_cells(const std::vector<uint32_t>& count, const SubLogs& logs,
                                            std::vector<SubOut>& outs) {
  const int32_t* r = g.top_res_;
  const int shift = g.shift_;
  const size_t num_top = count.size();
  g.top_.assign(num_top, TopEntry{});
  size_t next_nonempty = 0;
  for (size_t t = 0; t < num_top; ++t) {
    const int32_t tc[3] = {int32_t(t % r[0]), int32_t((t / r[0]) % r[1]),
                           int32_t(t / (size_t(r[0]) * r[1]))};
    if (count[t] == 0) {
      g.top_[t] = TopEntry{uint32_t(cells.size()), {0, 0, 0}, 1};
      BCell c;
      for (int a = 0; a < 3; ++a) {
        c.lo[a] = tc[a] << shift;
        c.hi[a] = (tc[a] + 1) << shift;
      }
      c.begin = uint32_t(refs.size());
      c.count = 0;
      cells.push_back(c);
      continue;
    }
    SubOut& out = outs[next_nonempty++];
    const auto& l = logs[t];
    const size_t nsub = out.count.size();
    if (nsub == 1) {
      g.top_[t] = TopEntry{uint32_t(cells.size()), {0, 0, 0}, 1};
    } else {
      g.top_[t] = TopEntry{uint32_t(g.sub_.size()), {l[0], l[1], l[2]}, 0};
    }
    size_t ref_pos = 0;
    for (size_t s = 0; s < nsub; ++s) {
      const int32_t sc[3] = {int32_t(s & ((size_t(1) << l[0]) - 1)),
                             int32_t((s >> l[0]) & ((size_t(1) << l[1]) - 1)),
                             int32_t(s >> (l[0] + l[1]))};
      BCell c;
      for (int a = 0; a < 3; ++a) {
        const int32_t size = 1 << (shift - l[a]);
        c.lo[a] = (tc[a] << shift) + sc[a] * size;
        c.hi[a] = c.lo[a] + size;
      }
      c.begin = uint32_t(refs.size());
      c.count = out.count[s];
      if (nsub > 1) g.sub_.push_back(uint32_t(cells.size()));
      cells.push_back(c);
      refs.insert(refs.end(), out.refs.begin() + ref_pos, out.refs.begin() + ref_pos + c.count);
      ref_pos += c.count;
    }
    std::vector<uint32_t>().swap(out.count);
    std::vector<uint32_t>().swap(out.refs);
  }
}

BuildStats IrregularGrid::build(const Mesh& mesh, const BuildParams& params) {
  const auto t_start = std::chrono::steady_clock::now();
  const float top = params.irregular_top_density, sub = params.irregular_sub_density;
  check_scene_range(mesh.bounds(), "irregular");
  if (!(std::isfinite(top) && top > 0.0f))
    throw ParamError("irregular_top_density = " + std::to_string(top) +
                     ": must be a positive number of top-level cells per triangle (default 0.12)");
  if (!(std::isfinite(sub) && sub > 0.0f))
    throw ParamError("irregular_sub_density = " + std::to_string(sub) +
                     ": must be a positive number of cells per reference (default 2.4)");
  // Memory guard before any allocation, from the lowest per-triangle peak at default
  // densities (docs/LIMITS.md, "The guards' constants"), mostly the reference lists of the
  // merge passes. The top and second levels are checked again once their cell and reference
  // counts are known (Builder), and every later phase checks what it holds before allocating
  // (require()).
  const uint64_t expected = check_memory_budget(
      "irregular", mesh.num_triangles(),
      {{"cells, references and merge buffers (~300 bytes per triangle at default densities, "
        "measured)",
        300.0 * double(mesh.num_triangles())}},
      params,
      "the grid's memory grows with the triangle count (lower --irregular-sub-density or "
      "--irregular-top-density only trims it): split the scene");
  mesh_ = &mesh;
  triangle_test_ = params.triangle_test;
  top_.clear();
  sub_.clear();
  cells_.clear();
  own_boxes_.clear();
  refs_.clear();
  shift_ = 0;
  for (int a = 0; a < 3; ++a) res_[a] = top_res_[a] = 0;
  bound_hits_ = 0;
  stats_ = {};
  // The cells and references follow the density rules and their pile-up guards, which are
  // estimates, not limits: no bound below the budget is known before building, and every
  // phase checks what it holds against the budget (require()).
  stats_.peak_estimate = build_peak_bound(kInf, expected, params);
  stats_.peak_expected = expected;

  Builder b(*this, mesh, params);
  tbb::task_arena arena(effective_threads(params.threads));
  try {
    arena.execute([&] { b.run(); });
  } catch (...) {
    // Leave an empty, usable structure behind when a parameter is rejected.
    top_.clear();
    sub_.clear();
    cells_.clear();
    own_boxes_.clear();
    refs_.clear();
    throw;
  }

  const uint64_t map_bytes = top_.size() * sizeof(TopEntry) + sub_.size() * sizeof(uint32_t);
  const uint64_t cell_bytes =
      cells_.size() * sizeof(Cell) + own_boxes_.size() * sizeof(own_boxes_[0]);
  const uint64_t ref_bytes = refs_.size() * sizeof(uint32_t);
  uint64_t empty = 0;
  for (const Cell& c : cells_) empty += c.end == c.begin;
  stats_.nodes = cells_.size();
  stats_.leaves = cells_.size();
  stats_.empty_leaves = empty;
  stats_.references = refs_.size();
  stats_.max_depth = cells_.empty() ? 0 : 2;
  stats_.sah_evaluations = b.merge_evaluations;
  stats_.bytes = sizeof(*this) + map_bytes + cell_bytes + ref_bytes;
  stats_.peak_accounted = std::max(uint64_t(std::ceil(b.peak)), stats_.bytes);
  stats_.bytes_by_part = {
      {"voxel map", map_bytes}, {"cells", cell_bytes}, {"references", ref_bytes}};
  stats_.extra = {
      {"top resolution", format_res(top_res_)},
      {"lattice resolution", format_res(res_)},
      {"sub-level shift", std::to_string(shift_)},
      {"cells before merge", std::to_string(b.cells_before_merge)},
      {"cells after merge", std::to_string(b.cells_after_merge)},
      {"cells after expansion", std::to_string(cells_.size())},
      {"cells expanded", std::to_string(b.expanded_cells)},
      {"merge rounds", std::to_string(b.merge_rounds)},
  };
  stats_.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return stats_;
}

void IrregularGrid::for_each_box(const std::function<void(const StructureBox&)>& fn) const {
  for (size_t i = 0; i < cells_.size(); ++i) {
    if (cells_[i].end == cells_[i].begin) continue;  // overlays show occupied cells only
    const auto& ob = own_boxes_[i];
    fn({world_box(ob.data(), ob.data() + 3), 2, true, cells_[i].end - cells_[i].begin});
  }
}

}  // namespace kdgrid
