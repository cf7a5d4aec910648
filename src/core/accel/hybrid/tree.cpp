// The hybrid's tree: an SAH kd-tree whose split planes lie on cell boundaries (docs/HYBRID.md,
// "The structure"), built over clipped triangle references, then flattened into the
// structure's nodes, leaves and references (GridKdHybrid::build_tree).
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "accel/guards.h"
#include "accel/hybrid/build.h"
#include "accel/hybrid/hybrid.h"
#include "accel/kdtree.h"
#include "util/cancel.h"
#include "util/error.h"
#include "util/memory.h"

namespace kdgrid {

namespace {

using hybrid::Ref;

/// The leaf subtrees' SAH cost of a leaf per triangle, on top of its groups (KdSubtreeBuilder;
/// the top level's is GridKdHybrid::kWideLaneCost): 0, leaves costed by their groups alone.
/// GridKdHybrid::kWideLaneCost there too makes the subtrees larger for no speed
/// (docs/EXPERIMENTS.md, "Wide leaves").
constexpr float kSubtreeLaneCost = 0.0f;

/// The triangles of a leaf's list among which each lane of a shared-corner group is chosen
/// (TreeFlattener::plan_groups): 32 for groups of 8 (16 corners), whose lanes it gives 7%
/// fewer corners; 1 (the leaf's order) for groups of 16 (32 corners), which hold about one
/// corner a lane already and would gain 1-2% of their bytes for a tenth more build time
/// (docs/EXPERIMENTS.md, "Memory").
constexpr uint32_t kGroupWindow = kWideLanes == 8 ? 32 : 1;

/// Nodes with more references than this build their children as parallel tasks.
constexpr size_t kParallelThreshold = 2048;

struct BuildNode {
  int axis = -1;  ///< -1 leaf
  int32_t split = 0;
  int32_t lo[3], hi[3];
  int depth = 0;
  std::unique_ptr<BuildNode> kid[2];
  std::vector<uint32_t> prims;
  std::vector<KdNode>
      sub_nodes;  ///< leaf subtree: its box (GridKdHybrid::kSubBoxNodes), then its nodes
  std::vector<uint32_t> sub_refs;  ///< its references (mesh triangle ids)
};

struct P3 {
  double v[3];
};

class TreeBuilder {
 public:
  /// `limit`: the bytes the account stops the build at (its peak bound).
  TreeBuilder(const Mesh& mesh, const double origin[3], double cell, const int32_t dims[3],
              const BuildParams& p, uint64_t limit)
      : mesh_(mesh),
        inv_cell_(1.0 / cell),
        cell_(cell),
        kd_(mesh, p, GridKdHybrid::kSubMaxDepth, kWideLanes, kSubtreeLaneCost, &account_),
        kd_deep_(mesh, p, KdTree::kMaxDepth, kWideLanes, kSubtreeLaneCost, &account_),
        cancel_(p.cancel),
        account_(limit) {
    for (int a = 0; a < 3; ++a) {
      origin_[a] = origin[a];
      dims_[a] = dims[a];
    }
    kt_ = p.hybrid_traversal_cost;
    ki_ = p.hybrid_intersection_cost;
    bonus_ = std::clamp(double(p.kd_empty_bonus), 0.0, 1.0);
    subtree_min_ = p.hybrid_subtree_min;
    max_depth_ = top_max_depth(p, double(mesh.num_triangles()));
  }

  /// The top tree's depth limit over n triangles.
  static int top_max_depth(const BuildParams& p, double n) {
    const int d =
        p.kd_max_depth > 0 ? p.kd_max_depth : int(8.0 + 1.3 * std::log2(std::max(1.0, n)));
    return std::clamp(d, 1, 64);
  }

