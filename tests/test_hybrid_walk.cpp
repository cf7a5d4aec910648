// The hybrid's walk: counted, fast and traced walks agree, traces visit leaves in ray order,
// the next-leaf cache never changes an answer, flat subtrees answer as the kd walk, empty-leaf
// boxes give the same hits in fewer steps, splits and boxes describe the tree, and the mailbox
// tests each triangle once.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <utility>
#include <vector>

#include "accel/hybrid/hybrid.h"
#include "comparator_meshes.h"
#include "extreme_rays.h"
#include "hybrid_check.h"
#include "scene/load.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

using namespace test;

TEST(Hybrid, CountedAndFastTraversalAgree) {
  const Mesh m = octahedron_sphere(4, 1.0f, Vec3(0.0f));
  GridKdHybrid h;
  BuildParams p = params_with(0.0f, false);
  p.hybrid_subtree_min = 0;  // plain leaves: every step is a leaf step (no subtree nodes)
  h.build(m, p);
  const auto rays = random_rays(m, 5000, 3);
  RayCounters total;
  for (const Ray& r : rays) {
    Hit a, b;
    RayCounters c;
    const bool ha = h.intersect(r, a), hb = h.intersect_counted(r, b, c);
    ASSERT_EQ(ha, hb);
    if (ha) {
      EXPECT_EQ(a.t, b.t);
      EXPECT_EQ(a.prim, b.prim);
    }
    EXPECT_EQ(h.occluded(r), h.occluded_counted(r, c));
    total += c;
  }
  EXPECT_GT(total.steps, 0u);
  EXPECT_GT(total.tri_tests, 0u);
  EXPECT_GE(total.lookups, total.steps / 2);
}

// The walk takes the leaf its thread last reached across the same leaf face when the exit
// cell lies in that leaf's kd box (the next-leaf cache, walk.h). Cache entries left by another
// structure (which NextLeafCache::claim must clear: in_kd_box does not check that a cached id is
// one of this structure's leaves, so without the claim this test fails), by incoherent rays or
// by the same coherent rays must never change an answer, nor the counters (every resolution
// counts as a lookup).
TEST(Hybrid, NextLeafCacheNeverChangesTheAnswer) {
  const Mesh ma = octahedron_sphere(5, 1.0f, Vec3(0.3f, -0.2f, 0.1f));
  const Mesh mb = random_soup(3000, 5, 0.08f);
  GridKdHybrid ha, hb;
  ha.build(ma, params_with(0.0f, false));
  hb.build(mb, params_with(0.13f, true));
  // Coherent rays from one eye (neighbours cross the same leaves), then incoherent ones.
  std::vector<Ray> ra = coherent_rays(64);
  const auto more = random_rays(ma, 4096, 11);
  ra.insert(ra.end(), more.begin(), more.end());
  const auto rb = random_rays(mb, int(ra.size()), 12);
  const BruteReference refa = brute_answers(ma, ra), refb = brute_answers(mb, rb);
  int failures = 0;
  uint64_t steps = 0;
  const uint64_t taken_before = GridKdHybrid::next_leaves_from_cache();
  // The two structures in turn on one thread: each finds the other's leaves in the cache.
  for (size_t i = 0; i < ra.size(); ++i) {
    failures += compare_hybrid(ha, ma, {ra[i]}, BruteReference{{refa.hits[i]}, {refa.occluded[i]}},
                               "sphere, in turn");
    failures += compare_hybrid(hb, mb, {rb[i]}, BruteReference{{refb.hits[i]}, {refb.occluded[i]}},
                               "soup, in turn");
    ASSERT_LE(failures, 5);
    // The same ray counted right after itself (the cache right) and after the other structure's
    // ray (the cache wrong): the same steps, lookups and tests.
    RayCounters once, again;
    Hit h1, h2;
    ha.intersect_counted(ra[i], h1, once);
    ha.intersect_counted(ra[i], h2, again);
    ASSERT_EQ(once.steps, again.steps);
    ASSERT_EQ(once.lookups, again.lookups);
    ASSERT_EQ(once.tri_tests, again.tri_tests);
    steps += once.steps;
  }
  EXPECT_EQ(failures, 0);
  EXPECT_GT(steps, 3 * ra.size()) << "the rays cross several leaves, so the cache is used";
  // Alone again: the coherent rays with their own cache entries warm.
  const uint64_t taken_in_turn = GridKdHybrid::next_leaves_from_cache();
  EXPECT_EQ(compare_hybrid(ha, ma, ra, refa, "sphere, alone"), 0);
  EXPECT_GT(taken_in_turn, taken_before)
      << "a ray traced right after itself takes its cached leaves";
  EXPECT_GT(GridKdHybrid::next_leaves_from_cache(), taken_in_turn)
      << "coherent rays take cached leaves";
}

