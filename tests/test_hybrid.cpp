// The hybrid grid/kd-tree against brute force on procedural meshes at several cell sizes and
// both matrix storages, the extreme rays of docs/DESIGN.md's numerical rules, memory behaviour on
// a teapot-in-a-stadium scene, counters and traces, and parameter validation.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "accel/brute.h"
#include "accel/hybrid/hybrid.h"
#include "comparator_meshes.h"
#include "extreme_rays.h"
#include "scene/load.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

// ---- procedural meshes -------------------------------------------------------------------

using test::add_quad;
using test::add_tri;
using test::lattice_quads;
using test::random_rays;
using test::random_soup;
using test::transformed;

/// An octahedron subdivided `levels` times and projected on the sphere (test::octahedron_sphere).
Mesh subdivided_sphere(Vec3 center, float radius, int levels) {
  return test::octahedron_sphere(levels, radius, center);
}

/// Long thin slivers crossing the whole box in random directions, plus a few small ones.
Mesh long_thin(uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  Mesh m;
  for (int i = 0; i < 400; ++i) {
    const Vec3 a(u(rng), u(rng), u(rng)), b(u(rng), u(rng), u(rng));
    const Vec3 w = Vec3(u(rng), u(rng), u(rng)) * 0.01f;
    add_tri(m, a, b, b + w);
  }
  const Mesh small = random_soup(300, seed + 1, 0.03f);
  m.append(small);
  return m;
}

/// A tiny dense sphere (the teapot) in the middle of a huge empty box (the stadium).
Mesh teapot_in_stadium(float stadium, int sphere_levels) {
  Mesh m = subdivided_sphere(Vec3(0.0f), 1.0f, sphere_levels);
  const float s = stadium;
  // Floor and the four walls and the roof of the stadium.
  add_quad(m, {-s, -s, -s}, {s, -s, -s}, {s, -s, s}, {-s, -s, s});
  add_quad(m, {-s, s, -s}, {-s, s, s}, {s, s, s}, {s, s, -s});
  add_quad(m, {-s, -s, -s}, {-s, s, -s}, {s, s, -s}, {s, -s, -s});
  add_quad(m, {-s, -s, s}, {s, -s, s}, {s, s, s}, {-s, s, s});
  add_quad(m, {-s, -s, -s}, {-s, -s, s}, {-s, s, s}, {-s, s, -s});
  add_quad(m, {s, -s, -s}, {s, s, -s}, {s, s, s}, {s, -s, s});
  return m;
}

// ---- rays --------------------------------------------------------------------------------

struct Reference {
  std::vector<Hit> hits;
  std::vector<char> occluded;
};

Reference brute_reference(const Mesh& m, const std::vector<Ray>& rays) {
  BruteForce bf;
  bf.build(m, BuildParams{});
  Reference ref;
  ref.hits.resize(rays.size());
  ref.occluded.resize(rays.size());
  for (size_t i = 0; i < rays.size(); ++i) {
    Hit h;
    bf.intersect(rays[i], h);
    ref.hits[i] = h;
    ref.occluded[i] = bf.occluded(rays[i]);
  }
  return ref;
}

/// The triangle's own t for the ray (the reported prim's t must equal the reference t).
float own_t(const Mesh& m, const Ray& r, uint32_t prim) {
  const auto c = m.corners(prim);
  float t = kInf, u, v;
  WatertightTest::intersect(WatertightTest::prepare(r), c[0], c[1], c[2], r.tmin, r.tmax, t, u, v);
  return t;
}

/// Checks every ray; returns the number of failures (and reports the first few).
int compare(const GridKdHybrid& h, const Mesh& m, const std::vector<Ray>& rays,
            const Reference& ref, const std::string& label) {
  int failures = 0;
  for (size_t i = 0; i < rays.size(); ++i) {
    Hit hh;
    const bool got = h.intersect(rays[i], hh);
    const Hit& rh = ref.hits[i];
    bool ok = got == rh.valid();
    if (ok && got) {
      const float tol = 1e-5f * std::max(1.0f, std::abs(rh.t));
      ok = std::abs(hh.t - rh.t) <= tol;
      if (ok && hh.prim != rh.prim) ok = std::abs(own_t(m, rays[i], hh.prim) - rh.t) <= tol;
    }
    const bool occ = h.occluded(rays[i]);
    ok = ok && occ == bool(ref.occluded[i]);
    if (!ok && ++failures <= 5) {
      const Ray& r = rays[i];
      ADD_FAILURE() << label << ": ray " << i << " org (" << r.org.x << "," << r.org.y << ","
                    << r.org.z << ") dir (" << r.dir.x << "," << r.dir.y << "," << r.dir.z << ") ["
                    << r.tmin << "," << r.tmax << "]: hybrid " << (got ? "hit" : "miss")
                    << " t=" << hh.t << " prim=" << hh.prim << " occ=" << occ << "; brute "
                    << (rh.valid() ? "hit" : "miss") << " t=" << rh.t << " prim=" << rh.prim
                    << " occ=" << int(ref.occluded[i]);
    }
  }
  EXPECT_EQ(h.step_bound_errors(), 0u) << label;
  return failures;
}

