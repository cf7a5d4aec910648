// kdgrid-viewer end to end: the tests run the real binary under Xvfb (Mesa llvmpipe gives an
// OpenGL 3.3 core context without a GPU) in its scripted mode and look at its screenshots and
// statistics (tests/support/viewer_run.h). This file: starting without a display or with bad
// options, the first picture, the outputs (screenshots, statistics, a full disk), the idle
// window and brute force's work limit. The other test_viewer_*.cpp files test the input,
// picks, overlays, flight, rebuilds, cell sizes, the panel and loading scenes.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <utility>

#include "image/image_module.h"
#include "viewer_checks.h"
#include "viewer_run.h"

#ifdef KDGRID_VIEWER_PATH

namespace kdgrid::test {
namespace {

namespace fs = std::filesystem;

TEST_F(Viewer, NoDisplayGivesClearMessageAndExitCode3) {
  const RunResult r = run_without_display("--frames 1 --screenshot shot.png");
  EXPECT_EQ(r.code, 3) << r.output;
  EXPECT_NE(r.output.find("DISPLAY"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("kdgrid render"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("xvfb-run"), std::string::npos) << r.output;
}

TEST_F(Viewer, BadOptionIsRejectedBeforeOpeningAWindow) {
  const RunResult r = run_without_display("--accel no-such-structure --frames 1");
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("no-such-structure"), std::string::npos) << r.output;
}

TEST_F(Viewer, DefaultSceneScreenshotIsNotBlank) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  const std::string accel = fast_accel().empty() ? "brute" : fast_accel();
  // No scene argument: the viewer must find its default scene by itself.
  const RunResult r = run("--accel " + accel + kSmall + "--screenshot shot.png");
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageRGB img = image("shot.png");
  EXPECT_EQ(img.width, 320);
  EXPECT_EQ(img.height, 240);
  EXPECT_GT(luminance_variance(img), 1e-3) << "screenshot looks blank";
}

TEST_F(Viewer, StanfordBunnyScreenshotIsNotBlank) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb | kNeedFastAccel, bunny, "bunny/bun_zipper.ply");
  const RunResult r =
      run("'" + bunny + "' --accel " + fast_accel() + kSmall + "--hide-ui --screenshot shot.png");
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageRGB img = image("shot.png");
  EXPECT_GT(luminance_variance(img), 1e-3) << "screenshot looks blank";
  // The bunny sits in the middle of the canonical camera's view: the centre is not background.
  const size_t c = (size_t(img.height / 2) * size_t(img.width) + size_t(img.width / 2)) * 3;
  const size_t corner = 0;
  EXPECT_NE(img.rgb[c], img.rgb[corner]);
}

TEST_F(Viewer, OutputsAreCheckedBeforeTheWindowOpens) {
  // No display is needed: the refusal comes first (exit code 2, not 3 for no display).
  for (const auto& [args, says] : std::initializer_list<std::pair<std::string, std::string>>{
           {"--frames 1 --screenshot /dev/null", "--screenshot /dev/null: exists and is not"},
           {"--frames 1 --stats-json no/such/folder/s.json", "does not exist"}}) {
    const RunResult r = run_without_display(args);
    EXPECT_EQ(r.code, 2) << args << ": " << r.output;
    EXPECT_NE(r.output.find(says), std::string::npos) << args << ": " << r.output;
  }
}

TEST_F(Viewer, APersonsRunLoadsTheImageModuleAtStartAndAScriptedOneOnlyToWriteAnImage) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  // --hold is a run a person (or xdotool) drives: its screenshot key must not be the first
  // image write. A scripted run writing no image never loads the module.
  const std::string args = "--accel bvh --width 64 --height 64 --max-samples 1 ";
  RunResult r = run(args + "--hold 0.5", "export LD_DEBUG=files;");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find(image_module::kFileName), std::string::npos) << "not loaded";
  r = run(args + "--frames 2", "export LD_DEBUG=files;");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_EQ(r.output.find(image_module::kFileName), std::string::npos) << "loaded for nothing";

  // A copy of the viewer with no module near it refuses a run that writes an image, as it
  // refuses bad options: before the window opens (no display here), with exit code 2.
  fs::create_directories(path("bin"));
  const std::string lone = path("bin/kdgrid-viewer");
  fs::copy_file(KDGRID_VIEWER_PATH, lone);
  r = run_command("cd '" + dir + "' && env -u DISPLAY '" + lone + "' '" + kDefaultScene +
                  "' --frames 1 --screenshot shot.png 2>&1");
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find(image_module::kFileName), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(path("shot.png")));
}

