// The uniform grid's build (UniformGrid::build): the scene box, the density rule's resolution
// (coarsened while references pile up), the memory guards, then the count and fill passes of
// each triangle's exactly overlapped cells. grid.h has the structure and its traversal.
#include "accel/grid.h"

#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <functional>
#include <string>

#include "accel/guards.h"
#include "scene/scene.h"
#include "util/cancel.h"
#include "util/error.h"

namespace kdgrid {
namespace {

// Cells are enlarged by this fraction of their size (plus a few ulps of the scene's largest
// coordinate) before the triangle/cell overlap test. The traversal computes cell boundaries
// in float; a triangle within rounding distance of a cell is then referenced by it too, so a
// DDA that rounds a corner the "wrong" way still finds every hit. It costs a few references.
constexpr double kCellPad = 1e-3;
constexpr double kCoordPad = 1.0 / (1 << 18);

/// Akenine-Möller (2001) triangle/box overlap by the separating axis theorem, in double:
/// box axes, the triangle normal, and the nine edge x box-axis cross products. Touching
/// counts as overlapping.
bool triangle_box_overlap(const double center[3], const double half[3], const Vec3& a,
                          const Vec3& b, const Vec3& c) {
  double v[3][3];
  for (int k = 0; k < 3; ++k) {
    v[0][k] = double(a[k]) - center[k];
    v[1][k] = double(b[k]) - center[k];
    v[2][k] = double(c[k]) - center[k];
  }
  // Box face normals: the triangle's bounds against the box.
  for (int k = 0; k < 3; ++k) {
    const double lo = std::min({v[0][k], v[1][k], v[2][k]});
    const double hi = std::max({v[0][k], v[1][k], v[2][k]});
    if (lo > half[k] || hi < -half[k]) return false;
  }
  double e[3][3];
  for (int k = 0; k < 3; ++k) {
    e[0][k] = v[1][k] - v[0][k];
    e[1][k] = v[2][k] - v[1][k];
    e[2][k] = v[0][k] - v[2][k];
  }
  // Edge x axis: axis_i x e = the vector with components permuted; project all three vertices.
  for (int j = 0; j < 3; ++j) {
    for (int i = 0; i < 3; ++i) {
      double ax[3] = {0, 0, 0};
      const int i1 = (i + 1) % 3, i2 = (i + 2) % 3;
      ax[i1] = -e[j][i2];
      ax[i2] = e[j][i1];
      const double p0 = ax[0] * v[0][0] + ax[1] * v[0][1] + ax[2] * v[0][2];
      const double p1 = ax[0] * v[1][0] + ax[1] * v[1][1] + ax[2] * v[1][2];
      const double p2 = ax[0] * v[2][0] + ax[1] * v[2][1] + ax[2] * v[2][2];
      const double r =
          half[0] * std::fabs(ax[0]) + half[1] * std::fabs(ax[1]) + half[2] * std::fabs(ax[2]);
      if (std::min({p0, p1, p2}) > r || std::max({p0, p1, p2}) < -r) return false;
    }
  }
  // Triangle plane against the box.
  const double n[3] = {e[0][1] * e[1][2] - e[0][2] * e[1][1], e[0][2] * e[1][0] - e[0][0] * e[1][2],
                       e[0][0] * e[1][1] - e[0][1] * e[1][0]};
  const double d = n[0] * v[0][0] + n[1] * v[0][1] + n[2] * v[0][2];
  const double r =
      half[0] * std::fabs(n[0]) + half[1] * std::fabs(n[1]) + half[2] * std::fabs(n[2]);
  return std::fabs(d) <= r;
}

}  // namespace

/// The build, step by step, with its scratch state. A nested class so it can fill the
/// grid's private members directly.
struct UniformGrid::Builder {
  UniformGrid& g;
  const Mesh& mesh;
  const BuildParams& params;
  const size_t n_tris;
  tbb::task_arena arena;
  uint64_t cells = 1;
  float max_abs = 0.0f;             ///< the largest coordinate magnitude of the scene's box
  std::string wanted_res, res_str;  ///< the density rule's resolution, and the one built
  double cell_bytes = 0, cursor_bytes = 0;
  double pad[3] = {0, 0, 0};      ///< each cell's enlargement for the overlap test
  uint64_t total = 0, empty = 0;  ///< references and empty cells