  /// Running account of the build's memory (reference lists alive in the recursion, build
  /// nodes and their leaf lists, the leaf subtrees' event lists). Straddling triangles are
  /// clipped into both children, so scenes of long thin triangles multiply references with
  /// depth; past the limit every pending node becomes an empty leaf and GridKdHybrid::build
  /// throws instead of exhausting RAM.
  void charge(int64_t bytes) { account_.charge(bytes); }
  bool over_budget() const { return account_.over_budget(); }
  int64_t live_bytes() const { return account_.live_bytes(); }
  int64_t peak_bytes() const { return account_.peak_bytes(); }
  uint64_t leaf_refs() const { return leaf_refs_.load(); }
  uint64_t nodes_made() const { return nodes_made_.load(); }

  std::unique_ptr<BuildNode> build_root() {
    const size_t n = mesh_.num_triangles();
    charge(int64_t(n * sizeof(Ref)));
    std::vector<Ref> refs(n);
    const int32_t lo[3] = {0, 0, 0};
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<size_t>& r) {
                        for (size_t i = r.begin(); i < r.end(); ++i)
                          clip_range(uint32_t(i), lo, dims_, refs[i]);
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
  bool clip_bounds(uint32_t prim, const double lo[3], const double hi[3], double bl[3],
                   double bh[3]) const {
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
    constexpr double eps = GridKdHybrid::kRangeEps;
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
      const double l = origin_[a] + double(node.lo[a]) * cell_,
                   h = origin_[a] + double(node.hi[a]) * cell_;
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
    const KdSubtreeBuilder& kd = node.prims.size() > GridKdHybrid::kSubDeepMin ? kd_deep_ : kd_;
    kd.build(node.prims, box, nodes, node.sub_refs, bounds);
    const float f[8] = {bounds.lo.x, bounds.lo.y, bounds.lo.z, -kInf,
                        bounds.hi.x, bounds.hi.y, bounds.hi.z, kInf};
    static_assert(sizeof f == GridKdHybrid::kSubBoxNodes * sizeof(KdNode));
    node.sub_nodes.resize(GridKdHybrid::kSubBoxNodes + nodes.size());
    std::memcpy(node.sub_nodes.data(), f, sizeof f);
    std::copy(nodes.begin(), nodes.end(), node.sub_nodes.begin() + GridKdHybrid::kSubBoxNodes);
    charge(
        int64_t(node.sub_nodes.size() * sizeof(KdNode) + node.sub_refs.size() * sizeof(uint32_t)));
    // The leaf's references are the subtree's (leaf_refs() counts what flattening copies).
    leaf_refs_.fetch_add(uint64_t(node.sub_refs.size()) - uint64_t(node.prims.size()),
                         std::memory_order_relaxed);
  }

  std::unique_ptr<BuildNode> build(std::vector<Ref>&& refs, const int32_t lo[3],
                                   const int32_t hi[3], int depth) {
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
      if (subtree_min_ > 0 && node->prims.size() > subtree_min_ && !over_budget())
        build_subtree(*node);
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
      // parallel_invoke, not a task_group: see the BVH builder (both halves may throw a cancel).
      tbb::parallel_invoke([&] { node->kid[0] = build(std::move(left), llo, lhi, depth + 1); },
                           [&] { node->kid[1] = build(std::move(right), rlo, rhi, depth + 1); });
    } else {
      node->kid[0] = build(std::move(left), llo, lhi, depth + 1);
      node->kid[1] = build(std::move(right), rlo, rhi, depth + 1);
    }
    return node;
  }

