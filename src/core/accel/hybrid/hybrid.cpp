#include "accel/hybrid/hybrid.h"

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <limits>
#include <bit>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>

#include "accel/guards.h"
#include "accel/hybrid/build.h"
#include "accel/kdtree.h"
#include "util/cancel.h"
#include "util/error.h"

namespace kdgrid {

namespace hybrid {

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

std::string bytes_str(double b) {
  if (b >= double(uint64_t(1) << 30)) return fmt("%.3g GiB", b / double(uint64_t(1) << 30));
  if (b >= double(1 << 20)) return fmt("%.3g MiB", b / double(1 << 20));
  return fmt("%.0f bytes", b);
}

}  // namespace hybrid

using hybrid::bytes_str;
using hybrid::fmt;

namespace {

/// Nodes with more references than this build their children as parallel tasks.
constexpr size_t kParallelThreshold = 2048;

/// A triangle reference during the build: its inclusive integer cell range in the node.
struct Ref {
  uint32_t prim;
  int32_t lo[3], hi[3];
};

struct BuildNode {
  int axis = -1;  ///< -1 leaf
  int32_t split = 0;
  int32_t lo[3], hi[3];
  int depth = 0;
  std::unique_ptr<BuildNode> kid[2];
  std::vector<uint32_t> prims;
  std::vector<KdNode> sub_nodes;  ///< leaf subtree: its box (Hybrid::kSubBoxNodes), then its nodes
  std::vector<uint32_t> sub_refs;  ///< its references (mesh triangle ids)
};

struct P3 {
  double v[3];
};

class TreeBuilder {
 public:
  TreeBuilder(const Mesh& mesh, const double origin[3], double cell, const int32_t dims[3],
              const BuildParams& p)
      : mesh_(mesh), inv_cell_(1.0 / cell), cell_(cell), kd_(mesh, p, Hybrid::kSubMaxDepth),
        kd_deep_(mesh, p, KdTree::kMaxDepth), cancel_(p.cancel) {
    for (int a = 0; a < 3; ++a) {
      origin_[a] = origin[a];
      dims_[a] = dims[a];
    }
    kt_ = p.hybrid_traversal_cost;
    ki_ = p.hybrid_intersection_cost;
    bonus_ = std::clamp(double(p.kd_empty_bonus), 0.0, 1.0);
    subtree_min_ = p.hybrid_subtree_min;
    const double n = double(std::max<size_t>(1, mesh.num_triangles()));
    max_depth_ = p.kd_max_depth > 0 ? p.kd_max_depth : int(8.0 + 1.3 * std::log2(n));
    max_depth_ = std::clamp(max_depth_, 1, 64);
    budget_ = int64_t(std::min<uint64_t>(effective_memory_budget(p), uint64_t(INT64_MAX)));
  }

  /// Running account of the build's memory (reference lists alive in the recursion, build
  /// nodes and their leaf lists). Straddling triangles are clipped into both children, so
  /// scenes of long thin triangles multiply references with depth; past the budget every
  /// pending node becomes an empty leaf and Hybrid::build throws instead of exhausting RAM.
  void charge(int64_t bytes) {
    const int64_t now = live_.fetch_add(bytes, std::memory_order_relaxed) + bytes;
    int64_t peak = peak_.load(std::memory_order_relaxed);
    while (now > peak && !peak_.compare_exchange_weak(peak, now, std::memory_order_relaxed)) {
    }
    if (bytes > 0 && now > budget_) over_.store(true, std::memory_order_relaxed);
  }
  bool over_budget() const { return over_.load(std::memory_order_relaxed); }
  int64_t live_bytes() const { return live_.load(); }
  int64_t peak_bytes() const { return peak_.load(); }
  uint64_t leaf_refs() const { return leaf_refs_.load(); }
  uint64_t nodes_made() const { return nodes_made_.load(); }

  std::unique_ptr<BuildNode> build_root() {
    const size_t n = mesh_.num_triangles();
    charge(int64_t(n * sizeof(Ref)));
    std::vector<Ref> refs(n);
    const int32_t lo[3] = {0, 0, 0};
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& r) {
      for (size_t i = r.begin(); i < r.end(); ++i) clip_range(uint32_t(i), lo, dims_, refs[i]);
    });
    return build(std::move(refs), lo, dims_, 0);
  }

  uint64_t sah_evaluations() const { return evals_.load(); }

 private:
  P3 grid_vertex(uint32_t v) const {
    const Vec3& p = mesh_.positions[v];
    return {{(double(p.x) - origin_[0]) * inv_cell_, (double(p.y) - origin_[1]) * inv_cell_,
             (double(p.z) - origin_[2]) * inv_cell_}};
  }

