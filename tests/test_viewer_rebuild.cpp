// kdgrid-viewer end to end (tests/support/viewer_run.h): rebuilding the structure while the
// viewer runs. A live rebuild with a new cell size, cancelling a running build (Esc, a newer
// request, Ctrl+Q during the first build) and the build's progress bar.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include "viewer_checks.h"
#include "viewer_run.h"

#ifdef KDGRID_VIEWER_PATH

namespace kdgrid::test {
namespace {

namespace fs = std::filesystem;

TEST_F(Viewer, LiveRebuildCompletes) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedSmallScene | kNeedFastAccel);
  const std::string accel = fast_accel();
  const RunResult r = run(quoted(small_scene()) + " --accel " + accel + kSmall +
                          "--rebuild-cell-size 0.5 --screenshot shot.png");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("rebuilt " + accel), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(path("shot.png")));
}

TEST_F(Viewer, LiveRebuildWithNewCellSizeChangesTheView) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedSmallScene);
  const auto names = accelerator_names();
  std::string accel;
  for (const char* n : {"hybrid", "grid"})
    if (std::find(names.begin(), names.end(), n) != names.end()) accel = n;
  if (accel.empty()) GTEST_SKIP() << "no structure with a cell size (hybrid, grid) is built in yet";
  // Cells overlay and a steps heat map: both depend on the cell size, the render does not.
  const std::string base = quoted(small_scene()) + " --accel " + accel + kSmall +
                           "--hide-ui --overlay cells --heatmap steps ";
  const RunResult before = run(base + "--screenshot before.png");
  ASSERT_EQ(before.code, 0) << before.output;
  const RunResult after = run(base + "--rebuild-cell-size 0.5 --screenshot after.png");
  ASSERT_EQ(after.code, 0) << after.output;
  EXPECT_NE(after.output.find("rebuilt " + accel), std::string::npos) << after.output;
  const double d = rmse(image("before.png"), image("after.png"));
  EXPECT_GT(d, 1e-3) << "the screenshot did not change after rebuilding with a new cell size";
}

TEST_F(Viewer, EscCancelsARunningBuildAndTheOldStructureStays) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedDrivenDefault, dragon, "dragon/dragon_vrip.ply");
  // The full dragon at kLongDragonBuildCell (with the build-time limit off) builds for seconds;
  // Esc 2 s in.
  const ViewerResult d = drive("'" + dragon +
                                   "' --accel hybrid --width 640 --height 480 --max-samples 1 "
                                   "--hold 90 --hybrid-max-build-seconds 0 --rebuild-cell-size " +
                                   kLongDragonBuildCell + " --screenshot shot.png",
                               "dragon_vrip.ply", "sleep 2\nkey Escape\nsleep 1");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto& builds = d.stats["builds"];
  ASSERT_EQ(builds.size(), 2u) << d.viewer_log;
  EXPECT_EQ(builds[1]["error"], "cancelled") << d.viewer_log;
  ASSERT_TRUE(builds[1]["cancel_seconds"].is_number()) << d.viewer_log;
  EXPECT_LT(builds[1]["cancel_seconds"].get<double>(), 1.0)
      << "the build took that long to stop after Esc";
  EXPECT_LT(builds[1]["wall_seconds"].get<double>(), 10.0);
  // The old structure (auto cell size) is what the viewer shows and renders.
  EXPECT_EQ(d.stats["state"]["accel"], "hybrid");
  EXPECT_EQ(d.stats["state"]["cell_size"], 0.0f);
  EXPECT_EQ(d.stats["state"]["error"], "") << "a cancel is not an error";
  const ImageRGB shot = image("shot.png");
  EXPECT_GT(luminance_variance(shot), 1e-3) << "no picture after the cancel";
}

