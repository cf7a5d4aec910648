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
// Nodes are 8 bytes, as in pbrt-v3: a float split position, or the one triangle index of a
// single-triangle leaf, or an offset into the triangle index array; and 32 bits holding the
// axis (0-2) or 3 for a leaf in the low 2 bits, and the above child's index or the leaf's
// triangle count in the other 30. The below child follows its parent in the array.
//
// Traversal: front-to-back with a stack of (node, t_min, t_max), pbrt-v3 style. At an
// interior node the child on the ray's near side is visited first over [t_min, t_plane] and
// the far child is pushed with [t_plane, t_max] (both widened by a bound on rounding error,
// see traverse()). Direction components that are +0 or -0 go
// to the origin's side; a ray lying exactly in the split plane visits both children (either
// may hold triangles that lie in the plane). The closest hit so far is kept across leaves and
// traversal stops after a leaf when that hit lies in the leaf's interval, i.e. before every
// node left on the stack. No mailboxing:
// with perfect splits straddling triangles are few, and re-testing one is as cheap as a
// mailbox lookup (measured by the counters: tri_tests vs. distinct triangles).
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <vector>

#include "accel/accelerator.h"

namespace kdgrid {

/// 8-byte kd-tree node (pbrt-v3 layout).
struct KdNode {
  union {
    float split;           ///< interior: plane position
    uint32_t one_prim;     ///< leaf with one triangle: its index
    uint32_t prim_offset;  ///< leaf with several: offset into KdTree::prims_
  };
  uint32_t bits;  ///< low 2 bits: axis or 3 = leaf; high 30: above child or triangle count

  bool leaf() const { return (bits & 3u) == 3u; }
  int axis() const { return int(bits & 3u); }
  uint32_t count() const { return bits >> 2; }
  uint32_t above() const { return bits >> 2; }
};
static_assert(sizeof(KdNode) == 8);

/// The kd-tree's builder over some of a mesh's triangles clipped to a box: the hybrid's leaf
/// subtrees, so that they are built as the whole-scene kd-tree is (exact event SAH, perfect
/// splits, the same BuildParams::kd_* costs and depth rule, at most `max_depth` levels).
/// build() may run concurrently.
class KdSubtreeBuilder {
 public:
  KdSubtreeBuilder(const Mesh& mesh, const BuildParams& params, int max_depth);
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

/// Four float lanes (GCC's vector extensions, SSE): x, y, z and a fourth that is padding.
using Float4 = float __attribute__((vector_size(16)));
using Int4 = int32_t __attribute__((vector_size(16)));
/// Whether any lane of a lane mask (all ones or zero per lane) is set, or all four are: one
/// movemask where the target has SSE, else the two 64-bit halves.
[[gnu::always_inline]] inline bool any_lane(Int4 m) {
#ifdef __SSE__
  return __builtin_ia32_movmskps((Float4)m) != 0;  // a vector cast: the same bits
#else
  uint64_t half[2];
  std::memcpy(half, &m, sizeof half);
  return (half[0] | half[1]) != 0;
#endif
}
[[gnu::always_inline]] inline bool all_lanes(Int4 m) {
#ifdef __SSE__
  return __builtin_ia32_movmskps((Float4)m) == 0xf;
#else
  uint64_t half[2];
  std::memcpy(half, &m, sizeof half);
  return (half[0] & half[1]) == ~uint64_t(0);
#endif
}

/// A box as kd_begin reads it: its corners' x, y, z, with -inf and +inf in the fourth lane.
struct ClipBox4 {
  Float4 lo = {kInf, kInf, kInf, -kInf}, hi = {-kInf, -kInf, -kInf, kInf};
  void set(const Box3& b) {
    lo = Float4{b.lo.x, b.lo.y, b.lo.z, -kInf};
    hi = Float4{b.hi.x, b.hi.y, b.hi.z, kInf};
  }
};

class KdTree final : public AcceleratorBase<KdTree> {
 public:
  /// Deepest tree the traversal stack supports.
  static constexpr int kMaxDepth = 60;

  std::string name() const override { return "kdtree"; }
  BuildStats build(const Mesh& mesh, const BuildParams& params) override;

  template <class Tri, class S>
  bool closest(const Ray& ray, Hit& hit, S& s) const {
    return traverse<Tri, S, false>(ray, hit, s);
  }
  template <class Tri, class S>
  bool any(const Ray& ray, S& s) const {
    Hit h;
    return traverse<Tri, S, true>(ray, h, s);
  }