// The next-leaf cache turns itself off while its predictions mostly fail (incoherent rays),
// scoring then only one lookup in NextLeafCache::kOffSample, and on again once the rays are
// coherent: a camera's rays after random ones take most of their leaves from it again.
TEST(Hybrid, NextLeafCacheTurnsOffForIncoherentRaysAndOnAgain) {
  const Mesh m = octahedron_sphere(5, 1.0f, Vec3(0.3f, -0.2f, 0.1f));
  GridKdHybrid h;
  h.build(m, params_with(0.0f, false));
  // Leaves taken from the cache and lookups (taken or not) over `rays`, traced in order.
  auto trace = [&h](const Ray* first, size_t n) {
    const uint64_t before = GridKdHybrid::next_leaves_from_cache();
    RayCounters c;
    Hit hit;
    for (size_t i = 0; i < n; ++i) h.intersect_counted(first[i], hit, c);
    return std::pair<uint64_t, uint64_t>{GridKdHybrid::next_leaves_from_cache() - before,
                                         c.lookups};
  };
  const std::vector<Ray> incoherent = random_rays(m, 8192, 21), coherent = coherent_rays(64);
  trace(incoherent.data(), 4096);  // the score falls to its floor
  const auto [taken_off, lookups_off] = trace(incoherent.data() + 4096, 4096);
  trace(coherent.data(), 1024);  // the sampled scoring climbs back
  const auto [taken_on, lookups_on] = trace(coherent.data() + 1024, coherent.size() - 1024);
  std::printf("incoherent: %llu of %llu lookups taken; coherent: %llu of %llu\n",
              (unsigned long long)taken_off, (unsigned long long)lookups_off,
              (unsigned long long)taken_on, (unsigned long long)lookups_on);
  EXPECT_GT(lookups_off, 3u * 4096 / 2) << "random rays cross several leaves";
  EXPECT_LT(taken_off, lookups_off / 4) << "off for incoherent rays";
  EXPECT_GT(taken_on, lookups_on / 2) << "on again for coherent rays";
}

// BuildParams::hybrid_next_leaf_cache = false (`--hybrid-no-next-leaf-cache`), the paper's walk:
// no leaf taken from the next-leaf cache, and the same hits and counters as the walk with it,
// ray by ray.
TEST(Hybrid, WithoutNextLeafCacheTheSameWalk) {
  const Mesh m = octahedron_sphere(5, 1.0f, Vec3(0.3f, -0.2f, 0.1f));
  BuildParams p = params_with(0.0f, false);
  GridKdHybrid cached, plain;
  cached.build(m, p);
  p.hybrid_next_leaf_cache = false;
  plain.build(m, p);
  const std::vector<Ray> rays = coherent_rays(48);
  const uint64_t before = GridKdHybrid::next_leaves_from_cache();
  RayCounters with_cache, without;
  std::vector<Hit> hits_with(rays.size()), hits_without(rays.size());
  std::vector<char> found_with(rays.size()), found_without(rays.size());
  for (size_t i = 0; i < rays.size(); ++i)
    found_with[i] = cached.intersect_counted(rays[i], hits_with[i], with_cache);
  const uint64_t between = GridKdHybrid::next_leaves_from_cache();
  EXPECT_GT(between, before) << "coherent rays take cached leaves";
  for (size_t i = 0; i < rays.size(); ++i)
    found_without[i] = plain.intersect_counted(rays[i], hits_without[i], without);
  EXPECT_EQ(GridKdHybrid::next_leaves_from_cache(), between)
      << "hybrid_next_leaf_cache = false takes no cached leaf";
  for (size_t i = 0; i < rays.size(); ++i) {
    ASSERT_EQ(found_with[i], found_without[i]) << "ray " << i;
    if (found_with[i]) {
      EXPECT_EQ(hits_with[i].prim, hits_without[i].prim) << "ray " << i;
      EXPECT_EQ(hits_with[i].t, hits_without[i].t) << "ray " << i;
    }
  }
  EXPECT_EQ(with_cache, without);
}

