// The irregular grid (Pérard-Gayot et al. 2017) against brute force on procedural meshes,
// plus the extreme-ray suite, memory bound, parameter errors and counter/trace consistency.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "accel/brute.h"
#include "accel/irregular.h"
#include "comparator_meshes.h"
#include "extreme_rays.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

// ---- procedural meshes --------------------------------------------------------------------

using test::add_quad;
using test::add_tri;
using test::random_rays;
using test::random_soup;
using test::transformed;

Mesh sphere(int levels) {
  return test::octahedron_sphere(levels);
}

using test::grid_quads;

/// Long thin triangles crossing the box: two far corners and a third a hair off the edge.
Mesh thin_triangles(int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f), t(0.1f, 0.9f), e(-1e-3f, 1e-3f);
  Mesh m;
  for (int i = 0; i < n; ++i) {
    const Vec3 a(u(rng), u(rng), u(rng)), b(u(rng), u(rng), u(rng));
    const Vec3 c = lerp(a, b, t(rng)) + Vec3(e(rng), e(rng), e(rng));
    add_tri(m, a, b, c);
  }
  return m;
}

/// Teapot in a stadium: a dense sphere (the teapot) of radius 1 at the origin inside a
/// 1000-unit arena of a few large quads.
Mesh teapot_in_stadium(int levels) {
  Mesh m = sphere(levels);  // 8 * 4^levels triangles
  const float s = 500.0f, h = 100.0f;
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 10; ++j) {
      const float x0 = -s + 100.0f * i, z0 = -s + 100.0f * j;
      add_quad(m, {x0, -2, z0}, {x0 + 100, -2, z0}, {x0 + 100, -2, z0 + 100}, {x0, -2, z0 + 100});
    }
  add_quad(m, {-s, -2, -s}, {s, -2, -s}, {s, h, -s}, {-s, h, -s});
  add_quad(m, {-s, -2, s}, {s, -2, s}, {s, h, s}, {-s, h, s});
  add_quad(m, {-s, -2, -s}, {-s, -2, s}, {-s, h, s}, {-s, h, -s});
  add_quad(m, {s, -2, -s}, {s, -2, s}, {s, h, s}, {s, h, -s});
  return m;
}

// ---- comparison with brute force ----------------------------------------------------------

struct Reference {
  std::vector<Hit> hits;
  std::vector<uint8_t> found, occluded;
};

Reference reference(const Mesh& m, const std::vector<Ray>& rays,
                    TriangleTestKind test = TriangleTestKind::Watertight) {
  BruteForce brute;
  BuildParams p;
  p.triangle_test = test;
  brute.build(m, p);
  Reference ref;
  ref.hits.resize(rays.size());
  ref.found.resize(rays.size());
  ref.occluded.resize(rays.size());
  for (size_t i = 0; i < rays.size(); ++i) {
    ref.found[i] = brute.intersect(rays[i], ref.hits[i]);
    ref.occluded[i] = brute.occluded(rays[i]);
  }
  return ref;
}

/// t of triangle `prim` alone along the ray, or -1 if the test misses it.
float own_t(const Mesh& m, const Ray& ray, uint32_t prim, TriangleTestKind test) {
  const auto c = m.corners(prim);
  float t, u, v;
  bool hit;
  if (test == TriangleTestKind::Watertight)
    hit = WatertightTest::intersect(WatertightTest::prepare(ray), c[0], c[1], c[2], ray.tmin,
                                    ray.tmax, t, u, v);
  else
    hit = MollerTest::intersect(MollerTest::prepare(ray), c[0], c[1], c[2], ray.tmin, ray.tmax, t,
                                u, v);
  return hit ? t : -1.0f;
}

bool close_t(float a, float b) {
  return std::fabs(a - b) <= 1e-5f * std::max(std::fabs(a), std::fabs(b)) || a == b;
}