  /// Exact per-cell SAH binning over every interior cell boundary of the node.
  void find_split(const std::vector<Ref>& refs, const int32_t lo[3], const int32_t hi[3],
                  int& best_axis, int32_t& best_split, size_t& best_nl, size_t& best_nr) {
    thread_local std::vector<uint32_t> starts, ends;
    const size_t n = refs.size();
    const double w[3] = {double(hi[0] - lo[0]), double(hi[1] - lo[1]), double(hi[2] - lo[2])};
    const double area = w[0] * w[1] + w[1] * w[2] + w[2] * w[0];
    const double inv_area = 1.0 / area;
    // A leaf costs a test per group of kWideLanes triangles (they are tested together) and
    // kWideLaneCost per triangle.
    auto tests = [](size_t k) {
      return double((k + kWideLanes - 1) / kWideLanes) + GridKdHybrid::kWideLaneCost * double(k);
    };
    double best_cost = ki_ * tests(n);
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
        double cost = kt_ + ki_ * (al * tests(nl) + ar * tests(nr)) * inv_area;
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
  const CancelToken* cancel_;      ///< polled once per node
  int32_t dims_[3];
  double kt_, ki_, bonus_;
  uint32_t subtree_min_ = 0;
  int max_depth_;
  std::atomic<uint64_t> evals_{0};
  MemoryAccount account_;
  std::atomic<uint64_t> leaf_refs_{0}, nodes_made_{0};
};

}  // namespace

double hybrid::worst_case_bytes(const Mesh& mesh, const double origin[3], double cell,
                                const double d[3], const BuildParams& params, int threads) {
  const size_t n = mesh.num_triangles();
  const double cells = d[0] * d[1] * d[2], inv = 1.0 / cell, eps = GridKdHybrid::kRangeEps;
  double refs = 0;  // the top tree's references: each triangle's cell count (clip_range's range)
  for (size_t i = 0; i < n; ++i) {
    const auto c = mesh.corners(i);
    double count = 1;
    for (int a = 0; a < 3; ++a) {
      double lo = kInf, hi = -kInf;
      for (int k = 0; k < 3; ++k) {
        const double g = (double(c[k][a]) - origin[a]) * inv;
        lo = std::min(lo, g);
        hi = std::max(hi, g);
      }
      const double top = d[a] - 1;
      count *= std::clamp(std::floor(hi + eps), 0.0, top) -
               std::clamp(std::floor(lo - eps), 0.0, top) + 1.0;
    }
    refs += std::min(count, cells);
  }
  const double nt = double(n);
  const double leaves = std::min(cells, std::ldexp(1.0, TreeBuilder::top_max_depth(params, nt)));
  refs = std::min(refs, leaves * nt);  // a leaf holds each triangle at most once
  // The lists of pending nodes and of the nodes being split lie in disjoint boxes: at most the
  // references twice over, with the leaves' lists, the build nodes and the binning arrays.
  double top = 2.0 * refs * sizeof(Ref) + refs * sizeof(uint32_t) +
               2.0 * leaves * sizeof(BuildNode) + 8.0 * (d[0] + d[1] + d[2]) * threads;
  double final_refs = refs, final_leaves = leaves;
  if (params.hybrid_subtree_min > 0) {
    const int rule = int(std::lround(8.0 + 1.3 * std::log2(std::max(1.0, nt))));
    const int depth = std::max(
        1, std::min(nt > GridKdHybrid::kSubDeepMin ? KdTree::kMaxDepth : GridKdHybrid::kSubMaxDepth,
                    rule));
    const double grow = std::ldexp(1.0, depth);
    final_refs = refs * grow;
    final_leaves = leaves * grow;
    // The subtrees' builds (their lists, trees and flags) and the subtrees the leaves keep.
    top += kd_build_worst_case_bytes(refs, depth, threads) +
           5.0 * leaves * 2.0 * grow * sizeof(KdNode) + nt * threads +
           final_refs * sizeof(uint32_t) +
           (2.0 * final_leaves + leaves * GridKdHybrid::kSubBoxNodes) * sizeof(KdNode);
  }
  // Flattening: each reference a lane (leaves pad their last group), planned, listed and
  // grouped while the build tree is alive; the nodes, leaves, subtrees and flat subtrees.
  const double lanes = final_refs + (final_leaves + leaves) * double(kWideLanes - 1);
  const double flat =
      lanes * (sizeof(uint32_t) + 6.0 + 4.0 * hybrid::kGroupLaneFloatsAtMost + 32.0) +
      2.0 * (final_leaves + leaves) * sizeof(GridKdHybrid::Node) +
      (final_leaves + leaves) * (sizeof(GridKdHybrid::Leaf) + 1 + sizeof(GridKdHybrid::KdBox)) +
      (2.0 * final_leaves + leaves * GridKdHybrid::kSubBoxNodes) * sizeof(KdNode) +
      leaves * 4.0 * (16.0 + hybrid::flat_subtree_floats(hybrid::kFlatLeaves));
  // The cell map: 4 bytes a cell dense; bricked, at most one brick per block of each level
  // and the top table.
  double matrix = cells * 4.0;
  if (!params.hybrid_dense_matrix) {
    matrix = 0;  // each level's blocks, the top table's entries among them
    for (double side = hybrid::BrickedCellMap::kBrickSide;;
         side *= hybrid::BrickedCellMap::kBrickSide) {
      const double blocks =
          std::ceil(d[0] / side) * std::ceil(d[1] / side) * std::ceil(d[2] / side);
      matrix += blocks * (hybrid::BrickedCellMap::kBrickEntries + 1) * 4.0;
      if (blocks <= 1) break;
    }
  }
  const double sat = (d[0] + 1) * (d[1] + 1) * (d[2] + 1);
  const double expand = params.hybrid_expand_empty && sat <= double(GridKdHybrid::kMaxExpandEntries)
                            ? 2.0 * sat * 4.0
                            : 0.0;
  // Twice the sum: the parts overlap in time only partly, and vectors keep slack.
  return 2.0 * (top + flat + matrix + expand);
}

namespace {

/// The kd build's account checked against its peak bound, then the flattening's exact needs
/// (the references are counted now; leaf subtrees add a few): each reference becomes a lane of
/// a triangle group, and each leaf pads its last group (at most kWideLanes - 1 lanes a leaf).
/// Flattening lists the lanes while the build tree is alive, then the groups replace both; the
/// group plan (group_plan_bytes a group) lives through both. Updates stats' account; returns the
/// build tree's node count.
double check_flatten_memory(const TreeBuilder& tb, const Mesh& mesh, const BuildParams& params,
                            double group_plan_bytes, BuildStats& stats) {
  const std::string fix =
      "fewer, larger leaves need less: a larger --cell-size (or --cell-percentile), or a "
      "lower kd_max_depth";
  stats.peak_accounted = uint64_t(std::max<int64_t>(0, tb.peak_bytes()));
  if (tb.over_budget())
    throw ParamError("hybrid: the kd build outgrew its peak bound of " +
                     format_bytes_iec(double(stats.peak_estimate)) + " (the memory budget of " +
                     format_bytes_iec(double(effective_memory_budget(params))) +
                     ", or less: the most this grid and the depth limits can need; its account "
                     "reached " +
                     format_bytes_iec(double(tb.peak_bytes())) + " after " +
                     std::to_string(tb.nodes_made()) + " nodes over " +
                     std::to_string(mesh.num_triangles()) + " triangles; a typical scene needs " +
                     format_bytes_iec(double(stats.peak_expected)) +
                     "): triangles straddling many cells are referenced by every leaf they "
                     "cross; " +
                     fix +
                     ", or raise --memory-budget-mb (0 = half of physical "
                     "memory) if the machine has the memory");
  const double refs = double(tb.leaf_refs()), nodes = double(tb.nodes_made());
  const double flat =
      nodes * sizeof(GridKdHybrid::Node) + (nodes + 1) / 2 * (sizeof(GridKdHybrid::Leaf) + 1);
  const double lane_count = refs + (nodes + 1) / 2 * double(kWideLanes - 1);
  // A lane's mesh index, and with shared corners its three corner indices (planned, then listed).
  const double lane_bytes = sizeof(uint32_t) + (hybrid::kSharedCorners ? 6 : 0);
  // The group plan's record of each group (first lane, float offset, fill, corners, narrow ids):
  // the references in full groups, and each leaf's last.
  const double groups = refs / hybrid::kFullGroupLanesAtLeast + (nodes + 1) / 2;
  const double group_plan = groups * group_plan_bytes;
  // Checked against the build's peak bound (at most the budget).
  BuildParams bounded = params;
  bounded.memory_budget = stats.peak_estimate;
  const uint64_t listed = check_memory_budget("hybrid", mesh.num_triangles(),
                                              {{"build tree", double(tb.live_bytes())},
                                               {"references", lane_count * lane_bytes},
                                               {"group plan", group_plan},
                                               {"nodes and leaves", flat}},
                                              bounded, fix);
  const uint64_t grouped = check_memory_budget(
      "hybrid", mesh.num_triangles(),
      {{"references", lane_count * lane_bytes},
       {"group plan", group_plan},
       {"triangle groups", lane_count * hybrid::kGroupLaneFloatsAtMost * sizeof(float)},
       {"nodes and leaves", flat}},
      bounded, fix);
  stats.peak_accounted = std::max({stats.peak_accounted, listed, grouped});
  return nodes;
}

/// A leaf's planned groups (shared corners): per group its lanes and distinct corners, and
/// three corner indices a lane.
struct LeafGroups {
  std::vector<uint8_t> fill, corners, index;
};

/// A flat subtree's leaf with triangles, with its kd box within the subtree's box.
struct FlatLeaf {
  const KdNode* node;
  Box3 box;
};

}  // namespace

/// Flattens the build tree into the structure's nodes, leaves, leaf subtrees, flat subtrees and
/// group plan, depth-first: a left child follows its parent, leaves numbered in that order.
struct GridKdHybrid::TreeFlattener {
  GridKdHybrid& g;
  const Mesh& mesh;
  GroupPlan& plan;
  uint64_t& references;
  /// Shared corners: each leaf's (and subtree leaf's) groups, planned before flattening, in the
  /// order flatten meets the leaves; next_list is the next one flatten takes.
  std::vector<LeafGroups> planned;
  size_t next_list = 0;
  /// The flat subtrees' floats (records.h, "Flat subtrees"); offset 0 means "no flat list".
  std::vector<float> flat_list = std::vector<float>(16, 0.0f);
  bool want_flat;
  uint32_t max_depth = 0;

