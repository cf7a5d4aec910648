// BVH-specific properties: structure invariants, deterministic parallel build, and the
// slab test's handling of +-0 direction components, axis-parallel rays, NaN rays and origins
// inside boxes.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>

#include "accel/brute.h"
#include "accel/bvh.h"
#include "agreement.h"
#include "bench/raysets.h"
#include "util/error.h"

namespace kdgrid {
namespace {

TEST(Bvh, StructureInvariants) {
  const Mesh mesh = test::triangle_soup(20000, 4);
  Bvh bvh;
  BuildParams p;
  const BuildStats st = bvh.build(mesh, p);
  const auto& nodes = bvh.nodes();
  const auto& prims = bvh.prims();
  ASSERT_EQ(st.nodes, nodes.size());
  EXPECT_EQ(st.nodes, 2 * st.leaves - 1);
  EXPECT_EQ(st.references, mesh.num_triangles());
  EXPECT_GT(st.sah_evaluations, 0u);
  EXPECT_EQ(st.bytes, nodes.size() * 32 + prims.size() * 4);
  ASSERT_EQ(st.bytes_by_part.size(), 2u);
  EXPECT_EQ(st.bytes_by_part[0].second + st.bytes_by_part[1].second, st.bytes);
  // Every triangle is referenced exactly once.
  std::vector<int> seen(mesh.num_triangles(), 0);
  for (uint32_t p2 : prims) ++seen.at(p2);
  for (int s : seen) ASSERT_EQ(s, 1);
  // Children lie inside parents; leaves cover their triangles and respect the leaf size.
  uint64_t leaves = 0;
  uint32_t deepest = 0;
  std::vector<std::pair<uint32_t, uint32_t>> todo{{0, 0}};
  while (!todo.empty()) {
    const auto [i, d] = todo.back();
    todo.pop_back();
    const BvhNode& n = nodes[i];
    deepest = std::max(deepest, d);
    const Box3 box(n.lo, n.hi);
    if (n.leaf()) {
      ++leaves;
      EXPECT_GE(n.count, 1u);
      EXPECT_LE(n.count, uint32_t(p.bvh_max_leaf));
      for (uint32_t k = n.offset; k < n.offset + n.count; ++k)
        for (const Vec3& c : mesh.corners(prims[k])) ASSERT_TRUE(box.contains(c));
    } else {
      for (uint32_t c : {i + 1, n.offset}) {
        ASSERT_LT(c, nodes.size());
        EXPECT_TRUE(box.contains(nodes[c].lo) && box.contains(nodes[c].hi));
        todo.push_back({c, d + 1});
      }
    }
  }
  EXPECT_EQ(leaves, st.leaves);
  EXPECT_EQ(deepest, st.max_depth);
  uint64_t boxes = 0, leaf_boxes = 0;
  bvh.for_each_box([&](const StructureBox& b) {
    ++boxes;
    leaf_boxes += b.leaf;
  });
  EXPECT_EQ(boxes, st.nodes);
  EXPECT_EQ(leaf_boxes, st.leaves);
}

TEST(Bvh, BuildIsIndependentOfThreadCount) {
  const Mesh mesh = test::triangle_soup(60000, 8);
  std::vector<BvhNode> ref_nodes;
  std::vector<uint32_t> ref_prims;
  for (int threads : {1, 2, 4, 7}) {
    Bvh bvh;
    BuildParams p;
    p.threads = threads;
    bvh.build(mesh, p);
    if (ref_nodes.empty()) {
      ref_nodes = bvh.nodes();
      ref_prims = bvh.prims();
      continue;
    }
    ASSERT_EQ(bvh.nodes().size(), ref_nodes.size()) << threads << " threads";
    EXPECT_EQ(std::memcmp(bvh.nodes().data(), ref_nodes.data(), ref_nodes.size() * sizeof(BvhNode)),
              0)
        << threads << " threads";
    EXPECT_EQ(bvh.prims(), ref_prims) << threads << " threads";
  }
}

TEST(Bvh, CoincidentCentroidsFallBackToMedianSplit) {
  // 100 copies of one triangle: no SAH plane separates them, yet leaves must stay small.
  Mesh mesh;
  mesh.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  for (int i = 0; i < 100; ++i) mesh.triangles.push_back({0, 1, 2});
  Bvh bvh;
  BuildParams p;
  p.bvh_max_leaf = 4;
  const BuildStats st = bvh.build(mesh, p);
  bvh.for_each_box([&](const StructureBox& b) {
    if (b.leaf) {
      EXPECT_LE(b.num_triangles, 4u);
    }
  });
  EXPECT_GE(st.leaves, 25u);
  Hit h;
  ASSERT_TRUE(bvh.intersect({{0.2f, 0.2f, -1}, 0, {0, 0, 1}, kInf}, h));
  EXPECT_EQ(h.t, 1.0f);
}

TEST(Bvh, RejectsBadParameters) {
  const Mesh mesh = test::triangle_soup(10, 1);
  Bvh bvh;
  test::expect_params_refused(
      bvh, mesh,
      {[](BuildParams& p) { p.bvh_bins = 1; }, [](BuildParams& p) { p.bvh_max_leaf = 0; }});
}

TEST(Bvh, EmptyMeshMissesEverything) {
  Mesh mesh;
  Bvh bvh;
  const BuildStats st = bvh.build(mesh, BuildParams{});
  EXPECT_EQ(st.nodes, 0u);
  Hit h;
  EXPECT_FALSE(bvh.intersect({{0, 0, 0}, 0, {0, 0, 1}, kInf}, h));
  EXPECT_FALSE(bvh.occluded({{0, 0, 0}, 0, {0, 0, 1}, kInf}));
  EXPECT_TRUE(bvh.trace({{0, 0, 0}, 0, {0, 0, 1}, kInf}).steps.empty());
}

// Rays with +0/-0 components along the lines of coplanar quads (NaN in the slab test):
// ExtremeRayFamilies.SignedZeroComponents.

TEST(Bvh, InvalidRaysMiss) {
  const Mesh mesh = test::subdivided_sphere(2);
  Bvh bvh;
  bvh.build(mesh, BuildParams{});
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<Ray> bad = {
      {{nan, 0, 0}, 0, {0, 0, 1}, kInf},   {{0, 0, -5}, 0, {nan, 0, 1}, kInf},
      {{0, 0, -5}, nan, {0, 0, 1}, kInf},  {{0, 0, -5}, 0, {0, 0, 1}, nan},
      {{0, 0, -5}, 0, {0, 0, 0}, kInf},    {{kInf, 0, -5}, 0, {0, 0, 1}, kInf},
      {{0, 0, -5}, 0, {0, 0, kInf}, kInf}, {{0, 0, -5}, 3, {0, 0, 1}, 2},
  };
  for (const Ray& r : bad) {
    Hit h;
    EXPECT_FALSE(bvh.intersect(r, h)) << test::describe(r);
    EXPECT_FALSE(h.valid());
    EXPECT_FALSE(bvh.occluded(r)) << test::describe(r);
    RayCounters c;
    EXPECT_FALSE(bvh.intersect_counted(r, h, c));
    EXPECT_FALSE(bvh.trace(r).hit.valid());
  }
  // The same ray without the NaN hits.
  Hit h;
  EXPECT_TRUE(bvh.intersect({{0, 0, -5}, 0, {0, 0, 1}, kInf}, h));
}

TEST(Bvh, OriginInsideBoxesHitsTheEnclosingSurface) {
  const Mesh mesh = test::subdivided_sphere(4, 2.0f, {1, 2, 3});
  Bvh bvh;
  bvh.build(mesh, BuildParams{});
  const auto dirs = random_rays(Box3({-1, -1, -1}, {1, 1, 1}), 2000, 3);
  for (const Ray& d : dirs) {
    const Ray r{{1, 2, 3}, 0.0f, normalize(d.dir), kInf};
    Hit h;
    ASSERT_TRUE(bvh.intersect(r, h)) << test::describe(r);
    // Flat facets lie inside the sphere: t between the facet distance and the radius.
    EXPECT_GT(h.t, 1.95f);
    EXPECT_LE(h.t, 2.0001f);
    EXPECT_TRUE(bvh.occluded(r));
    Ray short_ray = r;
    short_ray.tmax = 1.9f;
    EXPECT_FALSE(bvh.occluded(short_ray));
  }
}

TEST(Bvh, TraceListsNodesWithIntervalsBeforeTheirTests) {
  const Mesh mesh = test::triangle_soup(3000, 5);
  Bvh bvh;
  bvh.build(mesh, BuildParams{});
  const auto rays = random_rays(mesh.bounds(), 500, 6);
  size_t traced_hits = 0;
  for (const Ray& r : rays) {
    const Trace tr = bvh.trace(r);
    Hit h;
    const bool hit = bvh.intersect(r, h);
    ASSERT_EQ(tr.hit.valid(), hit);
    traced_hits += hit;
    EXPECT_EQ(tr.steps.size(), tr.counters.steps);
    uint64_t leaves = 0, tested = 0;
    for (const TraceStep& s : tr.steps) {
      EXPECT_EQ(s.first_tested, tested);  // tests are grouped after their node's visit
      tested += s.num_tested;
      if (s.kind == StepKind::Leaf) {
        ++leaves;
      } else {
        EXPECT_EQ(s.num_tested, 0u);
      }
      EXPECT_LE(s.t_in, s.t_out) << "a visited node must overlap the ray interval";
    }
    EXPECT_EQ(tested, tr.tested.size());
    EXPECT_EQ(leaves, tr.counters.leaves);
    if (hit) {
      bool found = false;
      for (uint32_t p : tr.tested) found |= p == h.prim;
      EXPECT_TRUE(found) << "the hit triangle was tested";
    }
    if (!tr.steps.empty()) {
      EXPECT_EQ(tr.steps[0].depth, 0);
    }
  }
  EXPECT_GT(traced_hits, 50u);
}

TEST(Bvh, VisitsFarFewerTrianglesThanBruteForce) {
  const Mesh mesh = test::subdivided_sphere(5);  // 20480 triangles
  Bvh bvh;
  bvh.build(mesh, BuildParams{});
  const auto rays = primary_rays(canonical_camera(mesh.bounds()), 64, 64);
  RayCounters c;
  for (const Ray& r : rays) {
    Hit h;
    bvh.intersect_counted(r, h, c);
  }
  const double tests_per_ray = double(c.tri_tests) / rays.size();
  EXPECT_LT(tests_per_ray, 64.0) << "a working BVH tests a handful of triangles per ray";
  EXPECT_GT(c.steps, 0u);
}

}  // namespace
}  // namespace kdgrid
