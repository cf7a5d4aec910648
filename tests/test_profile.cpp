// Where the time goes (bench/profile.h, `kdgrid profile`): the per-class single-thread costs,
// traversal alone (`kdgrid trace --traversal-only`), the repeated-pixel ray files of `kdgrid
// rays --pixel` and the cache-simulation passes.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "accel/hybrid/records.h"
#include "accel/triangle_wide.h"
#include "bench/bench.h"
#include "bench/profile.h"
#include "bench/rayfile.h"
#include "bench/raysets.h"
#include "bench_scenes.h"
#include "math/simd.h"
#include "scene/procedural.h"
#include "temp_dir.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using test::run_cli;
using test::slurp;
using test::TempDir;
using test::write_ascii_ply;

/// The primary rays of an n x n image from `eye` towards the origin, with a vertical field of
/// view of `fov_deg` degrees.
std::vector<Ray> square_image_rays(const Vec3& eye, int n, float fov_deg = Camera{}.fov_deg) {
  Camera cam;
  cam.eye = eye;
  cam.fov_deg = fov_deg;
  return primary_rays(cam, n, n);
}

// ---- profile: per-class single-thread costs -------------------------------------------------

TEST(Profile, ClassesPartitionTheRaysByTheReferenceAndTheBox) {
  const Mesh m = make_icosphere(3, Vec3(0.0f), 1.0f);
  const auto ref = build_accelerator("bvh", m, BuildParams{});
  // A camera close enough that some rays miss the sphere inside its box (near the box's
  // corners) and far enough that the image's corners miss the box.
  const std::vector<Ray> rays = square_image_rays(Vec3(0.0f, 0.0f, 4.0f), 48, 50.0f);
  const RayClasses c = classify_rays(*ref, m.bounds(), rays);
  EXPECT_EQ(c.hit.size() + c.miss_box.size() + c.miss_out.size(), rays.size());
  ASSERT_FALSE(c.hit.empty());
  ASSERT_FALSE(c.miss_box.empty());
  ASSERT_FALSE(c.miss_out.empty());
  const Box3 b = m.bounds();
  for (const Ray& r : c.hit) {
    Hit h;
    EXPECT_TRUE(ref->intersect(r, h));
  }
  for (const auto* set : {&c.miss_box, &c.miss_out})
    for (const Ray& r : *set) {
      Hit h;
      EXPECT_FALSE(ref->intersect(r, h));
    }
  // miss-out rays never enter the box: a float slab test agrees (to rounding).
  for (const Ray& r : c.miss_out) {
    float t0 = 0.0f, t1 = std::numeric_limits<float>::infinity();
    for (int a = 0; a < 3; ++a) {
      float ta = (b.lo[a] - r.org[a]) / r.dir[a], tb = (b.hi[a] - r.org[a]) / r.dir[a];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
    EXPECT_GT(t0 * (1.0f + 1e-5f), t1);
  }
}

TEST(Profile, FiguresMatchTheCountedPassAndHitCounts) {
  const Mesh m = make_icosphere(3, Vec3(0.0f), 1.0f);
  const auto kd = build_accelerator("kdtree", m, BuildParams{});
  const std::vector<Ray> rays = square_image_rays(Vec3(0.3f, 0.2f, 4.0f), 32);
  const ProfileFigures f = profile_rays(*kd, rays, 2);
  EXPECT_EQ(f.rays, rays.size());
  RayCounters c;
  uint64_t hits = 0;
  for (const Ray& r : rays) {
    Hit h;
    hits += kd->intersect_counted(r, h, c);
  }
  EXPECT_EQ(f.hits, hits);
  EXPECT_GT(f.hits, 0u);
  EXPECT_TRUE(f.counted);
  EXPECT_DOUBLE_EQ(f.steps, double(c.steps) / double(rays.size()));
  EXPECT_DOUBLE_EQ(f.tests, double(c.tri_tests) / double(rays.size()));
  EXPECT_GT(f.cold_ns, 0.0);
  EXPECT_GE(f.warm_ns, 0.0);
  const ProfileFigures empty = profile_rays(*kd, {}, 1);
  EXPECT_EQ(empty.rays, 0u);
  EXPECT_THROW(profile_rays(*kd, rays, 0), ParamError);
}

// ---- traversal alone (TriangleTestKind::None, `kdgrid trace --traversal-only`) --------------

// Without triangle tests every ray misses and crosses the whole structure: each structure then
// visits, ray by ray, at least the nodes, cells and triangles it visits when it can stop at a
// hit. Embree cannot run without its own tests and says so.
TEST(TraversalOnly, EveryRayMissesAndEachStructureVisitsAtLeastAsMuch) {
  const Mesh m = make_icosphere(3, Vec3(0.0f), 1.0f);
  const std::vector<Ray> rays = square_image_rays(Vec3(0.3f, 0.2f, 4.0f), 24);
  BuildParams none;
  none.triangle_test = TriangleTestKind::None;
  for (const std::string name : {"brute", "bvh", "grid", "kdtree", "hybrid", "irregular"}) {
    SCOPED_TRACE(name);
    const auto full = build_accelerator(name, m, BuildParams{});
    const auto bare = build_accelerator(name, m, none);
    uint64_t hits = 0, more = 0;
    for (const Ray& r : rays) {
      Hit h;
      RayCounters cf, cb;
      hits += full->intersect_counted(r, h, cf);
      ASSERT_FALSE(bare->intersect_counted(r, h, cb));
      ASSERT_FALSE(bare->occluded(r));
      ASSERT_GE(cb.steps, cf.steps);
      ASSERT_GE(cb.tri_tests, cf.tri_tests);
      ASSERT_GE(cb.lookups, cf.lookups);
      more += cb.steps + cb.tri_tests > cf.steps + cf.tri_tests;
    }
    ASSERT_GT(hits, 0u);
    if (name != "brute") {
      EXPECT_GT(more, 0u) << "rays that hit stop early with the tests on";
    }
  }
  EXPECT_THROW(build_accelerator("embree", m, none), ParamError);
}

TEST(TraceCli, TraversalOnlyReportsTimePerStepAndRefusesEmbree) {
  TempDir dir("trace");
  const fs::path ply = dir / "sphere.ply", rays = dir / "r.rays", log = dir / "log.txt";
  write_ascii_ply(make_icosphere(2, Vec3(0.0f), 1.0f), ply);
  write_rays(rays.string(), square_image_rays(Vec3(0.3f, 0.2f, 4.0f), 16));
  const std::string base =
      "trace \"" + ply.string() + "\" --rays \"" + rays.string() + "\" --repeat 1 ";
  ASSERT_EQ(run_cli(base + "--accel hybrid --traversal-only", log), 0) << slurp(log);
  EXPECT_NE(slurp(log).find("hit fraction 0.0000"), std::string::npos) << slurp(log);
  EXPECT_NE(slurp(log).find("ns per lookup"), std::string::npos) << slurp(log);
  // The next leaves taken from the next-leaf cache, counted: neighbouring rays of a finer
  // image take some, and none without the cache.
  const fs::path fine = dir / "fine.rays";
  write_rays(fine.string(), square_image_rays(Vec3(0.3f, 0.2f, 4.0f), 128));
  const std::string fine_base =
      "trace \"" + ply.string() + "\" --rays \"" + fine.string() + "\" --repeat 1 ";
  ASSERT_EQ(run_cli(fine_base + "--accel hybrid --threads 1", log), 0) << slurp(log);
  EXPECT_NE(slurp(log).find("of the lookups per ray answered by the next-leaf cache"),
            std::string::npos)
      << slurp(log);
  EXPECT_EQ(slurp(log).find("leaf cache   0.00 "), std::string::npos)
      << "coherent rays take cached leaves\n"
      << slurp(log);
  ASSERT_EQ(run_cli(fine_base + "--accel hybrid --threads 1 --json", log), 0) << slurp(log);
  EXPECT_GT(json::parse(slurp(log))["per_ray"]["next_leaves_from_cache"].get<double>(), 0.0)
      << slurp(log);
  ASSERT_EQ(run_cli(fine_base + "--accel hybrid --threads 1 --hybrid-no-next-leaf-cache", log), 0)
      << slurp(log);
  EXPECT_NE(slurp(log).find("leaf cache   0.00 "), std::string::npos) << slurp(log);
  ASSERT_EQ(
      run_cli(fine_base + "--accel hybrid --threads 1 --hybrid-no-next-leaf-cache --json", log), 0)
      << slurp(log);
  EXPECT_EQ(json::parse(slurp(log))["per_ray"]["next_leaves_from_cache"].get<double>(), 0.0)
      << slurp(log);
  ASSERT_EQ(run_cli(base + "--accel kdtree --traversal-only --json", log), 0) << slurp(log);
  const json j = json::parse(slurp(log));
  EXPECT_TRUE(j["traversal_only"].get<bool>());
  EXPECT_EQ(j["hit_fraction"].get<double>(), 0.0);
  EXPECT_GT(j["thread_ns_per_step"].get<double>(), 0.0);
  ASSERT_EQ(run_cli(base + "--accel kdtree", log), 0) << slurp(log);
  EXPECT_EQ(slurp(log).find("traversal    alone"), std::string::npos) << slurp(log);
  EXPECT_NE(run_cli(base + "--accel embree --traversal-only", log), 0);
  EXPECT_NE(slurp(log).find("no traversal-only timing"), std::string::npos) << slurp(log);
  EXPECT_NE(
      run_cli(base + "--accel kdtree --traversal-only --hits \"" + (dir / "h.hits").string() + "\"",
              log),
      0);
  EXPECT_NE(slurp(log).find("finds no hits: drop --hits"), std::string::npos) << slurp(log);
  EXPECT_NE(
      run_cli("trace \"" + ply.string() + "\" --pixel 8,8 --res 16 --accel kdtree --traversal-only",
              log),
      0);
  EXPECT_NE(slurp(log).find("use it with --rays, not --pixel"), std::string::npos) << slurp(log);
}

// `kdgrid rays --pixel X,Y`: copies of the very primary ray that the set has for that pixel
// (the same-ray timing of the README); a pixel outside the image, another set or no copies
// are refused with the fix.
TEST(RaysCli, PixelWritesCopiesOfThatPixelsPrimaryRay) {
  TempDir dir("rays");
  const fs::path ply = dir / "sphere.ply", all = dir / "all.rays", one = dir / "one.rays",
                 log = dir / "log.txt";
  write_ascii_ply(make_icosphere(2, Vec3(0.0f), 1.0f), ply);
  const std::string base = "rays \"" + ply.string() + "\" --res 16x12 ";
  ASSERT_EQ(run_cli(base + "-o \"" + all.string() + "\"", log), 0) << slurp(log);
  ASSERT_EQ(run_cli(base + "--pixel 5,7 --count 10 -o \"" + one.string() + "\"", log), 0)
      << slurp(log);
  EXPECT_NE(slurp(log).find("wrote 10 copies of the primary ray through pixel 5,7"),
            std::string::npos)
      << slurp(log);
  const std::vector<Ray> set = read_rays(all.string()), copies = read_rays(one.string());
  ASSERT_EQ(set.size(), 16u * 12u);
  ASSERT_EQ(copies.size(), 10u);
  const Ray& want = set[7 * 16 + 5];
  for (const Ray& r : copies) {
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(r.org[a], want.org[a]);
      EXPECT_EQ(r.dir[a], want.dir[a]);
    }
    EXPECT_EQ(r.tmin, want.tmin);
    EXPECT_EQ(r.tmax, want.tmax);
  }
  EXPECT_NE(run_cli(base + "--pixel 16,0 -o \"" + one.string() + "\"", log), 0);
  EXPECT_NE(slurp(log).find("must be X,Y inside the 16x12 image"), std::string::npos) << slurp(log);
  EXPECT_NE(run_cli(base + "--set shadow --pixel 1,1 -o \"" + one.string() + "\"", log), 0);
  EXPECT_NE(slurp(log).find("--pixel repeats one primary ray"), std::string::npos) << slurp(log);
  EXPECT_NE(run_cli(base + "--pixel 1,1 --count 0 -o \"" + one.string() + "\"", log), 0);
  EXPECT_NE(slurp(log).find("--count must be at least 1"), std::string::npos) << slurp(log);
  EXPECT_NE(run_cli(base + "--pixel 1,1 --count 100000000000 -o \"" + one.string() + "\"", log), 0);
  EXPECT_NE(slurp(log).find("GiB of rays: use at most 134217728"), std::string::npos) << slurp(log);
  EXPECT_NE(run_cli(base + "--set random --count 100000000000 -o \"" + one.string() + "\"", log),
            0);
  EXPECT_NE(slurp(log).find("GiB of rays: use at most 134217728"), std::string::npos) << slurp(log);
}