  TreeFlattener(GridKdHybrid& grid, const Mesh& m, const BuildParams& params, GroupPlan& p,
                uint64_t& refs)
      : g(grid),
        mesh(m),
        plan(p),
        references(refs),
        want_flat(hybrid::kFlatSubtrees && params.hybrid_flat_subtrees) {}

  /// Shared corners: every leaf's groups planned, in parallel (the corner sets are most of the
  /// groups' build time): up to kWideLanes lanes and kMaxGroupCorners distinct corners a group.
  /// Each lane after a group's first takes, of the leaf's next kGroupWindow triangles, the first
  /// that brings at most one new corner, else the one that brings fewest (the leaf's list is
  /// reordered so: its order is the walk's), so that a group holds a connected patch of the
  /// mesh.
  void plan_groups(BuildNode* root) {
    std::vector<std::pair<uint32_t*, uint32_t>> leaf_lists;
    auto collect = [&](auto&& self, BuildNode* n) -> void {
      if (n->axis >= 0) {
        self(self, n->kid[0].get());
        self(self, n->kid[1].get());
      } else if (n->sub_nodes.empty()) {
        leaf_lists.push_back({n->prims.data(), uint32_t(n->prims.size())});
      } else {
        for (size_t k = kSubBoxNodes; k < n->sub_nodes.size(); ++k)
          if (n->sub_nodes[k].leaf())
            leaf_lists.push_back(
                {n->sub_refs.data() + n->sub_nodes[k].prim_offset, n->sub_nodes[k].count()});
      }
    };
    collect(collect, root);
    planned.resize(leaf_lists.size());
    tbb::parallel_for(size_t(0), leaf_lists.size(), [&](size_t j) {
      const auto [prims, n] = leaf_lists[j];
      LeafGroups& lg = planned[j];
      lg.index.resize(3 * size_t(n));
      for (uint32_t i = 0; i < n;) {
        hybrid::CornerSet set;
        uint32_t k = 0;
        while (i + k < n && k < uint32_t(kWideLanes)) {
          const uint32_t at = i + k, end = std::min(n, at + kGroupWindow);
          uint32_t pick = at, least = 4;
          for (uint32_t c = at; kGroupWindow > 1 && k > 0 && c < end && least > 1; ++c)
            if (const uint32_t f = set.fresh(mesh.corners(prims[c])); f < least) {
              least = f;
              pick = c;
            }
          std::rotate(prims + at, prims + pick, prims + pick + 1);
          if (!set.add(mesh.corners(prims[at]), &lg.index[3 * size_t(at)])) break;
          ++k;
        }
        lg.fill.push_back(uint8_t(k));
        lg.corners.push_back(uint8_t(set.size));
        i += k;
      }
    });
  }