// Flat subtrees (BuildParams::hybrid_flat_subtrees, records.h): the leaves of a subtree tested
// against the ray all at once and visited in the kd walk's order for the ray's octant give the
// same answers as the kd walk of the same subtrees, bit for bit, closest hit and any hit, on
// rays from everywhere, axis-parallel ones (zero direction components) and segments; the
// traced walk (flat leaves one level below their grid leaf) ends at the same hit.
TEST(Hybrid, FlatSubtreesAnswerAsTheKdWalk) {
  if (!hybrid::kFlatSubtrees)
    GTEST_SKIP() << "flat subtrees are built for AVX2 and AVX-512 targets only; this build "
                    "walks every subtree by its kd nodes";
  // Cells of a fifth to a third of the meshes' size: leaves of hundreds of triangles, whose
  // subtrees have 5 to 16 leaves with triangles (the auto grid's leaves here hold at most 32).
  struct Case {
    const char* name;
    Mesh mesh;
    float cell;
  };
  const Case cases[] = {
      {"sphere", octahedron_sphere(6, 1.0f, Vec3(0.3f, -0.2f, 0.1f)), 0.2f},
      {"soup", random_soup(30000, 21, 0.03f), 0.3f},
      {"sphere far from the origin",
       transformed(octahedron_sphere(6, 1.0f, Vec3(0.0f)), 1.0f, Vec3(1e4f, -3e3f, 2e3f)), 0.2f}};
  for (const Case& c : cases) {
    BuildParams p = params_with(c.cell, false);
    GridKdHybrid flat, kd;
    const BuildStats st = flat.build(c.mesh, p);
    p.hybrid_flat_subtrees = false;
    const BuildStats st_kd = kd.build(c.mesh, p);
    const std::string subtrees = extra_value(st, "leaf subtrees");
    ASSERT_NE(subtrees.find(" stored flat"), std::string::npos) << c.name << ": " << subtrees;
    EXPECT_EQ(subtrees.find("(0 stored flat"), std::string::npos)
        << c.name << ": the test needs flat subtrees: " << subtrees;
    EXPECT_NE(extra_value(st_kd, "leaf subtrees").find("none flat"), std::string::npos)
        << c.name << ": " << extra_value(st_kd, "leaf subtrees");
    std::vector<Ray> rays = random_rays(c.mesh, 20000, 9);
    for (const Ray& r : coherent_rays(64)) rays.push_back(r);
    int hits = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
      const Ray& r = rays[i];
      Hit a, b;
      const bool fa = flat.intersect(r, a), fb = kd.intersect(r, b);
      ASSERT_EQ(fa, fb) << c.name << " ray " << i;
      if (fa) {
        ++hits;
        EXPECT_EQ(a.prim, b.prim) << c.name << " ray " << i;
        EXPECT_EQ(a.t, b.t) << c.name << " ray " << i;
        EXPECT_EQ(a.u, b.u) << c.name << " ray " << i;
      }
      ASSERT_EQ(flat.occluded(r), kd.occluded(r)) << c.name << " ray " << i;
      if (i % 16 == 0) {
        const Trace tr = flat.trace(r);
        ASSERT_EQ(tr.hit.valid(), fa) << c.name << " ray " << i;
        if (fa) {
          EXPECT_EQ(tr.hit.t, a.t) << c.name << " ray " << i;
        }
      }
    }
    EXPECT_GT(hits, 5000) << c.name;
  }
}

