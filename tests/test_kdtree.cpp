// SAH kd-tree: agreement with brute force on extreme rays lying in split planes, node layout
// and build statistics. The checks shared by every structure are in test_structures.cpp.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <random>
#include <set>

#include "accel/kdtree.h"
#include "comparator_meshes.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

using test::count_disagreements;
using test::kSanitizerBuild;

std::vector<std::pair<int, float>> split_planes(const KdTree& kd, size_t max_planes) {
  std::vector<std::pair<int, float>> planes;
  std::set<std::pair<int, float>> seen;
  kd.for_each_split([&](const SplitPlane& p) {
    if (planes.size() < max_planes && seen.insert({p.axis, p.position}).second)
      planes.push_back({p.axis, p.position});
  });
  for (int a = 0; a < 3; ++a) {
    planes.push_back({a, kd.bounds().lo[a]});
    planes.push_back({a, kd.bounds().hi[a]});
  }
  return planes;
}

// Agreement with brute force on rays in split planes at every extreme scale:
// ExtremeRayFamilies.RaysInStructurePlanes. The integer quads there make the SAH put many
// splits exactly on planes full of coplanar triangles; the tree does split on them.
TEST(KdTree, SplitsOnThePlanesOfIntegerQuads) {
  for (const test::ScaleCase& c : test::extreme_scale_cases()) {
    SCOPED_TRACE(c.name);
    const Mesh mesh = test::transformed(test::integer_quads(8), c.scale, c.offset);
    KdTree kd;
    kd.build(mesh, BuildParams{});
    int on_quads = 0;
    for (const auto& [a, p] : split_planes(kd, 60)) {
      const float q = (p - c.offset[a]) / c.scale;
      on_quads += std::fabs(q - std::round(q)) < 1e-3f;
    }
    EXPECT_GT(on_quads, 10);
  }
}

// A ray lying exactly in a plane full of coplanar triangles must find them whichever side
// the builder put them on.
TEST(KdTree, RayInPlaneOfCoplanarTriangles) {
  Mesh m = test::integer_quads(6);
  KdTree kd;
  kd.build(m, BuildParams{});
  std::vector<Ray> rays;
  for (int a = 0; a <= 6; ++a)
    for (float z : {0.0f, -0.0f})
      for (float s : {1.0f, -1.0f}) {
        rays.push_back({Vec3(float(a), -1.0f, 2.5f), 0.0f, Vec3(z, s * 1.0f, 0.3f), kInf});
        rays.push_back({Vec3(2.5f, float(a), 7.0f), 0.0f, Vec3(0.2f, z, -s), kInf});
        rays.push_back({Vec3(0.5f, 3.5f, float(a)), 0.0f, Vec3(s, 0.1f, z), kInf});
        rays.push_back({Vec3(float(a), 3.0f, 3.0f), 0.0f, Vec3(z, s, z), kInf});
      }
  EXPECT_EQ(count_disagreements(m, kd, rays), 0);
}

// Counted and traced traversal against the fast path on these rays:
// TracedStructures.CountedAndTracedTraversalMatchFastPath.
TEST(KdTree, TraceStartsAtTheRoot) {
  const Mesh mesh = test::random_soup(3000, 11);
  KdTree kd;
  kd.build(mesh, BuildParams{});
  const auto rays = test::random_rays(mesh, 5000, 3);
  // Interior and leaf steps are both reported, leaves deeper than the root.
  // rays[1] is aimed at a triangle (test::random_rays), so it enters the root box.
  const Trace t = kd.trace(rays[1]);
  ASSERT_FALSE(t.steps.empty());
  EXPECT_EQ(t.steps.front().kind, StepKind::Inner);
  EXPECT_EQ(t.steps.front().depth, 0);
}