  Builder(UniformGrid& grid, const Mesh& m, const BuildParams& p)
      : g(grid),
        mesh(m),
        params(p),
        n_tris(m.num_triangles()),
        arena(effective_threads(p.threads)) {}

  static std::string res_text(const std::array<int, 3>& r) {
    return std::to_string(r[0]) + "x" + std::to_string(r[1]) + "x" + std::to_string(r[2]);
  }

  /// The box, padded on degenerate axes so that every cell has a positive size.
  void set_box() {
    g.box_ = mesh.bounds();
    // Near float's limit the extent overflows to inf and the cell count wraps to 0.
    check_scene_range(g.box_, "grid");
    if (n_tris == 0 || g.box_.empty()) g.box_ = Box3(Vec3(0.0f), Vec3(1.0f));
    const float max_ext = max_component(g.box_.extent());
    max_abs = std::max(max_component(abs(g.box_.lo)), max_component(abs(g.box_.hi)));
    for (int a = 0; a < 3; ++a) {
      if (g.box_.hi[a] - g.box_.lo[a] <= 1e-6f * max_ext || g.box_.hi[a] <= g.box_.lo[a]) {
        const float p = std::max({1e-3f * max_ext, 1e-5f * max_abs, 1e-30f});
        g.box_.lo[a] = next_float_down(g.box_.lo[a] - p);
        g.box_.hi[a] = next_float_up(g.box_.hi[a] + p);
      }
    }
  }

  void set_resolution(const int (&res)[3]) {
    const Vec3 ext = g.box_.extent();
    cells = 1;
    for (int a = 0; a < 3; ++a) {
      g.res_[a] = res[a];
      cells *= uint64_t(g.res_[a]);
      g.cell_[a] = ext[a] / float(g.res_[a]);
      g.inv_cell_[a] = float(g.res_[a]) / ext[a];
    }
  }

  /// Density heuristic (see grid.h): cubical cells, lambda * N of them; axes that would get
  /// less than one cell are dropped from the volume and get exactly one.
  void choose_resolution() {
    const Vec3 ext = g.box_.extent();
    const double target = double(params.grid_lambda) * double(std::max<size_t>(n_tris, 1));
    bool active[3] = {true, true, true};
    double k = 0.0;
    for (int iter = 0; iter < 3; ++iter) {
      double vol = 1.0;
      int m = 0;
      for (int a = 0; a < 3; ++a)
        if (active[a]) vol *= double(ext[a]), ++m;
      if (m == 0) break;
      k = std::pow(target / vol, 1.0 / m);
      bool changed = false;
      for (int a = 0; a < 3; ++a)
        if (active[a] && double(ext[a]) * k < 1.0) active[a] = false, changed = true;
      if (!changed) break;
    }
    int res[3];
    for (int a = 0; a < 3; ++a) {
      const double n = active[a] ? std::round(double(ext[a]) * k) : 1.0;
      res[a] = int(std::clamp(n, 1.0, double(params.grid_max_resolution)));
    }
    set_resolution(res);
  }

  /// Work guard (accel/guards.h): the count and fill passes test every cell of each
  /// triangle's box and store a reference per overlapped cell. Estimate the references first,
  /// in one pass over the triangles, and halve the resolution while they pile up.
  void coarsen_while_piled_up() {
    auto estimate = [&] {
      const double lo[3] = {g.box_.lo[0], g.box_.lo[1], g.box_.lo[2]};
      const double h[3] = {g.cell_[0], g.cell_[1], g.cell_[2]};
      double e = 0;
      arena.execute([&] {
        e = tbb::parallel_reduce(
            tbb::blocked_range<size_t>(0, n_tris, 4096), 0.0,
            [&](const tbb::blocked_range<size_t>& r, double sum) {
              check_cancel(params.cancel);
              return sum + estimate_grid_references(mesh, nullptr, r.begin(), r.end(), lo, h,
                                                    g.res_.data());
            },
            std::plus<double>());
      });
      return e;
    };
    wanted_res = res_text(g.res_);
    while ((g.res_[0] > 1 || g.res_[1] > 1 || g.res_[2] > 1) &&
           grid_references_pile_up(estimate(), double(n_tris), double(cells))) {
      const int res[3] = {std::max(1, g.res_[0] / 2), std::max(1, g.res_[1] / 2),
                          std::max(1, g.res_[2] / 2)};
      set_resolution(res);
    }
    res_str = res_text(g.res_);
  }

