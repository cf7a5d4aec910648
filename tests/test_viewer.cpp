// kdgrid-viewer end to end: the tests run the real binary under Xvfb (Mesa llvmpipe gives an
// OpenGL 3.3 core context without a GPU) in its scripted mode and look at its screenshots.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "accel/accelerator.h"
#include "render/image_io.h"
#include "test_util.h"

#ifdef KDGRID_VIEWER_PATH

namespace kdgrid::test {
namespace {

namespace fs = std::filesystem;

struct RunResult {
  int code = -1;
  std::string output;  // stdout and stderr together
};

RunResult run_command(const std::string& cmd) {
  RunResult r;
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) r.output.append(buf, n);
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

bool have_xvfb() { return std::system("command -v xvfb-run >/dev/null 2>&1") == 0; }

/// A scratch directory per test (also the viewer's config directory, so no user settings leak
/// in and none are written to the user's home).
std::string scratch_dir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path d = fs::temp_directory_path() / ("kdgrid_viewer_" + std::string(info->name()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d.string();
}

/// Runs the viewer under a fresh virtual X server with software GL.
RunResult run_viewer(const std::string& dir, const std::string& args) {
  const std::string cmd = "cd '" + dir + "' && XDG_CONFIG_HOME='" + dir +
                          "' LIBGL_ALWAYS_SOFTWARE=1 xvfb-run -a -s '-screen 0 1280x1024x24' '" +
                          std::string(KDGRID_VIEWER_PATH) + "' " + args;
  return run_command(cmd);
}

/// The fastest structure built into this binary for scenes too big for brute force.
std::string fast_accel() {
  const auto names = accelerator_names();
  for (const char* n : {"bvh", "hybrid", "kdtree", "grid", "embree"})
    if (std::find(names.begin(), names.end(), n) != names.end()) return n;
  return "";
}

double luminance_variance(const ImageRGB& img) {
  double s = 0, s2 = 0;
  const size_t n = size_t(img.width) * size_t(img.height);
  for (size_t i = 0; i < n; ++i) {
    const double y = 0.2126 * img.rgb[i * 3] + 0.7152 * img.rgb[i * 3 + 1] + 0.0722 * img.rgb[i * 3 + 2];
    s += y;
    s2 += y * y;
  }
  const double m = s / double(n);
  return s2 / double(n) - m * m;
}

/// Pixels within `radius` of (cx, cy) whose colour differs between a and b by more than 0.05
/// in some channel.
int changed_pixels_near(const ImageRGB& a, const ImageRGB& b, int cx, int cy, int radius) {
  int n = 0;
  for (int y = std::max(0, cy - radius); y <= std::min(a.height - 1, cy + radius); ++y)
    for (int x = std::max(0, cx - radius); x <= std::min(a.width - 1, cx + radius); ++x) {
      const size_t i = (size_t(y) * size_t(a.width) + size_t(x)) * 3;
      float d = 0;
      for (int c = 0; c < 3; ++c) d = std::max(d, std::fabs(a.rgb[i + c] - b.rgb[i + c]));
      if (d > 0.05f) ++n;
    }
  return n;
}

#define KDGRID_REQUIRE_XVFB()                                                                   \
  if (!have_xvfb())                                                                             \
  GTEST_SKIP() << "xvfb-run is not installed (Debian package xvfb): the viewer tests need a "   \
                  "virtual X display"

const std::string kDefaultScene = source_path("assets/cornell.gltf");

#define KDGRID_REQUIRE_DEFAULT_SCENE()                                                          \
  if (!fs::exists(kDefaultScene))                                                               \
  GTEST_SKIP() << "default scene " << kDefaultScene << " is missing (generate it with "         \
                  "`kdgrid gen cornell -o assets/cornell.gltf`)"

// Small windows and one deterministic sample per pixel keep runs short and screenshots
// comparable pixel for pixel.
const std::string kSmall = " --width 320 --height 240 --frames 3 --min-samples 1 --max-samples 1 ";

TEST(Viewer, NoDisplayGivesClearMessageAndExitCode3) {
  const std::string cmd = "env -u DISPLAY -u WAYLAND_DISPLAY '" + std::string(KDGRID_VIEWER_PATH) +
                          "' --frames 1 --screenshot /dev/null";
  const RunResult r = run_command(cmd);
  EXPECT_EQ(r.code, 3) << r.output;
  EXPECT_NE(r.output.find("DISPLAY"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("kdgrid render"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("xvfb-run"), std::string::npos) << r.output;
}

TEST(Viewer, BadOptionIsRejectedBeforeOpeningAWindow) {
  const RunResult r = run_command("env -u DISPLAY '" + std::string(KDGRID_VIEWER_PATH) +
                                  "' --accel no-such-structure --frames 1");
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("no-such-structure"), std::string::npos) << r.output;
}

TEST(Viewer, DefaultSceneScreenshotIsNotBlank) {
  KDGRID_REQUIRE_XVFB();
  KDGRID_REQUIRE_DEFAULT_SCENE();
  const std::string dir = scratch_dir();
  const std::string accel = fast_accel().empty() ? "brute" : fast_accel();
  // No scene argument: the viewer must find its default scene by itself.
  const RunResult r = run_viewer(dir, "--accel " + accel + kSmall + "--screenshot shot.png");
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageRGB img = read_image(dir + "/shot.png");
  EXPECT_EQ(img.width, 320);
  EXPECT_EQ(img.height, 240);
  EXPECT_GT(luminance_variance(img), 1e-3) << "screenshot looks blank";
}

TEST(Viewer, StanfordBunnyScreenshotIsNotBlank) {
  KDGRID_REQUIRE_XVFB();
  KDGRID_REQUIRE_SCENE(bunny, "bunny/bun_zipper.ply");
  const std::string accel = fast_accel();
  if (accel.empty()) GTEST_SKIP() << "no structure faster than brute force is built in yet";
  const std::string dir = scratch_dir();
  const RunResult r = run_viewer(dir, "'" + bunny + "' --accel " + accel + kSmall + "--hide-ui --screenshot shot.png");
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageRGB img = read_image(dir + "/shot.png");
  EXPECT_GT(luminance_variance(img), 1e-3) << "screenshot looks blank";
  // The bunny sits in the middle of the canonical camera's view: the centre is not background.
  const size_t c = (size_t(img.height / 2) * size_t(img.width) + size_t(img.width / 2)) * 3;
  const size_t corner = 0;
  EXPECT_NE(img.rgb[c], img.rgb[corner]);
}

/// Scene used by the pick and rebuild tests: the default scene, else the bunny.
std::string small_scene() {
  if (fs::exists(kDefaultScene)) return kDefaultScene;
  return shared_scene("bunny/bun_zipper.ply");
}

TEST(Viewer, PickDrawsTraversalAtThePickedPixel) {
  KDGRID_REQUIRE_XVFB();
  const std::string scene = small_scene();
  if (scene.empty()) GTEST_SKIP() << "neither assets/cornell.gltf nor the shared bunny is available";
  const std::string accel = fast_accel();
  if (accel.empty()) GTEST_SKIP() << "no structure with a traversal to show is built in yet";
  const std::string dir = scratch_dir();
  const std::string base = "'" + scene + "' --accel " + accel + kSmall + "--hide-ui ";
  const RunResult plain = run_viewer(dir, base + "--screenshot plain.png");
  ASSERT_EQ(plain.code, 0) << plain.output;
  const int px = 170, py = 130;
  const RunResult picked = run_viewer(dir, base + "--pick 170,130 --screenshot picked.png");
  ASSERT_EQ(picked.code, 0) << picked.output;
  // The viewer prints the command line that replays the pick.
  EXPECT_NE(picked.output.find("kdgrid trace"), std::string::npos) << picked.output;
  EXPECT_NE(picked.output.find("--pixel 170,130 --res 320x240"), std::string::npos) << picked.output;

  const ImageRGB a = read_image(dir + "/plain.png"), b = read_image(dir + "/picked.png");
  ASSERT_EQ(a.width, b.width);
  // Same view, same single deterministic sample: only the overlay differs, and the hit marker
  // and the innermost boxes are drawn around the picked pixel.
  const int near = changed_pixels_near(a, b, px, py, 10);
  EXPECT_GE(near, 8) << "no overlay drawn near the picked pixel";
  // And without a pick the two runs agree there (the comparison is meaningful).
  const RunResult again = run_viewer(dir, base + "--screenshot again.png");
  ASSERT_EQ(again.code, 0) << again.output;
  EXPECT_EQ(changed_pixels_near(a, read_image(dir + "/again.png"), px, py, 10), 0);
}

TEST(Viewer, HeatMapExportsRawCountsAsExr) {
  KDGRID_REQUIRE_XVFB();
  const std::string scene = small_scene();
  if (scene.empty()) GTEST_SKIP() << "neither assets/cornell.gltf nor the shared bunny is available";
  const std::string accel = fast_accel();
  if (accel.empty()) GTEST_SKIP() << "no structure faster than brute force is built in yet";
  const std::string dir = scratch_dir();
  const RunResult r = run_viewer(dir, "'" + scene + "' --accel " + accel + kSmall +
                                          "--heatmap tests --export-heatmap tests.exr --screenshot shot.png");
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageRGB img = read_image(dir + "/tests.exr");
  ASSERT_EQ(img.width, 320);
  float lo = kInf, hi = 0;
  for (size_t i = 0; i < img.rgb.size(); i += 3) {
    lo = std::min(lo, img.rgb[i]);
    hi = std::max(hi, img.rgb[i]);
    // One sample per pixel: each value is a whole number of triangle tests, the same in R, G, B.
    ASSERT_EQ(img.rgb[i], std::floor(img.rgb[i]));
    ASSERT_EQ(img.rgb[i], img.rgb[i + 1]);
  }
  EXPECT_GE(lo, 0.0f);
  EXPECT_GE(hi, 1.0f) << "no pixel tested a triangle";
  EXPECT_GT(hi, lo) << "the heat map is flat";
}

TEST(Viewer, LiveRebuildCompletes) {
  KDGRID_REQUIRE_XVFB();
  const std::string scene = small_scene();
  if (scene.empty()) GTEST_SKIP() << "neither assets/cornell.gltf nor the shared bunny is available";
  const std::string accel = fast_accel();
  if (accel.empty()) GTEST_SKIP() << "no structure faster than brute force is built in yet";
  const std::string dir = scratch_dir();
  const RunResult r = run_viewer(dir, "'" + scene + "' --accel " + accel + kSmall +
                                          "--rebuild-cell-size 0.5 --screenshot shot.png");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("rebuilt " + accel), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(dir + "/shot.png"));
}

TEST(Viewer, LiveRebuildWithNewCellSizeChangesTheView) {
  KDGRID_REQUIRE_XVFB();
  const std::string scene = small_scene();
  if (scene.empty()) GTEST_SKIP() << "neither assets/cornell.gltf nor the shared bunny is available";
  const auto names = accelerator_names();
  std::string accel;
  for (const char* n : {"hybrid", "grid"})
    if (std::find(names.begin(), names.end(), n) != names.end()) accel = n;
  if (accel.empty()) GTEST_SKIP() << "no structure with a cell size (hybrid, grid) is built in yet";
  const std::string dir = scratch_dir();
  // Cells overlay and a steps heat map: both depend on the cell size, the render does not.
  const std::string base = "'" + scene + "' --accel " + accel + kSmall + "--hide-ui --overlay cells --heatmap steps ";
  const RunResult before = run_viewer(dir, base + "--screenshot before.png");
  ASSERT_EQ(before.code, 0) << before.output;
  const RunResult after = run_viewer(dir, base + "--rebuild-cell-size 0.5 --screenshot after.png");
  ASSERT_EQ(after.code, 0) << after.output;
  EXPECT_NE(after.output.find("rebuilt " + accel), std::string::npos) << after.output;
  const double d = rmse(read_image(dir + "/before.png"), read_image(dir + "/after.png"));
  EXPECT_GT(d, 1e-3) << "the screenshot did not change after rebuilding with a new cell size";
}

}  // namespace
}  // namespace kdgrid::test

#else

TEST(Viewer, NotBuilt) {
  GTEST_SKIP() << "kdgrid-viewer is not built (KDGRID_BUILD_VIEWER=OFF or GLFW/epoxy/imgui missing)";
}

#endif
