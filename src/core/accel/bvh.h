// Binned-SAH bounding volume hierarchy (Wald 2007, "On fast Construction of SAH-based
// Bounding Volume Hierarchies"). The classic baseline the hybrid grid/kd-tree is compared
// against: every triangle is referenced exactly once, nodes are 32 bytes, and traversal
// visits the nearer child first with a small explicit stack.
//
// Build: at each node the triangles' centroids are sorted into BuildParams::bvh_bins bins per
// axis and the SAH cost of every bin boundary is evaluated; the cheapest split wins unless a
// leaf is cheaper (and small enough). When all centroids coincide no plane separates them and
// the range is halved by index (median split). Large subtrees are built in parallel with
// oneTBB; every subtree owns a fixed slot range of the node array, so the result is
// bit-identical for any thread count.
//
// Traversal: slab test with the precomputed reciprocal direction. A zero direction component
// gives an infinite reciprocal and (box face - origin) = 0 then yields 0*inf = NaN; the
// min/max below are written so a NaN operand is dropped (the ray lies in that face plane and
// the slab imposes no constraint, which is the right answer for a closed box). The far
// distance is widened by 1 + 2*gamma(3) (pbrt-v4) so rounding can never cull a box the ray
// really enters.
#pragma once

#include <cstdint>
#include <vector>

#include "accel/accelerator.h"

namespace kdgrid {

/// One BVH node, 32 bytes. Children of an inner node: the left child follows it directly
/// (depth-first order), the right child is at `offset`. A leaf's triangles are
/// prims_[offset, offset + count).
struct BvhNode {
  static constexpr uint32_t kInner = 0xFFFFFFFFu;
  Vec3 lo;
  uint32_t offset = 0;
  Vec3 hi;
  uint32_t count = kInner;  ///< triangles in a leaf, kInner for an inner node
  bool leaf() const { return count != kInner; }
};
static_assert(sizeof(BvhNode) == 32, "BVH nodes are meant to be 32 bytes");

class Bvh final : public AcceleratorBase<Bvh> {
 public:
  /// Deepest tree the build produces; the traversal stack holds one entry per level.
  static constexpr int kMaxDepth = 64;

  std::string name() const override { return "bvh"; }
  BuildStats build(const Mesh& mesh, const BuildParams& params) override;

  /// The traversal of one ray (AcceleratorBase's contract).
  template <class TriangleTest, class Probe, bool kAny>
  bool traverse(const Ray& ray, Hit* hit, Probe& s) const;

  void for_each_box(const std::function<void(const StructureBox&)>& fn) const override;

  const std::vector<BvhNode>& nodes() const { return nodes_; }
  const std::vector<uint32_t>& prims() const { return prims_; }

 private:
  /// Per-ray constants of the slab test.
  struct RayBox {
    Vec3 org, inv;
    int neg[3];  ///< 1 where the direction's sign bit is set (including -0)
  };
  static RayBox prepare_box(const Ray& r);
  /// Entry/exit distances of the ray in `n`'s box clipped to [tmin, tmax]; true if non-empty.
  static bool slab(const RayBox& rb, const BvhNode& n, float tmin, float tmax, float& t_in,
                   float& t_out);