TEST(ProfileCli, PrintsEveryStructureAndClass) {
  TempDir dir("profile");
  const fs::path ply = dir / "sphere.ply", log = dir / "log.txt";
  write_ascii_ply(make_icosphere(2, Vec3(0.0f), 1.0f), ply);
  const int rc = run_cli(
      "profile \"" + ply.string() + "\" --res 24 --reps 1 --accel kdtree,hybrid --reference bvh",
      log);
  ASSERT_EQ(rc, 0) << slurp(log);
  const std::string out = slurp(log);
  for (const char* s :
       {"| kdtree | all |", "| kdtree | hit |", "| hybrid | miss-box |", "| hybrid | miss-out |"})
    EXPECT_NE(out.find(s), std::string::npos) << s << "\n" << out;
  EXPECT_NE(run_cli("profile \"" + ply.string() + "\" --reps 0", log), 0);
  EXPECT_NE(slurp(log).find("--reps must be at least 1"), std::string::npos) << slurp(log);
  // A misspelt structure fails before the scene is loaded and the reference built.
  EXPECT_NE(run_cli("profile \"" + ply.string() + "\" --accel kdtree,hybird", log), 0);
  EXPECT_NE(slurp(log).find("unknown accelerator 'hybird'"), std::string::npos) << slurp(log);
  EXPECT_EQ(slurp(log).find("| structure |"), std::string::npos) << "nothing measured\n"
                                                                 << slurp(log);
}