/// Number of rays on which the grid disagrees with the reference (closest t, triangle unless
/// a tie, any-hit). Prints the first few.
int count_disagreements(const IrregularGrid& g, const Mesh& m, const std::vector<Ray>& rays,
                        const Reference& ref, const std::string& label,
                        TriangleTestKind test = TriangleTestKind::Watertight) {
  int bad = 0;
  for (size_t i = 0; i < rays.size(); ++i) {
    Hit h;
    const bool found = g.intersect(rays[i], h);
    const bool occ = g.occluded(rays[i]);
    bool ok = found == bool(ref.found[i]) && occ == bool(ref.occluded[i]);
    if (ok && found) {
      ok = close_t(h.t, ref.hits[i].t);
      // A different triangle is fine only at a tie: its own t must equal the reference t.
      if (ok && h.prim != ref.hits[i].prim)
        ok = close_t(own_t(m, rays[i], h.prim, test), ref.hits[i].t);
    }
    if (!ok && ++bad <= 5) {
      const Ray& r = rays[i];
      ADD_FAILURE() << label << ": ray " << i << " org (" << r.org.x << ", " << r.org.y << ", "
                    << r.org.z << ") dir (" << r.dir.x << ", " << r.dir.y << ", " << r.dir.z
                    << ") [" << r.tmin << ", " << r.tmax << "]: grid " << found << " t=" << h.t
                    << " prim=" << h.prim << " occ=" << occ << ", brute " << int(ref.found[i])
                    << " t=" << ref.hits[i].t << " prim=" << ref.hits[i].prim
                    << " occ=" << int(ref.occluded[i]);
    }
  }
  return bad;
}

BuildParams params_for(float top, float sub, bool merge, bool expand) {
  BuildParams p;
  p.irregular_top_density = top;
  p.irregular_sub_density = sub;
  p.irregular_merge = merge;
  p.irregular_expand = expand;
  return p;
}

std::string stat(const BuildStats& s, const std::string& key) {
  for (const auto& [k, v] : s.extra)
    if (k == key) return v;
  return "";
}

/// Builds with every merge/expand combination at three densities and checks agreement.
void check_mesh_agreement(const Mesh& m, const std::string& name, int num_rays, uint32_t seed) {
  const auto rays = random_rays(m, num_rays, seed);
  const Reference ref = reference(m, rays);
  int hits = 0;
  for (uint8_t f : ref.found) hits += f;
  EXPECT_GT(hits, num_rays / 4) << name << ": the ray set should hit often";
  const float densities[3][2] = {{0.12f, 2.4f}, {0.02f, 0.5f}, {1.0f, 6.0f}};
  for (const auto& d : densities)
    for (int mode = 0; mode < 4; ++mode) {
      const bool merge = mode & 1, expand = mode & 2;
      IrregularGrid g;
      const BuildStats s = g.build(m, params_for(d[0], d[1], merge, expand));
      const std::string label = name + " top=" + std::to_string(d[0]) +
                                " sub=" + std::to_string(d[1]) + " merge=" + std::to_string(merge) +
                                " expand=" + std::to_string(expand);
      const auto t0 = std::chrono::steady_clock::now();
      EXPECT_EQ(count_disagreements(g, m, rays, ref, label), 0) << label;
      const double query_s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      EXPECT_EQ(g.step_bound_hits(), 0u) << label;
      std::printf(
          "[ info ] %s: cells %s -> %s merged, %s expanded; %llu refs; %llu bytes "
          "(map %llu, cells %llu, refs %llu); build %.3f s, queries %.3f s\n",
          label.c_str(), stat(s, "cells before merge").c_str(),
          stat(s, "cells after merge").c_str(), stat(s, "cells expanded").c_str(),
          (unsigned long long)s.references, (unsigned long long)s.bytes,
          (unsigned long long)s.bytes_by_part[0].second,
          (unsigned long long)s.bytes_by_part[1].second,
          (unsigned long long)s.bytes_by_part[2].second, s.seconds, query_s);
    }
}

// ---- agreement ----------------------------------------------------------------------------

TEST(Irregular, AgreesWithBruteForceOnRandomSoup) {
  check_mesh_agreement(random_soup(3000, 1, 0.15f), "soup", 20000, 11);
}

TEST(Irregular, AgreesWithBruteForceOnSphere) {
  check_mesh_agreement(sphere(5), "sphere", 20000, 12);
}