void check_trace_order(uint32_t subtree_min) {
  const Mesh m = random_soup(2000, 8, 0.08f);
  GridKdHybrid h;
  BuildParams p = params_with(0.0f, false);
  p.hybrid_subtree_min = subtree_min;
  h.build(m, p);
  const auto rays = random_rays(m, 3000, 4);
  int hits = 0;
  for (const Ray& r : rays) {
    const Trace tr = h.trace(r);
    Hit hit;
    const bool got = h.intersect(r, hit);
    ASSERT_EQ(got, tr.hit.valid());
    if (got) {
      EXPECT_EQ(hit.t, tr.hit.t);
    }
    for (size_t i = 1; i < tr.steps.size(); ++i) ASSERT_GE(tr.steps[i].t_in, tr.steps[i - 1].t_in);
    for (const TraceStep& s : tr.steps) ASSERT_LE(s.t_in, s.t_out);
    EXPECT_EQ(tr.counters.steps, tr.steps.size());
    // Traced walks step over empty leaves in walk_step, the others inline in walk(): both
    // must take the same steps, lookups and tests.
    RayCounters c;
    Hit counted_hit;
    h.intersect_counted(r, counted_hit, c);
    ASSERT_EQ(tr.counters.steps, c.steps);
    ASSERT_EQ(tr.counters.lookups, c.lookups);
    ASSERT_EQ(tr.counters.tri_tests, c.tri_tests);
    if (got) {
      ASSERT_FALSE(tr.steps.empty());
      const TraceStep& last = tr.steps.back();
      const float tol = 1e-5f * std::max(1.0f, hit.t);
      EXPECT_GE(hit.t, last.t_in - tol);
      EXPECT_LE(hit.t, last.t_out + tol);
      // The hit point lies inside the last leaf's box.
      const Vec3 hp = r.at(hit.t);
      const Vec3 slack(1e-4f);
      EXPECT_TRUE(Box3(last.box.lo - slack, last.box.hi + slack).contains(hp));
      ++hits;
    }
  }
  EXPECT_GT(hits, 500);
}

TEST(Hybrid, TraceVisitsLeavesInRayOrder) {
  check_trace_order(0);
}

TEST(Hybrid, TraceVisitsLeafSubtreesInRayOrder) {
  check_trace_order(2);
}

TEST(Hybrid, SplitsAndBoxesDescribeTheTree) {
  const Mesh m = random_soup(1000, 6, 0.1f);
  GridKdHybrid h;
  BuildParams p = params_with(0.0f, false);
  p.hybrid_subtree_min = 0;  // plain leaves: references are exactly the leaves' lists
  const BuildStats st = h.build(m, p);
  uint64_t splits = 0, boxes = 0, refs = 0;
  const double cell = h.cell_size();
  h.for_each_split([&](const SplitPlane& sp) {
    ++splits;
    // Split planes lie on whole cells.
    const double k = (double(sp.position) - double(h.origin()[sp.axis])) / cell;
    EXPECT_NEAR(k, std::round(k), 1e-3);
    EXPECT_GT(sp.position, sp.node_box.lo[sp.axis]);
    EXPECT_LT(sp.position, sp.node_box.hi[sp.axis]);
  });
  h.for_each_box([&](const StructureBox& b) {
    ++boxes;
    refs += b.num_triangles;
  });
  EXPECT_EQ(splits, st.nodes - st.leaves);
  EXPECT_EQ(boxes, st.leaves - st.empty_leaves);
  EXPECT_EQ(refs, st.references);
  EXPECT_GT(st.sah_evaluations, 0u);
  uint64_t sum = 0;
  for (const auto& part : st.bytes_by_part) sum += part.second;
  EXPECT_EQ(sum, st.bytes);
}

// ---- empty-leaf boxes ----------------------------------------------------------------

TEST(HybridEmptyBoxes, CoverOnlyEmptyCellsAndTheirOwnLeaf) {
  // Widening needs empty leaves with empty cells around them; the SAH's leaves (costed by
  // triangle groups) leave none to widen in some of these meshes, so it is required over all.
  uint64_t widened_all = 0, overlapping = 0;
  for (const Mesh& m : {random_soup(1500, 11, 0.08f), octahedron_sphere(4, 1.0f, Vec3(0.1f)),
                        lattice_quads(0.25f, 6, 3)}) {
    GridKdHybrid h;
    const BuildStats st = h.build(m, params_with(0.0f, false));
    const std::string text = extra_value(st, "empty-leaf boxes");
    ASSERT_NE(text.find("widened"), std::string::npos) << text;
    const int32_t* n = h.dims();
    const auto& leaves = h.leaves();
    uint64_t box_cells = 0, widened = 0;
    std::vector<uint64_t> own(leaves.size(), 0);
    for (int32_t z = 0; z < n[2]; ++z)
      for (int32_t y = 0; y < n[1]; ++y)
        for (int32_t x = 0; x < n[0]; ++x) ++own[h.leaf_at(x, y, z)];
    for (uint32_t i = 0; i < leaves.size(); ++i) {
      const auto& L = leaves[i];
      const uint64_t cells =
          uint64_t(L.hi[0] - L.lo[0]) * uint64_t(L.hi[1] - L.lo[1]) * uint64_t(L.hi[2] - L.lo[2]);
      box_cells += cells;
      if (L.count != 0) {
        // Leaves with triangles keep their kd box: exactly the cells that map to them.
        ASSERT_EQ(cells, own[i]) << "leaf " << i;
        continue;
      }
      widened += cells > own[i];
      // An empty leaf's step box holds only cells of empty leaves (its own among them).
      for (int32_t z = L.lo[2]; z < L.hi[2]; ++z)
        for (int32_t y = L.lo[1]; y < L.hi[1]; ++y)
          for (int32_t x = L.lo[0]; x < L.hi[0]; ++x)
            ASSERT_EQ(leaves[h.leaf_at(x, y, z)].count, 0u);
    }
    widened_all += widened;
    overlapping += box_cells > uint64_t(n[0]) * n[1] * n[2];
  }
  EXPECT_GT(widened_all, 0u);
  EXPECT_GT(overlapping, 0u) << "boxes overlap once widened";
}

