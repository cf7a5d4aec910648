// The speed-vs-accuracy sweeps behind `kdgrid sweep` (bench/sweep.h): the edge and vertex rays
// of the triangle-test sweep, the lambda, triangle, spp and cell-size tables and their outputs,
// and bad input.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "bench/sweep.h"
#include "bench_scenes.h"
#include "scene/procedural.h"
#include "temp_dir.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using test::gridded_box;
using test::TempDir;
using test::write_ascii_ply;

/// The index of column `name` of `t` (t.columns.size() when it has none).
size_t column(const SweepTable& t, const std::string& name) {
  return size_t(std::find(t.columns.begin(), t.columns.end(), name) - t.columns.begin());
}

/// The sweep of `kind` over `values` on a 6x6-gridded box written to a fresh folder named with
/// `tag`: one repetition of 32x32 rays.
SweepTable sweep_on_box(const std::string& kind, const std::vector<double>& values,
                        const std::string& tag) {
  TempDir dir(tag);
  write_ascii_ply(gridded_box(6, {0, 0, 0}, 1.0f), dir / "box.ply");
  SweepOptions o;
  o.kind = kind;
  o.scene = (dir / "box.ply").string();
  o.values = values;
  o.reps = 1;
  o.width = o.height = 32;
  return run_sweep(o);
}

TEST(Sweep, EdgeVertexRaysAllHitAClosedMeshWithTheWatertightTest) {
  const Mesh m = make_icosphere(2);  // 320 triangles, 480 edges, 162 vertices
  const std::vector<Ray> rays = edge_vertex_rays(m, 2, 3);
  EXPECT_EQ(rays.size(), 2u * (3u * 480u + 162u));
  auto brute = build_accelerator("brute", m, BuildParams{});
  for (const Ray& r : rays) {
    Hit h;
    ASSERT_TRUE(brute->intersect(r, h)) << "watertight test leaked";
    EXPECT_NEAR(h.t, 1.0f, 1e-4f) << "the ray must stop at its target";
  }
  // The same rays with tmax = inf would be caught by the far side; with the short segment
  // they are not: a ray aimed past the sphere misses.
  Ray outside = rays[0];
  outside.dir = outside.dir + Vec3(0, 0, 5);
  Hit h;
  EXPECT_FALSE(brute->intersect(outside, h));
}

TEST(Sweep, LambdaRowsAndBothOutputs) {
  const SweepTable t = sweep_on_box("lambda", {1, 8}, "sweep");
  ASSERT_EQ(t.rows.size(), 2u);
  auto col = [&](const std::string& c) {
    const auto it = std::find(t.columns.begin(), t.columns.end(), c);
    EXPECT_NE(it, t.columns.end()) << c;
    return size_t(it - t.columns.begin());
  };
  for (const char* c : {"lambda", "build_s", "bytes", "mrays", "steps_per_ray", "tests_per_ray"})
    col(c);
  const auto num = [&](size_t r, const std::string& c) {
    return std::get<double>(t.rows[r][col(c)]);
  };
  EXPECT_GT(num(0, "mrays"), 0.0);
  EXPECT_GT(num(1, "bytes"), num(0, "bytes")) << "a denser grid must take more memory";
  const json j = json::parse(sweep_to_json(t));
  EXPECT_EQ(j["rows"].size(), 2u);
  EXPECT_EQ(j["meta"]["kind"], "lambda");
  const std::string csv = sweep_to_csv(t);
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 3);
  EXPECT_EQ(csv.rfind("label,lambda,", 0), 0u) << csv;
}

TEST(Sweep, TriangleLeaksWatertightNever) {
  SweepOptions o;
  o.kind = "triangle";
  o.accels = {"bvh"};
  o.leak_rays_per_target = 1;
  const SweepTable t = run_sweep(o);  // no scene: the leak part only
  const size_t part = column(t, "part");
  const size_t test = column(t, "test");
  const size_t leaks = column(t, "leaks");
  ASSERT_LT(leaks, t.columns.size());
  size_t rows = 0;
  for (const auto& r : t.rows) {
    ASSERT_EQ(std::get<std::string>(r[part]), "leak");
    ++rows;
    if (std::get<std::string>(r[test]) == "watertight") {
      EXPECT_EQ(std::get<double>(r[leaks]), 0.0);
    }
  }
  EXPECT_EQ(rows, 2u * 4u * 2u * 2u) << "sphere and torus x 4 scales x {brute, bvh} x 2 tests";
}

TEST(Sweep, SppErrorFallsWithSamples) {
  SweepOptions o;
  o.kind = "spp";
  o.width = o.height = 24;
  o.spp_max = 16;
  o.spp_reference = 64;
  const SweepTable t = run_sweep(o);
  ASSERT_EQ(t.rows.size(), 5u);  // 1, 2, 4, 8, 16
  const size_t e = column(t, "rmse_display");
  ASSERT_LT(e, t.columns.size());
  const double first = std::get<double>(t.rows.front()[e]),
               last = std::get<double>(t.rows.back()[e]);
  EXPECT_GT(first, 0.0);
  EXPECT_LT(last, first) << "16 spp must be closer to the reference than 1 spp";
}

TEST(Sweep, CellsizeHasAnAutoRow) {
  const auto names = accelerator_names();
  if (std::find(names.begin(), names.end(), "hybrid") == names.end())
    GTEST_SKIP() << "hybrid is not registered in accel/factory.cpp yet";
  const SweepTable t = sweep_on_box("cellsize", {0.5, 2}, "cellsize");
  ASSERT_EQ(t.rows.size(), 3u);
  EXPECT_EQ(std::get<std::string>(t.rows[0][0]), "auto");
  // Accuracy beside speed: every cell size judged by check's reference, none contradicting it.
  auto col = [&](const std::string& n) { return column(t, n); };
  for (const auto& row : t.rows) {
    EXPECT_GT(std::get<double>(row.at(col("check_rays"))), 0.0);
    EXPECT_GT(std::get<double>(row.at(col("check_agree"))), 0.0);
    EXPECT_EQ(std::get<double>(row.at(col("check_disagree"))), 0.0);
    EXPECT_EQ(std::get<double>(row.at(col("check_leaks"))), 0.0) << "a closed box, watertight";
    EXPECT_GT(std::get<double>(row.at(col("acne_rays"))), 0.0);
    EXPECT_EQ(std::get<double>(row.at(col("acne_self_hits"))), 0.0) << "the robust offset";
  }
}

TEST(Sweep, RejectsBadInput) {
  SweepOptions o;
  o.kind = "sideways";
  EXPECT_THROW(run_sweep(o), ParamError);
  o.kind = "lambda";
  EXPECT_THROW(run_sweep(o), ParamError) << "lambda needs a scene";
  o.scene = "/nonexistent/scene.ply";
  EXPECT_THROW(run_sweep(o), LoadError);
  o.values = {-1};
  EXPECT_THROW(run_sweep(o), ParamError);
}

}  // namespace
}  // namespace kdgrid