BuildParams params_with(float cell, bool dense) {
  BuildParams p;
  p.cell_size = cell;
  p.hybrid_dense_matrix = dense;
  p.threads = 2;
  return p;
}

float min_triangle_extent(const Mesh& m) {
  float mn = kInf;
  for (size_t i = 0; i < m.num_triangles(); ++i) {
    const float e = max_component(m.triangle_bounds(i).extent());
    if (e > 0) mn = std::min(mn, e);
  }
  return mn;
}

/// Agreement at auto, one cell, a cell smaller than the smallest triangle, and an explicit
/// cell, for both storages.
void check_mesh(const Mesh& m, const std::string& name, float explicit_cell, int nrays = 20000) {
  const auto rays = random_rays(m, nrays, 1234);
  const Reference ref = brute_reference(m, rays);
  const float big = 10.0f * max_component(m.bounds().extent());
  const float tiny = 0.5f * min_triangle_extent(m);
  struct Case {
    float cell;
    const char* what;
  };
  const Case cases[] = {{0.0f, "auto"},
                        {big, "one cell"},
                        {tiny, "cell < smallest triangle"},
                        {explicit_cell, "explicit"}};
  for (const Case& c : cases) {
    // The defaults (bricked, leaf subtrees over 4 triangles, empty-leaf boxes), dense
    // storage, a subtree in every leaf of more than 2 triangles, plain leaves, and the
    // paper's hybrid (plain leaves stepping over kd leaf boxes).
    for (int variant = 0; variant < 5; ++variant) {
      const bool dense = variant == 1;
      GridKdHybrid h;
      BuildParams p = params_with(c.cell, dense);
      p.memory_budget = uint64_t(2) << 30;
      if (variant == 2) p.hybrid_subtree_min = 2;
      if (variant >= 3) p.hybrid_subtree_min = 0;
      if (variant == 4) p.hybrid_expand_empty = false;
      if (dense && c.cell > 0.0f) {
        // A dense matrix over the budget must be refused, not allocated.
        const Vec3 e = m.bounds().extent();
        double cells = 1.0;
        for (int a = 0; a < 3; ++a)
          cells *= std::max(1.0, std::ceil(double(e[a]) / double(c.cell)));
        if (cells * 4.0 > double(p.memory_budget)) {
          EXPECT_THROW(h.build(m, p), ParamError) << name << " " << c.what;
          continue;
        }
      }
      const BuildStats st = h.build(m, p);
      if (c.cell == big) {
        EXPECT_EQ(h.dims()[0] * h.dims()[1] * h.dims()[2], 1) << name;
      }
      const std::string label = name + " / " + c.what + " (" + st.extra[2].second + ", " +
                                (dense          ? "dense"
                                 : variant == 2 ? "bricked, subtrees over 2"
                                 : variant == 3 ? "bricked, plain leaves"
                                 : variant == 4 ? "bricked, plain leaves, kd leaf boxes"
                                                : "bricked") +
                                ")";
      const auto t0 = std::chrono::steady_clock::now();
      EXPECT_EQ(compare(h, m, rays, ref, label), 0) << label;
      if (getenv("HYB_TIME"))
        printf("%s build %.3fs rays %.3fs nodes %lu refs %lu\n", label.c_str(), st.seconds,
               std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
               (unsigned long)st.nodes, (unsigned long)st.references);
    }
  }
}

// ---- agreement with brute force ---------------------------------------------------------

TEST(Hybrid, AgreesWithBruteForceRandomSoup) {
  check_mesh(random_soup(3000, 1, 0.08f), "soup", 0.13f);
}

TEST(Hybrid, AgreesWithBruteForceSphere) {
  check_mesh(subdivided_sphere(Vec3(0.3f, -0.2f, 0.1f), 1.0f, 5), "sphere", 0.05f);
}

TEST(Hybrid, AgreesWithBruteForceLatticeQuads) {
  // cell 0.25 puts every quad exactly on cell boundaries (and so on split planes).
  check_mesh(lattice_quads(0.25f, 8, 3), "lattice", 0.25f);
}

TEST(Hybrid, AgreesWithBruteForceLongThinTriangles) {
  check_mesh(long_thin(5), "thin", 0.07f);
}

TEST(Hybrid, AgreesWithBruteForceTeapotInStadium) {
  check_mesh(teapot_in_stadium(100.0f, 4), "stadium", 0.5f, 10000);
}

