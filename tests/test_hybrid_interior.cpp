// The hybrid on an interior of large flat polygons: a hall (floor, walls, ceiling, columns, a
// table, chairs; every face two triangles, as scripts/gen-hall.py builds it without its
// tessellation and torus). The top-level SAH must cut the cell layer holding the ceiling off
// the hall's empty volume, so that rays crossing the hall step over it in few leaves instead
// of testing the ceiling, walls and columns of every whole-height leaf on their way; and the
// hits must stay the brute force's.
#include <gtest/gtest.h>

#include <cstdio>

#include "accel/brute.h"
#include "accel/hybrid/hybrid.h"
#include "scene/procedural.h"

namespace kdgrid::test {
namespace {

void add_box(Mesh& m, Vec3 lo, Vec3 hi) {
  m.append(make_box((lo + hi) * 0.5f, (hi - lo) * 0.5f));
}

/// A 1500 x 400 x 1000 hall with 16 columns, a table and 24 chairs of six boxes each.
Mesh hall() {
  Mesh m;
  add_box(m, Vec3(0, 0, 0), Vec3(1500, 400, 1000));
  for (int i = 0; i < 8; ++i)
    for (const float z : {150.0f, 850.0f})
      add_box(m, Vec3(100.0f + 185.0f * float(i), 0, z),
              Vec3(120.0f + 185.0f * float(i), 400, z + 20));
  add_box(m, Vec3(450, 70, 400), Vec3(1050, 80, 600));
  for (const float z : {370.0f, 610.0f})
    for (int i = 0; i < 12; ++i) {
      const float x = 460.0f + 50.0f * float(i);
      for (const float lx : {0.0f, 16.0f})
        for (const float lz : {0.0f, 16.0f})
          add_box(m, Vec3(x + lx, 0, z + lz), Vec3(x + lx + 2, 45, z + lz + 2));
      add_box(m, Vec3(x, 45, z), Vec3(x + 18, 50, z + 18));
      const float back = z < 400.0f ? z : z + 16.0f;
      add_box(m, Vec3(x, 50, back), Vec3(x + 18, 95, back + 2));
    }
  return m;
}

TEST(HybridInterior, RaysAcrossAHallStepOverItsEmptyVolume) {
  const Mesh m = hall();
  BuildParams p;
  p.threads = 1;
  GridKdHybrid h;
  h.build(m, p);
  BruteForce brute;
  brute.build(m, p);
  // Rays from one eye inside the hall to a lattice of points on the far wall, over the table.
  const Vec3 eye(100, 200, 500);
  RayCounters total;
  int rays = 0, wrong = 0;
  for (int iy = 0; iy < 32; ++iy)
    for (int iz = 0; iz < 32; ++iz) {
      const Vec3 target(1499, 10.0f + 12.0f * float(iy), 200.0f + 19.0f * float(iz));
      Ray r{eye, 0.0f, normalize(target - eye), kInf};
      Hit a, b;
      RayCounters c;
      h.intersect_counted(r, a, c);
      brute.intersect(r, b);
      wrong += a.valid() != b.valid() || a.t != b.t;  // ties: another triangle, same t
      total.steps += c.steps;
      total.tri_tests += c.tri_tests;
      ++rays;
    }
  const double steps = double(total.steps) / rays, tests = double(total.tri_tests) / rays;
  std::printf("[ counters ] %d rays: %.2f steps, %.2f lanes tested per ray\n", rays, steps, tests);
  EXPECT_EQ(wrong, 0);
  // With the kd-tree's cost ratio (1.5) the leaves holding the ceiling span the hall's height:
  // about 11 steps and 47 lanes a ray; the default takes about 6 and 17.
  EXPECT_LT(steps, 8.5);
  EXPECT_LT(tests, 30.0);
}

}  // namespace
}  // namespace kdgrid::test
