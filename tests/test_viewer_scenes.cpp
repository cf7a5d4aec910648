// kdgrid-viewer end to end (tests/support/viewer_run.h): loading scenes while it runs, through
// a dropped file, and the errors a scene that fails to load leaves on screen, in the output
// and in --stats-json.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <string>

#include "viewer_checks.h"
#include "viewer_run.h"

#ifdef KDGRID_VIEWER_PATH

namespace kdgrid::test {
namespace {

/// A tiny OBJ (a tetrahedron) to drop.
std::string write_tetrahedron(const std::string& dir) {
  const std::string path = dir + "/tetra.obj";
  std::ofstream f(path);
  f << "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
  return path;
}

/// Pixels of the error colour: ImGui text in (1, 0.4, 0.4), which read_image returns linear
/// (0.4 in sRGB is 0.133).
int error_red_pixels(const ImageRGB& img) {
  int n = 0;
  for (size_t i = 0; i + 2 < img.rgb.size(); i += 3) {
    const float r = img.rgb[i], g = img.rgb[i + 1], b = img.rgb[i + 2];
    if (r > 0.8f && g > 0.08f && g < 0.25f && std::fabs(g - b) < 0.03f) ++n;
  }
  return n;
}

TEST_F(Viewer, DropLoadsTheDroppedScene) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  // xdotool cannot drop files (XDND needs a drag source), so --drop calls the handler that
  // GLFW's drop callback calls, once the start-up scene is on screen.
  const std::string tetra = write_tetrahedron(dir);
  const std::string base = "'" + kDefaultScene + "' --accel bvh" + kSmall + "--hide-ui ";
  const RunResult before = run(base + "--screenshot before.png");
  ASSERT_EQ(before.code, 0) << before.output;
  const ViewerResult r = run_stats(base + "--drop '" + tetra + "' --screenshot after.png");
  ASSERT_TRUE(r.ok());
  const auto& stats = r.stats;
  EXPECT_EQ(stats["state"]["scene"], tetra);
  EXPECT_EQ(stats["state"]["triangles"], 4);
  ASSERT_EQ(stats["builds"].size(), 2u);
  EXPECT_EQ(stats["builds"][1]["kind"], "load");
  // A new scene is framed by its own camera: the picture changes.
  EXPECT_GT(rmse(image("before.png"), image("after.png")), 0.01);
}

TEST_F(Viewer, DroppedBadFileShowsAnErrorAndKeepsTheScene) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  const std::string bad = write_bad_ply();
  // With the panels, 640 wide so they fit.
  const std::string base =
      "'" + kDefaultScene + "' --accel bvh --width 640 --height 480 --frames 3 --max-samples 1 ";
  const RunResult ok = run(base + "--screenshot ok.png");
  ASSERT_EQ(ok.code, 0) << ok.output;
  // A scripted run reports the failed load with exit code 1, after writing its outputs.
  const ViewerResult r = run_stats(base + "--drop '" + bad + "' --screenshot shot.png");
  ASSERT_TRUE(r.ok(1));
  EXPECT_NE(r.output.find("bad.ply"), std::string::npos) << r.output;
  const auto& stats = r.stats;
  EXPECT_EQ(stats["state"]["scene"], kDefaultScene) << "the old scene was not kept";
  EXPECT_NE(stats["state"]["error"].get<std::string>().find("bad.ply"), std::string::npos);
  EXPECT_EQ(stats["builds"].back()["kind"], "load");
  EXPECT_TRUE(stats["builds"].back().contains("error"));
  // The panel shows the error in red; without the drop there is none of that colour.
  const int red = error_red_pixels(image("shot.png"));
  const int red_ok = error_red_pixels(image("ok.png"));
  EXPECT_GT(red, 50 + red_ok) << "no error text on screen";
}

TEST_F(Viewer, StatsJsonStaysValidWhenAnErrorQuotesInvalidUtf8) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  // Bytes that are not UTF-8 in the file's name (quoted as they are by every error that names
  // the file) and in its body (quoted by the loader, which escapes them as \xFF).
  const std::string bad = path("garbage\xff\xfe.ply");
  std::ofstream(bad, std::ios::binary)
      << "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
         "property float y\nproperty float z\nelement face 1\n"
         "property list uchar int vertex_indices\nend_header\n"
      << "\xff\xfe\xc3\x28 \xa0\xa1\n";
  const ViewerResult r = run_stats("'" + kDefaultScene +
                                   "' --accel bvh --width 320 --height 240 --frames 3 "
                                   "--max-samples 1 --drop '" +
                                   bad + "'");
  EXPECT_EQ(r.code, 1) << r.output;
  ASSERT_TRUE(r.stats.is_object()) << "stats.json is not valid JSON: " << r.output;
  const std::string error = r.stats["state"]["error"].get<std::string>();
  EXPECT_NE(error.find("garbage"), std::string::npos) << error;
  EXPECT_TRUE(error.find("\xef\xbf\xbd") != std::string::npos ||
              error.find("\\xFF") != std::string::npos)
      << "the quoted bytes, replaced by U+FFFD or escaped: " << error;
}

TEST_F(Viewer, MissingSceneKeepsTheWindowWithTheErrorShownAndPrintedOnce) {
  KDGRID_REQUIRE_XVFB();
  const ViewerResult r = run_stats("'" + dir +
                                   "/missing.ply' --accel bvh --width 640 --height 480 --frames 20 "
                                   "--screenshot shot.png");
  EXPECT_EQ(r.code, 1) << "the exit code says the load failed\n" << r.output;
  const auto& st = r.stats;
  ASSERT_TRUE(st.is_object()) << r.output;
  EXPECT_EQ(st["end"], "start-up scene failed");
  // The window stayed for the frames asked for, showing the error.
  EXPECT_GE(st["frames"]["count"].get<int>(), 20) << r.output;
  const std::string error = st["state"]["error"].get<std::string>();
  ASSERT_NE(error.find("missing.ply"), std::string::npos) << error;
  EXPECT_EQ(count_of(r.output, error), 1) << "the error is printed once:\n" << r.output;
  EXPECT_GT(error_red_pixels(image("shot.png")), 50) << "no error text on screen";
}

}  // namespace
}  // namespace kdgrid::test

#endif