TEST(Hybrid, NonCubicGrid7x3x11) {
  const Mesh m = random_soup(2000, 9, 0.3f, Vec3(0.0f), Vec3(6.9f, 2.9f, 10.9f));
  const auto rays = random_rays(m, 20000, 77);
  const Reference ref = brute_reference(m, rays);
  for (bool dense : {false, true}) {
    GridKdHybrid h;
    h.build(m, params_with(1.0f, dense));
    ASSERT_EQ(h.dims()[0], 7);
    ASSERT_EQ(h.dims()[1], 3);
    ASSERT_EQ(h.dims()[2], 11);
    EXPECT_EQ(compare(h, m, rays, ref, dense ? "7x3x11 dense" : "7x3x11 bricked"), 0);
  }
}

TEST(Hybrid, DenseAndBrickedMapEveryCellToTheSameCoveringLeaf) {
  const Mesh m = random_soup(1500, 4, 0.1f);
  GridKdHybrid d, b;
  d.build(m, params_with(0.05f, true));
  b.build(m, params_with(0.05f, false));
  ASSERT_EQ(d.leaves().size(), b.leaves().size());
  const int32_t* n = d.dims();
  for (int32_t z = 0; z < n[2]; ++z)
    for (int32_t y = 0; y < n[1]; ++y)
      for (int32_t x = 0; x < n[0]; ++x) {
        const uint32_t l = b.leaf_at(x, y, z);
        ASSERT_EQ(l, d.leaf_at(x, y, z));
        const auto& L = b.leaves()[l];
        ASSERT_TRUE(x >= L.lo[0] && x < L.hi[0] && y >= L.lo[1] && y < L.hi[1] && z >= L.lo[2] &&
                    z < L.hi[2]);
      }
}

// ---- extreme rays ----------------------------------------------------------------------
// Agreement with brute force on the extreme-ray families: test_extreme_rays.cpp. Here, what
// only the hybrid promises: its step bound, and rays missing the box take no step.

TEST(Hybrid, StepBoundOnExtremeRays) {
  const Mesh m = test::extreme_scene();
  std::vector<Ray> rays = test::axis_parallel_rays(-0.5f, 2.5f, 600, 1);
  for (const auto& more :
       {test::zero_component_rays(-0.5f, 2.5f, 600, 2, 6),
        test::rays_in_lattice_planes(test::kExtremeCell, -1, 9, -0.5f, 2.5f, 600, 3),
        test::rays_from_lattice_points(test::kExtremeCell, -1, 9, 600, 5),
        test::rays_inside_and_outside(Vec3(1.0f), 0.01f, 1.99f, 600, 6)})
    rays.insert(rays.end(), more.begin(), more.end());
  for (int variant = 0; variant < 5; ++variant) {
    GridKdHybrid h;
    BuildParams p = params_with(test::kExtremeCell, variant == 1);
    if (variant == 2) p.hybrid_subtree_min = 2;
    if (variant >= 3) p.hybrid_subtree_min = 0;
    if (variant == 4) p.hybrid_expand_empty = false;
    h.build(m, p);
    for (const Ray& r : rays) {
      RayCounters c;
      Hit hit;
      h.intersect_counted(r, hit, c);
      h.occluded(r);
      // One lookup per leaf step, and no ray reaches the step bound.
      ASSERT_LE(c.lookups, uint64_t(h.dims()[0] + h.dims()[1] + h.dims()[2] + 1)) << variant;
    }
    EXPECT_EQ(h.step_bound_errors(), 0u) << variant;
  }
}

TEST(Hybrid, RaysMissingTheBoxTakeNoStep) {
  GridKdHybrid h;
  h.build(test::extreme_scene(), params_with(test::kExtremeCell, false));
  for (const Ray& r : test::rays_beside_the_box(1500, 7)) {
    Hit hit;
    RayCounters c;
    EXPECT_FALSE(h.intersect_counted(r, hit, c));
    EXPECT_EQ(c.steps, 0u);  // rejected by the root-box clip without a lookup
  }
}

// ---- empty-leaf boxes ---------------------------------------------------------------------

std::string extra_value(const BuildStats& st, const std::string& key) {
  for (const auto& [k, v] : st.extra)
    if (k == key) return v;
  return "(no " + key + " in BuildStats::extra)";
}