  /// A group of `fill` lanes from plan.start's last, with `corners` distinct corners.
  void add_group(uint32_t fill, uint32_t corners) {
    plan.offset.push_back(uint32_t(plan.floats));
    plan.fill.push_back(fill);
    plan.corners.push_back(corners);
    const bool narrow =
        hybrid::kSharedCorners && hybrid::narrow_ids(plan.lanes.data() + plan.start.back(), fill);
    plan.narrow.push_back(narrow);
    plan.floats += hybrid::kSharedCorners ? hybrid::shared_group_floats(fill, corners, narrow)
                                          : hybrid::kGroupLaneFloats * uint32_t(kWideLanes);
    if (plan.floats >= (uint64_t(1) << 32))
      throw ParamError(
          "hybrid: more than 2^32 floats of triangle groups in the leaves: use a larger cell "
          "size or --hybrid-subtree-min 0");
  }
  /// A leaf's triangles as groups (records.h, "Triangle groups"), in the leaf's order; returns
  /// the first group's float offset.
  uint32_t add_groups(const uint32_t* prims, uint32_t n) {
    const uint64_t first = plan.floats;
    if constexpr (hybrid::kSharedCorners) {
      LeafGroups& lg = planned[next_list++];
      plan.lanes.insert(plan.lanes.end(), prims, prims + n);
      plan.index.insert(plan.index.end(), lg.index.begin(), lg.index.end());
      for (size_t k = 0, i = 0; k < lg.fill.size(); i += lg.fill[k++]) {
        plan.start.push_back(uint32_t(plan.lanes.size() - n + i));
        add_group(lg.fill[k], lg.corners[k]);
      }
      lg = LeafGroups{};
    } else {
      for (uint32_t i = 0; i < n; i += uint32_t(kWideLanes)) {
        // kWideLanes lanes, those left over filled with the leaf's last triangle.
        plan.start.push_back(uint32_t(plan.lanes.size()));
        for (uint32_t j = 0; j < uint32_t(kWideLanes); ++j)
          plan.lanes.push_back(prims[std::min(i + j, n - 1)]);
        add_group(std::min(n - i, uint32_t(kWideLanes)), 0);
      }
    }
    references += n;
    return uint32_t(first);
  }

