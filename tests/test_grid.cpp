// Uniform grid: agreement with brute force on extreme rays in cell planes, the DDA's step
// bound, mailboxing, resolution heuristic, exact overlap filter and memory guard. The checks
// shared by every structure are in test_structures.cpp.
#include <gtest/gtest.h>

#include "accel/grid.h"
#include "comparator_meshes.h"
#include "util/error.h"

namespace kdgrid {
namespace {

using test::count_disagreements;

// The planes of the grid's cell boundaries (every one, or every k-th on fine grids) and the
// box faces, for the extreme-ray suite.
std::vector<std::pair<int, float>> cell_planes(const UniformGrid& g) {
  std::vector<std::pair<int, float>> planes;
  const Box3 b = g.bounds();
  for (int a = 0; a < 3; ++a) {
    const int n = g.resolution()[a];
    const int every = std::max(1, n / 12);
    const float cs = b.extent()[a] / float(n);
    for (int k = 0; k <= n; k += every) planes.push_back({a, b.lo[a] + float(k) * cs});
    planes.push_back({a, b.hi[a]});
  }
  return planes;
}

// Every cell visited by a counted traversal stays under the bound nx+ny+nz+3.
int steps_over_bound(const UniformGrid& g, const std::vector<Ray>& rays) {
  int over = 0;
  for (const Ray& r : rays) {
    RayCounters c, o;
    Hit h;
    g.intersect_counted(r, h, c);
    g.occluded_counted(r, o);
    if (c.steps > g.max_steps() || o.steps > g.max_steps()) ++over;
  }
  return over;
}

// Agreement with brute force on these meshes and rays:
// Structures.AgreesWithBruteForceOnProceduralMeshes.
TEST(Grid, DdaStepBoundOnProceduralMeshes) {
  for (const auto& [name, mesh] : test::test_meshes()) {
    SCOPED_TRACE(name);
    UniformGrid g;
    g.build(mesh, BuildParams{});
    EXPECT_EQ(steps_over_bound(g, test::random_rays(mesh, 20000, 17)), 0);
  }
}

// Agreement with brute force on the extreme-ray families: test_extreme_rays.cpp. On the integer
// quads there, 8 cells per axis put the cell boundaries on the planes of the quads (checked
// here), and the DDA stays under its step bound on those rays.
TEST(Grid, DdaStepBoundOnExtremeRays) {
  for (const test::ScaleCase& c : test::extreme_scale_cases()) {
    SCOPED_TRACE(c.name);
    const Mesh mesh = test::transformed(test::integer_quads(8), c.scale, c.offset);
    BuildParams p;
    p.grid_lambda = 512.0f / float(mesh.num_triangles());
    UniformGrid g;
    g.build(mesh, p);
    ASSERT_EQ(g.resolution()[0], 8);
    ASSERT_EQ(g.resolution()[2], 8);
    EXPECT_EQ(steps_over_bound(g, test::extreme_rays(mesh, cell_planes(g), 23, 60)), 0);
  }
  for (const auto& [name, mesh] : test::test_meshes()) {
    SCOPED_TRACE(name);
    UniformGrid g;
    g.build(mesh, BuildParams{});
    EXPECT_EQ(steps_over_bound(g, test::extreme_rays(mesh, cell_planes(g), 29, 20)), 0);
  }
}

// Agreement and counted/traced traversal on these rays:
// ExtremeRayFamilies.SignedZeroComponents.
TEST(Grid, DdaStepBoundOnSignedZeroDirections) {
  const Mesh mesh = test::sphere(16, 32);
  UniformGrid g;
  g.build(mesh, BuildParams{});
  EXPECT_EQ(steps_over_bound(g, test::signed_zero_rays()), 0);
}

// Counted and traced traversal against the fast path on these rays:
// TracedStructures.CountedAndTracedTraversalMatchFastPath.
TEST(Grid, MailboxingSkipsRepeatedTests) {
  const Mesh mesh = test::random_soup(3000, 11);
  UniformGrid g;
  g.build(mesh, BuildParams{});
  const auto rays = test::random_rays(mesh, 5000, 3);
  // Mailboxing does skip repeated tests of triangles spanning several cells.
  RayCounters sum;
  for (const Ray& r : rays) {
    Hit h;
    g.intersect_counted(r, h, sum);
  }
  EXPECT_GT(sum.mailbox_skips, 0u);
  EXPECT_EQ(sum.lookups, sum.steps);
}

TEST(Grid, ResolutionFollowsDensityHeuristic) {
  const Mesh mesh = test::random_soup(4000, 1);  // roughly a cube
  BuildParams p;
  UniformGrid g;
  const BuildStats st = g.build(mesh, p);
  const double cells = double(st.nodes), target = p.grid_lambda * 4000.0;
  EXPECT_GT(cells, 0.7 * target);
  EXPECT_LT(cells, 1.4 * target);
  const auto r = g.resolution();
  EXPECT_EQ(st.extra.at(0).second,
            std::to_string(r[0]) + "x" + std::to_string(r[1]) + "x" + std::to_string(r[2]));
  EXPECT_EQ(st.bytes, (st.nodes + 1) * 4 + st.references * 4);
  EXPECT_EQ(st.bytes_by_part.size(), 2u);

  // A flat mesh (all z = 0) gets one cell along z and the density in x, y.
  Mesh flat;
  for (int i = 0; i < 100; ++i)
    for (int j = 0; j < 100; ++j)
      test::add_tri(flat, Vec3(i, j, 0), Vec3(i + 1, j, 0), Vec3(i, j + 1, 0));
  UniformGrid gf;
  const BuildStats sf = gf.build(flat, p);
  EXPECT_EQ(gf.resolution()[2], 1);
  EXPECT_GT(double(sf.nodes), 0.7 * p.grid_lambda * 10000);
  EXPECT_LT(double(sf.nodes), 1.4 * p.grid_lambda * 10000);

  // The clamp.
  p.grid_max_resolution = 4;
  UniformGrid gc;
  gc.build(mesh, p);
  for (int a = 0; a < 3; ++a) EXPECT_LE(gc.resolution()[a], 4);
}

// The exact triangle/cell test keeps a diagonal sliver out of the cells its box covers but
// it does not touch.
TEST(Grid, ExactOverlapFilterBeatsBoundingBoxes) {
  Mesh m;
  test::add_tri(m, Vec3(0, 0, 0), Vec3(1, 1, 1), Vec3(1.001f, 1, 1));
  // Corner triangles fix the box to the unit cube.
  test::add_tri(m, Vec3(0, 0, 0), Vec3(0.01f, 0, 0), Vec3(0, 0.01f, 0));
  test::add_tri(m, Vec3(1, 1, 1), Vec3(0.99f, 1, 1), Vec3(1, 0.99f, 1));
  BuildParams p;
  p.grid_lambda = 20.0f * 20 * 20 / 3.0f;  // 20^3 cells
  UniformGrid g;
  const BuildStats st = g.build(m, p);
  ASSERT_EQ(g.resolution()[0], 20);
  // A bounding-box grid would reference 8000 cells for the sliver; the diagonal touches a
  // few per step along it.
  EXPECT_LT(st.references, 200u);
  EXPECT_GE(st.references, 20u);
  uint64_t boxes = 0;
  g.for_each_box([&](const StructureBox& b) {
    ++boxes;
    EXPECT_GT(b.num_triangles, 0u);
  });
  EXPECT_EQ(boxes, st.nodes - st.empty_leaves);
  EXPECT_EQ(count_disagreements(m, g, test::random_rays(m, 3000, 5)), 0);
}

TEST(Grid, MemoryGuardFailsFastWithClearMessage) {
  const Mesh mesh = test::random_soup(1000, 1);
  BuildParams p;
  p.grid_lambda = 1e7f;
  p.grid_max_resolution = 100000;
  p.memory_budget = uint64_t(8) << 20;
  UniformGrid g;
  const auto t0 = std::chrono::steady_clock::now();
  try {
    g.build(mesh, p);
    FAIL() << "expected ParamError";
  } catch (const ParamError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("memory budget"), std::string::npos) << msg;
    EXPECT_NE(msg.find("--grid-lambda"), std::string::npos) << msg;
    // The suggested lambda fits.
    const auto at = msg.find("--grid-lambda ");
    const double fit = std::stod(msg.substr(at + 14));
    p.grid_lambda = float(fit);
    UniformGrid ok;
    EXPECT_NO_THROW(ok.build(mesh, p)) << msg;
  }
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 30.0);
  p.grid_lambda = -1.0f;
  EXPECT_THROW(g.build(mesh, p), ParamError);
}

}  // namespace
}  // namespace kdgrid