TEST(Irregular, AgreesWithBruteForceOnGridQuads) {
  check_mesh_agreement(grid_quads(), "quads", 20000, 13);
}

TEST(Irregular, AgreesWithBruteForceOnThinTriangles) {
  check_mesh_agreement(thin_triangles(1000, 4), "thin", 20000, 14);
}

TEST(Irregular, AgreesWithBruteForceOnTeapotInStadium) {
  check_mesh_agreement(teapot_in_stadium(5), "stadium", 6000, 15);
}

TEST(Irregular, AgreesWithBruteForceWithMollerTest) {
  const Mesh m = sphere(4);
  const auto rays = random_rays(m, 10000, 16);
  const Reference ref = reference(m, rays, TriangleTestKind::Moller);
  IrregularGrid g;
  BuildParams p;
  p.triangle_test = TriangleTestKind::Moller;
  g.build(m, p);
  EXPECT_EQ(count_disagreements(g, m, rays, ref, "moller", TriangleTestKind::Moller), 0);
}

// ---- merge and expansion do what they say -------------------------------------------------

TEST(Irregular, MergeReducesCellsAndExpansionGrowsBoxes) {
  const Mesh m = random_soup(3000, 2, 0.15f);
  IrregularGrid plain, merged;
  const BuildStats a = plain.build(m, params_for(0.12f, 2.4f, false, false));
  const BuildStats b = merged.build(m, params_for(0.12f, 2.4f, true, true));
  EXPECT_EQ(stat(a, "cells before merge"), stat(a, "cells after merge"));
  EXPECT_EQ(stat(a, "cells expanded"), "0");
  EXPECT_EQ(stat(a, "cells before merge"), stat(b, "cells before merge"));
  EXPECT_LT(std::stoull(stat(b, "cells after merge")), std::stoull(stat(b, "cells before merge")));
  EXPECT_GT(std::stoull(stat(b, "cells expanded")), 0u);
  EXPECT_EQ(b.nodes, merged.num_cells());
  // The voxel map and the cells account for all structure bytes but the object itself.
  uint64_t parts = 0;
  for (const auto& [k, v] : b.bytes_by_part) parts += v;
  EXPECT_EQ(parts + sizeof(IrregularGrid), b.bytes);
  // Overlay boxes are non-empty cells inside the grid.
  uint64_t boxes = 0, refs = 0;
  merged.for_each_box([&](const StructureBox& sb) {
    ++boxes;
    refs += sb.num_triangles;
    EXPECT_FALSE(sb.box.empty());
  });
  EXPECT_EQ(boxes, b.nodes - b.empty_leaves);
  EXPECT_EQ(refs, b.references);
}

// ---- extreme rays -------------------------------------------------------------------------
// Agreement with brute force on the extreme-ray families: test_extreme_rays.cpp. Here, what
// only the irregular grid promises: its step bound, and rays far from the grid take no step.

/// Builds the default grid over m, and one without merge/expand, and checks the given rays
/// against brute force and the step bound.
void check_rays(const Mesh& m, const std::vector<Ray>& rays, const std::string& label,
                const BuildParams& p = BuildParams()) {
  const Reference ref = reference(m, rays);
  IrregularGrid g;
  g.build(m, p);
  EXPECT_EQ(count_disagreements(g, m, rays, ref, label), 0);
  EXPECT_EQ(g.step_bound_hits(), 0u) << label;
  BuildParams q = p;
  q.irregular_merge = q.irregular_expand = false;
  g.build(m, q);
  EXPECT_EQ(count_disagreements(g, m, rays, ref, label + " (no merge/expand)"), 0);
  EXPECT_EQ(g.step_bound_hits(), 0u) << label;
}