TEST_F(Viewer, ANewCellSizeRequestCancelsTheRunningBuildAndBuildsTheNewSize) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb, dragon, "dragon/dragon_vrip.ply");
  // The full dragon at kLongDragonBuildCell (build-time limit off) builds for seconds, longer on
  // a busy machine; 2 s into it a 0.003 cell is requested through the
  // panel's cell-size path (under a second to build). The newer request stops the running build
  // within a second, and the 0.003 structure is what remains.
  const ViewerResult r =
      run_stats("'" + dragon +
                "' --accel hybrid --width 640 --height 480 --max-samples 1 "
                "--frames 3 --timeout 120 --hybrid-max-build-seconds 0 --rebuild-cell-size " +
                kLongDragonBuildCell +
                " "
                "--supersede-cell-size 0.003 --supersede-after 2");
  ASSERT_TRUE(r.ok());
  const auto& st = r.stats;
  const auto& builds = st["builds"];
  ASSERT_EQ(builds.size(), 3u) << "load, the long rebuild, the 0.003 rebuild: " << builds.dump()
                               << r.output;
  EXPECT_EQ(builds[1].value("error", ""), "cancelled")
      << "the running build was not superseded: " << builds[1].dump();
  ASSERT_TRUE(builds[1]["cancel_seconds"].is_number()) << builds[1].dump();
  EXPECT_LT(builds[1]["cancel_seconds"].get<double>(), 1.0) << "the build took that long to stop";
  EXPECT_FALSE(builds[2].contains("error")) << builds[2].dump();
  EXPECT_FLOAT_EQ(builds[2]["requested_cell_size"].get<float>(), 0.003f) << builds[2].dump();
  EXPECT_FLOAT_EQ(st["state"]["cell_size"].get<float>(), 0.003f) << st["state"].dump();
  EXPECT_EQ(st["state"]["error"], "") << "a superseded build is not an error";
  // The long build ended within a second of the second request (2 s in), not at its own end.
  EXPECT_LT(builds[1]["wall_seconds"].get<double>(), 3.0) << builds.dump();
}

TEST_F(Viewer, CtrlQDuringTheFirstBuildExitsWithinASecond) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb | kNeedXdotool, dragon, "dragon/dragon_vrip.ply");
  const std::string driver = path("driver.sh");
  // An interactive run (no --hold), as a person starts it: the full dragon at
  // kLongDragonBuildCell (seconds to build, the build-time limit off); Ctrl+Q 3 s into the
  // build, before the window's title names a scene.
  std::ofstream(driver)
      << "#!/bin/bash\ncd '" << dir << "'\n'" << KDGRID_VIEWER_PATH << "' '" << dragon
      << "' --accel hybrid --cell-size " << kLongDragonBuildCell
      << " --hybrid-max-build-seconds 0 --width 640 --height 480 "
         "> viewer.log 2>&1 &\n"
      << "pid=$!\n"
      << "wid=$(timeout 60 xdotool search --sync --name '^kdgrid-viewer$' | head -1)\n"
      << "xdotool windowfocus --sync \"$wid\"; sleep 3\n"
      << kTimedCtrlQ << "kill -0 $pid 2>/dev/null && { echo 'driver: still running'; kill $pid; }\n"
      << "wait $pid; echo \"driver: rc $?\"\n";
  const RunResult r =
      run_command(xvfb_command(dir, "bash", driver, "1280x1024x24", "timeout -k 10 120 "));
  const size_t at = r.output.find("driver: rc ");
  ASSERT_NE(at, std::string::npos) << r.output;
  int rc = -1;
  ASSERT_EQ(std::sscanf(r.output.c_str() + at, "driver: rc %d", &rc), 1) << r.output;
  EXPECT_EQ(rc, 0) << r.output;
  const int ms = exit_ms(r.output);
  ASSERT_GE(ms, 0) << r.output;
  EXPECT_LT(ms, 1000) << "Ctrl+Q took " << ms << " ms to end the viewer during a build\n"
                      << r.output;
  // It was during the build: the first build never finished.
  std::ifstream log(path("viewer.log"));
  const std::string said((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
  EXPECT_EQ(said.find("loaded and built"), std::string::npos)
      << "the build had finished before Ctrl+Q:\n"
      << said;
}

TEST_F(Viewer, TheBuildProgressBarRisesMonotonically) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb, dragon, "dragon/dragon_vrip.ply");
  // A build of a few seconds (1e-4 on the full dragon: 3 s on an idle Zen 5), its bar recorded
  // every frame.
  const ViewerResult r = run_stats("'" + dragon +
                                   "' --accel hybrid --width 640 --height 480 --frames 3 "
                                   "--max-samples 1 --hybrid-max-build-seconds 0 "
                                   "--rebuild-cell-size 1e-4");
  ASSERT_EQ(r.code, 0) << r.output;
  const auto& bar = r.stats["build_progress"];
  ASSERT_GE(bar.size(), 10u) << bar.dump();
  double last = -1;
  for (const auto& e : bar) {
    const double f = e[1].get<double>();
    EXPECT_GE(f, last) << "the bar moved back at " << e.dump();
    EXPECT_LT(f, 1.0);
    last = f;
  }
  EXPECT_GT(last, bar[0][1].get<double>()) << "the bar did not rise: " << bar.dump();
}

}  // namespace
}  // namespace kdgrid::test

#endif