TEST(KdTree, BuildStatisticsAreConsistent) {
  const Mesh mesh = test::sphere(60, 120);
  KdTree kd;
  const BuildStats st = kd.build(mesh, BuildParams{});
  EXPECT_EQ(st.nodes, kd.nodes().size());
  EXPECT_EQ(st.nodes, 2 * st.leaves - 1);  // a full binary tree
  EXPECT_GT(st.sah_evaluations, st.nodes);
  EXPECT_GE(st.references, mesh.num_triangles());
  EXPECT_GT(st.empty_leaves, 0u);
  const int limit = int(std::lround(8 + 1.3 * std::log2(double(mesh.num_triangles()))));
  EXPECT_LE(int(st.max_depth), limit);
  EXPECT_GT(st.max_depth, 8u);
  EXPECT_EQ(st.bytes, st.nodes * 8 + (st.bytes_by_part.at(1).second));
  uint64_t splits = 0, leaves = 0, refs = 0;
  kd.for_each_split([&](const SplitPlane& p) {
    ++splits;
    EXPECT_GE(p.position, p.node_box.lo[p.axis]);
    EXPECT_LE(p.position, p.node_box.hi[p.axis]);
  });
  kd.for_each_box([&](const StructureBox& b) {
    ++leaves;
    refs += b.num_triangles;
    EXPECT_TRUE(b.leaf);
  });
  EXPECT_EQ(splits + leaves, st.nodes);
  EXPECT_EQ(leaves, st.leaves);
  EXPECT_EQ(refs, st.references);
  // Every triangle of a leaf touches the leaf's box (perfect splits never add strays).
  kd.for_each_box([&](const StructureBox& b) { EXPECT_FALSE(b.box.empty()); });

  // A higher intersection cost buys a deeper, finer tree.
  BuildParams p;
  p.kd_intersection_cost = 20.0f;
  KdTree fine;
  const BuildStats sf = fine.build(mesh, p);
  EXPECT_LT(double(sf.references) / double(sf.leaves), double(st.references) / double(st.leaves));
}

TEST(KdTree, PlanarTrianglesAreNotDuplicated) {
  // A flat grid of triangles in z = 0: splits cut between triangles, and the coplanar
  // triangles are never referenced twice merely for lying in a split plane.
  Mesh flat;
  for (int i = 0; i < 64; ++i)
    for (int j = 0; j < 64; ++j)
      test::add_tri(flat, Vec3(i, j, 0), Vec3(i + 1, j, 0), Vec3(i, j + 1, 0));
  KdTree kd;
  const BuildStats st = kd.build(flat, BuildParams{});
  EXPECT_LT(double(st.references), 1.6 * double(flat.num_triangles()));
  EXPECT_EQ(count_disagreements(flat, kd, test::random_rays(flat, 5000, 4)), 0);
}

TEST(KdTree, RejectsBadParameters) {
  const Mesh mesh = test::sphere(4, 8);
  KdTree kd;
  test::expect_params_refused(kd, mesh,
                              {[](BuildParams& p) { p.kd_max_depth = 1000; },
                               [](BuildParams& p) { p.kd_intersection_cost = 0.0f; },
                               [](BuildParams& p) { p.kd_empty_bonus = 1.0f; }});
}

TEST(KdTree, BuildsLargeMeshQuickly) {
  // 300K triangles: checks the O(N log N) build stays far from quadratic (about 3 s of CPU).
  // Under ASan the same build took 141 s (measured), so a time bound says nothing there: a
  // sanitizer build builds a quarter of the mesh and checks only memory safety and answers.
  const Mesh mesh = kSanitizerBuild ? test::sphere(200, 188) : test::sphere(400, 375);
  KdTree kd;
  const BuildStats st = kd.build(mesh, BuildParams{});
  std::printf("kd-tree over %zu triangles: %.2f s, %llu nodes, %llu refs, depth %u\n",
              mesh.num_triangles(), st.seconds, (unsigned long long)st.nodes,
              (unsigned long long)st.references, st.max_depth);
  if (!kSanitizerBuild) {
    EXPECT_LT(st.seconds, 60.0);
  }
  EXPECT_EQ(count_disagreements(mesh, kd, test::random_rays(mesh, 200, 8)), 0);
}

// The ray as the scalar set-up builds it (the form kd_begin is held to): reciprocals, 0 on a
// zero component, and err from max(|org|, max_abs).
KdRay scalar_kd_ray(const Ray& ray, float max_abs) {
  KdRay ref;
  ref.org = ray.org;
  ref.dir = ray.dir;
  const float err_scale = std::max(max_component(abs(ray.org)), max_abs) * 0x1p-20f;
  for (int a = 0; a < 3; ++a) {
    ref.inv_dir[a] = ray.dir[a] == 0.0f ? 0.0f : 1.0f / ray.dir[a];
    ref.err[a] = err_scale * std::fabs(ref.inv_dir[a]);
  }
  return ref;
}

