// The hybrid grid/kd-tree against brute force on procedural meshes at several cell sizes, both
// matrix storages and every leaf variant, on non-cubic grids, and what only the hybrid promises
// on the extreme rays of docs/DESIGN.md's numerical rules (its step bound; rays missing the box
// take no step).
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

// ---- agreement with brute force ------------------------------------------------------

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
  const BruteReference ref = brute_answers(m, rays);
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
      EXPECT_EQ(compare_hybrid(h, m, rays, ref, label), 0) << label;
      if (getenv("HYB_TIME"))
        printf("%s build %.3fs rays %.3fs nodes %lu refs %lu\n", label.c_str(), st.seconds,
               std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
               (unsigned long)st.nodes, (unsigned long)st.references);
    }
  }
}

TEST(Hybrid, AgreesWithBruteForceRandomSoup) {
  check_mesh(random_soup(3000, 1, 0.08f), "soup", 0.13f);
}

TEST(Hybrid, AgreesWithBruteForceSphere) {
  check_mesh(octahedron_sphere(5, 1.0f, Vec3(0.3f, -0.2f, 0.1f)), "sphere", 0.05f);
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
  const BruteReference ref = brute_answers(m, rays);
  for (bool dense : {false, true}) {
    GridKdHybrid h;
    h.build(m, params_with(1.0f, dense));
    ASSERT_EQ(h.dims()[0], 7);
    ASSERT_EQ(h.dims()[1], 3);
    ASSERT_EQ(h.dims()[2], 11);
    EXPECT_EQ(compare_hybrid(h, m, rays, ref, dense ? "7x3x11 dense" : "7x3x11 bricked"), 0);
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

}  // namespace
}  // namespace kdgrid
