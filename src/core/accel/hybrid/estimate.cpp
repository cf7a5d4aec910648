// GridKdHybrid::estimate: what a build at given parameters would make (grid, bytes, seconds), from
// the mesh alone, and the smallest cell size that fits when it does not (HybridEstimate).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "accel/guards.h"
#include "accel/hybrid/build.h"
#include "accel/hybrid/hybrid.h"
#include "util/error.h"
#include "util/format.h"

namespace kdgrid {

namespace {

/// The estimate's figures at cell size `c` (HybridEstimate's fields but the cell choice);
/// `cell_seconds` is the part of the time that the cell size adds (the matrix, the binning),
/// which the time limit bounds: the triangles' part is the same at any size.
struct EstimateAt {
  double dims[3], cells, bytes, structure_bytes, seconds, cell_seconds;
  bool fits;
};

EstimateAt estimate_at(double c, const double ext[3], double ntri, double area,
                       const BuildParams& p, uint64_t budget, int threads) {
  EstimateAt e{};
  hybrid::dims_for(ext, c, e.dims);
  e.cells = e.dims[0] * e.dims[1] * e.dims[2];
  const double axis_sum = e.dims[0] + e.dims[1] + e.dims[2];
  double matrix = 0, matrix_ops = 0;
  if (p.hybrid_dense_matrix) {
    matrix = e.cells * 4.0;
    matrix_ops = e.cells;
  } else {
    // Bricks refine where leaves meet, along the surface: about kHybridBricksPerArea per
    // (4 cells)^2 of triangle area, and never more than the grid's 4^3-cell blocks (and their
    // parents, 1/63 more).
    const double bricks =
        std::min(kHybridBricksPerArea * area / (16.0 * c * c), e.cells / 64.0 * 64.0 / 63.0);
    double top = 1;
    for (int level = 1;; ++level) {
      top = 1;
      for (int a = 0; a < 3; ++a) top *= std::ceil(e.dims[a] / std::pow(4.0, level));
      if (top <= double(hybrid::BrickedCellMap::kMaxTopEntries)) break;
    }
    matrix = bricks * hybrid::BrickedCellMap::kBrickEntries * 4.0 + top * 4.0;
    matrix_ops = bricks * (kHybridSecondsPerBrick / kHybridSecondsPerBinOp);
  }
  // Binning: every node clears and sums 2 arrays of its width per axis. Widths halve about
  // every three levels, so the sum over the tree's ~n leaves is ~2.7 n^(2/3) times the root's.
  const double bins = 2.0 * axis_sum * 2.7 * std::pow(std::max(1.0, ntri), 2.0 / 3.0);
  const double sat = (e.dims[0] + 1) * (e.dims[1] + 1) * (e.dims[2] + 1);
  const double expand =
      p.hybrid_expand_empty && sat <= double(GridKdHybrid::kMaxExpandEntries) ? sat * 4.0 : 0.0;
  e.structure_bytes = matrix + ntri * kHybridBytesPerTriangle;
  e.bytes = e.structure_bytes + 8.0 * axis_sum * threads + expand;
  e.cell_seconds = (matrix_ops + bins) * kHybridSecondsPerBinOp / threads;
  // Cells coarser than the triangles leave about ntri / cells triangles a leaf, whose subtree
  // takes log2 of its size over hybrid_subtree_min levels.
  const double per_leaf = ntri / std::max(1.0, std::min(e.cells, ntri));
  const double levels = p.hybrid_subtree_min > 0
                            ? std::log2(std::max(1.0, per_leaf / double(p.hybrid_subtree_min)))
                            : 0.0;
  const double table = expand > 0.0 ? sat * kHybridSecondsPerExpandEntry : 0.0;
  e.seconds =
      e.cell_seconds +
      (ntri * kHybridSecondsPerTriangle * (1.0 + kHybridSubtreeLevelShare * levels) + table) /
          threads;
  const double max_axis = std::max({e.dims[0], e.dims[1], e.dims[2]});
  e.fits = e.bytes <= double(budget) && max_axis <= double(kHybridMaxAxisCells) &&
           (p.hybrid_max_build_seconds <= 0 || e.cell_seconds <= p.hybrid_max_build_seconds);
  return e;
}

/// x rounded up to two significant digits (a size a person can type that is >= x).
double round_up_2(double x) {
  if (!(x > 0.0) || !std::isfinite(x)) return x;
  const double scale = std::pow(10.0, std::floor(std::log10(x)) - 1.0);
  double r = std::ceil(x / scale * (1.0 - 1e-12)) * scale;
  if (r < x) r = std::nextafter(x, INFINITY);
  return r;
}

std::string seconds_str(double s) {
  if (s < 1.0) return "under a second";
  if (s < 120.0) return format_double("about %.0f s", s);
  if (s < 7200.0) return format_double("about %.0f min", s / 60.0);
  return format_double("about %.3g hours", s / 3600.0);
}

}  // namespace

std::string HybridEstimate::refusal() const {
  const HybridEstimate& e = *this;
  std::string why;
  if (e.bytes > double(e.budget))
    why = "above the memory budget of " + format_bytes_iec(double(e.budget));
  const double max_axis = std::max({e.dims[0], e.dims[1], e.dims[2]});
  if (max_axis > double(kHybridMaxAxisCells))
    why += std::string(why.empty() ? "" : ", and ") + "more than " +
           std::to_string(kHybridMaxAxisCells) + " cells per axis";
  if (why.empty())
    why = "longer than the limit of " + format_double("%g", e.seconds_limit) +
          " s (--hybrid-max-build-seconds; the memory budget is " +
          format_bytes_iec(double(e.budget)) + ")";
  std::string fix;
  if (e.suggested_cell > 0.0) {
    fix = "use a cell size of at least " + format_double("%.2g", e.suggested_cell) + " (" +
          format_double("%.3g", e.suggested_cell / e.auto_cell) + "x auto)";
  } else {
    fix = "even one cell does not fit: raise --memory-budget-mb";
  }
  return "hybrid: cell size " + format_double("%g", e.cell) + " gives " + e.describe() + ", " +
         why + ": " + fix + ", or 'auto' (" + format_double("%.4g", e.auto_cell) + ")";
}

std::string HybridEstimate::describe() const {
  char grid[96];
  std::snprintf(grid, sizeof grid, "a %.0fx%.0fx%.0f grid (%.3g cells)", dims[0], dims[1], dims[2],
                cells);
  return std::string(grid) + ", about " + format_bytes_iec(bytes) + " and " + seconds_str(seconds) +
         " to build";
}

HybridEstimate GridKdHybrid::estimate(const Mesh& mesh, const BuildParams& params) {
  if (std::isnan(params.cell_size) || std::isinf(params.cell_size))
    throw ParamError("hybrid: cell_size " + format_double("%g", params.cell_size) +
                     " is not a finite number");
  HybridEstimate e;
  e.budget = effective_memory_budget(params);
  e.seconds_limit = params.hybrid_max_build_seconds;
  const int threads = effective_threads(params.threads);
  double origin[3], ext[3];
  hybrid::scene_box(mesh, origin, ext);
  std::string auto_rule;
  e.auto_cell = hybrid::auto_cell_size(mesh, params, ext, e.budget, auto_rule);
  e.cell = hybrid::choose_cell_size(mesh, params, ext, e.budget, e.rule);
  const double ntri = double(mesh.num_triangles());
  // The area along which the matrix refines: a triangle far larger than most (a stadium's
  // wall, Sponza's floor) has few, large leaves beside it, which node entries cover without
  // bricks, so each triangle counts at most as one whose extent is the cell_percentile-th
  // percentile of the triangles' (the auto rule's first step).
  double area = 0.0;
  if (mesh.num_triangles() > 0) {
    const size_t n = mesh.num_triangles();
    std::vector<float> ex(n);
    for (size_t i = 0; i < n; ++i) ex[i] = max_component(mesh.triangle_bounds(i).extent());
    const double q = double(params.cell_percentile) / 100.0;
    const size_t k = size_t(std::clamp(std::ceil(q * double(n)) - 1.0, 0.0, double(n - 1)));
    std::nth_element(ex.begin(), ex.begin() + ptrdiff_t(k), ex.end());
    const double cap = double(ex[k]) * double(ex[k]);
    for (size_t i = 0; i < n; ++i) {
      const auto c = mesh.corners(i);
      const Vec3 nv = cross(c[1] - c[0], c[2] - c[0]);
      area += std::min(
          cap, 0.5 * std::sqrt(double(nv.x) * nv.x + double(nv.y) * nv.y + double(nv.z) * nv.z));
    }
  }
  const EstimateAt at = estimate_at(e.cell, ext, ntri, area, params, e.budget, threads);
  for (int a = 0; a < 3; ++a) e.dims[a] = at.dims[a];
  e.cells = at.cells;
  e.bytes = at.bytes;
  e.structure_bytes = at.structure_bytes;
  e.seconds = at.seconds;
  e.fits = at.fits;
  if (!e.fits) {
    // The estimate shrinks as the cell grows: bisect (in log) between this size and one cell.
    const double one = std::max({ext[0], ext[1], ext[2], e.cell}) * 1.001;
    if (estimate_at(one, ext, ntri, area, params, e.budget, threads).fits) {
      double lo = std::log(e.cell), hi = std::log(one);
      for (int i = 0; i < 60; ++i) {
        const double mid = 0.5 * (lo + hi);
        (estimate_at(std::exp(mid), ext, ntri, area, params, e.budget, threads).fits ? hi : lo) =
            mid;
      }
      e.suggested_cell = round_up_2(std::exp(hi));
    }
  }
  return e;
}

}  // namespace kdgrid
