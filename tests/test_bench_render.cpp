// The render column of `kdgrid bench` (BenchOptions::render): every structure's whole Whitted
// render, paired pass by pass with the reference's, in the report's JSON and Markdown.
#include <gtest/gtest.h>

#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "bench/bench.h"
#include "bench/bench_render.h"
#include "scene/load.h"

namespace kdgrid {
namespace {

BenchReport run_cornell(bool render, std::vector<std::string> accels) {
  Suite suite;
  SuiteScene scene;
  scene.name = "cornell";
  scene.file = std::string(KDGRID_SOURCE_DIR) + "/assets/cornell.gltf";
  suite.scenes.push_back(scene);
  BenchOptions o;
  o.accels = std::move(accels);
  o.reference = "bvh";
  o.sets = {"primary"};
  o.width = o.height = 32;
  o.reps = 2;
  o.packet_tile = 0;
  o.render = render;
  return run_bench(suite, o);
}

TEST(BenchRender, EveryStructureRendersTheSamePictureBesideTheReference) {
  const BenchReport r = run_cornell(true, {"bvh", "kdtree", "hybrid"});
  ASSERT_EQ(r.scenes.size(), 1u);
  ASSERT_EQ(r.scenes[0].structures.size(), 3u);
  const RenderFigures& ref = r.scenes[0].structures[0].render;
  ASSERT_TRUE(ref.measured);
  EXPECT_EQ(ref.primary, 32u * 32u);  // pixel centres, one sample
  EXPECT_GT(ref.shadow, 0u);          // the scene's lights
  EXPECT_GT(ref.reflection, 0u);      // its mirror sphere
  EXPECT_EQ(ref.ratio_to_reference, 1.0);
  for (const StructureFigures& a : r.scenes[0].structures) {
    SCOPED_TRACE(a.accel);
    ASSERT_TRUE(a.error.empty()) << a.error;
    const RenderFigures& x = a.render;
    ASSERT_TRUE(x.measured);
    EXPECT_EQ(x.seconds_reps.size(), 2u);
    EXPECT_GT(x.seconds_median, 0.0);
    EXPECT_GT(x.mrays_median, 0.0);
    EXPECT_GT(x.ratio_to_reference, 0.0);
    EXPECT_GT(x.reference_seconds, 0.0);
    // The same hits (every structure agrees with the reference here), so the same rays and
    // the same picture.
    EXPECT_EQ(x.rays(), ref.rays());
    EXPECT_EQ(x.pixels_differ, 0);
  }

  const auto j = nlohmann::json::parse(bench_to_json(r));
  ASSERT_EQ(j["renders"].size(), 3u);
  EXPECT_EQ(j["renders"][1]["accel"], "kdtree");
  EXPECT_EQ(j["renders"][1]["rays"]["total"], ref.rays());
  EXPECT_EQ(j["renders"][1]["pixels_differ"], 0);
  const std::string md = bench_to_markdown(r);
  EXPECT_NE(md.find("### The whole render"), std::string::npos) << md;
  EXPECT_NE(md.find("| cornell | hybrid | " + std::to_string(ref.rays()) + " |"), std::string::npos)
      << md;
}

TEST(BenchRender, PicturesThatDifferAreCountedPixelByPixel) {
  // The column's comparison itself: the reference's picture (measured without a reference),
  // then structures compared with it, as run_bench pairs them.
  const Scene scene = load_scene(std::string(KDGRID_SOURCE_DIR) + "/assets/cornell.gltf");
  const auto full = build_accelerator("bvh", scene.mesh, BuildParams{});
  BenchOptions o;
  o.width = o.height = 32;
  o.reps = 1;
  std::vector<uint8_t> ref_image;
  RenderJob job;
  job.scene = &scene;
  job.camera = *scene.camera;
  job.reference_image = &ref_image;
  EXPECT_EQ(measure_render(*full, job, o).pixels_differ, 0);
  ASSERT_EQ(ref_image.size(), size_t(32 * 32 * 3));
  job.reference = full.get();
  EXPECT_EQ(measure_render(*full, job, o).pixels_differ, 0);

  // Three pixels of the reference's picture changed (one channel each): exactly three differ.
  for (const size_t px : {0u, 517u, 1023u}) ref_image[px * 3 + px % 3] ^= 0x40;
  EXPECT_EQ(measure_render(*full, job, o).pixels_differ, 3);
  for (const size_t px : {0u, 517u, 1023u}) ref_image[px * 3 + px % 3] ^= 0x40;

  // A structure over half the scene's triangles (a prefix, so its hits name the scene's own
  // triangles) misses the rest: another picture.
  Mesh half = scene.mesh;
  half.triangles.resize(half.triangles.size() / 2);
  if (!half.material_ids.empty()) half.material_ids.resize(half.triangles.size());
  const auto part = build_accelerator("bvh", half, BuildParams{});
  const int64_t differ = measure_render(*part, job, o).pixels_differ;
  EXPECT_GT(differ, 32);
  EXPECT_LE(differ, 32 * 32);
}

TEST(BenchRender, NoRenderColumnUnlessAskedFor) {
  const BenchReport r = run_cornell(false, {"bvh"});
  for (const StructureFigures& a : r.scenes[0].structures) EXPECT_FALSE(a.render.measured);
  EXPECT_TRUE(nlohmann::json::parse(bench_to_json(r))["renders"].empty());
  EXPECT_EQ(bench_to_markdown(r).find("The whole render"), std::string::npos);
}

}  // namespace
}  // namespace kdgrid