  /// The leaves with triangles of the subtree from `nd` (box b), depth-first (below first),
  /// each with its kd box within the subtree's box; a leaf whose box lies outside it holds no
  /// part of a triangle. False once there are more than kFlatLeaves.
  bool flat_leaves(const KdNode* nd, Box3 b, std::vector<FlatLeaf>& list) const {
    if (nd->leaf()) {
      if (nd->count() == 0) return true;
      for (int a = 0; a < 3; ++a)
        if (b.lo[a] > b.hi[a]) return true;
      list.push_back({nd, b});
      return list.size() <= hybrid::kFlatLeaves;
    }
    const int a = nd->axis();
    Box3 below = b, above = b;
    below.hi[a] = std::min(b.hi[a], nd->split);
    above.lo[a] = std::max(b.lo[a], nd->split);
    return flat_leaves(nd + 1, below, list) &&
           flat_leaves(g.sub_nodes_.data() + nd->above(), above, list);
  }
  /// Each octant's front-to-back order of the n leaves of `list` under root_node: at a split,
  /// first the side a ray moving along the octant's signs meets first.
  void write_flat_orders(const KdNode* root_node, const std::vector<FlatLeaf>& list,
                         uint8_t* order) const {
    const uint32_t n = uint32_t(list.size());
    for (uint32_t oct = 0, k = 0; oct < 8; ++oct) {
      auto visit = [&](auto&& self, const KdNode* nd) -> void {
        if (nd->leaf()) {
          for (uint32_t i = 0; i < n; ++i)
            if (list[i].node == nd) order[k++] = uint8_t(i);
          return;
        }
        const KdNode* below = nd + 1;
        const KdNode* above = g.sub_nodes_.data() + nd->above();
        const bool down = (oct >> nd->axis()) & 1u;
        self(self, down ? above : below);
        self(self, down ? below : above);
      };
      visit(visit, root_node);
    }
  }
  /// A subtree's leaves with triangles as one flat list (records.h, "Flat subtrees"), when it
  /// has kFlatMinLeaves to kFlatLeaves of them; returns its float offset in flat_list (0: none).
  /// `sub` is the relocated subtree in sub_nodes_ (its box, then its nodes).
  uint32_t add_flat(const KdNode* sub) {
    if (!want_flat) return 0;
    std::vector<FlatLeaf> list;
    float box8[8];
    std::memcpy(box8, sub, sizeof box8);
    const Box3 sub_box(Vec3(box8[0], box8[1], box8[2]), Vec3(box8[4], box8[5], box8[6]));
    const KdNode* const root_node = sub + kSubBoxNodes;
    if (!flat_leaves(root_node, sub_box, list) || list.size() < hybrid::kFlatMinLeaves) return 0;
    const uint32_t n = uint32_t(list.size());
    // Offsets are 32-bit float indices (the leaf record's pad); past that, the kd walk.
    if (flat_list.size() + hybrid::flat_subtree_floats(n) + 16 >= (uint64_t(1) << 32)) return 0;
    const uint32_t off = uint32_t(flat_list.size());
    flat_list.resize(off + (hybrid::flat_subtree_floats(n) + 15) / 16 * 16, 0.0f);
    float* const f = flat_list.data() + off;
    std::memcpy(f, box8, sizeof box8);
    std::memcpy(f + 8, &n, sizeof n);
    float* const q = f + 16;
    for (uint32_t i = 0; i < n; ++i) {
      for (int a = 0; a < 3; ++a) {
        q[uint32_t(a) * n + i] = list[i].box.lo[a];
        q[uint32_t(3 + a) * n + i] = list[i].box.hi[a];
      }
      const uint32_t first = list[i].node->prim_offset, count = list[i].node->count();
      std::memcpy(q + 6 * n + i, &first, sizeof first);
      std::memcpy(q + 7 * n + i, &count, sizeof count);
    }
    write_flat_orders(root_node, list, reinterpret_cast<uint8_t*>(q + 8 * n));
    return off;
  }