TEST(Irregular, StepBoundOnExtremeRays) {
  const Mesh quads = grid_quads(), soup = random_soup(2000, 5, 0.2f), ball = sphere(4);
  for (const Mesh* m : {&quads, &soup, &ball}) {
    std::vector<Ray> rays = test::axis_parallel_rays_from_outside(1000, 21);
    const auto zeros = test::zero_component_rays(-1.2f, 1.2f, 1000, 22, 5);
    const auto planes = test::rays_in_lattice_planes(0.5f, -2, 2, -1.2f, 1.2f, 1000, 23);
    rays.insert(rays.end(), zeros.begin(), zeros.end());
    rays.insert(rays.end(), planes.begin(), planes.end());
    for (bool merge_expand : {true, false}) {
      BuildParams p;
      p.irregular_merge = p.irregular_expand = merge_expand;
      IrregularGrid g;
      g.build(*m, p);
      for (const Ray& r :
           test::rays_from_structure_boundaries(test::structure_planes(g, *m, 200), *m, 1000, 24))
        rays.push_back(r);
      for (const Ray& r : rays) {
        Hit h;
        g.intersect(r, h);
        g.occluded(r);
      }
      EXPECT_EQ(g.step_bound_hits(), 0u) << merge_expand;
    }
  }
}

TEST(Irregular, RaysFarFromTheGridTakeNoStep) {
  IrregularGrid g;
  g.build(sphere(4), BuildParams());
  const auto rays = test::rays_missing_the_sphere(1000, 25);
  for (size_t i = 0; i < rays.size(); ++i) {
    RayCounters c;
    Hit h;
    EXPECT_FALSE(g.intersect_counted(rays[i], h, c));
    // Pointing away and passing by never come within 5 of the centre: they never enter.
    if (i % 3 != 2) {
      EXPECT_EQ(c.steps, 0u);
    }
  }
}

// ---- memory and parameters ----------------------------------------------------------------

TEST(Irregular, TeapotInStadiumMemoryBound) {
  const Mesh m = teapot_in_stadium(6);
  IrregularGrid g;
  const BuildStats s = g.build(m, BuildParams());
  const auto res = g.lattice_resolution();
  const double dense_map = 4.0 * double(res[0]) * res[1] * res[2];
  std::printf(
      "[ info ] stadium: %zu tris, top %s, lattice %s, %llu cells, %llu refs, %llu bytes "
      "(map %llu, cells %llu, refs %llu); a dense voxel map would take %.0f bytes\n",
      m.num_triangles(), stat(s, "top resolution").c_str(), stat(s, "lattice resolution").c_str(),
      (unsigned long long)s.nodes, (unsigned long long)s.references, (unsigned long long)s.bytes,
      (unsigned long long)s.bytes_by_part[0].second, (unsigned long long)s.bytes_by_part[1].second,
      (unsigned long long)s.bytes_by_part[2].second, dense_map);
  // Stated bound: at most 256 bytes per triangle, and far below a dense map of the lattice.
  EXPECT_LT(double(s.bytes), 256.0 * double(m.num_triangles()));
  EXPECT_LT(double(s.bytes_by_part[0].second), 0.05 * dense_map);
}

TEST(Irregular, AbsurdParametersThrowParamError) {
  const Mesh m = sphere(3);
  IrregularGrid g;
  BuildParams p;
  p.memory_budget = uint64_t(1) << 30;
  // The message of the ParamError that building with `p` must throw.
  const auto refusal = [&]() -> std::string {
    try {
      g.build(m, p);
    } catch (const ParamError& e) {
      return e.what();
    }
    ADD_FAILURE() << "expected ParamError";
    return "";
  };
  p.irregular_top_density = 1e12f;
  EXPECT_CONTAINS(refusal(), "irregular_top_density");
  p.irregular_top_density = 0.12f;
  p.irregular_sub_density = 1e12f;
  EXPECT_CONTAINS(refusal(), "irregular_sub_density");
  for (float bad : {0.0f, -1.0f, std::numeric_limits<float>::quiet_NaN(), kInf}) {
    p.irregular_sub_density = 2.4f;
    p.irregular_top_density = bad;
    EXPECT_THROW(g.build(m, p), ParamError);
    p.irregular_top_density = 0.12f;
    p.irregular_sub_density = bad;
    EXPECT_THROW(g.build(m, p), ParamError);
  }
  // A failed build leaves a usable, empty structure; a good build afterwards works.
  Hit h;
  EXPECT_FALSE(g.intersect({Vec3(-5, 0, 0), 0.0f, Vec3(1, 0, 0), kInf}, h));
  p.irregular_sub_density = 2.4f;
  g.build(m, p);
  EXPECT_TRUE(g.intersect({Vec3(-5, 0, 0), 0.0f, Vec3(1, 0, 0), kInf}, h));
}

