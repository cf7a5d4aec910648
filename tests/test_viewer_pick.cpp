// kdgrid-viewer end to end (tests/support/viewer_run.h): the picked ray. Its traversal drawn
// at the picked pixel, the `kdgrid trace` command that replays it, the step table, and
// --frame-pick, which brings the camera close to the visited leaves.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdio>
#include <regex>
#include <string>
#include <utility>
#include <vector>

#include "viewer_checks.h"
#include "viewer_run.h"

#ifdef KDGRID_VIEWER_PATH

namespace kdgrid::test {
namespace {

TEST_F(Viewer, PickDrawsTraversalAtThePickedPixel) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedSmallScene | kNeedFastAccel);
  const std::string base =
      quoted(small_scene()) + " --accel " + fast_accel() + kSmall + "--hide-ui ";
  const RunResult plain = run(base + "--screenshot plain.png");
  ASSERT_EQ(plain.code, 0) << plain.output;
  const int px = 170, py = 130;
  const RunResult picked = run(base + "--pick 170,130 --screenshot picked.png");
  ASSERT_EQ(picked.code, 0) << picked.output;
  // The viewer prints the command line that replays the pick.
  EXPECT_NE(picked.output.find("kdgrid trace"), std::string::npos) << picked.output;
  EXPECT_NE(picked.output.find("--pixel 170,130 --res 320x240"), std::string::npos)
      << picked.output;

  const ImageRGB a = image("plain.png"), b = image("picked.png");
  ASSERT_EQ(a.width, b.width);
  // Same view, same single deterministic sample: only the overlay differs, and the hit marker
  // and the innermost boxes are drawn around the picked pixel.
  const int near = changed_pixels_near(a, b, px, py, 10);
  EXPECT_GE(near, 8) << "no overlay drawn near the picked pixel";
  // And without a pick the two runs agree there (the comparison is meaningful).
  const RunResult again = run(base + "--screenshot again.png");
  ASSERT_EQ(again.code, 0) << again.output;
  EXPECT_EQ(changed_pixels_near(a, image("again.png"), px, py, 10), 0);
}

TEST_F(Viewer, PickPrintsTheBuildFlagsUnderTheirFieldNamesAndTraceReplaysIt) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  // Every knob through its earlier flag name, which the viewer still accepts.
  const std::vector<std::pair<std::string, std::string>> renamed = {
      {"--dense-matrix", "--hybrid-dense-matrix"},
      {"--hybrid-subtree 2", "--hybrid-subtree-min 2"},
      {"--hybrid-no-expand", "--hybrid-no-expand-empty"},
      {"--hybrid-no-guess", "--hybrid-no-next-leaf-cache"},
      {"--hybrid-cost-ratio 2", "--hybrid-intersection-cost 2"},
      {"--kd-cost-ratio 3", "--kd-intersection-cost 3"},
      {"--bvh-leaf 4", "--bvh-max-leaf 4"},
      {"--irr-top-density 0.5", "--irregular-top-density 0.5"},
      {"--irr-sub-density 3", "--irregular-sub-density 3"}};
  std::string args = "'" + kDefaultScene + "' --accel hybrid" + kSmall + "--hide-ui --pick 170,130";
  for (const auto& [earlier, name] : renamed) args += " " + earlier;
  const RunResult picked = run(args);
  ASSERT_EQ(picked.code, 0) << picked.output;
  std::smatch m;
  ASSERT_TRUE(
      std::regex_search(picked.output, m,
                        std::regex(R"(pick 170,130: \d+ steps, (\d+) triangle tests, )"
                                   R"((hit triangle \d+|miss)[^\n]*\n  kdgrid trace ([^\n]*))")))
      << picked.output;
  const std::string tests = m[1], hit = m[2], command = m[3];
  // The printed command names each flag after the field it sets.
  for (const auto& [earlier, name] : renamed) {
    EXPECT_NE((command + " ").find(" " + name + " "), std::string::npos) << name << ": " << command;
    EXPECT_EQ((command + " ").find(" " + earlier + " "), std::string::npos)
        << earlier << ": " << command;
  }
  // And `kdgrid trace` with it walks the same structure to the same answer.
  const RunResult trace = run_command(quoted(KDGRID_CLI_PATH) + " trace " + command);
  ASSERT_EQ(trace.code, 0) << command << "\n" << trace.output;
  EXPECT_NE(trace.output.find(hit + (hit == "miss" ? "\n" : " at t")), std::string::npos)
      << "viewer: " << hit << "\n"
      << trace.output;
  EXPECT_NE(trace.output.find("triangle tests " + tests + ","), std::string::npos)
      << "viewer: " << tests << " triangle tests\n"
      << trace.output;
}