  /// Bounds (grid space) of the triangle clipped to the box [lo, hi] (Sutherland-Hodgman).
  /// False if the triangle misses the box.
  bool clip_bounds(uint32_t prim, const double lo[3], const double hi[3], double bl[3], double bh[3]) const {
    P3 buf[2][16];
    P3* poly = buf[0];
    P3* tmp = buf[1];
    int n = 3;
    const auto& tri = mesh_.triangles[prim];
    for (int k = 0; k < 3; ++k) poly[k] = grid_vertex(tri[k]);
    auto bounds = [&] {
      for (int a = 0; a < 3; ++a) {
        bl[a] = bh[a] = poly[0].v[a];
        for (int k = 1; k < n; ++k) {
          bl[a] = std::min(bl[a], poly[k].v[a]);
          bh[a] = std::max(bh[a], poly[k].v[a]);
        }
      }
    };
    bounds();
    bool inside = true;
    for (int a = 0; a < 3; ++a) inside = inside && bl[a] >= lo[a] && bh[a] <= hi[a];
    if (inside) return true;
    for (int a = 0; a < 3 && n > 0; ++a) {
      for (int side = 0; side < 2 && n > 0; ++side) {
        const double plane = side == 0 ? lo[a] : hi[a];
        // Planes the polygon lies entirely inside of leave it unchanged.
        if (side == 0 ? bl[a] >= plane : bh[a] <= plane) continue;
        auto in = [&](const P3& q) { return side == 0 ? q.v[a] >= plane : q.v[a] <= plane; };
        int m = 0;
        for (int k = 0; k < n; ++k) {
          const P3& p = poly[k];
          const P3& q = poly[k + 1 == n ? 0 : k + 1];
          const bool pin = in(p), qin = in(q);
          if (pin) tmp[m++] = p;
          if (pin != qin) {
            const double t = (plane - p.v[a]) / (q.v[a] - p.v[a]);
            P3 x;
            for (int b = 0; b < 3; ++b) x.v[b] = p.v[b] + (q.v[b] - p.v[b]) * t;
            x.v[a] = plane;
            tmp[m++] = x;
          }
        }
        n = m;
        std::swap(poly, tmp);
      }
    }
    if (n == 0) return false;
    bounds();
    return true;
  }

  /// The triangle clipped to the node box [lo, hi) widened by kRangeEps, as an inclusive
  /// integer cell range. False if the triangle misses the box.
  bool clip_range(uint32_t prim, const int32_t lo[3], const int32_t hi[3], Ref& out) const {
    constexpr double eps = Hybrid::kRangeEps;
    double blo[3], bhi[3], bl[3], bh[3];
    for (int a = 0; a < 3; ++a) {
      blo[a] = double(lo[a]) - eps;
      bhi[a] = double(hi[a]) + eps;
    }
    if (!clip_bounds(prim, blo, bhi, bl, bh)) return false;
    out.prim = prim;
    for (int a = 0; a < 3; ++a) {
      const double l = std::floor(bl[a] - eps), h = std::floor(bh[a] + eps);
      out.lo[a] = l < lo[a] ? lo[a] : (l > hi[a] - 1 ? hi[a] - 1 : int32_t(l));
      out.hi[a] = h < lo[a] ? lo[a] : (h > hi[a] - 1 ? hi[a] - 1 : int32_t(h));
    }
    return true;
  }

  /// Builds the kd subtree of a leaf into node.sub_nodes/sub_refs with the kd-tree's own
  /// builder, over the leaf's world box (rounded outwards to floats, so that it holds every
  /// point of the leaf). The subtree starts with the box of its clipped triangles.
  void build_subtree(BuildNode& node) {
    Box3 box;
    for (int a = 0; a < 3; ++a) {
      const double l = origin_[a] + double(node.lo[a]) * cell_, h = origin_[a] + double(node.hi[a]) * cell_;
      float fl = float(l), fh = float(h);
      if (double(fl) > l) fl = next_float_down(fl);
      if (double(fh) < h) fh = next_float_up(fh);
      box.lo[a] = fl;
      box.hi[a] = fh;
    }
    Box3 bounds;
    std::vector<KdNode> nodes;
    // A leaf far larger than the auto grid's (a coarse explicit cell, one cell for the whole
    // scene) gets the kd-tree's whole depth rule: 6 levels would leave thousands of triangles
    // per subtree leaf.
    const KdSubtreeBuilder& kd = node.prims.size() > Hybrid::kSubDeepMin ? kd_deep_ : kd_;
    kd.build(node.prims, box, nodes, node.sub_refs, bounds);
    const float f[8] = {bounds.lo.x, bounds.lo.y, bounds.lo.z, -kInf,
                        bounds.hi.x, bounds.hi.y, bounds.hi.z, kInf};
    static_assert(sizeof f == Hybrid::kSubBoxNodes * sizeof(KdNode));
    node.sub_nodes.resize(Hybrid::kSubBoxNodes + nodes.size());
    std::memcpy(node.sub_nodes.data(), f, sizeof f);
    std::copy(nodes.begin(), nodes.end(), node.sub_nodes.begin() + Hybrid::kSubBoxNodes);
    charge(int64_t(node.sub_nodes.size() * sizeof(KdNode) + node.sub_refs.size() * sizeof(uint32_t)));
    // The leaf's references are the subtree's (leaf_refs() counts what flattening copies).
    leaf_refs_.fetch_add(uint64_t(node.sub_refs.size()) - uint64_t(node.prims.size()), std::memory_order_relaxed);
  }