/// A ray clipped to `box` by kd_clip of its scalar KdRay and by kd_begin (whose lane form r4
/// kd_clip_x4 reads).
struct BothClips {
  KdRay ref;
  float r0, r1;  // kd_clip's interval
  bool ref_hit;
  KdRay kr;
  KdRayX4 r4;
  float t0, t1;  // kd_begin's interval
  bool hit;
};

BothClips clip_both(const Ray& ray, const Box3& box, const ClipBox4& cb, float max_abs) {
  BothClips c{};
  c.ref = scalar_kd_ray(ray, max_abs);
  c.r0 = ray.tmin;
  c.r1 = ray.tmax;
  c.ref_hit = kd_clip(c.ref, box, c.r0, c.r1);
  c.hit = kd_begin(ray, cb, max_abs, c.kr, c.t0, c.t1, &c.r4);
  return c;
}

/// The bits of `f`.
uint32_t bits(float f) {
  uint32_t b;
  std::memcpy(&b, &f, sizeof b);
  return b;
}

/// kd_begin's reciprocals and error bounds are the scalar KdRay's, bit for bit.
void assert_same_kd_ray(const KdRay& got, const KdRay& want, int ray) {
  for (int a = 0; a < 3; ++a) {
    ASSERT_EQ(bits(got.inv_dir[a]), bits(want.inv_dir[a])) << "ray " << ray << " axis " << a;
    ASSERT_EQ(bits(got.err[a]), bits(want.err[a])) << "ray " << ray << " axis " << a;
  }
}

// kd_begin, the traversals' set-up computed for three axes at once, gives what the scalar form
// (reciprocal, err, kd_clip per axis) gives, bit for bit: reciprocals, err, hit or miss and the
// clipped interval; and kd_clip_x4 (the hybrid's clip to a leaf subtree's box, from kd_begin's
// KdRayX4) what kd_clip gives on a second box. The rays include zero and negative-zero direction
// components (inside and outside their slab), origins on the box's faces, far origins and
// finite tmin/tmax.
TEST(KdTree, BeginMatchesScalarClipBitForBit) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  const Box3 box(Vec3(-1.0f, 0.5f, 2.0f), Vec3(3.0f, 0.75f, 1e3f));
  ClipBox4 cb;
  cb.set(box);
  const float max_abs = std::max(max_component(abs(box.lo)), max_component(abs(box.hi)));
  // A second, smaller box for kd_clip_x4 (the hybrid's clip to a leaf subtree's box), with faces
  // that some origins lie on; its corners as kd_clip_x4 reads them.
  const Box3 sub(Vec3(0.25f, 0.55f, 400.0f), Vec3(2.0f, 0.7f, 600.0f));
  const Float4 sub_lo = {sub.lo.x, sub.lo.y, sub.lo.z, -kInf},
               sub_hi = {sub.hi.x, sub.hi.y, sub.hi.z, kInf};
  int hits = 0, misses = 0, sub_hits = 0, sub_misses = 0;
  for (int i = 0; i < 20000; ++i) {
    const float scale = (i % 5 == 0) ? 1e6f : (i % 5 == 1 ? 1e-3f : 10.0f);
    Ray ray;
    ray.org = Vec3(u(rng), u(rng), u(rng)) * scale + Vec3(1.0f, 0.6f, 500.0f);
    ray.dir = Vec3(u(rng), u(rng), u(rng));
    for (int a = 0; a < 3; ++a) {
      const int k = (i / 7 + a) % 6;
      if (k == 0) ray.dir[a] = 0.0f;
      if (k == 1) ray.dir[a] = -0.0f;
      if (k == 2 && i % 3 == 0) ray.org[a] = (i % 2) ? box.lo[a] : box.hi[a];
      if (k == 3 && i % 3 == 0) ray.org[a] = (i % 2) ? sub.lo[a] : sub.hi[a];
    }
    if (i % 4 == 0) {
      ray.tmin = 0.5f;
      ray.tmax = 200.0f;
    }
    // The scalar form and kd_begin's.
    const auto [ref, r0, r1, ref_hit, kr, r4, t0, t1, hit] = clip_both(ray, box, cb, max_abs);
    // The same answer and, for a hit, the same interval bit for bit; counts the outcomes.
    auto same_clip = [&](bool got, float g0, float g1, bool want, float w0, float w1, int& n_hit,
                         int& n_miss) {
      ASSERT_EQ(got, want) << "ray " << i;
      if (!got) {
        ++n_miss;
        return;
      }
      ASSERT_EQ(bits(g0), bits(w0)) << "ray " << i;
      ASSERT_EQ(bits(g1), bits(w1)) << "ray " << i;
      ++n_hit;
    };
    same_clip(hit, t0, t1, ref_hit, r0, r1, hits, misses);
    ASSERT_NO_FATAL_FAILURE(assert_same_kd_ray(kr, ref, i));
    if (hit) {
      // kd_clip_x4 against kd_clip on the smaller box, over an interval within [t0, t1].
      float s0 = t0 + 0.25f * (t1 - t0), s1 = t1, q0 = s0, q1 = s1;
      const bool sub_ref = kd_clip(ref, sub, s0, s1);
      const bool sub_hit = kd_clip_x4(r4, sub_lo, sub_hi, q0, q1);
      same_clip(sub_hit, q0, q1, sub_ref, s0, s1, sub_hits, sub_misses);
    }
    if (HasFatalFailure()) return;
  }
  // Both outcomes were exercised.
  EXPECT_GT(hits, 1000);
  EXPECT_GT(misses, 1000);
  EXPECT_GT(sub_hits, 500);
  EXPECT_GT(sub_misses, 500);
}