  const Mesh* mesh_ = nullptr;
  std::vector<BvhNode> nodes_;
  std::vector<uint32_t> prims_;  ///< triangle indices in leaf order
};

// ---- traversal ----------------------------------------------------------------------------

inline Bvh::RayBox Bvh::prepare_box(const Ray& r) {
  RayBox rb;
  rb.org = r.org;
  for (int a = 0; a < 3; ++a) {
    rb.inv[a] = 1.0f / r.dir[a];  // +-0 -> +-inf
    rb.neg[a] = std::signbit(r.dir[a]) ? 1 : 0;
  }
  return rb;
}

inline bool Bvh::slab(const RayBox& rb, const BvhNode& n, float tmin, float tmax, float& t_in,
                      float& t_out) {
  // 1 + 2*gamma(3), gamma(k) = k*eps/(1-k*eps) with eps = 2^-24 (pbrt-v4 Bounds3::IntersectP).
  constexpr float kEps = 0.5f * 1.1920929e-7f;
  constexpr float kWiden = 1.0f + 2.0f * (3.0f * kEps) / (1.0f - 3.0f * kEps);
  float tn = tmin, tf = tmax;
  for (int a = 0; a < 3; ++a) {
    const float near_face = rb.neg[a] ? n.hi[a] : n.lo[a];
    const float far_face = rb.neg[a] ? n.lo[a] : n.hi[a];
    const float t0 = (near_face - rb.org[a]) * rb.inv[a];
    const float t1 = (far_face - rb.org[a]) * rb.inv[a] * kWiden;
    // Comparisons with NaN are false, so a NaN t0/t1 leaves tn/tf unchanged.
    tn = t0 > tn ? t0 : tn;
    tf = t1 < tf ? t1 : tf;
  }
  t_in = tn;
  t_out = tf;
  return tn <= tf;
}

template <class TriangleTest, class Probe, bool kAny>
bool Bvh::traverse(const Ray& ray, Hit* hit, Probe& s) const {
  if (nodes_.empty()) return false;
  const RayBox rb = prepare_box(ray);
  const auto rd = TriangleTest::prepare(ray);
  const auto& pos = mesh_->positions;
  const auto& tris = mesh_->triangles;
  float tmax = ray.tmax;
  bool found = false;

  struct Entry {
    uint32_t node;
    float t_in;
  };
  Entry stack[kMaxDepth + 1];
  [[maybe_unused]] int depth_stack[kMaxDepth + 1];
  int sp = 0;
  [[maybe_unused]] int depth = 0;

  float t_in, t_out;
  if (!slab(rb, nodes_[0], ray.tmin, tmax, t_in, t_out)) return false;
  uint32_t cur = 0;
  for (;;) {
    const BvhNode& n = nodes_[cur];
    s.step();
    if constexpr (Probe::kTrace) {
      TraceStep st;
      st.kind = n.leaf() ? StepKind::Leaf : StepKind::Inner;
      st.depth = depth;
      st.id = cur;
      st.box = Box3(n.lo, n.hi);
      slab(rb, n, ray.tmin, tmax, st.t_in, st.t_out);
      s.visit(st);
    }
    if (n.leaf()) {
      s.leaf();
      for (uint32_t i = n.offset, e = n.offset + n.count; i < e; ++i) {
        const uint32_t p = prims_[i];
        s.tri_test(p);
        if (hit_triangle<TriangleTest, kAny>(rd, pos, tris[p], p, ray.tmin, tmax, hit)) {
          if constexpr (kAny) return true;
          found = true;
        }
      }
    } else {
      const uint32_t l = cur + 1, r = n.offset;
      float tl_in, tl_out, tr_in, tr_out;
      const bool hl = slab(rb, nodes_[l], ray.tmin, tmax, tl_in, tl_out);
      const bool hr = slab(rb, nodes_[r], ray.tmin, tmax, tr_in, tr_out);
      if (hl && hr) {
        const bool left_first = tl_in <= tr_in;
        stack[sp] = left_first ? Entry{r, tr_in} : Entry{l, tl_in};
        if constexpr (Probe::kTrace) depth_stack[sp] = depth + 1;
        ++sp;
        cur = left_first ? l : r;
        if constexpr (Probe::kTrace) ++depth;
        continue;
      }
      if (hl || hr) {
        cur = hl ? l : r;
        if constexpr (Probe::kTrace) ++depth;
        continue;
      }
    }
    // Pop the next node whose entry still lies before the closest hit found so far.
    for (;;) {
      if (sp == 0) return found;
      --sp;
      if (stack[sp].t_in <= tmax) break;
    }
    cur = stack[sp].node;
    if constexpr (Probe::kTrace) depth = depth_stack[sp];
  }
}

}  // namespace kdgrid