TEST(Irregular, EmptyAndFlatMeshes) {
  Mesh empty;
  IrregularGrid g;
  g.build(empty, BuildParams());
  Hit h;
  EXPECT_FALSE(g.intersect({Vec3(0.0f), 0.0f, Vec3(1, 0, 0), kInf}, h));
  // A single flat quad: the box is flat on y; rays from above and in its plane.
  Mesh flat;
  add_quad(flat, {-1, 0, -1}, {1, 0, -1}, {1, 0, 1}, {-1, 0, 1});
  std::mt19937 rng(27);
  std::uniform_real_distribution<float> u(-1.5f, 1.5f);
  std::vector<Ray> rays;
  for (int i = 0; i < 3000; ++i) {
    rays.push_back({Vec3(u(rng), 1.0f, u(rng)), 0.0f, Vec3(u(rng), -1.0f, u(rng)), kInf});
    rays.push_back({Vec3(u(rng), 0.0f, u(rng)), 0.0f, Vec3(u(rng), 0.0f, u(rng)), kInf});
  }
  check_rays(flat, rays, "flat");
}

// ---- counters and traces ------------------------------------------------------------------

TEST(Irregular, CountedAndTracedAgreeWithFast) {
  const Mesh m = teapot_in_stadium(5);
  IrregularGrid g;
  g.build(m, BuildParams());
  const auto rays = random_rays(m, 3000, 28);
  RayCounters total;
  for (const Ray& r : rays) {
    Hit fast, counted;
    RayCounters c;
    const bool f = g.intersect(r, fast);
    ASSERT_EQ(f, g.intersect_counted(r, counted, c));
    if (f) {
      EXPECT_EQ(fast.t, counted.t);
      EXPECT_EQ(fast.prim, counted.prim);
    }
    RayCounters ca;
    EXPECT_EQ(g.occluded(r), g.occluded_counted(r, ca));
    // Any-hit walks the same cells in the same order and stops no later than closest-hit.
    EXPECT_LE(ca.tri_tests, c.tri_tests);
    const Trace t = g.trace(r);
    EXPECT_EQ(t.counters, c);
    EXPECT_EQ(t.hit.prim, f ? fast.prim : kInvalidPrim);
    EXPECT_EQ(t.steps.size(), c.steps);
    EXPECT_EQ(t.tested.size(), c.tri_tests);
    EXPECT_EQ(c.lookups, c.steps);  // one voxel-map lookup per cell visited
    EXPECT_LE(c.leaves, c.steps);
    uint64_t tested = 0;
    for (size_t k = 0; k < t.steps.size(); ++k) {
      const TraceStep& st = t.steps[k];
      EXPECT_EQ(st.kind, StepKind::Cell);
      EXPECT_LE(st.t_in, st.t_out);
      if (k > 0) {
        EXPECT_LE(t.steps[k - 1].t_in, st.t_in) << "trace t_in must not decrease";
      }
      EXPECT_EQ(st.first_tested, tested);
      tested += st.num_tested;
      // The ray really is inside the cell's (exit) box between t_in and t_out.
      const Vec3 mid = r.at(0.5f * (st.t_in + st.t_out));
      const Vec3 slack = st.box.extent() * 1e-3f + Vec3(1e-3f);
      EXPECT_TRUE(Box3(st.box.lo - slack, st.box.hi + slack).contains(mid)) << "step " << k;
    }
    EXPECT_EQ(tested, t.tested.size());
    if (f && !t.steps.empty()) {
      // The hit lies before the exit of the last cell visited.
      EXPECT_LE(fast.t, t.steps.back().t_out * (1 + 1e-6f) + 1e-6f);
    }
    total += c;
  }
  EXPECT_GT(total.tri_tests, 0u);
  EXPECT_GT(total.steps, 0u);
  // The stadium's big floor quads are referenced by many cells along a ray.
  EXPECT_GT(total.mailbox_skips, 0u);
  EXPECT_EQ(g.step_bound_hits(), 0u);
}

}  // namespace
}  // namespace kdgrid