  /// Memory guard: refuse before allocating anything proportional to the cell count. The
  /// peak is the fill pass: offsets, a cursor per cell and the references (at least one per
  /// triangle; their exact count is checked again after the count pass).
  void check_cells_fit() {
    const uint64_t budget = effective_memory_budget(params);
    cell_bytes = double(cells + 1) * sizeof(uint32_t);
    cursor_bytes = double(cells) * sizeof(uint32_t);
    const double room = 0.9 * double(budget) - double(n_tris) * sizeof(uint32_t);
    const double fit = double(params.grid_lambda) * std::min(room / (cell_bytes + cursor_bytes),
                                                             0.9 * 0xFFFFFFFEull / double(cells));
    char lam[32];
    std::snprintf(lam, sizeof lam, "%.3g", fit);
    if (cells >= 0xFFFFFFFFull)
      throw ParamError("grid: resolution " + res_str + " has " + std::to_string(cells) +
                       " cells, beyond the 2^32 cell limit (and needs " +
                       format_bytes_iec(cell_bytes + cursor_bytes) + ", memory budget " +
                       format_bytes_iec(double(budget)) + "); use --grid-lambda " + lam +
                       " or less, or a lower grid_max_resolution");
    g.stats_.peak_estimate = check_memory_budget(
        "grid", n_tris,
        {{"cell offsets", cell_bytes},
         {"fill cursors", cursor_bytes},
         {"references (at least one per triangle)", double(n_tris) * sizeof(uint32_t)}},
        params,
        fit > 0
            ? "resolution " + res_str + " (" + std::to_string(cells) +
                  " cells): use --grid-lambda " + lam + " or less, or a lower grid_max_resolution"
            : std::string(
                  "the references alone (4 bytes per triangle) exceed it: split the scene"));
  }

  /// Visits every cell that triangle i overlaps (exact test), calling fn(linear cell index).
  template <class Fn>
  void for_cells_of(size_t i, Fn&& fn) const {
    const auto c = mesh.corners(i);
    const Box3 tb = mesh.triangle_bounds(i);
    int lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
      const double l = (double(tb.lo[a]) - pad[a] - g.box_.lo[a]) / double(g.cell_[a]);
      const double h = (double(tb.hi[a]) + pad[a] - g.box_.lo[a]) / double(g.cell_[a]);
      lo[a] = int(std::clamp(std::floor(l), 0.0, double(g.res_[a] - 1)));
      hi[a] = int(std::clamp(std::floor(h), 0.0, double(g.res_[a] - 1)));
    }
    const bool single = lo[0] == hi[0] && lo[1] == hi[1] && lo[2] == hi[2];
    for (int z = lo[2]; z <= hi[2]; ++z)
      for (int y = lo[1]; y <= hi[1]; ++y)
        for (int x = lo[0]; x <= hi[0]; ++x) {
          const int cc[3] = {x, y, z};
          if (!single) {
            double center[3], half[3];
            for (int a = 0; a < 3; ++a) {
              const double l = double(g.box_.lo[a]) + double(cc[a]) * double(g.cell_[a]);
              half[a] = 0.5 * double(g.cell_[a]) + pad[a];
              center[a] = l + 0.5 * double(g.cell_[a]);
            }
            if (!triangle_box_overlap(center, half, c[0], c[1], c[2])) continue;
          }
          fn(uint64_t(x) + uint64_t(g.res_[0]) * (uint64_t(y) + uint64_t(g.res_[1]) * uint64_t(z)));
        }
  }

