// SAH kd-tree (the classic comparator of the hybrid).
//
// Build: Wald & Havran 2006, "On building fast kd-trees for ray tracing, and on doing that
// in O(N log N)". Split events (start / planar / end of each triangle's clipped bounds on
// each axis) are sorted once; each node sweeps its sorted event list to evaluate the SAH
// at every candidate plane, classifies triangles left / right / both, and splits the list
// stably, so children inherit sorted lists. Triangles straddling the plane are clipped to
// each child box (Sutherland-Hodgman on the box planes: "perfect splits") and only their
// few new events are sorted and merged in.
//
// SAH (BuildParams::kd_*): cost(split) = K_T + K_I * (P_L N_L + P_R N_R), with P the ratio
// of child to parent surface area, multiplied by (1 - kd_empty_bonus) when one side is empty
// to favour cutting off empty space. Triangles lying in the candidate plane go to whichever
// side is cheaper (as in the paper). A node becomes a leaf when the best split costs at least
// K_I * N (testing its triangles), or at the depth limit (auto: 8 + 1.3 log2 N, pbrt).
// Candidates on the node's own boundary are only considered when they separate triangles
// (planar ones from the rest), and never get the empty bonus: a zero-volume empty child
// would otherwise be "free" and the recursion could repeat the same split forever.
// The top levels of the tree are built in parallel with oneTBB.
//
// Nodes, the ray set-up and the walk are the kd kernel (kd_kernel.h), shared with the
// hybrid's leaf subtrees.
//
// Traversal: front-to-back with a stack of (node, t_min, t_max), pbrt-v3 style. At an
// interior node the child on the ray's near side is visited first over [t_min, t_plane] and
// the far child is pushed with [t_plane, t_max] (both widened by a bound on rounding error,
// see kd_kernel.h). Direction components that are +0 or -0 go
// to the origin's side; a ray lying exactly in the split plane visits both children (either
// may hold triangles that lie in the plane). The closest hit so far is kept across leaves and
// traversal stops after a leaf when that hit lies in the leaf's interval, i.e. before every
// node left on the stack. No mailboxing:
// with perfect splits straddling triangles are few, and re-testing one is as cheap as a
// mailbox lookup (measured by the counters: tri_tests vs. distinct triangles).
#pragma once

#include <functional>
#include <memory>
#include <vector>

#include "accel/accelerator.h"
#include "accel/kd_kernel.h"
#include "util/memory.h"

namespace kdgrid {

/// The kd-tree's builder over some of a mesh's triangles clipped to a box: the hybrid's leaf
/// subtrees, so that they are built as the whole-scene kd-tree is (exact event SAH, perfect
/// splits, the same BuildParams::kd_* costs and depth rule, at most `max_depth` levels).
/// build() may run concurrently. `leaf_lanes`: the triangles the structure's leaves test at once
/// (the hybrid's groups, kWideLanes); above 1 the SAH costs a leaf of n triangles as
/// ceil(n / leaf_lanes) tests plus `lane_cost` tests per triangle.
/// `account`: charged with the builds' transient memory (event lists; the subtrees returned are
/// the caller's to account), shared with the caller; null: a budget-limited account per thread.
class KdSubtreeBuilder {
 public:
  KdSubtreeBuilder(const Mesh& mesh, const BuildParams& params, int max_depth, int leaf_lanes = 1,
                   float lane_cost = 0.0f, MemoryAccount* account = nullptr);
  ~KdSubtreeBuilder();
  /// The tree of `prims` (mesh triangle ids) clipped to `box`, built over `bounds`, the box of
  /// the clipped triangles (within `box`), which the walk should clip a ray to first. Child
  /// indices count from nodes[0]; every leaf indexes prims_out (one-triangle leaves too).
  /// Throws ParamError when the builds outgrow the memory budget.
  void build(const std::vector<uint32_t>& prims, const Box3& box, std::vector<KdNode>& nodes,
             std::vector<uint32_t>& prims_out, Box3& bounds) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int max_depth_;
};

/// Upper bound of the bytes a kd build over `n` triangles, at most `depth` levels deep on
/// `threads` threads, holds at once: the event lists alive in the recursion, the tree (at most
/// 2^depth leaves of at most n references) with its vector slack and copies, the per-thread
/// classification flags. KdTree's peak bound (BuildStats::peak_estimate) and the hybrid's
/// subtrees'.
double kd_build_worst_case_bytes(double n, int depth, int threads);

class KdTree final : public AcceleratorBase<KdTree> {
 public:
  /// Deepest tree the traversal stack supports.
  static constexpr int kMaxDepth = kKdMaxDepth;

  std::string name() const override { return "kdtree"; }
  BuildStats build(const Mesh& mesh, const BuildParams& params) override;

  /// The traversal of one ray (AcceleratorBase's contract).
  template <class TriangleTest, class Probe, bool kAny>
  bool traverse(const Ray& ray, Hit* hit, Probe& s) const;

  void for_each_split(const std::function<void(const SplitPlane&)>& fn) const override;
  void for_each_box(const std::function<void(const StructureBox&)>& fn) const override;

  const Box3& bounds() const { return bounds_; }
  const std::vector<KdNode>& nodes() const { return nodes_; }

 private:
  const Mesh* mesh_ = nullptr;
  Box3 bounds_;
  float max_abs_ = 0.0f;  ///< largest coordinate magnitude of bounds_
  ClipBox4 clip_box_;     ///< bounds_ as kd_begin reads it
  std::vector<KdNode> nodes_;
  std::vector<uint32_t> prims_;
};

template <class TriangleTest, class Probe, bool kAny>
bool KdTree::traverse(const Ray& ray, Hit* hit, Probe& s) const {
  if (nodes_.empty()) return false;
  // Clip to the root box (kd_begin); zero direction components never bound t.
  KdRay kr;
  float t0, t1;
  if (!kd_begin(ray, clip_box_, max_abs_, kr, t0, t1)) return false;
  const auto rd = TriangleTest::prepare(ray);
  const auto& pos = mesh_->positions;
  const auto& tris = mesh_->triangles;
  auto leaf = [&](const KdNode& n, float& best, bool& found) __attribute__((always_inline)) {
    s.leaf();
    const uint32_t count = n.count();
    const uint32_t* list = count == 1 ? &n.one_prim : prims_.data() + n.prim_offset;
    for (uint32_t i = 0; i < count; ++i) {
      const uint32_t prim = list[i];
      s.tri_test(prim);
      if (hit_triangle<TriangleTest, kAny>(rd, pos, tris[prim], prim, ray.tmin, best, hit)) {
        if constexpr (kAny) return true;
        found = true;
      }
    }
    return false;
  };
  auto visit = [&](StepKind kind, int depth, uint32_t node, const Box3& box, float t_min,
                   float t_max) {
    s.visit(TraceStep{kind, depth, node, box, t_min, t_max});
  };
  float best = ray.tmax;
  bool found = false;
  return kd_traverse(nodes_.data(), 0, kr, t0, t1, bounds_, best, found, s, leaf, visit) || found;
}

}  // namespace kdgrid