TEST_F(Viewer, EmbreePickSaysEmbreeExposesNoTraversal) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  const auto names = accelerator_names();
  if (std::find(names.begin(), names.end(), "embree") == names.end())
    GTEST_SKIP() << "Embree is not built in";
  const ViewerResult r = run_stats("'" + kDefaultScene + "' --accel embree --width 640 " +
                                   "--height 480 --frames 3 --max-samples 1 --pick 320,300");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_TRUE(has_item(r.stats, "embree exposes no traversal")) << r.stats["ui"].dump();
}

TEST_F(Viewer, PickStepTableShowsEveryColumnAndLeavesThePickAndTheLegendUncovered) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb, bunny, "bunny/bun_zipper.ply");
  // A pick in the lower half of a heat map: the table's default place is the bottom edge.
  const ViewerResult r =
      run_stats("'" + bunny +
                "' --accel kdtree --width 1280 --height 720 --frames 3 --heatmap steps "
                "--min-samples 1 --max-samples 1 --threads 2 --timeout 120 --pick 640,560");
  ASSERT_TRUE(r.ok());
  const auto& st = r.stats;
  const auto& rects = st["ui"]["rects"];
  ASSERT_TRUE(rects["pick steps"].is_array()) << st["ui"].dump();
  ASSERT_TRUE(rects["legend"].is_array()) << st["ui"].dump();
  const auto rect = [&](const char* n) {
    std::array<double, 4> v{};
    for (size_t i = 0; i < 4; ++i) v[i] = rects[n][i].get<double>();
    return v;
  };
  const auto s = rect("pick steps"), l = rect("legend");
  const bool overlap =
      s[0] < l[0] + l[2] && l[0] < s[0] + s[2] && s[1] < l[1] + l[3] && l[1] < s[1] + s[3];
  EXPECT_FALSE(overlap) << "the step table covers the legend: " << st["ui"].dump();
  EXPECT_GE(s[2] + 1, st["ui"]["steps_table_width"].get<double>()) << "columns cut";
  const bool covers_pick = 640 >= s[0] && 640 <= s[0] + s[2] && 560 >= s[1] && 560 <= s[1] + s[3];
  EXPECT_FALSE(covers_pick) << "the step table covers the picked pixel: " << st["ui"].dump();
}

TEST_F(Viewer, PickStepTableShowsEveryValueWhole) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb, bunny, "bunny/bun_zipper.ply");
  // The kd-tree's trace has dozens of steps with long coordinates in every column.
  const ViewerResult r = run_stats(
      "'" + bunny +
      "' --accel kdtree --width 960 --height 540 --frames 3 --min-samples 1 --max-samples 1 "
      "--threads 2 --timeout 120 --pick 480,270 --screenshot shot.png");
  ASSERT_TRUE(r.ok());
  EXPECT_GT(r.stats["state"]["pick"]["steps"].get<int>(), 5);
  EXPECT_GE(r.stats["ui"]["table_cells"].get<int>(), 6 * 5) << "the step table drew too few cells";
  const std::string cut = clipped_list(r.stats);
  EXPECT_TRUE(cut.empty()) << "cut labels or values:" << cut;
}

// ---- --frame-pick -----------------------------------------------------------------------------

/// The fraction of the image whose colour differs between a and b (see changed_pixels_near).
double changed_fraction(const ImageRGB& a, const ImageRGB& b) {
  return double(changed_pixels_near(a, b, a.width / 2, a.height / 2, std::max(a.width, a.height))) /
         (double(a.width) * double(a.height));
}

/// The fraction of the image covered by areas that differ between a and b: differing pixels
/// whose whole 5x5 neighbourhood differs too, so that lines up to 4 pixels wide (box edges,
/// the ray) do not count and filled regions (the visited leaves' faces) do.
double changed_area_fraction(const ImageRGB& a, const ImageRGB& b) {
  std::vector<uint8_t> diff(size_t(a.width) * size_t(a.height));
  for (int y = 0; y < a.height; ++y)
    for (int x = 0; x < a.width; ++x)
      diff[size_t(y) * size_t(a.width) + size_t(x)] = changed_pixels_near(a, b, x, y, 0) > 0;
  size_t n = 0;
  for (int y = 2; y + 2 < a.height; ++y)
    for (int x = 2; x + 2 < a.width; ++x) {
      bool all = true;
      for (int dy = -2; dy <= 2 && all; ++dy)
        for (int dx = -2; dx <= 2 && all; ++dx)
          all = diff[size_t(y + dy) * size_t(a.width) + size_t(x + dx)] != 0;
      n += all;
    }
  return double(n) / (double(a.width) * double(a.height));
}