  /// Count pass, then the prefix sum into offsets_; the exact references checked against the
  /// budget.
  void count_references() {
    std::vector<uint32_t> counts(cells + 1, 0);
    for (int a = 0; a < 3; ++a)
      pad[a] = kCellPad * double(g.cell_[a]) + kCoordPad * double(max_abs);
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, n_tris, 256), [&](const auto& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
          check_cancel(params.cancel);  // one triangle may cover many cells
          for_cells_of(i, [&](uint64_t cidx) {
            std::atomic_ref<uint32_t>(counts[cidx]).fetch_add(1, std::memory_order_relaxed);
          });
        }
      });
    });
    // Prefix sum into offsets (counts becomes the offsets array in place).
    for (uint64_t c = 0; c < cells; ++c) {
      if ((c & 0xFFFFF) == 0) check_cancel(params.cancel);
      const uint64_t n = counts[c];
      empty += n == 0;
      counts[c] = uint32_t(total);
      total += n;
      if (total >= 0xFFFFFFFFull)
        throw ParamError("grid: more than 2^32 triangle references at resolution " + res_str +
                         "; use a smaller --grid-lambda");
    }
    counts[cells] = uint32_t(total);
    // Exact now: the references are counted.
    g.stats_.peak_estimate =
        check_memory_budget("grid", n_tris,
                            {{"cell offsets", cell_bytes},
                             {"fill cursors", cursor_bytes},
                             {"references", double(total) * sizeof(uint32_t)}},
                            params,
                            std::to_string(total) + " references at resolution " + res_str +
                                ": use a smaller --grid-lambda");
    g.offsets_ = std::move(counts);
  }

  /// Fill pass: a cursor per cell, then sort each cell's references so the structure (and
  /// the order of triangle tests) does not depend on thread scheduling.
  void fill_references() {
    g.refs_.assign(total, 0);
    std::vector<uint32_t> cursor(g.offsets_.begin(), g.offsets_.end() - 1);
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, n_tris, 256), [&](const auto& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
          check_cancel(params.cancel);
          for_cells_of(i, [&](uint64_t cidx) {
            const uint32_t at =
                std::atomic_ref<uint32_t>(cursor[cidx]).fetch_add(1, std::memory_order_relaxed);
            g.refs_[at] = uint32_t(i);
          });
        }
      });
      tbb::parallel_for(tbb::blocked_range<uint64_t>(0, cells, 1024), [&](const auto& r) {
        check_cancel(params.cancel);
        for (uint64_t c = r.begin(); c < r.end(); ++c)
          if (g.offsets_[c + 1] - g.offsets_[c] > 1) {
            check_cancel(params.cancel);
            std::sort(g.refs_.begin() + g.offsets_[c], g.refs_.begin() + g.offsets_[c + 1]);
          }
      });
    });
  }

  void report() {
    BuildStats& s = g.stats_;
    s.nodes = cells;
    s.leaves = cells;
    s.empty_leaves = empty;
    s.references = total;
    const uint64_t b_cells = g.offsets_.size() * sizeof(uint32_t);
    const uint64_t b_refs = g.refs_.size() * sizeof(uint32_t);
    s.bytes = b_cells + b_refs;
    s.bytes_by_part = {{"cells", b_cells}, {"references", b_refs}};
    s.peak_expected = s.peak_estimate;
    s.extra = {{"resolution", res_str}};
    if (res_str != wanted_res)
      s.extra.push_back({"coarsened from", wanted_res + " (triangles piled up in the same cells)"});
  }
};

BuildStats UniformGrid::build(const Mesh& mesh, const BuildParams& params) {
  const auto t_start = std::chrono::steady_clock::now();
  if (!(params.grid_lambda > 0.0f) || !std::isfinite(params.grid_lambda))
    throw ParamError(
        "grid: grid_lambda (--grid-lambda) must be a positive number of cells per "
        "triangle, e.g. 4; got " +
        std::to_string(params.grid_lambda));
  if (params.grid_max_resolution < 1)
    throw ParamError("grid: grid_max_resolution must be >= 1; got " +
                     std::to_string(params.grid_max_resolution));
  mesh_ = &mesh;
  triangle_test_ = params.triangle_test;
  stats_ = {};
  offsets_.clear();
  refs_.clear();
  Builder b(*this, mesh, params);
  b.set_box();
  b.choose_resolution();
  b.coarsen_while_piled_up();
  b.check_cells_fit();
  b.count_references();
  b.fill_references();
  b.report();
  stats_.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return stats_;
}

void UniformGrid::for_each_box(const std::function<void(const StructureBox&)>& fn) const {
  if (offsets_.empty()) return;
  int c[3];
  uint64_t idx = 0;
  for (c[2] = 0; c[2] < res_[2]; ++c[2])
    for (c[1] = 0; c[1] < res_[1]; ++c[1])
      for (c[0] = 0; c[0] < res_[0]; ++c[0], ++idx) {
        const uint32_t n = offsets_[idx + 1] - offsets_[idx];
        if (n) fn({cell_box(c), 0, true, n});
      }
}

}  // namespace kdgrid