TEST(HybridEmptyBoxes, CoverOnlyEmptyCellsAndTheirOwnLeaf) {
  // Widening needs empty leaves with empty cells around them; the SAH's leaves (costed by
  // triangle groups) leave none to widen in some of these meshes, so it is required over all.
  uint64_t widened_all = 0, overlapping = 0;
  for (const Mesh& m : {random_soup(1500, 11, 0.08f), subdivided_sphere(Vec3(0.1f), 1.0f, 4),
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
                           subdivided_sphere(Vec3(0.5f, -0.5f, 0.0f), 0.3f, 3)})
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

// ---- memory -----------------------------------------------------------------------------

TEST(HybridMemory, TeapotInStadiumBrickedStaysSmall) {
  // Sphere of radius 1 with 32768 triangles (edges ~0.02-0.03) inside a stadium of side 2000.
  const Mesh m = teapot_in_stadium(1000.0f, 6);
  GridKdHybrid h;
  BuildParams p = params_with(0.05f, false);  // 40000 cells per axis: 6.4e13 cells
  const BuildStats st = h.build(m, p);
  const double cells = double(h.dims()[0]) * h.dims()[1] * h.dims()[2];
  EXPECT_GT(cells, 6e13);
  uint64_t matrix = 0;
  for (const auto& part : st.bytes_by_part)
    if (part.first.rfind("matrix", 0) == 0) matrix = part.second;
  // Stated bound: the bricked matrix of this scene stays under 16 MiB (content: ~33K
  // triangles), while the dense matrix at the same cell size would need 4 bytes per cell.
  EXPECT_LT(matrix, uint64_t(16) << 20) << "bricked matrix bytes";
  EXPECT_LT(st.bytes, uint64_t(32) << 20) << "whole structure";
  EXPECT_EQ(h.matrix_bytes(false), matrix);
  EXPECT_GT(double(h.matrix_bytes(true)), 1e7 * double(matrix));
  // Empty-leaf boxes need a table of 4 bytes per cell: skipped here, and said so.
  EXPECT_NE(extra_value(st, "empty-leaf boxes").find("skipped"), std::string::npos)
      << extra_value(st, "empty-leaf boxes");
  // The dense storage at this size is refused by the memory guard instead of allocated.
  GridKdHybrid d;
  BuildParams pd = p;
  pd.hybrid_dense_matrix = true;
  EXPECT_THROW(d.build(m, pd), ParamError);
  // And the structure still answers rays correctly.
  const auto rays = random_rays(m, 5000, 5);
  EXPECT_EQ(compare(h, m, rays, brute_reference(m, rays), "stadium fine"), 0);
}

TEST(HybridMemory, DenseVersusBrickedWhereDenseStillFits) {
  const Mesh m = teapot_in_stadium(100.0f, 5);
  GridKdHybrid d, b;
  const BuildStats sd = d.build(m, params_with(0.5f, true));  // 400^3 = 64M cells = 256 MB
  const BuildStats sb = b.build(m, params_with(0.5f, false));
  EXPECT_GT(sd.bytes, 100 * sb.bytes) << "dense " << sd.bytes << " bricked " << sb.bytes;
}

TEST(HybridMemory, GuardRejectsAbsurdCellSize) {
  const Mesh m = random_soup(500, 2, 0.1f);
  for (bool dense : {false, true}) {
    GridKdHybrid h;
    try {
      h.build(m, params_with(2e-9f, dense));
      ADD_FAILURE() << "expected ParamError";
    } catch (const ParamError& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find("cell size"), std::string::npos) << msg;
      EXPECT_NE(msg.find("at least"), std::string::npos) << msg;
      EXPECT_NE(msg.find("budget"), std::string::npos) << msg;
    }
  }
  // A small explicit budget also trips the dense guard at a size that would otherwise work.
  GridKdHybrid h;
  BuildParams p = params_with(0.001f, true);  // 2000^3 cells = 32 GB dense
  p.memory_budget = uint64_t(64) << 20;
  EXPECT_THROW(h.build(m, p), ParamError);
}

// ---- counters and traces -----------------------------------------------------------------

TEST(Hybrid, CountedAndFastTraversalAgree) {
  const Mesh m = subdivided_sphere(Vec3(0.0f), 1.0f, 4);
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

// n x n rays from one eye through a square window over the test sphere, in image order:
// neighbours cross the same leaves.
std::vector<Ray> coherent_rays(int n) {
  std::vector<Ray> rays;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      Ray r;
      r.org = Vec3(0.2f, 0.1f, 4.0f);
      r.dir = normalize(Vec3(-1.3f + 2.6f * float(i) / float(n - 1),
                             -1.3f + 2.6f * float(j) / float(n - 1), -4.0f));
      rays.push_back(r);
    }
  return rays;
}