  std::unique_ptr<BuildNode> build(std::vector<Ref>&& refs, const int32_t lo[3], const int32_t hi[3],
                                   int depth) {
    check_cancel(cancel_);
    auto node = std::make_unique<BuildNode>();
    charge(int64_t(sizeof(BuildNode)));
    nodes_made_.fetch_add(1, std::memory_order_relaxed);
    for (int a = 0; a < 3; ++a) {
      node->lo[a] = lo[a];
      node->hi[a] = hi[a];
    }
    node->depth = depth;
    const size_t n = refs.size();
    int best_axis = -1;
    int32_t best_split = 0;
    size_t n_left = 0, n_right = 0;
    if (n > 0 && depth < max_depth_ && !over_budget())
      find_split(refs, lo, hi, best_axis, best_split, n_left, n_right);
    if (best_axis < 0) {
      // Over budget: an empty leaf, so the recursion unwinds at once (the tree is discarded).
      if (!over_budget()) {
        charge(int64_t(n * sizeof(uint32_t)));
        leaf_refs_.fetch_add(n, std::memory_order_relaxed);
        node->prims.reserve(n);
        for (const Ref& r : refs) node->prims.push_back(r.prim);
      }
      charge(-int64_t(refs.capacity() * sizeof(Ref)));
      std::vector<Ref>().swap(refs);
      if (subtree_min_ > 0 && node->prims.size() > subtree_min_ && !over_budget()) build_subtree(*node);
      return node;
    }
    node->axis = best_axis;
    node->split = best_split;
    int32_t llo[3], lhi[3], rlo[3], rhi[3];
    for (int a = 0; a < 3; ++a) {
      llo[a] = rlo[a] = lo[a];
      lhi[a] = rhi[a] = hi[a];
    }
    lhi[best_axis] = best_split;
    rlo[best_axis] = best_split;
    std::vector<Ref> left, right;
    charge(int64_t((n_left + n_right) * sizeof(Ref)));
    left.reserve(n_left);  // exact upper bounds: clipping can only drop references
    right.reserve(n_right);
    for (const Ref& r : refs) {
      if (r.hi[best_axis] < best_split) {
        left.push_back(r);
      } else if (r.lo[best_axis] >= best_split) {
        right.push_back(r);
      } else {
        Ref c;
        if (clip_range(r.prim, llo, lhi, c)) left.push_back(c);
        if (clip_range(r.prim, rlo, rhi, c)) right.push_back(c);
      }
    }
    charge(-int64_t(refs.capacity() * sizeof(Ref)));
    std::vector<Ref>().swap(refs);
    if (n > kParallelThreshold) {
      tbb::task_group tg;
      tg.run([&] { node->kid[0] = build(std::move(left), llo, lhi, depth + 1); });
      node->kid[1] = build(std::move(right), rlo, rhi, depth + 1);
      tg.wait();
    } else {
      node->kid[0] = build(std::move(left), llo, lhi, depth + 1);
      node->kid[1] = build(std::move(right), rlo, rhi, depth + 1);
    }
    return node;
  }

  /// Exact per-cell SAH binning over every interior cell boundary of the node.
  void find_split(const std::vector<Ref>& refs, const int32_t lo[3], const int32_t hi[3], int& best_axis,
                  int32_t& best_split, size_t& best_nl, size_t& best_nr) {
    thread_local std::vector<uint32_t> starts, ends;
    const size_t n = refs.size();
    const double w[3] = {double(hi[0] - lo[0]), double(hi[1] - lo[1]), double(hi[2] - lo[2])};
    const double area = w[0] * w[1] + w[1] * w[2] + w[2] * w[0];
    const double inv_area = 1.0 / area;
    double best_cost = ki_ * double(n);
    uint64_t evals = 0;
    for (int a = 0; a < 3; ++a) {
      const int32_t width = hi[a] - lo[a];
      if (width < 2) continue;
      starts.assign(size_t(width), 0);
      ends.assign(size_t(width), 0);
      for (const Ref& r : refs) {
        ++starts[size_t(r.lo[a] - lo[a])];
        ++ends[size_t(r.hi[a] - lo[a])];
      }
      const double wb = w[(a + 1) % 3], wc = w[(a + 2) % 3];
      const double cross = wb * wc, perim = wb + wc;
      size_t nl = 0, nr = n;
      for (int32_t j = 1; j < width; ++j) {
        nl += starts[size_t(j - 1)];
        nr -= ends[size_t(j - 1)];
        const double al = double(j) * perim + cross, ar = double(width - j) * perim + cross;
        double cost = kt_ + ki_ * (al * double(nl) + ar * double(nr)) * inv_area;
        if (nl == 0 || nr == 0) cost *= 1.0 - bonus_;
        if (cost < best_cost) {
          best_cost = cost;
          best_axis = a;
          best_split = lo[a] + j;
          best_nl = nl;
          best_nr = nr;
        }
      }
      evals += uint64_t(width - 1);
    }
    evals_.fetch_add(evals, std::memory_order_relaxed);
  }

  const Mesh& mesh_;
  double origin_[3];
  double inv_cell_, cell_;
  KdSubtreeBuilder kd_, kd_deep_;  ///< leaf subtrees of kSubMaxDepth levels, and above kSubDeepMin
  const CancelToken* cancel_;       ///< polled once per node
  int32_t dims_[3];
  double kt_, ki_, bonus_;
  uint32_t subtree_min_ = 0;
  int max_depth_;
  std::atomic<uint64_t> evals_{0};
  int64_t budget_ = 0;
  std::atomic<int64_t> live_{0}, peak_{0};
  std::atomic<bool> over_{false};
  std::atomic<uint64_t> leaf_refs_{0}, nodes_made_{0};
};

void dims_for(const double ext[3], double cell, double out[3]) {
  for (int a = 0; a < 3; ++a) out[a] = std::max(1.0, std::ceil(ext[a] / cell));
}

/// The scene box's low corner and extent, over the triangles' vertices (a point at 0 without
/// triangles).
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