// A subnormal direction component has an infinite reciprocal and an infinite err, so its slab
// gives NaN t's (inf - inf, or 0 * inf with the origin on a face). kd_clip's loop over the axes
// drops a NaN; the lane reductions of kd_begin and kd_clip_x4 may instead keep it in place of
// another axis's bound. Either way the interval only widens: the traversals then visit more,
// never less. So the lane forms must hit whenever kd_clip hits, with an interval that contains
// kd_clip's (and bit for bit the same reciprocals and err).
TEST(KdTree, LaneClipsContainScalarClipWithSubnormalDirections) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  const Box3 box(Vec3(-1.0f, -2.0f, -0.5f), Vec3(1.0f, 2.0f, 0.5f));
  ClipBox4 cb;
  cb.set(box);
  const Float4 lo = {box.lo.x, box.lo.y, box.lo.z, -kInf},
               hi = {box.hi.x, box.hi.y, box.hi.z, kInf};
  const float max_abs = 2.0f;
  int hits = 0, nan_axes = 0;
  for (int i = 0; i < 20000; ++i) {
    Ray ray;
    ray.org = Vec3(u(rng), u(rng), u(rng)) * 3.0f;
    ray.dir = Vec3(u(rng), u(rng), u(rng));
    for (int a = 0; a < 3; ++a) {
      const int k = (i / 3 + a) % 4;
      if (k == 0) ray.dir[a] = (i % 2 ? -1.0f : 1.0f) * 1e-40f;  // subnormal
      if (k == 1 && i % 2) ray.org[a] = (i % 4 < 2) ? box.lo[a] : box.hi[a];
    }
    const auto [ref, r0, r1, ref_hit, kr, r4, t0, t1, hit] = clip_both(ray, box, cb, max_abs);
    for (int a = 0; a < 3; ++a)
      if (std::isinf(ref.inv_dir[a])) ++nan_axes;
    ASSERT_NO_FATAL_FAILURE(assert_same_kd_ray(kr, ref, i));
    if (!ref_hit) continue;
    ++hits;
    ASSERT_TRUE(hit) << "ray " << i;
    EXPECT_LE(t0, r0) << "ray " << i;
    EXPECT_GE(t1, r1) << "ray " << i;
    float q0 = ray.tmin, q1 = ray.tmax;
    ASSERT_TRUE(kd_clip_x4(r4, lo, hi, q0, q1)) << "ray " << i;
    EXPECT_LE(q0, r0) << "ray " << i;
    EXPECT_GE(q1, r1) << "ray " << i;
    if (HasFailure()) return;
  }
  EXPECT_GT(hits, 1000);
  EXPECT_GT(nan_axes, 5000);
}

}  // namespace
}  // namespace kdgrid
