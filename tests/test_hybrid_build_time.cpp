// The hybrid's build-time estimate (GridKdHybrid::estimate, HybridEstimate::seconds) follows the
// cell size: it grows as the cell shrinks below the auto size (matrix, binning, empty-leaf
// table), and at one cell (the whole scene in one subtree), and its ratios between sizes are
// those of the builds within a factor of 3 (ratios, so that a loaded machine's rates cancel);
// its rates put the bunny's builds from the auto size to 0.1x auto within a factor of 4.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdio>

#include "accel/accelerator.h"
#include "accel/hybrid/hybrid.h"
#include "scene/load.h"
#include "scene/procedural.h"
#include "test_util.h"

namespace kdgrid::test {
namespace {

BuildParams at_cell(double cell) {
  BuildParams p;
  p.threads = 1;
  p.cell_size = float(cell);
  return p;
}

/// The fastest of three builds, in seconds.
double build_seconds(const Mesh& m, const BuildParams& p) {
  double best = 1e30;
  for (int i = 0; i < 3; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    make_accelerator("hybrid")->build(m, p);
    best = std::min(best,
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  return best;
}

TEST(HybridBuildTime, EstimateFollowsTheCellSize) {
  const Mesh m = make_icosphere(4);
  BuildParams a;
  a.threads = 1;
  const double auto_cell = GridKdHybrid::estimate(m, a).auto_cell;
  double last = 0;
  for (const double mult : {1.0, 0.5, 0.25, 0.125}) {
    const double s = GridKdHybrid::estimate(m, at_cell(mult * auto_cell)).seconds;
    std::printf("[ time     ] %.3gx auto: estimate %.3g s\n", mult, s);
    EXPECT_GT(s, last) << mult << "x auto";
    last = s;
  }
  const double one = GridKdHybrid::estimate(m, at_cell(1e3)).seconds;
  EXPECT_GT(one, GridKdHybrid::estimate(m, at_cell(auto_cell)).seconds);
}

TEST(HybridBuildTime, EstimatedRatiosMatchTheBuildsWithinAFactorOf3) {
  const Mesh m = make_icosphere(4);
  BuildParams a;
  a.threads = 1;
  const double auto_cell = GridKdHybrid::estimate(m, a).auto_cell;
  const double base_est = GridKdHybrid::estimate(m, at_cell(auto_cell)).seconds;
  const double base = build_seconds(m, at_cell(auto_cell));
  for (const double mult : {0.4, 1e3 / auto_cell}) {
    const double est = GridKdHybrid::estimate(m, at_cell(mult * auto_cell)).seconds / base_est;
    const double got = build_seconds(m, at_cell(mult * auto_cell)) / base;
    std::printf("[ time     ] %.3gx auto: estimated %.3gx the auto build's time, measured %.3gx\n",
                mult, est, got);
    EXPECT_LT(est, 3.0 * got);
    EXPECT_GT(est, got / 3.0);
  }
}

TEST(HybridBuildTime, EstimateOfTheBunnysBuildsIsWithinAFactorOf4) {
  // The estimate is what the viewer's progress bar runs towards and what the default
  // --hybrid-max-build-seconds refuses by: rates several times too slow refuse sizes that build
  // in under a second. One thread, the fastest of three builds; the bound leaves room for a
  // loaded machine, not for a sanitizer's slowdown.
  if (kSanitizerBuild) GTEST_SKIP() << "a sanitizer slows the build, not the estimate";
  KDGRID_REQUIRE_SCENE(path, "bunny/bun_zipper.ply");
  const Mesh m = load_scene(path).mesh;
  BuildParams a;
  a.threads = 1;
  const double auto_cell = GridKdHybrid::estimate(m, a).auto_cell;
  for (const double mult : {1.0, 0.1}) {
    BuildParams p = at_cell(mult * auto_cell);
    p.hybrid_max_build_seconds = 0;
    const double est = GridKdHybrid::estimate(m, p).seconds;
    const double got = build_seconds(m, p);
    std::printf("[ time     ] bunny at %.3gx auto: estimated %.3g s, built in %.3g s\n", mult, est,
                got);
    EXPECT_LT(est, 4.0 * got) << mult << "x auto";
    EXPECT_GT(est, got / 4.0) << mult << "x auto";
  }
}

}  // namespace
}  // namespace kdgrid::test