/// The auto rule of hybrid.h ("Auto cell size"); `rule` describes each step taken.
double auto_cell(const Mesh& mesh, const BuildParams& params, const double ext[3], uint64_t budget,
                 std::string& rule) {
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
  rule = fmt("p%g", params.cell_percentile);
  rule += " of triangle extents = " + fmt("%.6g", c);
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
      rule += "; lowered to " + fmt("%.6g", c) + " for >= " + fmt("%g", kHybridAutoCellsPerTriangle) +
              " cells per triangle";
    }
  }
  if (!(c > 0.0)) {
    c = 1.0;
    rule += "; degenerate scene, using 1";
  }
  const double axis_floor = max_ext / double(kHybridAutoMaxAxisCells);
  if (c < axis_floor) {
    c = axis_floor;
    rule += "; raised to " + fmt("%.6g", c) + " for <= " + std::to_string(kHybridAutoMaxAxisCells) +
            " cells per axis";
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
  if (raised) rule += "; raised to " + fmt("%.6g", c) + " for <= " + fmt("%.0f", limit) + " cells";
  return c;
}

/// The cell size a build uses: params.cell_size, or the auto rule.
double resolve_cell(const Mesh& mesh, const BuildParams& params, const double ext[3], uint64_t budget,
                    std::string& rule) {
  if (params.cell_size > 0.0f) {
    rule = "explicit";
    // A cell larger than the scene is one cell of the scene's size: the same single cell,
    // but a grid box reaching far beyond the scene would widen the walk's rounding bound
    // (KdRay::err grows with the box's coordinates) until every ray crossed every node of the
    // cell's subtree (a cell of 1e9 on the bunny: 108,828 triangle tests for one ray).
    const double max_ext = std::max({ext[0], ext[1], ext[2]});
    if (double(params.cell_size) > max_ext && max_ext > 0.0) {
      rule += fmt(" %g", params.cell_size);
      rule += ", larger than the scene: one cell of its extent ";
      rule += fmt("%.6g", max_ext);
      return max_ext;
    }
    return double(params.cell_size);
  }
  return auto_cell(mesh, params, ext, budget, rule);
}

}  // namespace

// ---- estimate ---------------------------------------------------------------------------

namespace {

/// The estimate's figures at cell size `c` (HybridEstimate's fields but the cell choice);
/// `cell_seconds` is the part of the time that the cell size adds (the matrix, the binning),
/// which the time limit bounds: the triangles' part is the same at any size.
struct EstimateAt {
  double dims[3], cells, bytes, structure_bytes, seconds, cell_seconds;
  bool fits;
};

EstimateAt estimate_at(double c, const double ext[3], double ntri, double area, const BuildParams& p,
                       uint64_t budget, int threads) {
  EstimateAt e{};
  dims_for(ext, c, e.dims);
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
    const double bricks = std::min(kHybridBricksPerArea * area / (16.0 * c * c), e.cells / 64.0 * 64.0 / 63.0);
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
  const double expand = p.hybrid_expand_empty && sat <= double(Hybrid::kMaxExpandEntries) ? sat * 4.0 : 0.0;
  e.structure_bytes = matrix + ntri * kHybridBytesPerTriangle;
  e.bytes = e.structure_bytes + 8.0 * axis_sum * threads + expand;
  e.cell_seconds = (matrix_ops + bins) * kHybridSecondsPerBinOp / threads;
  e.seconds = e.cell_seconds + ntri * kHybridSecondsPerTriangle / threads;
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
  if (s < 120.0) return fmt("about %.0f s", s);
  if (s < 7200.0) return fmt("about %.0f min", s / 60.0);
  return fmt("about %.3g hours", s / 3600.0);
}

}  // namespace

std::string HybridEstimate::refusal() const {
  const HybridEstimate& e = *this;
  std::string why;
  if (e.bytes > double(e.budget)) why = "above the memory budget of " + format_bytes_iec(double(e.budget));
  const double max_axis = std::max({e.dims[0], e.dims[1], e.dims[2]});
  if (max_axis > double(kHybridMaxAxisCells))
    why += std::string(why.empty() ? "" : ", and ") + "more than " + std::to_string(kHybridMaxAxisCells) +
           " cells per axis";
  if (why.empty())
    why = "longer than the limit of " + fmt("%g", e.seconds_limit) +
          " s (--hybrid-max-build-seconds; the memory budget is " + format_bytes_iec(double(e.budget)) + ")";
  std::string fix;
  if (e.suggested_cell > 0.0) {
    fix = "use a cell size of at least " + fmt("%.2g", e.suggested_cell) + " (" + fmt("%.3g", e.suggested_cell / e.auto_cell) +
          "x auto)";
  } else {
    fix = "even one cell does not fit: raise --memory-budget-mb";
  }
  return "hybrid: cell size " + fmt("%g", e.cell) + " gives " + e.describe() + ", " + why + ": " + fix +
         ", or 'auto' (" + fmt("%.4g", e.auto_cell) + ")";
}

std::string HybridEstimate::describe() const {
  char grid[96];
  std::snprintf(grid, sizeof grid, "a %.0fx%.0fx%.0f grid (%.3g cells)", dims[0], dims[1], dims[2], cells);
  return std::string(grid) + ", about " + format_bytes_iec(bytes) + " and " + seconds_str(seconds) + " to build";
}

