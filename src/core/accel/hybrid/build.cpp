// GridKdHybrid::build: validates the parameters, chooses the cell size (choose_cell_size: explicit
// or the auto rule), checks the memory budget, then builds the tree (tree.cpp), the cell map
// (cell_map.cpp) and the widened empty leaves (widen.cpp), and reports the build's figures.
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>

#include "accel/guards.h"
#include "accel/hybrid/build.h"
#include "accel/hybrid/hybrid.h"
#include "util/cancel.h"
#include "util/error.h"
#include "util/format.h"

namespace kdgrid {

namespace hybrid {

void dims_for(const double ext[3], double cell, double out[3]) {
  for (int a = 0; a < 3; ++a) out[a] = std::max(1.0, std::ceil(ext[a] / cell));
}

void scene_box(const Mesh& mesh, double origin[3], double ext[3]) {
  Box3 sb;
  for (const auto& t : mesh.triangles)
    for (uint32_t v : t) sb.grow(mesh.positions[v]);
  if (mesh.num_triangles() == 0) sb = Box3(Vec3(0.0f), Vec3(0.0f));
  for (int a = 0; a < 3; ++a) {
    origin[a] = double(sb.lo[a]);
    ext[a] = double(sb.hi[a]) - double(sb.lo[a]);
  }
}

double auto_cell_size(const Mesh& mesh, const BuildParams& params, const double ext[3],
                      uint64_t budget, std::string& rule) {
  const size_t ntri = mesh.num_triangles();
  const double max_ext = std::max({ext[0], ext[1], ext[2]});
  double c = 0.0;
  if (ntri > 0) {
    std::vector<float> e(ntri);
    for (size_t i = 0; i < ntri; ++i) e[i] = max_component(mesh.triangle_bounds(i).extent());
    const double p = double(params.cell_percentile) / 100.0;
    const size_t k = size_t(std::clamp(std::ceil(p * double(ntri)) - 1.0, 0.0, double(ntri - 1)));
    std::nth_element(e.begin(), e.begin() + ptrdiff_t(k), e.end());
    c = double(e[k]);
  }
  rule = format_double("p%g", params.cell_percentile);
  rule += " of triangle extents = " + format_double("%.6g", c);
  // Density floor: scenes mixing huge and tiny triangles (Sponza) would otherwise get a
  // handful of cells holding hundreds of triangles each.
  double vol = 1.0;
  int flat_axes = 0;
  for (int a = 0; a < 3; ++a) {
    if (ext[a] > 0.0)
      vol *= ext[a];
    else
      ++flat_axes;
  }
  if (ntri > 0 && flat_axes < 3) {
    const double cd =
        std::pow(vol / (kHybridAutoCellsPerTriangle * double(ntri)), 1.0 / double(3 - flat_axes));
    if (cd < c || !(c > 0.0)) {
      c = cd;
      rule += "; lowered to " + format_double("%.6g", c) +
              " for >= " + format_double("%g", kHybridAutoCellsPerTriangle) + " cells per triangle";
    }
  }
  if (!(c > 0.0)) {
    c = 1.0;
    rule += "; degenerate scene, using 1";
  }
  const double axis_floor = max_ext / double(kHybridAutoMaxAxisCells);
  if (c < axis_floor) {
    c = axis_floor;
    rule += "; raised to " + format_double("%.6g", c) +
            " for <= " + std::to_string(kHybridAutoMaxAxisCells) + " cells per axis";
  }
  // Plain leaves (no subtrees) need cells about a triangle wide: only the binning and the
  // matrix bound them.
  double limit = params.hybrid_subtree_min > 0 ? kHybridAutoMaxCells : kHybridAutoMaxCellsPlain;
  if (params.hybrid_dense_matrix) limit = std::min(limit, double(budget) / 4.0);
  bool raised = false;
  for (int it = 0; it < 200; ++it) {
    double d[3];
    dims_for(ext, c, d);
    const double cells = d[0] * d[1] * d[2];
    if (cells <= limit) break;
    c *= std::max(1.0001, std::cbrt(cells / limit));
    raised = true;
  }
  if (raised)
    rule += "; raised to " + format_double("%.6g", c) + " for <= " + format_double("%.0f", limit) +
            " cells";
  return c;
}

double choose_cell_size(const Mesh& mesh, const BuildParams& params, const double ext[3],
                        uint64_t budget, std::string& rule) {
  if (params.cell_size > 0.0f) {
    rule = "explicit";
    // A cell larger than the scene is one cell of the scene's size: the same single cell,
    // but a grid box reaching far beyond the scene would widen the walk's rounding bound
    // (KdRay::err grows with the box's coordinates) until every ray crossed every node of the
    // cell's subtree (HybridEstimate.CellLargerThanTheSceneIsOneCellWalkedLikeTheKdTree).
    const double max_ext = std::max({ext[0], ext[1], ext[2]});
    // A size within float rounding of the extent (the one cell's size, read back as a float)
    // is that one cell too, not 2 cells along the longest axis.
    if (double(params.cell_size) * (1.0 + 0x1p-22) >= max_ext && max_ext > 0.0) {
      rule += format_double(" %g", params.cell_size);
      rule += ", larger than the scene: one cell of its extent ";
      rule += format_double("%.6g", max_ext);
      return max_ext;
    }
    return double(params.cell_size);
  }
  return auto_cell_size(mesh, params, ext, budget, rule);
}

}  // namespace hybrid

// ---- build ------------------------------------------------------------------------------

namespace {

/// Refuses parameters and meshes the build cannot take, before any state is touched.
void validate_build_input(const Mesh& mesh, const BuildParams& params) {
  if (std::isnan(params.cell_size) || std::isinf(params.cell_size))
    throw ParamError("hybrid: cell_size " + format_double("%g", params.cell_size) +
                     " is not a finite number: give a positive size in scene units, or 0 "
                     "(--cell-size auto) for the percentile rule");
  if (!(params.cell_percentile > 0.0f && params.cell_percentile <= 100.0f))
    throw ParamError("hybrid: cell_percentile " + format_double("%g", params.cell_percentile) +
                     " is out of range: give a value in (0, 100], e.g. 90");
  if (!(params.hybrid_traversal_cost > 0.0f) || !std::isfinite(params.hybrid_traversal_cost) ||
      !(params.hybrid_intersection_cost > 0.0f) || !std::isfinite(params.hybrid_intersection_cost))
    throw ParamError(
        "hybrid: hybrid_traversal_cost and hybrid_intersection_cost must be positive "
        "finite numbers, e.g. 1 and 1.5");
  const size_t ntri = mesh.num_triangles();
  for (size_t i = 0; i < ntri; ++i)
    for (uint32_t v : mesh.triangles[i])
      if (v >= mesh.positions.size() || !is_finite(mesh.positions[v]))
        throw ParamError("hybrid: triangle " + std::to_string(i) +
                         " has an out-of-range or non-finite vertex: validate the mesh first");
}

/// The memory guard before any allocation: what the build needs at least, whatever the scene —
/// the root's reference list and its children's at the first split (28 bytes per reference),
/// then at least one reference and the corners and id of every triangle. How many references a
/// triangle ends in depends on the scene (a few on scans and landscapes, hundreds for long thin
/// triangles), so the kd build keeps a running account (TreeBuilder::charge), the exact
/// reference count is checked before the per-reference arrays are allocated, and the matrices
/// are checked once the grid is known. Returns the estimate.
uint64_t check_least_memory(size_t ntri, const BuildParams& params) {
  const double nt = double(ntri);
  return check_memory_budget(
      "hybrid", ntri,
      {{"reference lists of the first split (at least)", 2.0 * nt * sizeof(hybrid::Ref)},
       {"triangle groups and their lane list (at least one lane and one entry per triangle)",
        nt * (sizeof(uint32_t) + hybrid::kGroupLaneBytesAtLeast)},
       {"leaf subtrees' classification flags (a byte per triangle per thread)",
        params.hybrid_subtree_min > 0 ? nt * double(effective_threads(params.threads)) : 0.0}},
      params,
      "fewer, larger leaves need less: a larger --cell-size (or --cell-percentile), or a "
      "lower kd_max_depth");
}

/// Refuses a grid of d cells of size `cell` whose matrix (dense) or per-cell binning arrays
/// (bricked) would not fit the budget, or with more cells on an axis than supported.
void check_grid_memory(double cell, const double d[3], size_t ntri, uint64_t budget, int threads,
                       bool dense) {
  const double cells = d[0] * d[1] * d[2];
  const double max_axis = std::max({d[0], d[1], d[2]});
  auto dims_text = [&] {
    return format_double("%.0f", d[0]) + "x" + format_double("%.0f", d[1]) + "x" +
           format_double("%.0f", d[2]);
  };
  const double tri_bytes = double(ntri) * (hybrid::kGroupLaneBytesAtLeast + 4 * sizeof(uint32_t));
  if (dense) {
    const double need = cells * 4.0 + tri_bytes;
    if (need > double(budget) || max_axis > double(kHybridMaxAxisCells)) {
      const double fit =
          cell *
          std::max(std::cbrt(need / double(budget)), max_axis / double(kHybridMaxAxisCells)) * 1.05;
      throw ParamError("hybrid: cell size " + format_double("%g", cell) + " gives a " +
                       dims_text() + " grid whose dense matrix needs " + format_bytes_iec(need) +
                       ", above the memory budget of " + format_bytes_iec(double(budget)) +
                       ": use a cell size of at least " + format_double("%.3g", fit) +
                       ", 'auto', or the default bricked storage");
    }
  } else {
    // The bricked matrix is guarded while it is built; before that, the build bins every
    // node per cell along each axis (2 x 4 bytes per cell per axis per thread).
    const double need = 8.0 * (d[0] + d[1] + d[2]) * double(threads) + tri_bytes;
    if (need > double(budget) || max_axis > double(kHybridMaxAxisCells)) {
      const double fit =
          cell * std::max(need / double(budget), max_axis / double(kHybridMaxAxisCells)) * 1.05;
      throw ParamError(
          "hybrid: cell size " + format_double("%g", cell) + " gives a " + dims_text() +
          " grid; building it needs at least " + format_bytes_iec(need) +
          " (per-cell binning arrays) and at most " + std::to_string(kHybridMaxAxisCells) +
          " cells per axis are supported (memory budget " + format_bytes_iec(double(budget)) +
          "): use a cell size of at least " + format_double("%.3g", fit) + " or 'auto'");
    }
  }
}

}  // namespace

/// What build_parts reports: each phase's seconds and what the empty-leaf widening did.
struct GridKdHybrid::BuildPhases {
  double tree = 0, matrix = 0, expand = 0;
  uint64_t references = 0;
  std::string expand_text;
};

BuildStats GridKdHybrid::build(const Mesh& mesh, const BuildParams& params) {
  const auto t_start = std::chrono::steady_clock::now();
  validate_build_input(mesh, params);
  const size_t ntri = mesh.num_triangles();
  const uint64_t estimate = check_least_memory(ntri, params);
  reset_for_build(mesh, params, estimate);

  const uint64_t budget = effective_memory_budget(params);
  const int threads = effective_threads(params.threads);

  double ext[3];
  hybrid::scene_box(mesh, origin_, ext);

  // ---- cell size ----
  std::string rule;
  const double cell = hybrid::choose_cell_size(mesh, params, ext, budget, rule);
  if (params.cell_size > 0.0f) {
    // An explicit size: refused before anything is allocated when its estimate does not fit.
    const HybridEstimate est = GridKdHybrid::estimate(mesh, params);
    if (!est.fits) throw ParamError(est.refusal());
  }
  cell_ = cell;
  inv_cell_ = 1.0 / cell;

  // ---- memory guard before any allocation ----
  double d[3];
  hybrid::dims_for(ext, cell, d);
  check_grid_memory(cell, d, ntri, budget, threads, map_.dense());
  for (int a = 0; a < 3; ++a) dims_[a] = int32_t(d[a]);
  // The peak bound, now that the grid is known: what this grid and the depth limits can need
  // at most, within the budget. The tree's account, the checks after it and the matrix and
  // empty-leaf budgets stop the build at it.
  stats_.peak_estimate = build_peak_bound(
      hybrid::worst_case_bytes(mesh, origin_, cell, d, params, threads) + sizeof(*this), estimate,
      params);
  set_grid_box();

  BuildPhases phases;
  tbb::task_arena arena(threads);
  arena.execute([&] { build_parts(mesh, params, stats_.peak_estimate, phases); });
  report_build(params, rule, phases);
  stats_.peak_accounted = std::max(stats_.peak_accounted, stats_.bytes);
  stats_.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return stats_;
}

void GridKdHybrid::reset_for_build(const Mesh& mesh, const BuildParams& params, uint64_t estimate) {
  mesh_ = &mesh;
  triangle_test_ = params.triangle_test;
  next_leaf_cache_ = params.hybrid_next_leaf_cache;
  nodes_.clear();
  leaves_.clear();
  kd_boxes_.clear();
  leaf_depth_.clear();
  sub_nodes_.clear();
  groups_.clear();
  flat_subtree_floats_.clear();
  group_count_ = group_lanes_ = group_corners_ = 0;
  flat_subtrees_ = 0;
  map_.reset(params.hybrid_dense_matrix);
  step_errors_.store(0);
  {
    static std::atomic<uint64_t> builds{0};
    uid_ = ++builds;
  }
  stats_ = {};
  stats_.peak_expected = estimate;
  stats_.peak_estimate = estimate;
}

void GridKdHybrid::set_grid_box() {
  const double cell = cell_;
  {
    // The grid's world box for walk_begin's float clip, widened by 2^-18 of the largest
    // coordinate: it contains the exact (double) grid box after rounding to float. The
    // rounding of the clip itself grows with the ray's origin, not with this box, and is
    // covered per ray by the clip's err (walk_begin); this widening alone lost rays from far
    // away that graze the box.
    double m = 0.0;
    for (int a = 0; a < 3; ++a)
      m = std::max({m, std::fabs(origin_[a]), std::fabs(origin_[a] + double(dims_[a]) * cell)});
    const double widen = m * 0x1p-18 + std::numeric_limits<float>::min();
    for (int a = 0; a < 3; ++a) {
      world_box_.lo[a] = next_float_down(float(origin_[a] - widen));
      world_box_.hi[a] = next_float_up(float(origin_[a] + double(dims_[a]) * cell + widen));
    }
    max_abs_ = std::max(max_component(abs(world_box_.lo)), max_component(abs(world_box_.hi)));
    world_clip_.set(world_box_);
  }
  max_steps_ = uint64_t(dims_[0]) + uint64_t(dims_[1]) + uint64_t(dims_[2]) + 1;
  origin4_ = Double4{origin_[0], origin_[1], origin_[2], 0.0};
  last_cell4_ = Double4{double(dims_[0] - 1), double(dims_[1] - 1), double(dims_[2] - 1), 0.0};
  map_.set_grid(dims_);
}

void GridKdHybrid::build_parts(const Mesh& mesh, const BuildParams& params, uint64_t bound,
                               BuildPhases& phases) {
  const auto t0 = std::chrono::steady_clock::now();
  {
    GroupPlan plan;
    build_tree(mesh, params, plan, phases.references);
    check_cancel(params.cancel);
    fill_groups(mesh, plan);
  }
  uint64_t other = 0;
  other += nodes_.size() * sizeof(Node) + leaves_.size() * (sizeof(Leaf) + sizeof(KdBox)) +
           leaf_depth_.size() + groups_.size() * sizeof(hybrid::GroupLine) +
           sub_nodes_.size() * sizeof(KdNode) +
           flat_subtree_floats_.size() * sizeof(hybrid::GroupLine) +
           (next_leaf_cache_ ? leaves_.size() * sizeof(KdBox) : 0) + sizeof(*this);
  const auto t1 = std::chrono::steady_clock::now();
  const uint64_t left = bound > other ? bound - other : 0;
  map_.build(dims_, nodes_, leaves_, left, params.cancel);
  check_cancel(params.cancel);
  const uint64_t matrix = map_.entries() * sizeof(uint32_t);
  const auto t2 = std::chrono::steady_clock::now();
  // The kd leaf boxes, kept before empty leaves are widened: they tile the grid, so a cell
  // inside one names its leaf (the next-leaf cache's check, walk.h; not kept without the cache).
  if (next_leaf_cache_) kd_boxes_.resize(leaves_.size());
  for (size_t i = 0; i < kd_boxes_.size(); ++i) {
    for (int a = 0; a < 3; ++a) {
      kd_boxes_[i].lo[a] = int32_t(leaves_[i].lo[a]);
      kd_boxes_[i].hi[a] = int32_t(leaves_[i].hi[a]);
    }
    kd_boxes_[i].lo[3] = std::numeric_limits<int32_t>::min();
    kd_boxes_[i].hi[3] = std::numeric_limits<int32_t>::max();
  }
  phases.expand_text = params.hybrid_expand_empty
                           ? hybrid::widen_empty_leaves(
                                 leaves_, dims_, left > matrix ? left - matrix : 0, params.cancel)
                           : std::string("off (the paper's kd leaf boxes)");
  phases.expand = std::chrono::duration<double>(std::chrono::steady_clock::now() - t2).count();
  phases.tree = std::chrono::duration<double>(t1 - t0).count();
  phases.matrix = std::chrono::duration<double>(t2 - t1).count();
}

void GridKdHybrid::fill_groups(const Mesh& mesh, const GroupPlan& plan) {
  groups_.assign(size_t((plan.floats + 15) / 16), hybrid::GroupLine{});
  group_count_ = plan.fill.size();
  group_lanes_ = hybrid::kSharedCorners ? plan.lanes.size() : group_count_ * kWideLanes;
  group_corners_ = 0;
  for (const uint32_t u : plan.corners) group_corners_ += u;
  group_narrow_ = 0;
  for (size_t g = 0; g < plan.fill.size(); ++g)
    if (plan.narrow[g]) group_narrow_ += plan.fill[g];
  float* const base = groups_.empty() ? nullptr : groups_[0].f;
  tbb::parallel_for(size_t(0), plan.fill.size(), [&](size_t g) {
    float* const p = base + plan.offset[g];
    const uint32_t* const lanes = plan.lanes.data() + plan.start[g];
    if constexpr (hybrid::kSharedCorners) {
      const uint32_t n = plan.fill[g], u = plan.corners[g];
      const bool narrow = plan.narrow[g];
      const uint32_t header = n | u << 8 | hybrid::shared_group_floats(n, u, narrow) << 16 |
                              (narrow ? hybrid::kNarrowIds : 0);
      std::memcpy(p, &header, sizeof header);
      uint8_t* const index = reinterpret_cast<uint8_t*>(p + 1 + 3 * u);
      const uint32_t stride = hybrid::shared_index_stride(n);
      const uint8_t* const planned = plan.index.data() + 3 * size_t(plan.start[g]);
      for (uint32_t i = 0; i < n; ++i) {
        const auto c = mesh.corners(lanes[i]);
        for (int k = 0; k < 3; ++k) {
          const uint32_t j = planned[3 * i + uint32_t(k)];
          if constexpr (kWideLanes == 8)
            index[uint32_t(k) * stride + i / 2] |= uint8_t(j << (4 * (i & 1)));
          else
            index[uint32_t(k) * stride + i] = uint8_t(j);
          for (int a = 0; a < 3; ++a) p[1 + uint32_t(a) * u + j] = component(c[k], a);
        }
      }
      float* const ids = p + 1 + 3 * u + hybrid::shared_index_floats(n);
      if (narrow) {
        const uint32_t lo = *std::min_element(lanes, lanes + n);
        std::memcpy(ids, &lo, sizeof lo);
        for (uint32_t i = 0; i < n; ++i) {
          const uint16_t d = uint16_t(lanes[i] - lo);
          std::memcpy(reinterpret_cast<char*>(ids + 1) + 2 * i, &d, sizeof d);
        }
      } else {
        std::memcpy(ids, lanes, n * sizeof(uint32_t));
      }
    } else {
      constexpr uint32_t W = uint32_t(kWideLanes);
      for (uint32_t i = 0; i < W; ++i) {
        const auto c = mesh.corners(lanes[i]);
        for (int k = 0; k < 3; ++k)
          for (int a = 0; a < 3; ++a) p[uint32_t(3 * k + a) * W + i] = component(c[k], a);
        std::memcpy(p + 9 * W + i, &lanes[i], sizeof(uint32_t));
      }
    }
  });
}

std::string GridKdHybrid::subtrees_text(const BuildParams& params) const {
  if (params.hybrid_subtree_min == 0) return "off (plain leaves)";
  uint64_t subtree_leaves = 0;
  uint32_t largest_leaf = 0;
  for (const Leaf& l : leaves_) {
    subtree_leaves += (l.count & kSubtreeFlag) != 0;
    largest_leaf = std::max(largest_leaf, l.count & ~kSubtreeFlag);
  }
  return std::to_string(subtree_leaves) + " leaves with more than " +
         std::to_string(params.hybrid_subtree_min) + " triangles (" +
         (params.hybrid_flat_subtrees && hybrid::kFlatSubtrees
              ? std::to_string(flat_subtrees_) +
                    " stored flat: " + std::to_string(hybrid::kFlatMinLeaves) + " to " +
                    std::to_string(hybrid::kFlatLeaves) + " leaves with triangles"
              : std::string("none flat")) +
         "), " + std::to_string(sub_nodes_.size()) + " kd nodes; largest leaf " +
         std::to_string(largest_leaf) + " triangles";
}

std::string GridKdHybrid::groups_text(uint64_t references) const {
  const double groups = double(std::max<uint64_t>(1, group_count_));
  if (hybrid::kSharedCorners)
    return std::to_string(group_count_) + " groups of up to " + std::to_string(kWideLanes) +
           " lanes for " + std::to_string(references) + " references (" +
           format_double("%.1f", double(references) / groups) + " lanes and " +
           format_double("%.1f", double(group_corners_) / groups) +
           " distinct corners a group; 16-bit triangle ids for " +
           format_double(
               "%.1f", 100.0 * double(group_narrow_) / double(std::max<uint64_t>(1, references))) +
           "% of references)";
  return std::to_string(group_count_) + " groups of " + std::to_string(kWideLanes) + " lanes for " +
         std::to_string(references) + " references (" +
         format_double("%.1f", 100.0 * (1.0 - double(references) /
                                                  double(std::max<uint64_t>(1, group_lanes_)))) +
         "% padding lanes)";
}

void GridKdHybrid::report_build(const BuildParams& params, const std::string& rule,
                                const BuildPhases& phases) {
  stats_.nodes = nodes_.size();
  stats_.leaves = leaves_.size();
  for (const Leaf& l : leaves_) stats_.empty_leaves += l.count == 0;
  stats_.references = phases.references;
  const uint64_t b_tree = nodes_.size() * sizeof(Node);
  const uint64_t b_sub = sub_nodes_.size() * sizeof(KdNode);
  const uint64_t b_flat = flat_subtree_floats_.size() * sizeof(hybrid::GroupLine);
  const uint64_t b_leaves = leaves_.size() * (sizeof(Leaf) + 1);  // + depth byte
  const uint64_t b_kd_boxes = kd_boxes_.size() * sizeof(KdBox);
  const uint64_t b_groups = groups_.size() * sizeof(hybrid::GroupLine);
  const uint64_t b_matrix = map_.entries() * sizeof(uint32_t);
  stats_.bytes =
      b_tree + b_leaves + b_kd_boxes + b_sub + b_flat + b_groups + b_matrix + sizeof(*this);
  stats_.bytes_by_part = {{"tree nodes", b_tree},
                          {"leaves", b_leaves},
                          {"leaf kd boxes", b_kd_boxes},
                          {"leaf subtrees", b_sub},
                          {"flat subtrees", b_flat},
                          {"triangle groups (corners + triangle ids)", b_groups},
                          {map_.dense() ? "matrix (dense)" : "matrix (bricked)", b_matrix},
                          {"object", sizeof(*this)}};
  stats_.extra = {
      {"cell_size", format_double("%.6g", cell_)},
      {"auto rule", rule},
      {"grid",
       std::to_string(dims_[0]) + "x" + std::to_string(dims_[1]) + "x" + std::to_string(dims_[2])},
      {"matrix", map_.dense() ? "dense" : map_.bricked().describe()},
      {"leaf subtrees", subtrees_text(params)},
      {"triangle groups", groups_text(phases.references)},
      {"empty-leaf boxes", phases.expand_text},
      {"build phases", "tree " + format_double("%.3f", phases.tree) + " s, matrix " +
                           format_double("%.3f", phases.matrix) + " s, empty-leaf boxes " +
                           format_double("%.3f", phases.expand) + " s"}};
}

}  // namespace kdgrid