TEST(HybridEmptyBoxes, SameHitsInFewerSteps) {
  // Two clusters in opposite corners of the box and a sphere between them: empty space
  // around and between them, crossed by most rays.
  Mesh m;
  for (const Mesh& part : {random_soup(1500, 12, 0.05f, Vec3(-1), Vec3(-0.4f)),
                           random_soup(1500, 13, 0.05f, Vec3(0.4f), Vec3(1)),
                           octahedron_sphere(3, 0.3f, Vec3(0.5f, -0.5f, 0.0f))})
    for (size_t i = 0; i < part.num_triangles(); ++i) {
      const auto c = part.corners(i);
      add_tri(m, c[0], c[1], c[2]);
    }
  // Plain leaves, so that steps count leaf steps only (no subtree nodes).
  GridKdHybrid wide, kd;
  BuildParams p = params_with(0.0f, false);
  p.hybrid_subtree_min = 0;
  wide.build(m, p);
  p.hybrid_expand_empty = false;
  const BuildStats st = kd.build(m, p);
  EXPECT_NE(extra_value(st, "empty-leaf boxes").find("off"), std::string::npos);
  const auto rays = random_rays(m, 20000, 21);
  RayCounters cw, ck;
  for (const Ray& r : rays) {
    Hit a, b;
    const bool ha = wide.intersect_counted(r, a, cw), hb = kd.intersect_counted(r, b, ck);
    ASSERT_EQ(ha, hb);
    if (ha) {
      ASSERT_EQ(a.t, b.t);  // the same triangles' own t, bit for bit
    }
    ASSERT_EQ(wide.occluded(r), kd.occluded(r));
  }
  // Steps drop (5% here: the SAH already leaves large empty leaves around these clusters;
  // 27% on Sponza), the leaves with triangles visited do not change.
  EXPECT_LT(double(cw.steps), 0.97 * double(ck.steps)) << cw.steps << " vs " << ck.steps;
  EXPECT_EQ(cw.leaves, ck.leaves);
  EXPECT_EQ(wide.step_bound_errors(), 0u);
}

// ---- the mailbox's exactness ---------------------------------------------------------