  /// Leaf n's subtree relocated into sub_nodes_ (child indices are local to the leaf, and each
  /// of its leaves gets its own groups in place of its range of sub_refs), or stored flat.
  void relocate_subtree(BuildNode* n, Leaf& l) {
    const uint32_t base = uint32_t(g.sub_nodes_.size());
    if (g.sub_nodes_.size() + n->sub_nodes.size() >= (uint64_t(1) << 29))
      throw ParamError(
          "hybrid: more than 2^29 subtree nodes: use a larger cell size or "
          "--hybrid-subtree-min 0");
    for (size_t k = 0; k < n->sub_nodes.size(); ++k) {
      KdNode kn = n->sub_nodes[k];
      if (k < kSubBoxNodes) {
      } else if (kn.leaf()) {
        kn.prim_offset = add_groups(n->sub_refs.data() + kn.prim_offset, kn.count());
      } else {
        kn.bits = ((kn.above() + base + kSubBoxNodes) << 2) | uint32_t(kn.axis());
      }
      g.sub_nodes_.push_back(kn);
    }
    l.first = base;
    l.count |= kSubtreeFlag;
    // A flat subtree replaces the kd nodes, which the walk then never reads.
    const uint32_t flat_at = add_flat(g.sub_nodes_.data() + base);
    if (flat_at != 0) {
      std::memcpy(&l.pad, &flat_at, sizeof flat_at);
      g.sub_nodes_.resize(base);
      l.first = 0;
      ++g.flat_subtrees_;
    }
  }