TEST(Profile, CacheSimPassTracesEachRayOnceAndCountRaysMatchesTheCountedPass) {
  const Mesh m = make_icosphere(3, Vec3(0.0f), 1.0f);
  const auto hy = build_accelerator("hybrid", m, BuildParams{});
  const std::vector<Ray> rays = square_image_rays(Vec3(0.3f, 0.2f, 4.0f), 32);
  uint64_t hits = 0;
  RayCounters c;
  for (const Ray& r : rays) {
    Hit h;
    hits += hy->intersect_counted(r, h, c);
  }
  ASSERT_GT(hits, 0u);
  ASSERT_LT(hits, rays.size());
  EXPECT_EQ(cache_sim_pass(*hy, rays), hits);
  EXPECT_EQ(cache_sim_pass(*hy, {}), 0u);
  ProfileFigures f;
  count_rays(*hy, rays, f);
  EXPECT_EQ(f.rays, rays.size());
  EXPECT_TRUE(f.counted);
  EXPECT_DOUBLE_EQ(f.lookups, double(c.lookups) / double(rays.size()));
  EXPECT_DOUBLE_EQ(f.tests, double(c.tri_tests) / double(rays.size()));
  ProfileFigures e;
  count_rays(*build_accelerator("embree", m, BuildParams{}), rays, e);
  EXPECT_FALSE(e.counted);  // Embree has no counters
  EXPECT_EQ(e.rays, rays.size());
}