TEST_F(Viewer, FullDiskKeepsTheOldScreenshotAndStatsAndFails) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  const std::string args = "--accel bvh" + kSmall + "--screenshot shot.png --stats-json stats.json";
  RunResult r = run(args);
  ASSERT_EQ(r.code, 0) << r.output;
  const std::string shot = read_file_bytes(path("shot.png")),
                    stats = read_file_bytes(path("stats.json"));
  ASSERT_GT(shot.size(), 2048u);
  ASSERT_GT(stats.size(), 2048u);
  // A 2 KiB file-size limit, SIGXFSZ ignored: every write past it fails as on a full disk.
  r = run(args, "trap '' XFSZ; ulimit -f 2; ");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_EQ(r.output.find("wrote shot.png"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("shot.png: writing failed"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("--stats-json stats.json: writing failed"), std::string::npos)
      << r.output;
  EXPECT_EQ(read_file_bytes(path("shot.png")), shot) << "the old screenshot was replaced";
  EXPECT_EQ(read_file_bytes(path("stats.json")), stats) << "the old statistics were replaced";
}

TEST_F(Viewer, IdleWindowSleepsButStillShowsEveryPass) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  // Three seconds with nothing to do after four passes: a loop drawing at 60 Hz would draw
  // about 180 frames; an idle one sleeps on its event queue (waking every 0.25 s at most)
  // and is woken by each finished pass, which it must still show.
  const ViewerResult r = run_stats("'" + kDefaultScene +
                                   "' --accel bvh --width 320 --height 240 --threads 1 "
                                   "--hold 3 --min-samples 4 --max-samples 4");
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r.stats["end"], "hold expired");
  EXPECT_EQ(r.stats["state"]["samples"], 4) << "a finished pass did not reach the screen";
  const int frames = r.stats["frames"]["count"];
  EXPECT_LT(frames, 60) << "the idle viewer kept drawing";
  EXPECT_GE(frames, 5);
}

TEST_F(Viewer, InputTwoScreenshotsInOneSecondAreBothKept) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedXdotool | kNeedDefaultScene);
  const ViewerResult d = drive_default("mv 500 400\nxdotool key p p\nsleep 0.5");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  int shots = 0;
  for (const auto& e : fs::directory_iterator(dir))
    shots += e.path().filename().string().rfind("kdgrid-screenshot-", 0) == 0;
  EXPECT_EQ(shots, 2) << d.viewer_log;
}

// ---- brute force's work limit ------------------------------------------------------------------

/// Pixels of the refusal's orange (1, 0.6, 0.1), which read_image returns linear (0.6 in sRGB
/// is 0.32, 0.1 is 0.01).
int refusal_orange_pixels(const ImageRGB& img) {
  int n = 0;
  for (size_t i = 0; i + 2 < img.rgb.size(); i += 3)
    if (img.rgb[i] > 0.8f && img.rgb[i + 1] > 0.2f && img.rgb[i + 1] < 0.45f &&
        img.rgb[i + 2] < 0.06f)
      ++n;
  return n;
}

TEST_F(Viewer, BruteForceStopsAtItsWorkLimitAndSaysSoOnScreen) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  // 320 x 240 pixels x 2572 triangles = 1.98e8 tests per pass, above a limit of 1e6.
  const std::string base = "'" + kDefaultScene +
                           "' --accel brute --width 320 --height 240 --frames 3 --min-samples 1 "
                           "--max-samples 1 --threads 2 --hide-ui --timeout 120 ";
  const ViewerResult r = run_stats(base + "--brute-work-limit 1e6 --screenshot stopped.png");
  ASSERT_TRUE(r.ok(1));
  const auto& st = r.stats;
  EXPECT_EQ(st["end"], "brute-force work limit");
  const std::string refusal = st["state"]["render_refusal"].get<std::string>();
  EXPECT_NE(refusal.find("--brute-work-limit"), std::string::npos) << refusal;
  EXPECT_EQ(count_of(r.output, refusal), 1) << "printed once:\n" << r.output;
  EXPECT_TRUE(st["passes"].empty()) << "brute force rendered past its limit";
  const ImageRGB stopped = image("stopped.png");
  EXPECT_GT(refusal_orange_pixels(stopped), 100) << "no message on screen";
  // Without a limit (0) the same run renders the scene, with no message.
  const RunResult ok = run(base + "--brute-work-limit 0 --screenshot ok.png");
  ASSERT_EQ(ok.code, 0) << ok.output;
  const ImageRGB rendered = image("ok.png");
  EXPECT_EQ(refusal_orange_pixels(rendered), 0);
  EXPECT_GT(luminance_variance(rendered), 1e-3);
}

}  // namespace
}  // namespace kdgrid::test

#else

TEST(Viewer, NotBuilt) {
  GTEST_SKIP()
      << "kdgrid-viewer is not built (KDGRID_BUILD_VIEWER=OFF or GLFW/epoxy/imgui missing)";
}

#endif