  void flatten(BuildNode* n) {
    const size_t idx = g.nodes_.size();
    g.nodes_.push_back({});
    max_depth = std::max(max_depth, uint32_t(n->depth));
    if (n->axis < 0) {
      Leaf l{};
      for (int a = 0; a < 3; ++a) {
        l.lo[a] = n->lo[a];
        l.hi[a] = n->hi[a];
      }
      l.count = uint32_t(n->prims.size());
      if (!n->sub_nodes.empty())
        relocate_subtree(n, l);
      else
        l.first = add_groups(n->prims.data(), uint32_t(n->prims.size()));
      g.nodes_[idx] = {int32_t(g.leaves_.size()), 0, 3};
      g.leaves_.push_back(l);
      g.leaf_depth_.push_back(uint8_t(std::min(n->depth, 255)));
      return;
    }
    flatten(n->kid[0].get());
    g.nodes_[idx] = {n->split, uint32_t(g.nodes_.size()), uint32_t(n->axis)};
    flatten(n->kid[1].get());
  }
};

void GridKdHybrid::build_tree(const Mesh& mesh, const BuildParams& params, GroupPlan& plan,
                              uint64_t& references) {
  TreeBuilder tb(mesh, origin_, cell_, dims_, params, stats_.peak_estimate);
  std::unique_ptr<BuildNode> root = tb.build_root();
  stats_.sah_evaluations = tb.sah_evaluations();
  const double nodes = check_flatten_memory(tb, mesh, params, GroupPlan::kBytesPerGroup, stats_);
  const double refs = double(tb.leaf_refs());
  nodes_.reserve(size_t(nodes));
  leaves_.reserve(size_t(nodes + 1) / 2);
  leaf_depth_.reserve(size_t(nodes + 1) / 2);
  plan = GroupPlan{};
  plan.lanes.reserve(size_t(refs));
  if constexpr (hybrid::kSharedCorners) plan.index.reserve(3 * size_t(refs));
  references = 0;
  TreeFlattener f(*this, mesh, params, plan, references);
  if constexpr (hybrid::kSharedCorners) f.plan_groups(root.get());
  flat_subtree_floats_.clear();
  f.flatten(root.get());
  stats_.max_depth = f.max_depth;
  if (f.flat_list.size() > 16) {  // offset 0 alone: no flat subtree
    flat_subtree_floats_.assign(f.flat_list.size() / 16, hybrid::GroupLine{});
    std::memcpy(flat_subtree_floats_[0].f, f.flat_list.data(), f.flat_list.size() * sizeof(float));
  }
}

}  // namespace kdgrid