TEST(ProfileCli, CacheSimNumbersItsPassesInCallOrder) {
  // scripts/cache-profile.sh maps callgrind's k-th profile part (one per cache_sim_pass call)
  // to the k-th line of this table, so the numbers must run 1..N over the non-empty classes.
  TempDir dir("profile-cache");
  const fs::path ply = dir / "sphere.ply", log = dir / "log.txt";
  write_ascii_ply(make_icosphere(2, Vec3(0.0f), 1.0f), ply);
  const int rc = run_cli("profile \"" + ply.string() +
                             "\" --res 24 --accel kdtree,hybrid --reference bvh --cache-sim --eye "
                             "0,0,4 --target 0,0,0 --fov 50",
                         log);
  ASSERT_EQ(rc, 0) << slurp(log);
  const std::string out = slurp(log);
  EXPECT_NE(out.find("one untimed pass per class"), std::string::npos) << out;
  EXPECT_EQ(out.find("cold ns/ray"), std::string::npos) << out;
  // This camera sees the sphere in the middle, the box around it and space beyond: every
  // class is present for both structures, in structure then class order.
  const char* expected[] = {"| 1 | kdtree | hit |",      "| 2 | kdtree | miss-box |",
                            "| 3 | kdtree | miss-out |", "| 4 | hybrid | hit |",
                            "| 5 | hybrid | miss-box |", "| 6 | hybrid | miss-out |"};
  size_t at = 0;
  for (const char* s : expected) {
    const size_t pos = out.find(s, at);
    ASSERT_NE(pos, std::string::npos) << s << "\n" << out;
    at = pos;
  }
  EXPECT_EQ(out.find("| 7 |"), std::string::npos) << out;
}

}  // namespace
}  // namespace kdgrid