  void for_each_split(const std::function<void(const SplitPlane&)>& fn) const override;
  void for_each_box(const std::function<void(const StructureBox&)>& fn) const override;

  const Box3& bounds() const { return bounds_; }
  const std::vector<KdNode>& nodes() const { return nodes_; }

 private:
  template <class Tri, class S, bool kAny>
  bool traverse(const Ray& ray, Hit& hit, S& s) const;

  const Mesh* mesh_ = nullptr;
  Box3 bounds_;
  float max_abs_ = 0.0f;  ///< largest coordinate magnitude of bounds_
  ClipBox4 clip_box_;     ///< bounds_ as kd_begin reads it
  std::vector<KdNode> nodes_;
  std::vector<uint32_t> prims_;
};

/// A ray as the kd traversal reads it: origin and direction, the reciprocal direction (0 on
/// an axis the ray does not move along) and err, a bound on the rounding of a plane crossing
/// along each axis, in units of t: crossings t = (split - o) / d and a triangle test's own t
/// are both off by a few ulps of the coordinates involved (the origin's and the tree's), which
/// far from the origin can exceed a small leaf, so every interval decision is widened by
/// err[a] = max(|org|, |tree box|) 2^-20 |inv_dir[a]|, as KdTree::traverse widens its own.
struct KdRay {
  Vec3 org, dir, inv_dir, err;
};

/// Clips [t0, t1] to `box` (widened by err); false if the ray misses it. A zero direction
/// component never bounds t: the origin must lie inside the slab. The scalar form of
/// kd_begin's clip and of kd_clip4, which its tests hold them to bit for bit.
[[gnu::always_inline]] inline bool kd_clip(const KdRay& r, const Box3& box, float& t0, float& t1) {
  for (int a = 0; a < 3; ++a) {
    if (r.dir[a] == 0.0f) {
      if (r.org[a] < box.lo[a] || r.org[a] > box.hi[a]) return false;
      continue;
    }
    float tn = (box.lo[a] - r.org[a]) * r.inv_dir[a], tf = (box.hi[a] - r.org[a]) * r.inv_dir[a];
    if (tn > tf) std::swap(tn, tf);
    tn -= r.err[a];
    tf += r.err[a];
    t0 = tn > t0 ? tn : t0;
    t1 = tf < t1 ? tf : t1;
  }
  return t0 <= t1;
}

/// The ray as kd_clip4 reads it, an axis per lane: origin, reciprocal direction and err as in
/// KdRay, and `fixed`, all ones on the axes the ray does not move along. The fourth lane is an
/// axis that never bounds t (origin, reciprocal and err 0, fixed).
struct KdRay4 {
  Float4 org, inv, err;
  Int4 fixed;
};

/// kd_clip with the three axes as lanes: the same [t0, t1] bit for bit (the slabs' near and far
/// t's combined by one maximum and one minimum instead of in axis order), except for a
/// subnormal direction component: its reciprocal and err are infinite and its slab's t's NaN,
/// which kd_clip drops and this reduction may keep in place of another axis's bound, so the
/// interval can only be wider (KdTree.LaneClipsContainScalarClipWithSubnormalDirections).
/// `lo` and `hi` hold the box's corners with -inf and +inf in the fourth lane (ClipBox4's layout).
[[gnu::always_inline]] inline bool kd_clip4(const KdRay4& r, Float4 lo, Float4 hi, float& t0, float& t1) {
  const Float4 inf = {kInf, kInf, kInf, kInf};
  const Int4 outside = r.fixed & ((r.org < lo) | (r.org > hi));
  const Float4 tn = (lo - r.org) * r.inv, tf = (hi - r.org) * r.inv;
  const Int4 swap = tn > tf;
  Float4 near = r.fixed ? -inf : (swap ? tf : tn) - r.err;
  Float4 far = r.fixed ? inf : (swap ? tn : tf) + r.err;
  // The largest near and smallest far t of the four lanes: lanes 0-1 against 2-3, then 0 and 1.
  const Float4 near_swapped = __builtin_shufflevector(near, near, 2, 3, 0, 1);
  const Float4 far_swapped = __builtin_shufflevector(far, far, 2, 3, 0, 1);
  near = near > near_swapped ? near : near_swapped;
  far = far < far_swapped ? far : far_swapped;
  const float n = std::max(near[0], near[1]), f = std::min(far[0], far[1]);
  t0 = n > t0 ? n : t0;
  t1 = f < t1 ? f : t1;
  return !any_lane(outside) && t0 <= t1;
}

/// A ray's (org, tmin) and (dir, tmax) as four float lanes each, from Ray's layout (the
/// fourth lane, tmin or tmax, is for the caller to ignore).
[[gnu::always_inline]] inline void load_ray4(const Ray& ray, Float4& org, Float4& dir) {
  static_assert(sizeof(Ray) == 32 && offsetof(Ray, tmin) == 12 && offsetof(Ray, dir) == 16 &&
                offsetof(Ray, tmax) == 28);
  std::memcpy(&org, reinterpret_cast<const char*>(&ray), sizeof org);
  std::memcpy(&dir, reinterpret_cast<const char*>(&ray) + offsetof(Ray, dir), sizeof dir);
}

/// The kd traversals' set-up, the three axes at once: `kr` for `ray` (reciprocals, 0 on a zero
/// component; err from max(|org|, max_abs) as KdRay says) and [t0, t1] = [tmin, tmax] clipped
/// to `box` by kd_clip4, each slab widened by err: the results of kd_clip bit for bit
/// (KdTree.BeginMatchesScalarClipBitForBit; a subnormal direction component only widens the
/// interval, see kd_clip4); false if the ray misses the box. With `r4`, the ray as kd_clip4
/// reads it is kept for the caller. Against the loop over the axes it replaced, instructions
/// per closest-hit ray (scripts/instr-count.sh, the dragon's central primary rays): the
/// kd-tree 1476.2 -> 1464.6, the hybrid's pre-clip 1548.7 -> 1518.7; the clip by kd_clip4
/// instead of its own scalar tail, the kd-tree 1464.6 -> 1455.6 and the hybrid 1264.9 -> 1254.9.
[[gnu::always_inline]] inline bool kd_begin(const Ray& ray, const ClipBox4& box, float max_abs, KdRay& kr, float& t0,
                                            float& t1, KdRay4* r4 = nullptr) {
  Float4 o, d;  // the fourth lanes (tmin, tmax) are not used
  load_ray4(ray, o, d);
  const Float4 zero = {0.0f, 0.0f, 0.0f, 0.0f};
  const Int4 moving = d != zero;
  const Float4 inv = moving ? 1.0f / d : zero;
  const float err_scale = std::max(max_component(abs(ray.org)), max_abs) * 0x1p-20f;
  const Float4 err = err_scale * (inv < zero ? -inv : inv);
  kr.org = ray.org;
  kr.dir = ray.dir;
  kr.inv_dir = Vec3(inv[0], inv[1], inv[2]);
  kr.err = Vec3(err[0], err[1], err[2]);
  // The clip itself is kd_clip4's: a zero direction component never bounds t, and the
  // origin must lie inside its slab.
  const Int4 xyz = {-1, -1, -1, 0};
  KdRay4 own;
  KdRay4& k4 = r4 ? *r4 : own;
  k4.org = xyz ? o : zero;
  k4.inv = xyz ? inv : zero;
  k4.err = xyz ? err : zero;
  k4.fixed = ~(moving & xyz);
  t0 = ray.tmin;
  t1 = ray.tmax;
  return kd_clip4(k4, box.lo, box.hi, t0, t1);
}

/// The kd-tree's traversal (see the file comment) as a template, for the hybrid's leaf
/// subtrees: the same walk as KdTree::traverse below, which keeps its own copy because the
/// kd-tree written through this template ran its primary rays 5-7% slower (dragon and Sponza,
/// two threads, A/B against Embree, tried twice: with the clip out of line, 8% more
/// instructions under callgrind; again with it inline). A change to one belongs in both.
/// It walks front to back over [t_min, t_max] from nodes[root], whose box is `root_box` (used
/// for traces). `leaf(node, best, found)` tests a leaf's triangles, updating the closest hit's
/// t (`best`) and whether there is one (`found`), and returns true when an any-hit query is
/// answered (the walk then returns true at once); best and found are copied in and out, as the
/// walk's own locals. The walk ends after a leaf once the closest hit lies before every node
/// left on the stack. Traced walks call `visit(kind, depth, node, box, t_min, t_max)` for each
/// node, depth counted from the root.
template <class S, class LeafFn, class VisitFn>
[[gnu::always_inline]] inline bool kd_traverse(const KdNode* nodes, uint32_t root, const KdRay& r, float t_min,
                                               float t_max, [[maybe_unused]] const Box3& root_box, float& best_io,
                                               bool& found_io, S& s, LeafFn&& leaf, [[maybe_unused]] VisitFn&& visit) {
  float best = best_io;
  bool found = found_io;
  // Stack of nodes still to visit, front to back. It is kept sorted (top has the smallest
  // t_min) by lowering a pushed t_min to the top's where widening or a ray lying in a split
  // plane would break the order; lowering only widens an interval.
  struct Entry {
    uint32_t node;
    float t_min, t_max;
  };
  Entry stack[KdTree::kMaxDepth + 4];
  // Traces only: the depth and box of each node, and of each on the stack.
  [[maybe_unused]] Box3 box_stack[S::kTrace ? KdTree::kMaxDepth + 4 : 1];
  [[maybe_unused]] int depth_stack[S::kTrace ? KdTree::kMaxDepth + 4 : 1];
  int sp = 0;
  uint32_t node = root;
  [[maybe_unused]] int depth = 0;
  [[maybe_unused]] Box3 box;
  if constexpr (S::kTrace) box = root_box;
  for (;;) {
    const KdNode& n = nodes[node];
    s.step();
    if (!n.leaf()) {
      if constexpr (S::kTrace) visit(StepKind::Inner, depth, node, box, t_min, t_max);
      const int a = n.axis();
      const float split = n.split, o = component(r.org, a), d = component(r.dir, a);
      const uint32_t below = node + 1, above = n.above();
      uint32_t first, second;
      bool visit_first = true, visit_second = true;
      float first_max = t_max,
            second_min = t_min;  // first: [t_min, first_max], second: [second_min, t_max]
      if (d == 0.0f) {
        // Parallel to the plane: the origin's side, or both when the ray lies in it.
        first = o <= split ? below : above;
        second = first == below ? above : below;
        visit_second = o == split;
      } else {
        // pbrt's belowFirst = (o < split) || (o == split && d <= 0), written by direction so
        // that it also holds for rays with tmin < 0: before crossing, the ray is below the
        // plane if it moves up.
        const float t_plane = (split - o) * component(r.inv_dir, a), err = component(r.err, a);
        first = d > 0.0f ? below : above;
        second = first == below ? above : below;
        if (t_plane - err > t_max) {
          visit_second = false;
        } else if (t_plane + err < t_min) {
          visit_first = false;
        } else {
          first_max = std::min(t_max, t_plane + err);
          second_min = std::max(t_min, t_plane - err);
        }
      }
      Box3 box_first, box_second;
      if constexpr (S::kTrace) {
        Box3 lo_box = box, hi_box = box;
        lo_box.hi[a] = split;
        hi_box.lo[a] = split;
        box_first = first == below ? lo_box : hi_box;
        box_second = first == below ? hi_box : lo_box;
      }
      if constexpr (S::kTrace) ++depth;
      if (visit_first && visit_second) {
        if (sp > 0 && stack[sp - 1].t_min < second_min) second_min = stack[sp - 1].t_min;
        stack[sp] = {second, second_min, t_max};
        if constexpr (S::kTrace) {
          box_stack[sp] = box_second;
          depth_stack[sp] = depth;
        }
        ++sp;
        node = first;
        t_max = first_max;
        if constexpr (S::kTrace) box = box_first;
      } else if (visit_first) {
        node = first;
        if constexpr (S::kTrace) box = box_first;
      } else {
        node = second;
        if constexpr (S::kTrace) box = box_second;
      }
      continue;
    }

    // Leaf.
    if constexpr (S::kTrace) visit(StepKind::Leaf, depth, node, box, t_min, t_max);
    if (leaf(n, best, found)) {
      best_io = best;
      found_io = found;
      return true;
    }
    // Done when the closest hit lies within this leaf's interval, that is before every node
    // left on the stack (the top starts where this leaf ends, give or take err).
    if (sp == 0) break;
    if (found && best < stack[sp - 1].t_min) break;
    --sp;
    node = stack[sp].node;
    t_min = stack[sp].t_min;
    t_max = stack[sp].t_max;
    if constexpr (S::kTrace) {
      box = box_stack[sp];
      depth = depth_stack[sp];
    }
  }
  best_io = best;
  found_io = found;
  return false;
}

template <class Tri, class S, bool kAny>
bool KdTree::traverse(const Ray& ray, Hit& hit, S& s) const {
  if (nodes_.empty()) return false;
  // Rounding: plane crossings t = (split - o) / d and the triangle test's own t are both off
  // by a few ulps of the coordinates involved (the origin's and the scene's). Far from the
  // origin that can exceed a small leaf, so every interval decision is widened by err[a],
  // a bound on that error along axis a in units of t.
  // Clip to the root box (kd_begin); zero direction components never bound t.
  KdRay kr;
  float t0, t1;
  if (!kd_begin(ray, clip_box_, max_abs_, kr, t0, t1)) return false;
  const Vec3& inv_dir = kr.inv_dir;
  const Vec3& err = kr.err;

  // Stack of nodes still to visit, front to back. It is kept sorted (top has the smallest
  // t_min) by lowering a pushed t_min to the top's where widening or a ray lying in a split
  // plane would break the order; lowering only widens an interval.
  struct Entry {
    uint32_t node;
    int depth;
    float t_min, t_max;
  };
  Entry stack[kMaxDepth + 4];
  [[maybe_unused]] Box3 box_stack[S::kTrace ? kMaxDepth + 4 : 1];
  int sp = 0;
  uint32_t node = 0;
  int depth = 0;
  float t_min = t0, t_max = t1;
  [[maybe_unused]] Box3 box;
  if constexpr (S::kTrace) box = bounds_;

  const auto rd = Tri::prepare(ray);
  const auto& pos = mesh_->positions;
  const auto& tris = mesh_->triangles;
  float best = ray.tmax;
  bool found = false;
  for (;;) {
    const KdNode& n = nodes_[node];
    s.step();
    if (!n.leaf()) {
      if constexpr (S::kTrace) s.visit({StepKind::Inner, depth, node, box, t_min, t_max});
      const int a = n.axis();
      const float split = n.split, o = component(ray.org, a), d = component(ray.dir, a);
      const uint32_t below = node + 1, above = n.above();
      uint32_t first, second;
      bool visit_first = true, visit_second = true;
      float first_max = t_max,
            second_min = t_min;  // first: [t_min, first_max], second: [second_min, t_max]
      if (d == 0.0f) {
        // Parallel to the plane: the origin's side, or both when the ray lies in it.
        first = o <= split ? below : above;
        second = first == below ? above : below;
        visit_second = o == split;
      } else {
        // pbrt's belowFirst = (o < split) || (o == split && d <= 0), written by direction so
        // that it also holds for rays with tmin < 0: before crossing, the ray is below the
        // plane if it moves up.
        const float t_plane = (split - o) * component(inv_dir, a), e = component(err, a);
        first = d > 0.0f ? below : above;
        second = first == below ? above : below;
        if (t_plane - e > t_max) {
          visit_second = false;
        } else if (t_plane + e < t_min) {
          visit_first = false;
        } else {
          first_max = std::min(t_max, t_plane + e);
          second_min = std::max(t_min, t_plane - e);
        }
      }
      Box3 box_first, box_second;
      if constexpr (S::kTrace) {
        Box3 lo_box = box, hi_box = box;
        lo_box.hi[a] = split;
        hi_box.lo[a] = split;
        box_first = first == below ? lo_box : hi_box;
        box_second = first == below ? hi_box : lo_box;
      }
      ++depth;
      if (visit_first && visit_second) {
        if (sp > 0 && stack[sp - 1].t_min < second_min) second_min = stack[sp - 1].t_min;
        stack[sp] = {second, depth, second_min, t_max};
        if constexpr (S::kTrace) box_stack[sp] = box_second;
        ++sp;
        node = first;
        t_max = first_max;
        if constexpr (S::kTrace) box = box_first;
      } else if (visit_first) {
        node = first;
        if constexpr (S::kTrace) box = box_first;
      } else {
        node = second;
        if constexpr (S::kTrace) box = box_second;
      }
      continue;
    }

    // Leaf.
    s.leaf();
    if constexpr (S::kTrace) s.visit({StepKind::Leaf, depth, node, box, t_min, t_max});
    const uint32_t count = n.count();
    const uint32_t* list = count == 1 ? &n.one_prim : prims_.data() + n.prim_offset;
    for (uint32_t i = 0; i < count; ++i) {
      const uint32_t prim = list[i];
      s.tri_test(prim);
      const auto& tri = tris[prim];
      float t, u, v;
      if (Tri::intersect(rd, pos[tri[0]], pos[tri[1]], pos[tri[2]], ray.tmin, best, t, u, v)) {
        if constexpr (kAny) return true;
        best = t;
        hit = {t, prim, u, v};
        found = true;
      }
    }
    // Done when the closest hit lies within this leaf's interval, that is before every node
    // left on the stack (the top starts where this leaf ends, give or take err).
    if (sp == 0) break;
    if (found && best < stack[sp - 1].t_min) break;
    --sp;
    node = stack[sp].node;
    depth = stack[sp].depth;
    t_min = stack[sp].t_min;
    t_max = stack[sp].t_max;
    if constexpr (S::kTrace) box = box_stack[sp];
  }
  return found;
}

}  // namespace kdgrid
