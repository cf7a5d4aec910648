// The kd traversal kernel shared by the SAH kd-tree (KdTree) and the hybrid's leaf subtrees:
// the node layout, the ray set-up and slab clip (scalar, and with the three axes as SIMD lanes),
// and the front-to-back walk over a node array.
//
// Nodes are 8 bytes, as in pbrt-v3: a float split position, or the one triangle index of a
// single-triangle leaf, or an offset into the triangle index array; and 32 bits holding the
// axis (0-2) or 3 for a leaf in the low 2 bits, and the above child's index or the leaf's
// triangle count in the other 30. The below child follows its parent in the array.
//
// Rounding: plane crossings t = (split - o) / d and a triangle test's own t are both off by a
// few ulps of the coordinates involved, so every interval decision is widened by a per-axis
// bound err (KdRay). A direction component of +0 or -0 never bounds t: the ray goes to the
// origin's side of a plane, and a ray lying in a plane visits both children.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstring>

#include "accel/accelerator.h"
#include "math/simd.h"

namespace kdgrid {

/// Deepest kd-tree the traversal stacks support (KdTree and the hybrid's subtrees).
constexpr int kKdMaxDepth = 60;

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

/// A box as kd_begin reads it: its corners' x, y, z, with -inf and +inf in the fourth lane.
struct ClipBox4 {
  Float4 lo = {kInf, kInf, kInf, -kInf}, hi = {-kInf, -kInf, -kInf, kInf};
  void set(const Box3& b) {
    lo = Float4{b.lo.x, b.lo.y, b.lo.z, -kInf};
    hi = Float4{b.hi.x, b.hi.y, b.hi.z, kInf};
  }
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
/// kd_begin's clip and of kd_clip_x4, which its tests hold them to bit for bit.
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

/// The ray as kd_clip_x4 reads it, an axis per lane: origin, reciprocal direction and err as in
/// KdRay, and `fixed`, all ones on the axes the ray does not move along. The fourth lane is an
/// axis that never bounds t (origin, reciprocal and err 0, fixed).
struct KdRayX4 {
  Float4 org, inv, err;
  Int4 fixed;
};

/// kd_clip with the three axes as lanes: the same [t0, t1] bit for bit (the slabs' near and far
/// t's combined by one maximum and one minimum instead of in axis order), except for a
/// subnormal direction component: its reciprocal and err are infinite and its slab's t's NaN,
/// which kd_clip drops and this reduction may keep in place of another axis's bound, so the
/// interval can only be wider (KdTree.LaneClipsContainScalarClipWithSubnormalDirections).
/// `lo` and `hi` hold the box's corners with -inf and +inf in the fourth lane (ClipBox4's layout).
[[gnu::always_inline]] inline bool kd_clip_x4(const KdRayX4& r, Float4 lo, Float4 hi, float& t0,
                                              float& t1) {
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
/// to `box` by kd_clip_x4, each slab widened by err: the results of kd_clip bit for bit
/// (KdTree.BeginMatchesScalarClipBitForBit; a subnormal direction component only widens the
/// interval, see kd_clip_x4); false if the ray misses the box. With `r4`, the ray as kd_clip_x4
/// reads it is kept for the caller.
[[gnu::always_inline]] inline bool kd_begin(const Ray& ray, const ClipBox4& box, float max_abs,
                                            KdRay& kr, float& t0, float& t1,
                                            KdRayX4* r4 = nullptr) {
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
  // The clip itself is kd_clip_x4's: a zero direction component never bounds t, and the
  // origin must lie inside its slab.
  const Int4 xyz = {-1, -1, -1, 0};
  KdRayX4 own;
  KdRayX4& k4 = r4 ? *r4 : own;
  k4.org = xyz ? o : zero;
  k4.inv = xyz ? inv : zero;
  k4.err = xyz ? err : zero;
  k4.fixed = ~(moving & xyz);
  t0 = ray.tmin;
  t1 = ray.tmax;
  return kd_clip_x4(k4, box.lo, box.hi, t0, t1);
}

/// The kd traversal, front to back with a stack of (node, t_min, t_max), pbrt-v3 style: at an
/// interior node the child on the ray's near side is visited over [t_min, t_plane] and the far
/// child is pushed with [t_plane, t_max], both widened by err. KdTree::traverse and the hybrid's
/// leaf subtrees both walk through it.
/// It walks front to back over [t_min, t_max] from nodes[root], whose box is `root_box` (used
/// for traces). `leaf(node, best, found)` tests a leaf's triangles, updating the closest hit's
/// t (`best`) and whether there is one (`found`), and returns true when an any-hit query is
/// answered (the walk then returns true at once); best and found are copied in and out, as the
/// walk's own locals. The walk ends after a leaf once the closest hit lies before every node
/// left on the stack. Traced walks call `visit(kind, depth, node, box, t_min, t_max)` for each
/// node, depth counted from the root.
template <class Probe, class LeafFn, class VisitFn>
[[gnu::always_inline]] inline bool kd_traverse(const KdNode* nodes, uint32_t root, const KdRay& r,
                                               float t_min, float t_max,
                                               [[maybe_unused]] const Box3& root_box,
                                               float& best_io, bool& found_io, Probe& s,
                                               LeafFn&& leaf, [[maybe_unused]] VisitFn&& visit) {
  float best = best_io;
  bool found = found_io;
  // Stack of nodes still to visit, front to back. It is kept sorted (top has the smallest
  // t_min) by lowering a pushed t_min to the top's where widening or a ray lying in a split
  // plane would break the order; lowering only widens an interval.
  struct Entry {
    uint32_t node;
    float t_min, t_max;
  };
  Entry stack[kKdMaxDepth + 4];
  // Traces only: the depth and box of each node, and of each on the stack.
  [[maybe_unused]] Box3 box_stack[Probe::kTrace ? kKdMaxDepth + 4 : 1];
  [[maybe_unused]] int depth_stack[Probe::kTrace ? kKdMaxDepth + 4 : 1];
  int sp = 0;
  uint32_t node = root;
  [[maybe_unused]] int depth = 0;
  [[maybe_unused]] Box3 box;
  if constexpr (Probe::kTrace) box = root_box;
  for (;;) {
    const KdNode& n = nodes[node];
    s.step();
    if (!n.leaf()) {
      if constexpr (Probe::kTrace) visit(StepKind::Inner, depth, node, box, t_min, t_max);
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
      if constexpr (Probe::kTrace) {
        Box3 lo_box = box, hi_box = box;
        lo_box.hi[a] = split;
        hi_box.lo[a] = split;
        box_first = first == below ? lo_box : hi_box;
        box_second = first == below ? hi_box : lo_box;
      }
      if constexpr (Probe::kTrace) ++depth;
      if (visit_first && visit_second) {
        if (sp > 0 && stack[sp - 1].t_min < second_min) second_min = stack[sp - 1].t_min;
        stack[sp] = {second, second_min, t_max};
        if constexpr (Probe::kTrace) {
          box_stack[sp] = box_second;
          depth_stack[sp] = depth;
        }
        ++sp;
        node = first;
        t_max = first_max;
        if constexpr (Probe::kTrace) box = box_first;
      } else if (visit_first) {
        node = first;
        if constexpr (Probe::kTrace) box = box_first;
      } else {
        node = second;
        if constexpr (Probe::kTrace) box = box_second;
      }
      continue;
    }

    // Leaf.
    if constexpr (Probe::kTrace) visit(StepKind::Leaf, depth, node, box, t_min, t_max);
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
    if constexpr (Probe::kTrace) {
      box = box_stack[sp];
      depth = depth_stack[sp];
    }
  }
  best_io = best;
  found_io = found;
  return false;
}

}  // namespace kdgrid