HybridEstimate Hybrid::estimate(const Mesh& mesh, const BuildParams& params) {
  if (std::isnan(params.cell_size) || std::isinf(params.cell_size))
    throw ParamError("hybrid: cell_size " + fmt("%g", params.cell_size) + " is not a finite number");
  HybridEstimate e;
  e.budget = effective_memory_budget(params);
  e.seconds_limit = params.hybrid_max_build_seconds;
  const int threads = effective_threads(params.threads);
  double origin[3], ext[3];
  scene_box(mesh, origin, ext);
  std::string auto_rule;
  e.auto_cell = auto_cell(mesh, params, ext, e.budget, auto_rule);
  e.cell = resolve_cell(mesh, params, ext, e.budget, e.rule);
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
      area += std::min(cap, 0.5 * std::sqrt(double(nv.x) * nv.x + double(nv.y) * nv.y + double(nv.z) * nv.z));
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
        (estimate_at(std::exp(mid), ext, ntri, area, params, e.budget, threads).fits ? hi : lo) = mid;
      }
      e.suggested_cell = round_up_2(std::exp(hi));
    }
  }
  return e;
}

// ---- build ------------------------------------------------------------------------------

BuildStats Hybrid::build(const Mesh& mesh, const BuildParams& params) {
  const auto t_start = std::chrono::steady_clock::now();
  // Validate parameters before touching any state.
  if (std::isnan(params.cell_size) || std::isinf(params.cell_size))
    throw ParamError("hybrid: cell_size " + fmt("%g", params.cell_size) +
                     " is not a finite number: give a positive size in scene units, or 0 "
                     "(--cell-size auto) for the percentile rule");
  if (!(params.cell_percentile > 0.0f && params.cell_percentile <= 100.0f))
    throw ParamError("hybrid: cell_percentile " + fmt("%g", params.cell_percentile) +
                     " is out of range: give a value in (0, 100], e.g. 90");
  if (!(params.hybrid_traversal_cost > 0.0f) || !std::isfinite(params.hybrid_traversal_cost) ||
      !(params.hybrid_intersection_cost > 0.0f) || !std::isfinite(params.hybrid_intersection_cost))
    throw ParamError("hybrid: hybrid_traversal_cost and hybrid_intersection_cost must be positive "
                     "finite numbers, e.g. 1 and 1.5");
  const size_t ntri = mesh.num_triangles();
  for (size_t i = 0; i < ntri; ++i)
    for (uint32_t v : mesh.triangles[i])
      if (v >= mesh.positions.size() || !is_finite(mesh.positions[v]))
        throw ParamError("hybrid: triangle " + std::to_string(i) +
                         " has an out-of-range or non-finite vertex: validate the mesh first");

  // Memory guard before any allocation: what the build needs at least, whatever the scene —
  // the root's reference list and its children's at the first split (28 bytes per
  // reference), then at least one reference and the corners and id of every triangle. How many
  // references a triangle ends in depends on the scene (2.9 on the 1M landscape and the
  // dragon, 1.2 on the 10M landscape, hundreds for long thin triangles), so the kd build
  // keeps a running account (TreeBuilder::charge), the exact reference count is checked
  // before the per-reference arrays are allocated, and the matrices are checked once the grid
  // is known.
  uint64_t estimate = 0;
  {
    const double nt = double(ntri);
    estimate = check_memory_budget(
        "hybrid", ntri,
        {{"reference lists of the first split (at least)", 2.0 * nt * sizeof(Ref)},
         {"references, triangle corners and ids (at least one of each per triangle)",
          nt * (2 * sizeof(uint32_t) + sizeof(TriVerts))},
         {"leaf subtrees' classification flags (a byte per triangle per thread)",
          params.hybrid_subtree_min > 0 ? nt * double(effective_threads(params.threads)) : 0.0}},
        params,
        "fewer, larger leaves need less: a larger --cell-size (or --cell-percentile), or a "
        "lower kd_max_depth");
  }
  mesh_ = &mesh;
  test_ = params.triangle_test;
  next_leaf_cache_ = params.hybrid_guess;
  nodes_.clear();
  leaves_.clear();
  kd_boxes_.clear();
  leaf_depth_.clear();
  refs_.clear();
  sub_nodes_.clear();
  tris_.clear();
  prim_of_.clear();
  map_.reset(params.hybrid_dense_matrix);
  step_errors_.store(0);
  {
    static std::atomic<uint64_t> builds{0};
    uid_ = ++builds;
  }
  stats_ = {};
  stats_.peak_estimate = estimate;

  const uint64_t budget = effective_memory_budget(params);
  const int threads = effective_threads(params.threads);

  double ext[3];
  scene_box(mesh, origin_, ext);

  // ---- cell size ----
  std::string rule;
  const double cell = resolve_cell(mesh, params, ext, budget, rule);
  if (params.cell_size > 0.0f) {
    // An explicit size: refused before anything is allocated when its estimate does not fit.
    const HybridEstimate est = Hybrid::estimate(mesh, params);
    if (!est.fits) throw ParamError(est.refusal());
  }
  cell_ = cell;
  inv_cell_ = 1.0 / cell;

  // ---- memory guard before any allocation ----
  double d[3];
  dims_for(ext, cell, d);
  const double cells = d[0] * d[1] * d[2];
  const double max_axis = std::max({d[0], d[1], d[2]});
  auto dims_text = [&] { return fmt("%.0f", d[0]) + "x" + fmt("%.0f", d[1]) + "x" + fmt("%.0f", d[2]); };
  const double tri_bytes = double(ntri) * (sizeof(TriVerts) + 4 * sizeof(uint32_t));
  if (map_.dense()) {
    const double need = cells * 4.0 + tri_bytes;
    if (need > double(budget) || max_axis > double(kHybridMaxAxisCells)) {
      const double fit = cell * std::max(std::cbrt(need / double(budget)), max_axis / double(kHybridMaxAxisCells)) * 1.05;
      throw ParamError("hybrid: cell size " + fmt("%g", cell) + " gives a " + dims_text() +
                       " grid whose dense matrix needs " + bytes_str(need) + ", above the memory budget of " +
                       bytes_str(double(budget)) + ": use a cell size of at least " + fmt("%.3g", fit) +
                       ", 'auto', or the default bricked storage");
    }
  } else {
    // The bricked matrix is guarded while it is built; before that, the build bins every
    // node per cell along each axis (2 x 4 bytes per cell per axis per thread).
    const double need = 8.0 * (d[0] + d[1] + d[2]) * double(threads) + tri_bytes;
    if (need > double(budget) || max_axis > double(kHybridMaxAxisCells)) {
      const double fit =
          cell * std::max(need / double(budget), max_axis / double(kHybridMaxAxisCells)) * 1.05;
      throw ParamError("hybrid: cell size " + fmt("%g", cell) + " gives a " + dims_text() +
                       " grid; building it needs at least " + bytes_str(need) +
                       " (per-cell binning arrays) and at most " + std::to_string(kHybridMaxAxisCells) +
                       " cells per axis are supported (memory budget " + bytes_str(double(budget)) +
                       "): use a cell size of at least " + fmt("%.3g", fit) + " or 'auto'");
    }
  }
  for (int a = 0; a < 3; ++a) dims_[a] = int32_t(d[a]);
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
      wbox_.lo[a] = next_float_down(float(origin_[a] - widen));
      wbox_.hi[a] = next_float_up(float(origin_[a] + double(dims_[a]) * cell + widen));
    }
    max_abs_ = std::max(max_component(abs(wbox_.lo)), max_component(abs(wbox_.hi)));
    wclip_.set(wbox_);
  }
  max_steps_ = uint64_t(dims_[0]) + uint64_t(dims_[1]) + uint64_t(dims_[2]) + 1;
  origin4_ = Double4{origin_[0], origin_[1], origin_[2], 0.0};
  top4_ = Double4{double(dims_[0] - 1), double(dims_[1] - 1), double(dims_[2] - 1), 0.0};
  map_.set_grid(dims_);

  double t_tree = 0, t_matrix = 0, t_expand = 0;
  std::string expand_text;
  tbb::task_arena arena(threads);
  arena.execute([&] {
    const auto t0 = std::chrono::steady_clock::now();
    build_tree(mesh, params);
    check_cancel(params.cancel);
    // Local triangle ids in first-reference order (leaves are numbered depth-first).
    std::vector<uint32_t> local_of(ntri, kInvalidPrim);
    prim_of_.clear();
    prim_of_.reserve(ntri);
    for (uint32_t& r : refs_) {
      uint32_t& l = local_of[r];
      if (l == kInvalidPrim) {
        l = uint32_t(prim_of_.size());
        prim_of_.push_back(r);
      }
      r = l;
    }
    tris_.resize(prim_of_.size());
    tbb::parallel_for(size_t(0), prim_of_.size(), [&](size_t i) {
      const auto c = mesh.corners(prim_of_[i]);
      tris_[i] = {c[0], c[1], c[2]};
    });
    uint64_t other = 0;
    other += nodes_.size() * sizeof(Node) + leaves_.size() * (sizeof(Leaf) + sizeof(CellBox)) + leaf_depth_.size() +
             refs_.size() * 4 + tris_.size() * (sizeof(TriVerts) + 4);
    const auto t1 = std::chrono::steady_clock::now();
    const uint64_t left = budget > other ? budget - other : 0;
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
    expand_text = params.hybrid_expand_empty ? expand_empty_leaves(left > matrix ? left - matrix : 0, params.cancel)
                                             : std::string("off (the paper's kd leaf boxes)");
    t_expand = std::chrono::duration<double>(std::chrono::steady_clock::now() - t2).count();
    t_tree = std::chrono::duration<double>(t1 - t0).count();
    t_matrix = std::chrono::duration<double>(t2 - t1).count();
  });

  // ---- stats ----
  stats_.nodes = nodes_.size();
  stats_.leaves = leaves_.size();
  for (const Leaf& l : leaves_) stats_.empty_leaves += l.count == 0;
  uint64_t subtree_leaves = 0;
  uint32_t largest_leaf = 0;
  for (const Leaf& l : leaves_) {
    subtree_leaves += (l.count & kSubtreeFlag) != 0;
    largest_leaf = std::max(largest_leaf, l.count & ~kSubtreeFlag);
  }
  stats_.references = refs_.size();
  const uint64_t b_tree = nodes_.size() * sizeof(Node);
  const uint64_t b_sub = sub_nodes_.size() * sizeof(KdNode);
  const uint64_t b_leaves = leaves_.size() * (sizeof(Leaf) + 1);  // + depth byte
  const uint64_t b_kd_boxes = kd_boxes_.size() * sizeof(CellBox);
  const uint64_t b_refs = refs_.size() * sizeof(uint32_t);
  const uint64_t b_tris = tris_.size() * (sizeof(TriVerts) + sizeof(uint32_t));
  const uint64_t b_matrix = map_.entries() * sizeof(uint32_t);
  stats_.bytes = b_tree + b_leaves + b_kd_boxes + b_sub + b_refs + b_tris + b_matrix + sizeof(*this);
  stats_.bytes_by_part = {{"tree nodes", b_tree},
                          {"leaves", b_leaves},
                          {"leaf kd boxes", b_kd_boxes},
                          {"leaf subtrees", b_sub},
                          {"references", b_refs},
                          {"triangles (corners + ids)", b_tris},
                          {map_.dense() ? "matrix (dense)" : "matrix (bricked)", b_matrix},
                          {"object", sizeof(*this)}};
  stats_.extra = {{"cell_size", fmt("%.6g", cell_)},
                  {"auto rule", rule},
                  {"grid", std::to_string(dims_[0]) + "x" + std::to_string(dims_[1]) + "x" +
                               std::to_string(dims_[2])},
                  {"matrix", map_.dense() ? "dense" : map_.bricked().describe()},
                  {"leaf subtrees", params.hybrid_subtree_min == 0
                                        ? std::string("off (plain leaves)")
                                        : std::to_string(subtree_leaves) + " leaves with more than " +
                                              std::to_string(params.hybrid_subtree_min) + " triangles, " +
                                              std::to_string(sub_nodes_.size()) + " nodes; largest leaf " +
                                              std::to_string(largest_leaf) + " triangles"},
                  {"empty-leaf boxes", expand_text},
                  {"build phases", "tree " + fmt("%.3f", t_tree) + " s, matrix " + fmt("%.3f", t_matrix) +
                                       " s, empty-leaf boxes " + fmt("%.3f", t_expand) + " s"}};
  stats_.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return stats_;
}