/// How much of the image the pick's overlay covers, with and without --frame-pick: each
/// picked screenshot is compared with one of the same camera without the pick (the framed
/// camera comes back through --stats-json as command-line flags), so only the overlay differs.
struct PickCoverage {
  double framed = 0, unframed = 0;            // changed pixels, lines included
  double framed_area = 0, unframed_area = 0;  // changed areas (changed_area_fraction)
  nlohmann::json framed_stats;
};

PickCoverage pick_coverage(const std::string& dir, const std::string& scene,
                           const std::string& accel, const std::string& pick) {
  PickCoverage c;
  const std::string base =
      "'" + scene + "' --accel " + accel +
      " --width 640 --height 360 --frames 3 --min-samples 1 --max-samples 1 --hide-ui "
      "--threads 2 --timeout 120 ";
  const RunResult framed =
      run_viewer(dir, base + "--pick " + pick +
                          " --frame-pick --stats-json framed.json --screenshot framed.png");
  EXPECT_EQ(framed.code, 0) << framed.output;
  c.framed_stats = read_json(dir + "/framed.json");
  if (!c.framed_stats.is_object()) {
    ADD_FAILURE() << "no framed.json\n" << framed.output;
    return c;
  }
  const std::string flags = c.framed_stats["state"]["camera_flags"].get<std::string>();
  for (const std::string& args :
       {base + flags + " --screenshot framed-nopick.png",
        base + "--pick " + pick + " --screenshot picked.png", base + "--screenshot plain.png"}) {
    const RunResult r = run_viewer(dir, args);
    EXPECT_EQ(r.code, 0) << r.output;
  }
  const auto shot = [&](const char* name) { return read_image(dir + "/" + name); };
  const ImageRGB fa = shot("framed.png"), fb = shot("framed-nopick.png");
  const ImageRGB ua = shot("picked.png"), ub = shot("plain.png");
  c.framed = changed_fraction(fa, fb);
  c.unframed = changed_fraction(ua, ub);
  c.framed_area = changed_area_fraction(fa, fb);
  c.unframed_area = changed_area_fraction(ua, ub);
  std::printf("pick overlay: framed %.4f of the image (areas %.4f), unframed %.4f (areas %.4f)\n",
              c.framed, c.framed_area, c.unframed, c.unframed_area);
  return c;
}

TEST_F(Viewer, FramePickFillsTheViewWithTheBunnysVisitedLeaves) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb, bunny, "bunny/bun_zipper.ply");
  const PickCoverage c = pick_coverage(dir, bunny, "bvh", "320,180");
  if (HasFailure()) return;
  const auto& pick = c.framed_stats["state"]["pick"];
  EXPECT_EQ(pick["hit"], true) << "the pick must hit the bunny";
  EXPECT_EQ(pick["framed"], true);
  // Framed, the visited leaves (filled in visit order) cover a clear part of the picture; at
  // the scene's own camera they are specks, and the overlay there is mostly the inner nodes'
  // thin frames.
  EXPECT_GE(c.framed_area, 0.10) << "framed leaves cover " << c.framed_area << " of the image";
  EXPECT_LT(c.unframed_area, 0.01)
      << "unframed leaves cover " << c.unframed_area << " of the image";
  EXPECT_GT(c.framed, 2 * c.unframed) << "framed " << c.framed << ", unframed " << c.unframed;
  // The camera kept its view direction.
  const auto [a, b] = start_and_end_cameras(c.framed_stats);
  EXPECT_GT(dot(normalize(a.target - a.eye), normalize(b.target - b.eye)), 0.9999f);
  EXPECT_LT(length(b.target - b.eye), 0.5f * length(a.target - a.eye))
      << "the camera did not move closer";
}

TEST_F(Viewer, FramePickFillsTheViewOnTheDefaultScene) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  // A pixel on the glass sphere, whose BVH leaves are small.
  const PickCoverage c = pick_coverage(dir, kDefaultScene, "bvh", "380,270");
  if (HasFailure()) return;
  EXPECT_EQ(c.framed_stats["state"]["pick"]["framed"], true);
  EXPECT_EQ(c.framed_stats["state"]["pick"]["hit"], true);
  EXPECT_GE(c.framed_area, 0.10) << "framed leaves cover " << c.framed_area << " of the image";
  EXPECT_GT(c.framed_area, 5 * c.unframed_area)
      << "framed " << c.framed_area << ", unframed " << c.unframed_area;
}

}  // namespace
}  // namespace kdgrid::test

#endif