/// Walks every ray closest-hit, any-hit, counted and traced: each must agree with brute force,
/// no traced ray may test a triangle twice, and a counted ray's triangle tests must be the
/// traced ray's distinct triangles (a ray that the fast walk gave up to the exact walk counts
/// only the exact walk's tests and next-leaf cache takes). Returns the closest-hit and the any-hit
/// queries re-walked.
std::pair<uint64_t, uint64_t> check_exact(const GridKdHybrid& h, const Mesh& m,
                                          const std::vector<Ray>& rays, const std::string& label) {
  uint64_t before = h.rewalked_rays();
  for (const Ray& r : rays) {
    Hit hit;
    scalar_closest(h, r, hit);
  }
  const uint64_t closest = h.rewalked_rays() - before;
  before = h.rewalked_rays();
  for (const Ray& r : rays) scalar_any(h, r);
  const uint64_t any = h.rewalked_rays() - before;
  int twice = 0, miscounted = 0, mismatched = 0;
  for (const Ray& r : rays) {
    const Trace t = scalar_trace(h, r);
    std::vector<uint32_t> tested = t.tested;
    std::sort(tested.begin(), tested.end());
    twice += std::adjacent_find(tested.begin(), tested.end()) != tested.end();
    Hit fast, counted;
    RayCounters c;
    const bool got = scalar_closest(h, r, fast);
    const uint64_t taken0 = GridKdHybrid::next_leaves_from_cache();
    const bool got_counted = scalar_counted(h, r, counted, c);
    // Each leaf taken from the next-leaf cache is one of the counted lookups.
    const uint64_t taken = GridKdHybrid::next_leaves_from_cache() - taken0;
    miscounted += c.tri_tests != tested.size() || c.tri_tests != t.counters.tri_tests ||
                  c.mailbox_skips != t.counters.mailbox_skips || c.steps != t.counters.steps ||
                  taken > c.lookups;
    // The same walk three ways: bitwise the same hit.
    mismatched +=
        got != got_counted || got != t.hit.valid() ||
        (got && (fast.t != counted.t || fast.prim != counted.prim || fast.u != counted.u ||
                 fast.v != counted.v || fast.t != t.hit.t || fast.prim != t.hit.prim));
  }
  EXPECT_EQ(twice, 0) << label << ": rays that tested a triangle twice";
  EXPECT_EQ(miscounted, 0) << label << ": rays whose counts are not their exact walk's";
  EXPECT_EQ(mismatched, 0) << label << ": rays whose fast, counted and traced hits differ";
  EXPECT_EQ(compare_hybrid(h, m, rays, brute_answers(m, rays), label), 0) << label;
  std::printf("%s: %zu rays, %llu closest-hit and %llu any-hit queries re-walked\n", label.c_str(),
              rays.size(), (unsigned long long)closest, (unsigned long long)any);
  return {closest, any};
}

// Slivers across the whole scene are referenced by every leaf they cross, so a ray through a
// grid of plain leaves tests hundreds of distinct slivers, evicting far more than kEvicted of
// them from its mailbox; some of them it meets again in later leaves. The fast walk gives
// such rays to the exact walk, so each triangle is still tested once.
TEST(HybridMailbox, RaysEvictingMoreThanTheListTestEachTriangleOnce) {
  const Mesh m = long_thin(31);
  for (const float cell : {0.2f, 0.4f}) {
    BuildParams p = params_with(cell, false);
    p.hybrid_subtree_min = 0;
    GridKdHybrid h;
    h.build(m, p);
    const auto [closest, any] = check_exact(h, m, random_rays(m, 3000, 17),
                                            "slivers, plain leaves, cell " + std::to_string(cell));
    EXPECT_GT(closest, 0u) << "the case must evict more than kEvicted";
    EXPECT_GT(any, 0u) << "any-hit queries must be re-walked too";
  }
}

// A cell larger than the scene gives one cell; with leaf subtrees its subtree is the kd-tree,
// whose leaves share straddling triangles; with plain leaves it is one leaf of every triangle.
TEST(HybridMailbox, OneCellOfTheWholeSceneTestsEachTriangleOnce) {
  const Mesh m = long_thin(32);
  for (const uint32_t subtree_min : {4u, 0u}) {
    BuildParams p = params_with(1e9f, false);
    p.hybrid_subtree_min = subtree_min;
    GridKdHybrid h;
    h.build(m, p);
    ASSERT_EQ(h.dims()[0] * h.dims()[1] * h.dims()[2], 1);
    check_exact(h, m, random_rays(m, 2000, 18),
                subtree_min ? "one cell, leaf subtree" : "one cell, plain leaf");
  }
}

// The bunny's triangles are small, but the plain leaves of a grid 11 times coarser than the
// auto one hold about 330 references each, and rays through a few of them evict hundreds.
TEST(HybridMailbox, BunnyInCoarsePlainLeavesTestsEachTriangleOnce) {
  KDGRID_REQUIRE_SCENE(path, "bunny/bun_zipper.ply");
  const Mesh m = load_scene(path).mesh;
  BuildParams p = params_with(0.02f, false);
  p.hybrid_subtree_min = 0;
  GridKdHybrid h;
  h.build(m, p);
  const auto [closest, any] =
      check_exact(h, m, random_rays(m, 1000, 19), "bunny, cell 0.02, plain");
  EXPECT_GT(closest, 0u);
}

}  // namespace
}  // namespace kdgrid
