// Difference maps in the viewer: a pinned heat map against the map after a change of cell size,
// written as EXR (R = current - pinned, G = current, B = pinned) and read back through the
// core image I/O.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "image/image_io.h"
#include "temp_dir.h"
#include "test_util.h"
#include "viewer_run.h"

#ifdef KDGRID_VIEWER_PATH

namespace kdgrid::test {
namespace {

namespace fs = std::filesystem;

const std::string kCornell = source_path("assets/cornell.gltf");

/// --stats-json's difference map: ready, with the totals of the pinned and current maps, the
/// pinned one built with --cell-size 0.5.
void expect_diff_state(const nlohmann::json& st, double pinned_total, double current_total) {
  ASSERT_TRUE(st["diff"].is_object()) << st.dump();
  EXPECT_TRUE(st["diff"]["ready"].get<bool>());
  EXPECT_DOUBLE_EQ(st["diff"]["pinned_total"].get<double>(), pinned_total);
  EXPECT_DOUBLE_EQ(st["diff"]["current_total"].get<double>(), current_total);
  EXPECT_NE(st["diff"]["pinned"].get<std::string>().find("--cell-size 0.5"), std::string::npos)
      << st["diff"].dump();
}

TEST(DiffMap, PinnedCellSizeChangeWritesTheDifferenceOfTheTwoMaps) {
  KDGRID_REQUIRE_XVFB();
  if (!fs::exists(kCornell)) GTEST_SKIP() << "assets/cornell.gltf is missing";
  TempDir dir("diff_map");
  const std::string d = dir.path().string();
  const std::string common = "'" + kCornell +
                             "' --accel hybrid --width 200 --height 150 --frames 2 "
                             "--min-samples 1 --max-samples 1 --heatmap steps ";
  // The map at the first cell size alone.
  RunResult r = run_viewer(d, common + "--cell-size 0.5 --export-heatmap before.exr");
  ASSERT_EQ(r.code, 0) << r.output;
  // Pinned at that size, rebuilt at another, the difference written at the end.
  r = run_viewer(d,
                 common +
                     "--cell-size 0.5 --pin-heatmap --rebuild-cell-size 0.08 --diff-exr diff.exr "
                     "--export-heatmap after.exr --stats-json stats.json");
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageRGB before = read_image(d + "/before.exr"), after = read_image(d + "/after.exr");
  const ImageRGB diff = read_image(d + "/diff.exr");
  ASSERT_EQ(diff.width, 200);
  ASSERT_EQ(diff.height, 150);
  ASSERT_EQ(before.rgb.size(), diff.rgb.size());
  ASSERT_EQ(after.rgb.size(), diff.rgb.size());
  double sum_r = 0, sum_g = 0, sum_b = 0;
  size_t changed = 0;
  for (size_t i = 0; i < diff.rgb.size(); i += 3) {
    EXPECT_EQ(diff.rgb[i + 1], after.rgb[i]) << "current, pixel " << i / 3;
    EXPECT_EQ(diff.rgb[i + 2], before.rgb[i]) << "pinned, pixel " << i / 3;
    EXPECT_EQ(diff.rgb[i], diff.rgb[i + 1] - diff.rgb[i + 2]) << "pixel " << i / 3;
    sum_r += diff.rgb[i];
    sum_g += diff.rgb[i + 1];
    sum_b += diff.rgb[i + 2];
    changed += diff.rgb[i] != 0;
  }
  // The totals: the difference map's is the two maps' difference, and the cell size changed it.
  EXPECT_DOUBLE_EQ(sum_r, sum_g - sum_b);
  EXPECT_GT(changed, 100u);
  EXPECT_NE(sum_r, 0.0);
  std::ifstream in(d + "/stats.json");
  const nlohmann::json st = nlohmann::json::parse(in)["state"];
  expect_diff_state(st, sum_b, sum_g);
}

TEST(DiffMap, PinnedTimeMapWritesTheDifferenceOfTheTwoMaps) {
  KDGRID_REQUIRE_XVFB();
  if (!fs::exists(kCornell)) GTEST_SKIP() << "assets/cornell.gltf is missing";
  TempDir dir("diff_time");
  const std::string d = dir.path().string();
  // Nanoseconds per pixel, pinned at one structure's cell size and compared with another's.
  const RunResult r =
      run_viewer(d, "'" + kCornell +
                        "' --accel hybrid --width 120 --height 90 --frames 2 --min-samples 1 "
                        "--max-samples 1 --heatmap time --cell-size 0.5 --pin-heatmap "
                        "--rebuild-cell-size 0.08 --diff-exr diff.exr --stats-json stats.json");
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageRGB diff = read_image(d + "/diff.exr");
  ASSERT_EQ(diff.width, 120);
  ASSERT_EQ(diff.height, 90);
  double sum_g = 0, sum_b = 0;
  size_t timed = 0;
  for (size_t i = 0; i < diff.rgb.size(); i += 3) {
    EXPECT_EQ(diff.rgb[i], diff.rgb[i + 1] - diff.rgb[i + 2]) << "pixel " << i / 3;
    // Every pixel's query takes some time, hit or miss.
    timed += diff.rgb[i + 1] > 0 && diff.rgb[i + 2] > 0;
    sum_g += diff.rgb[i + 1];
    sum_b += diff.rgb[i + 2];
  }
  EXPECT_EQ(timed, diff.rgb.size() / 3);
  std::ifstream in(d + "/stats.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  const nlohmann::json& st = j["state"];
  EXPECT_EQ(j["settings"]["mode"], "time") << j["settings"].dump();
  expect_diff_state(st, sum_b, sum_g);
}

TEST(DiffMap, DiffExrWithoutAPinIsRefusedBeforeAWindowOpens) {
  TempDir dir("diff_refused");
  const RunResult r =
      run_command("env -u DISPLAY '" + std::string(KDGRID_VIEWER_PATH) +
                  "' --heatmap steps --frames 1 --diff-exr " + (dir.path() / "d.exr").string());
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("--pin-heatmap"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace kdgrid::test

#endif