// The walk takes the leaf its thread last reached across the same leaf face when the exit
// cell lies in that leaf's kd box (the next-leaf cache, walk.h). Cache entries left by another
// structure (which NextLeafCache::claim must clear: in_kd_box does not check that a cached id is
// one of this structure's leaves, so without the claim this test fails), by incoherent rays or
// by the same coherent rays must never change an answer, nor the counters (every resolution
// counts as a lookup).
TEST(Hybrid, NextLeafCacheNeverChangesTheAnswer) {
  const Mesh ma = subdivided_sphere(Vec3(0.3f, -0.2f, 0.1f), 1.0f, 5);
  const Mesh mb = random_soup(3000, 5, 0.08f);
  GridKdHybrid ha, hb;
  ha.build(ma, params_with(0.0f, false));
  hb.build(mb, params_with(0.13f, true));
  // Coherent rays from one eye (neighbours cross the same leaves), then incoherent ones.
  std::vector<Ray> ra = coherent_rays(64);
  const auto more = random_rays(ma, 4096, 11);
  ra.insert(ra.end(), more.begin(), more.end());
  const auto rb = random_rays(mb, int(ra.size()), 12);
  const Reference refa = brute_reference(ma, ra), refb = brute_reference(mb, rb);
  int failures = 0;
  uint64_t steps = 0;
  const uint64_t taken_before = GridKdHybrid::next_leaves_from_cache();
  // The two structures in turn on one thread: each finds the other's leaves in the cache.
  for (size_t i = 0; i < ra.size(); ++i) {
    failures +=
        compare(ha, ma, {ra[i]}, Reference{{refa.hits[i]}, {refa.occluded[i]}}, "sphere, in turn");
    failures +=
        compare(hb, mb, {rb[i]}, Reference{{refb.hits[i]}, {refb.occluded[i]}}, "soup, in turn");
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
  EXPECT_EQ(compare(ha, ma, ra, refa, "sphere, alone"), 0);
  EXPECT_GT(taken_in_turn, taken_before)
      << "a ray traced right after itself takes its cached leaves";
  EXPECT_GT(GridKdHybrid::next_leaves_from_cache(), taken_in_turn)
      << "coherent rays take cached leaves";
}

// BuildParams::hybrid_next_leaf_cache = false (`--hybrid-no-next-leaf-cache`), the paper's walk:
// no leaf taken from the next-leaf cache, and the same hits and counters as the walk with it,
// ray by ray.
TEST(Hybrid, WithoutNextLeafCacheTheSameWalk) {
  const Mesh m = subdivided_sphere(Vec3(0.3f, -0.2f, 0.1f), 1.0f, 5);
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
    GTEST_SKIP() << "flat subtrees are built for AVX-512 targets only; this build walks every "
                    "subtree by its kd nodes";
  // Cells of a fifth to a third of the meshes' size: leaves of hundreds of triangles, whose
  // subtrees have 5 to 16 leaves with triangles (the auto grid's leaves here hold at most 32).
  struct Case {
    const char* name;
    Mesh mesh;
    float cell;
  };
  const Case cases[] = {
      {"sphere", subdivided_sphere(Vec3(0.3f, -0.2f, 0.1f), 1.0f, 6), 0.2f},
      {"soup", random_soup(30000, 21, 0.03f), 0.3f},
      {"sphere far from the origin",
       transformed(subdivided_sphere(Vec3(0.0f), 1.0f, 6), 1.0f, Vec3(1e4f, -3e3f, 2e3f)), 0.2f}};
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

// ---- parameters and degenerate scenes ----------------------------------------------------

TEST(HybridParams, CellSizeValidation) {
  const Mesh m = random_soup(300, 3, 0.1f);
  GridKdHybrid ref;
  ref.build(m, params_with(0.0f, false));
  for (float bad : {std::nanf(""), kInf, -kInf}) {
    GridKdHybrid h;
    EXPECT_THROW(h.build(m, params_with(bad, false)), ParamError) << bad;
  }
  // 0 and negative sizes mean auto.
  for (float autoish : {0.0f, -1.0f}) {
    GridKdHybrid h;
    h.build(m, params_with(autoish, false));
    EXPECT_EQ(h.cell_size(), ref.cell_size());
  }
  for (float pct : {0.0f, -5.0f, 150.0f, std::nanf("")}) {
    GridKdHybrid h;
    BuildParams p = params_with(0.0f, false);
    p.cell_percentile = pct;
    EXPECT_THROW(h.build(m, p), ParamError) << pct;
  }
  GridKdHybrid h;
  BuildParams p;
  p.hybrid_intersection_cost = 0.0f;
  EXPECT_THROW(h.build(m, p), ParamError);
}

TEST(HybridParams, AutoRuleIsReported) {
  const Mesh m = random_soup(3000, 3, 0.05f);
  GridKdHybrid h;
  const BuildStats st = h.build(m, params_with(0.0f, false));
  ASSERT_GE(st.extra.size(), 3u);
  EXPECT_EQ(st.extra[0].first, "cell_size");
  EXPECT_EQ(st.extra[1].first, "auto rule");
  EXPECT_NE(st.extra[1].second.find("p90"), std::string::npos);
  EXPECT_EQ(st.extra[2].first, "grid");
  // The auto cell is the 90th percentile of the triangles' largest extents, unless the
  // density floor (16 cells per triangle) asks for a smaller one.
  std::vector<float> e;
  for (size_t i = 0; i < m.num_triangles(); ++i)
    e.push_back(max_component(m.triangle_bounds(i).extent()));
  std::sort(e.begin(), e.end());
  const double p90 = e[size_t(std::ceil(0.9 * double(e.size()))) - 1];
  const Vec3 ext = m.bounds().extent();
  const double dens =
      std::cbrt(double(ext.x) * ext.y * ext.z / (kHybridAutoCellsPerTriangle * m.num_triangles()));
  EXPECT_NEAR(h.cell_size(), std::min(p90, dens), 1e-6 * p90);
  // A few large triangles among many small ones: the percentile rule alone would keep them
  // in a handful of cells; the density floor gives at least 16 cells per triangle.
  Mesh mixed = random_soup(200, 4, 0.9f);
  mixed.append(random_soup(20, 5, 0.002f));
  GridKdHybrid hm;
  hm.build(mixed, params_with(0.0f, false));
  EXPECT_GE(double(hm.dims()[0]) * hm.dims()[1] * hm.dims()[2], 16.0 * 220.0);
  EXPECT_NE(hm.stats().extra[1].second.find("lowered"), std::string::npos)
      << hm.stats().extra[1].second;
}

TEST(HybridParams, AutoGridCappedAtItsCellBudget) {
  // 100K small triangles: their p90 extent asks for 22M cells; the auto rule raises the cell
  // until the grid has at most kHybridAutoMaxCells (the leaf subtrees resolve the geometry
  // below a cell), and says so.
  const Mesh m = random_soup(100000, 6, 0.004f);
  GridKdHybrid h;
  h.build(m, params_with(0.0f, false));
  const double cells = double(h.dims()[0]) * h.dims()[1] * h.dims()[2];
  EXPECT_LE(cells, kHybridAutoMaxCells);
  EXPECT_GE(cells, 0.5 * kHybridAutoMaxCells) << "raised no further than the cap needs";
  EXPECT_NE(h.stats().extra[1].second.find("raised"), std::string::npos)
      << h.stats().extra[1].second;
  // Plain leaves keep cells about a triangle wide, up to the larger kHybridAutoMaxCellsPlain.
  BuildParams plain = params_with(0.0f, false);
  plain.hybrid_subtree_min = 0;
  GridKdHybrid hp;
  hp.build(m, plain);
  const double plain_cells = double(hp.dims()[0]) * hp.dims()[1] * hp.dims()[2];
  EXPECT_GT(plain_cells, 8.0 * kHybridAutoMaxCells);
  EXPECT_LE(plain_cells, kHybridAutoMaxCellsPlain);
}

TEST(HybridParams, FlatScenesAndOversizedCells) {
  // All triangles in the plane z = 3: zero extent on z still gives one cell there.
  Mesh flat;
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (int i = 0; i < 500; ++i) {
    const Vec3 c(u(rng), u(rng), 3.0f);
    add_tri(flat, c, c + Vec3(0.05f, 0.0f, 0.0f), c + Vec3(0.0f, 0.05f, 0.0f));
  }
  GridKdHybrid h;
  h.build(flat, params_with(0.0f, false));
  EXPECT_EQ(h.dims()[2], 1);
  EXPECT_GT(h.dims()[0], 1);
  const auto rays = random_rays(flat, 5000, 2);
  EXPECT_EQ(compare(h, flat, rays, brute_reference(flat, rays), "flat"), 0);
  // A cell larger than the scene gives one cell.
  GridKdHybrid one;
  one.build(flat, params_with(100.0f, true));
  EXPECT_EQ(one.dims()[0] * one.dims()[1] * one.dims()[2], 1);
  EXPECT_EQ(compare(one, flat, rays, brute_reference(flat, rays), "flat one cell"), 0);
  // An empty mesh builds and misses everything.
  Mesh empty;
  GridKdHybrid e;
  e.build(empty, params_with(0.0f, false));
  Hit hit;
  EXPECT_FALSE(e.intersect(Ray{Vec3(0.0f), 0.0f, Vec3(1, 0, 0), kInf}, hit));
}

TEST(HybridParams, RejectsNonFiniteGeometryAndInvalidRays) {
  Mesh m = random_soup(10, 3, 0.1f);
  GridKdHybrid ok;
  ok.build(m, params_with(0.0f, false));
  Hit hit;
  EXPECT_FALSE(ok.intersect(Ray{Vec3(std::nanf("")), 0.0f, Vec3(1, 0, 0), kInf}, hit));
  EXPECT_FALSE(ok.intersect(Ray{Vec3(0.0f), 0.0f, Vec3(0.0f), kInf}, hit));
  m.positions[4].y = std::nanf("");
  GridKdHybrid h;
  EXPECT_THROW(h.build(m, params_with(0.0f, false)), ParamError);
}

TEST(Hybrid, BuildIsDeterministic) {
  const Mesh m = random_soup(20000, 12, 0.03f);
  GridKdHybrid a, b;
  BuildParams p = params_with(0.0f, false);
  const BuildStats sa = a.build(m, p);
  p.threads = 1;
  const BuildStats sb = b.build(m, p);
  EXPECT_EQ(sa.nodes, sb.nodes);
  EXPECT_EQ(sa.references, sb.references);
  EXPECT_EQ(sa.bytes, sb.bytes);
  ASSERT_EQ(a.leaves().size(), b.leaves().size());
  for (size_t i = 0; i < a.leaves().size(); ++i) {
    ASSERT_EQ(a.leaves()[i].first, b.leaves()[i].first);
    ASSERT_EQ(a.leaves()[i].count, b.leaves()[i].count);
  }
}

// ---- cell-size estimate, refusal and one cell ---------------------------------------------

TEST(HybridEstimate, MatchesTheBuildAtAutoAndFinerSizes) {
  const Mesh m = subdivided_sphere(Vec3(0.0f), 1.0f, 6);  // 32768 triangles, edges ~0.02-0.03
  GridKdHybrid a;
  const BuildStats sa = a.build(m, params_with(0.0f, false));
  const HybridEstimate ea = GridKdHybrid::estimate(m, params_with(0.0f, false));
  EXPECT_EQ(ea.cell, a.cell_size());
  EXPECT_EQ(ea.auto_cell, a.cell_size());
  for (int k = 0; k < 3; ++k) EXPECT_EQ(ea.dims[k], double(a.dims()[k]));
  EXPECT_TRUE(ea.fits);
  EXPECT_EQ(ea.rule, extra_value(sa, "auto rule"));
  // At the auto size and 4 and 8 times finer the structure's bytes are those of the build
  // within a factor of 3 (the matrix dominates at the finer sizes), and the peak is above them.
  for (double f : {1.0, 4.0, 8.0}) {
    const float c = float(a.cell_size() / f);
    GridKdHybrid h;
    const BuildStats st = h.build(m, params_with(c, false));
    const HybridEstimate e = GridKdHybrid::estimate(m, params_with(c, false));
    EXPECT_TRUE(e.fits) << f;
    EXPECT_GT(e.structure_bytes, double(st.bytes) / 3.0)
        << "cells " << f << "x finer than auto: " << e.describe();
    EXPECT_LT(e.structure_bytes, double(st.bytes) * 3.0)
        << "cells " << f << "x finer than auto: " << e.describe();
    EXPECT_GE(e.bytes, e.structure_bytes);
  }
}

/// The size suggested by an explicit size's refusal; 0 if the build was not refused.
double refused_and_suggested(const Mesh& m, float cell, std::string* msg) {
  GridKdHybrid h;
  try {
    h.build(m, params_with(cell, false));
  } catch (const ParamError& e) {
    *msg = e.what();
    const std::string tag = "at least ";
    const size_t at = msg->find(tag);
    return at == std::string::npos ? -1.0 : std::atof(msg->c_str() + at + tag.size());
  }
  return 0.0;
}

TEST(HybridEstimate, TinyCellIsRefusedUpFrontWithASizeThatBuildsQuickly) {
  const Mesh m = subdivided_sphere(Vec3(0.0f), 1.0f, 6);
  std::vector<double> built;  // each distinct suggestion is built once
  for (float tiny : {1e-9f, 1e-6f, 1e-4f}) {
    std::string msg;
    const auto t0 = std::chrono::steady_clock::now();
    const double suggested = refused_and_suggested(m, tiny, &msg);
    const double refuse_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    ASSERT_GT(suggested, 0.0) << tiny << ": " << msg;
    EXPECT_LT(refuse_s, 2.0) << "the refusal is an estimate, not a build";
    EXPECT_NE(msg.find("cells"), std::string::npos) << msg;
    EXPECT_NE(msg.find("GiB"), std::string::npos) << msg;
    EXPECT_NE(msg.find("budget"), std::string::npos) << msg;
    // The suggestion fits its own estimate, and builds within a bound (on a loaded 2-core
    // machine; the limit it was chosen for is 10 estimated seconds).
    EXPECT_TRUE(GridKdHybrid::estimate(m, params_with(float(suggested), false)).fits) << suggested;
    std::printf("cell %g refused; suggested %g\n", double(tiny), suggested);
    if (std::find(built.begin(), built.end(), suggested) != built.end()) continue;
    built.push_back(suggested);
    GridKdHybrid h;
    const auto t1 = std::chrono::steady_clock::now();
    ASSERT_NO_THROW(h.build(m, params_with(float(suggested), false))) << suggested;
    const double build_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
    EXPECT_LT(build_s, 60.0) << "suggested cell size " << suggested;
    const auto rays = random_rays(m, 2000, 41);
    EXPECT_EQ(compare(h, m, rays, brute_reference(m, rays), "suggested size"), 0);
  }
}

TEST(HybridEstimate, BunnySuggestedSizeBuildsWithinABound) {
  KDGRID_REQUIRE_SCENE(path, "bunny/bun_zipper.ply");
  const Mesh m = load_scene(path).mesh;
  std::string msg;
  const double suggested = refused_and_suggested(m, 1e-8f, &msg);
  ASSERT_GT(suggested, 0.0) << msg;
  GridKdHybrid h;
  const auto t0 = std::chrono::steady_clock::now();
  const BuildStats st = h.build(m, params_with(float(suggested), false));
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_LT(s, 90.0) << msg;
  const HybridEstimate e = GridKdHybrid::estimate(m, params_with(float(suggested), false));
  EXPECT_LT(double(st.bytes), e.bytes * 3.0) << e.describe();
  std::printf("bunny: %s\nsuggested %g built in %.1f s, %.0f MiB (estimate: %s)\n", msg.c_str(),
              suggested, s, double(st.bytes) / 1048576.0, e.describe().c_str());
}

// The mailbox serves the lane-by-lane walk (WatertightScalar here; MollerTest); the wide walk
// tests its groups without it (docs/HYBRID.md, "Wide leaves"), and tests/test_wide.cpp holds its
// hits to these. The queries below are the lane-by-lane walk's.
bool scalar_closest(const GridKdHybrid& h, const Ray& r, Hit& hit) {
  NoProbe s;
  return h.traverse<WatertightScalar, NoProbe, false>(r, &hit, s);
}
bool scalar_any(const GridKdHybrid& h, const Ray& r) {
  NoProbe s;
  return h.traverse<WatertightScalar, NoProbe, true>(r, nullptr, s);
}
bool scalar_counted(const GridKdHybrid& h, const Ray& r, Hit& hit, RayCounters& c) {
  CountProbe s;
  const bool got = h.traverse<WatertightScalar, CountProbe, false>(r, &hit, s);
  c += s.c;
  return got;
}
Trace scalar_trace(const GridKdHybrid& h, const Ray& r) {
  Trace t;
  TraceProbe s(&t);
  Hit hit;
  h.traverse<WatertightScalar, TraceProbe, false>(r, &hit, s);
  t.hit = hit;
  return t;
}

TEST(HybridEstimate, CellLargerThanTheSceneIsOneCellWalkedLikeTheKdTree) {
  const Mesh m = subdivided_sphere(Vec3(0.0f), 1.0f, 6);
  GridKdHybrid one;
  const BuildStats st = one.build(m, params_with(1e9f, false));
  EXPECT_EQ(one.dims()[0] * one.dims()[1] * one.dims()[2], 1);
  EXPECT_LE(one.cell_size(), 2.0 + 1e-6) << "one cell of the scene's extent, not 1e9";
  EXPECT_NE(extra_value(st, "auto rule").find("larger than the scene"), std::string::npos);
  const auto rays = random_rays(m, 4000, 9);
  EXPECT_EQ(compare(one, m, rays, brute_reference(m, rays), "one cell"), 0);
  // Tests per ray as the auto grid's (the subtree of the one leaf splits as the kd-tree does),
  // and no ray tests a triangle twice, although the one leaf's subtree holds each straddling
  // triangle in several leaves and a 32-entry mailbox alone lost 12 of these 4000 rays' repeats.
  GridKdHybrid grid;
  grid.build(m, params_with(0.0f, false));
  double tests_one = 0, tests_grid = 0;
  int twice = 0;
  for (const Ray& r : rays) {
    const Trace t = scalar_trace(one, r);
    tests_one += double(t.counters.tri_tests);
    std::vector<uint32_t> tested = t.tested;
    std::sort(tested.begin(), tested.end());
    twice += std::adjacent_find(tested.begin(), tested.end()) != tested.end();
    tests_grid += double(scalar_trace(grid, r).counters.tri_tests);
  }
  EXPECT_EQ(twice, 0) << "rays that tested a triangle twice";
  // The one leaf's subtree is deeper and its SAH fills leaves up to a group (kWideLanes): with
  // groups of 16 the one cell tests 18.2 triangles a ray against the auto grid's 7.4, of the
  // sphere's 32,768.
  EXPECT_LT(tests_one, 3.0 * tests_grid)
      << "one cell " << tests_one / double(rays.size()) << " tests per ray, auto grid "
      << tests_grid / double(rays.size());
}

// ---- the mailbox's exactness ------------------------------------------------------------

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
  EXPECT_EQ(compare(h, m, rays, brute_reference(m, rays), label), 0) << label;
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