std::string Hybrid::expand_empty_leaves(uint64_t budget, const CancelToken* cancel) {
  const int64_t nx = dims_[0], ny = dims_[1], nz = dims_[2];
  const uint64_t entries = uint64_t(nx + 1) * uint64_t(ny + 1) * uint64_t(nz + 1);
  if (entries > kMaxExpandEntries || entries * sizeof(uint32_t) > budget)
    return "skipped: its table of occupied cells would take " + bytes_str(double(entries) * 4.0) +
           (entries > kMaxExpandEntries ? " (more than " + std::to_string(kMaxExpandEntries) + " cells)"
                                        : ", above the memory left in the budget") +
           "; steps use the kd leaf boxes";
  // sat(x, y, z) = the number of occupied cells (cells of leaves with triangles) in
  // [0, x) x [0, y) x [0, z): any box's count in 8 loads (a summed-volume table).
  const int64_t sx = nx + 1, sxy = (nx + 1) * (ny + 1);
  std::vector<uint32_t> sat(entries, 0);
  auto at = [&](int64_t x, int64_t y, int64_t z) -> uint32_t& { return sat[uint64_t(x + sx * y + sxy * z)]; };
  tbb::parallel_for(size_t(0), leaves_.size(), [&](size_t i) {
    const Leaf& l = leaves_[i];
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
    return int64_t(at(x1, y1, z1)) - at(x0, y1, z1) - at(x1, y0, z1) - at(x1, y1, z0) + at(x0, y0, z1) +
               at(x0, y1, z0) + at(x1, y0, z0) - at(x0, y0, z0) != 0;
  };
  // Each empty leaf's box grows face by face, in rounds, by the most (at most its current
  // extent, so it stays roughly cubic) that keeps it free of occupied cells; binary search
  // per face. Leaves with triangles keep their kd boxes. Read-only table: deterministic.
  std::atomic<uint64_t> widened{0}, cells_before{0}, cells_after{0};
  tbb::parallel_for(tbb::blocked_range<size_t>(0, leaves_.size()), [&](const tbb::blocked_range<size_t>& r) {
    check_cancel(cancel);
    uint64_t w = 0, before = 0, after = 0;
    for (size_t i = r.begin(); i != r.end(); ++i) {
      Leaf& l = leaves_[i];
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
            const int32_t room = up ? dims_[a] - hi[a] : lo[a];
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
      const uint64_t v0 = uint64_t(l.hi[0] - l.lo[0]) * uint64_t(l.hi[1] - l.lo[1]) * uint64_t(l.hi[2] - l.lo[2]);
      const uint64_t v1 = uint64_t(hi[0] - lo[0]) * uint64_t(hi[1] - lo[1]) * uint64_t(hi[2] - lo[2]);
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
  return std::to_string(widened.load()) + " empty leaves widened over empty cells (step boxes hold " +
         fmt("%.2f", double(cells_after.load()) / double(std::max<uint64_t>(1, cells_before.load()))) +
         "x the cells of the kd leaf boxes; table " + bytes_str(double(entries) * 4.0) + ", freed)";
}

void Hybrid::build_tree(const Mesh& mesh, const BuildParams& params) {
  TreeBuilder tb(mesh, origin_, cell_, dims_, params);
  std::unique_ptr<BuildNode> root = tb.build_root();
  stats_.sah_evaluations = tb.sah_evaluations();
  const std::string fix =
      "fewer, larger leaves need less: a larger --cell-size (or --cell-percentile), or a "
      "lower kd_max_depth";
  if (tb.over_budget())
    throw ParamError("hybrid: the kd build outgrew the memory budget of " +
                     format_bytes_iec(double(effective_memory_budget(params))) +
                     " (its account reached " + format_bytes_iec(double(tb.peak_bytes())) +
                     " after " + std::to_string(tb.nodes_made()) + " nodes over " +
                     std::to_string(mesh.num_triangles()) + " triangles; the estimate before "
                     "building was " + format_bytes_iec(double(stats_.peak_estimate)) +
                     "): triangles straddling many cells are referenced by every leaf they "
                     "cross; " + fix + ", or raise --memory-budget-mb (0 = half of physical "
                     "memory) if the machine has the memory");
  // Exact now: the references are counted (leaf subtrees add a few). Flattening copies them
  // while the build tree is alive, then the triangle corners replace the build tree.
  const double refs = double(tb.leaf_refs()), nodes = double(tb.nodes_made());
  const double flat = nodes * sizeof(Node) + (nodes + 1) / 2 * (sizeof(Leaf) + 1);
  check_memory_budget("hybrid", mesh.num_triangles(),
                      {{"build tree", double(tb.live_bytes())},
                       {"references", refs * sizeof(uint32_t)},
                       {"nodes and leaves", flat}},
                      params, fix);
  check_memory_budget("hybrid", mesh.num_triangles(),
                      {{"references", refs * sizeof(uint32_t)},
                       {"triangle corners and ids", double(mesh.num_triangles()) * (sizeof(TriVerts) + 4)},
                       {"nodes and leaves", flat}},
                      params, fix);
  nodes_.reserve(size_t(nodes));
  leaves_.reserve(size_t(nodes + 1) / 2);
  leaf_depth_.reserve(size_t(nodes + 1) / 2);
  refs_.reserve(size_t(refs));
  // Flatten depth-first: left child follows its parent, leaves numbered in that order.
  uint32_t max_depth = 0;
  auto flatten = [&](auto&& self, BuildNode* n) -> void {
    const size_t idx = nodes_.size();
    nodes_.push_back({});
    max_depth = std::max(max_depth, uint32_t(n->depth));
    if (n->axis < 0) {
      Leaf l{};
      for (int a = 0; a < 3; ++a) {
        l.lo[a] = n->lo[a];
        l.hi[a] = n->hi[a];
      }
      l.first = uint32_t(refs_.size());
      l.count = uint32_t(n->prims.size());
      if (!n->sub_nodes.empty()) {
        // Relocate the subtree: child and reference indices are local to the leaf.
        const uint32_t base = uint32_t(sub_nodes_.size()), ref_base = uint32_t(refs_.size());
        if (refs_.size() + n->sub_refs.size() >= (uint64_t(1) << 30) ||
            sub_nodes_.size() + n->sub_nodes.size() >= (uint64_t(1) << 29))
          throw ParamError("hybrid: more than 2^30 subtree references or 2^29 nodes: use a larger cell size "
                           "or --hybrid-subtree 0");
        for (size_t k = 0; k < n->sub_nodes.size(); ++k) {
          KdNode kn = n->sub_nodes[k];
          if (k < kSubBoxNodes) {
          } else if (kn.leaf()) {
            kn.prim_offset += ref_base;
          } else {
            kn.bits = ((kn.above() + base + kSubBoxNodes) << 2) | uint32_t(kn.axis());
          }
          sub_nodes_.push_back(kn);
        }
        refs_.insert(refs_.end(), n->sub_refs.begin(), n->sub_refs.end());
        l.first = base;
        l.count |= kSubtreeFlag;
      } else {
        refs_.insert(refs_.end(), n->prims.begin(), n->prims.end());
      }
      nodes_[idx] = {int32_t(leaves_.size()), 0, 3};
      leaves_.push_back(l);
      leaf_depth_.push_back(uint8_t(std::min(n->depth, 255)));
      return;
    }
    self(self, n->kid[0].get());
    nodes_[idx] = {n->split, uint32_t(nodes_.size()), uint32_t(n->axis)};
    self(self, n->kid[1].get());
  };
  flatten(flatten, root.get());
  stats_.max_depth = max_depth;
}

uint64_t Hybrid::matrix_bytes(bool dense) const {
  if (dense) return hybrid::DenseCellMap::bytes_for(dims_);
  return map_.bricked().bytes(nodes_);
}

// ---- walks ------------------------------------------------------------------------------

Box3 Hybrid::leaf_box(uint32_t leaf) const {
  const Leaf& l = leaves_[leaf];
  Box3 b;
  for (int a = 0; a < 3; ++a) {
    b.lo[a] = float(origin_[a] + l.lo[a] * cell_);
    b.hi[a] = float(origin_[a] + l.hi[a] * cell_);
  }
  return b;
}

void Hybrid::for_each_split(const std::function<void(const SplitPlane&)>& fn) const {
  if (nodes_.empty()) return;
  struct Item {
    uint32_t node;
    int32_t lo[3], hi[3];
    int depth;
  };
  std::vector<Item> stack;
  stack.push_back({0, {0, 0, 0}, {dims_[0], dims_[1], dims_[2]}, 0});
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    const Node& n = nodes_[it.node];
    if (n.axis == 3) continue;
    SplitPlane sp;
    sp.axis = int(n.axis);
    sp.position = float(origin_[n.axis] + double(n.split) * cell_);
    for (int a = 0; a < 3; ++a) {
      sp.node_box.lo[a] = float(origin_[a] + double(it.lo[a]) * cell_);
      sp.node_box.hi[a] = float(origin_[a] + double(it.hi[a]) * cell_);
    }
    sp.depth = it.depth;
    fn(sp);
    Item l = it, r = it;
    l.node = it.node + 1;
    l.hi[n.axis] = n.split;
    r.node = n.right;
    r.lo[n.axis] = n.split;
    l.depth = r.depth = it.depth + 1;
    stack.push_back(r);  // left popped first: depth-first, left before right
    stack.push_back(l);
  }
}

void Hybrid::for_each_box(const std::function<void(const StructureBox&)>& fn) const {
  for (uint32_t i = 0; i < leaves_.size(); ++i)
    if (leaves_[i].count) fn({leaf_box(i), int(leaf_depth_[i]), true, leaves_[i].count & ~kSubtreeFlag});
}

}  // namespace kdgrid
