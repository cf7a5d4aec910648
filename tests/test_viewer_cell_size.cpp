// kdgrid-viewer end to end (tests/support/viewer_run.h): the hybrid's cell size. Typed into the
// panel (its estimate before Enter, a short Enter, Esc while it builds), remembered per scene
// or as a multiple of auto, refused when too small, and a cell larger than the scene.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "viewer_checks.h"
#include "viewer_run.h"

#ifdef KDGRID_VIEWER_PATH

namespace kdgrid::test {
namespace {

namespace fs = std::filesystem;

TEST_F(Viewer, InputEscInACellSizeFieldCancelsTheRunningBuildWithoutRestartingIt) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedDrivenDefault, dragon, "dragon/dragon_vrip.ply");
  const std::string args = "'" + dragon + "'" + kFieldArgs;
  const auto rects = field_rects(args, "dragon_vrip.ply");
  ASSERT_TRUE(rects.is_object());
  // The full dragon at kLongDragonBuildCell (seconds to build, the build-time limit off) starts
  // after the first picture; in the units field a digit is typed and Esc pressed about 1.5 s
  // into the build.
  const ViewerResult d = drive(
      args + " --hold 60 --hybrid-max-build-seconds 0 --rebuild-cell-size " + kLongDragonBuildCell,
      "dragon_vrip.ply",
      "sleep 1\n" + click_field(rects, "units") + "\nxdotool type 5\nkey Escape\nsleep 1");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto& builds = d.stats["builds"];
  ASSERT_EQ(builds.size(), 2u) << "Esc restarted the build: " << builds.dump();
  EXPECT_EQ(builds[1].value("error", ""), "cancelled") << builds.dump();
  ASSERT_TRUE(builds[1]["cancel_seconds"].is_number()) << builds.dump();
  EXPECT_LT(builds[1]["cancel_seconds"].get<double>(), 1.0);
  EXPECT_EQ(d.stats["state"]["cell_size"], 0.0f) << "the auto size stays";
}

/// The grid of an estimate ("a 88x87x68 grid ..."): its three axes.
std::array<int, 3> estimate_dims(const std::string& estimate) {
  std::array<int, 3> d{0, 0, 0};
  std::sscanf(estimate.c_str(), "a %dx%dx%d", &d[0], &d[1], &d[2]);
  return d;
}

TEST_F(Viewer, InputATypedCellSizeShowsItsEstimateBeforeEnterAndAShortEnterBuildsIt) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedDrivenDefault, bunny, "bunny/bun_zipper.ply");
  const std::string args = "'" + bunny + "'" + kFieldArgs;
  const auto rects = field_rects(args, "bun_zipper.ply");
  ASSERT_TRUE(rects.is_object());
  const auto auto_dims = estimate_dims(rects["state"]["cell_estimate"].get<std::string>());
  ASSERT_GT(auto_dims[0], 0) << rects["state"].dump();
  // 0.5x typed, no Enter: the estimate names the finer grid and nothing is built.
  ViewerResult d =
      drive(args + " --hold 30", "bun_zipper.ply",
            click_field(rects, "x auto") + "\nxdotool type 0.5\nsleep 0.5\n" + kTimedCtrlQ);
  ASSERT_TRUE(d.ended_by_ctrl_q());
  EXPECT_EQ(d.stats["builds"].size(), 1u);
  const auto dims = estimate_dims(d.stats["state"]["cell_estimate"].get<std::string>());
  for (int a = 0; a < 3; ++a)
    EXPECT_NEAR(dims[size_t(a)], 2 * auto_dims[size_t(a)], 2) << d.stats["state"].dump();
  // 2x typed and Enter pressed and released at once (within one frame): it is built (waited
  // for in the viewer's log, up to 30 s on a loaded machine).
  d = drive(args + " --hold 30", "bun_zipper.ply",
            click_field(rects, "x auto") +
                "\nxdotool type 2\nxdotool keydown Return keyup Return\n"
                "waitlog 'rebuilt hybrid' 30");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  ASSERT_EQ(d.stats["builds"].size(), 2u) << "the short Enter was lost";
  EXPECT_NEAR(d.stats["state"]["built_cell_size"].get<double>(),
              2 * d.stats["state"]["auto_cell_size"].get<double>(), 1e-6);
}

TEST_F(Viewer, InputACancelledCellSizeIsNeitherShownNorSavedAndAChosenOneStaysWithItsScene) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedDrivenDefault, dragon, "dragon/dragon_vrip.ply");
  // Interactive runs: they read and write the remembered settings.
  const std::string args = "'" + dragon + "'" + kFieldArgs + " --hybrid-max-build-seconds 0";
  const auto rects = field_rects(args, "dragon_vrip.ply");
  ASSERT_TRUE(rects.is_object());
  // 0.02x typed and entered (about kLongDragonBuildCell: seconds to build), Esc 1 s later.
  ViewerResult d = drive(args, "dragon_vrip.ply",
                         click_field(rects, "x auto") +
                             "\nxdotool type 0.02\nxdotool key Return\nsleep 1\nkey Escape\n"
                             "sleep 0.5");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto& st = d.stats["state"];
  ASSERT_EQ(d.stats["builds"].size(), 2u) << d.stats["builds"].dump();
  EXPECT_EQ(d.stats["builds"][1].value("error", ""), "cancelled");
  EXPECT_EQ(st["cell_choice"], "auto");
  EXPECT_NEAR(st["cell_size_shown"].get<double>(), st["built_cell_size"].get<double>(), 1e-6)
      << "the panel shows the cancelled size";
  auto saved = json("kdgrid/viewer.json");
  ASSERT_TRUE(saved.is_object());
  EXPECT_EQ(saved["cell_size"], "auto") << saved.dump();
  EXPECT_FALSE(saved["cell_size_by_scene"].contains(fs::canonical(dragon).string()))
      << saved.dump();
  // 2x built (waited for: the dragon's build takes seconds under load): remembered for the
  // dragon only, not for every scene.
  d = drive(args, "dragon_vrip.ply",
            click_field(rects, "x auto") +
                "\nxdotool type 2\nxdotool key Return\nwaitlog 'rebuilt hybrid' 60");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  EXPECT_EQ(d.stats["state"]["cell_choice"], "2x");
  saved = json("kdgrid/viewer.json");
  EXPECT_EQ(saved["cell_size"], "auto") << saved.dump();
  EXPECT_EQ(saved["cell_size_by_scene"][fs::canonical(dragon).string()], "2x") << saved.dump();
}

// ---- remembered per scene, built size shown, refusal ------------------------------------------

/// An interactive run (it reads and writes the remembered settings) of `scene` with the hybrid
/// and `settings` as viewer.json; returns its statistics.
ViewerResult run_with_settings(const ViewerRun& v, const std::string& scene,
                               const nlohmann::json& settings) {
  fs::create_directories(v.path("kdgrid"));
  std::ofstream(v.path("kdgrid/viewer.json")) << settings.dump(2);
  return v.drive(
      "'" + scene + "' --accel hybrid --width 640 --height 480 --threads 2 --max-samples 1",
      fs::path(scene).filename().string(), "sleep 1");
}

TEST_F(Viewer, CellSizeInSceneUnitsIsRememberedPerSceneOnly) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb | kNeedXdotool, bunny, "bunny/bun_zipper.ply");
  const std::string dragon = shared_scene("dragon/dragon_vrip.ply").empty()
                                 ? "/elsewhere/dragon_vrip.ply"
                                 : shared_scene("dragon/dragon_vrip.ply");
  // 0.0008 remembered for the dragon, and as a bare number (an older file): the bunny builds
  // its own auto size (0.00178), and the dragon's size stays remembered for the dragon.
  ViewerResult d = run_with_settings(
      *this, bunny,
      {{"accel", "hybrid"}, {"cell_size", "0.0008"}, {"cell_size_by_scene", {{dragon, "0.0008"}}}});
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto& st = d.stats["state"];
  ASSERT_TRUE(st.contains("built_cell_size")) << st.dump();
  EXPECT_EQ(st["cell_choice"], "auto");
  EXPECT_NEAR(st["built_cell_size"].get<double>(), st["auto_cell_size"].get<double>(), 1e-9);
  EXPECT_GT(st["built_cell_size"].get<double>(), 0.0015);
  // The slider shows the built size, not 5% of the scene's radius.
  EXPECT_NEAR(st["cell_size_shown"].get<double>(), st["built_cell_size"].get<double>(), 1e-6);
  auto saved = json("kdgrid/viewer.json");
  ASSERT_TRUE(saved.is_object());
  EXPECT_EQ(saved["cell_size"], "auto");
  EXPECT_EQ(saved["cell_size_by_scene"][dragon], "0.0008");
  const double auto_cell = st["auto_cell_size"].get<double>();
  // A multiple of auto applies to any scene.
  d = run_with_settings(*this, bunny, {{"cell_size", "2x"}});
  ASSERT_TRUE(d.ended_by_ctrl_q());
  EXPECT_EQ(d.stats["state"]["cell_choice"], "2x");
  EXPECT_NEAR(d.stats["state"]["built_cell_size"].get<double>(), 2.0 * auto_cell, 1e-6);
  // A size in scene units remembered for this scene is this scene's.
  d = run_with_settings(*this, bunny,
                        {{"cell_size_by_scene", {{fs::canonical(bunny).string(), "0.004"}}}});
  ASSERT_TRUE(d.ended_by_ctrl_q());
  EXPECT_NEAR(d.stats["state"]["built_cell_size"].get<double>(), 0.004, 1e-7);
  EXPECT_NEAR(d.stats["state"]["cell_size_shown"].get<double>(), 0.004, 1e-7);
}

TEST_F(Viewer, ARememberedCellSizeTheSceneRefusesFallsBackToAutoNamingTheSettings) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  // A multiple of auto chosen on another scene, far too fine a grid for this one.
  const ViewerResult d =
      run_with_settings(*this, kDefaultScene, {{"accel", "hybrid"}, {"cell_size", "1e-30x"}});
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto& st = d.stats["state"];
  EXPECT_EQ(st["cell_choice"], "auto");
  EXPECT_NEAR(st["built_cell_size"].get<double>(), st["auto_cell_size"].get<double>(), 1e-9);
  const std::string log = d.output + d.viewer_log;
  EXPECT_NE(log.find(dir + "/kdgrid/viewer.json: the remembered cell size 1e-30x does not suit"),
            std::string::npos)
      << log;
}

TEST_F(Viewer, CellLargerThanTheSceneRendersAsTheKdTreeDoes) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb, bunny, "bunny/bun_zipper.ply");
  ImageRGB a, b;
  two_shots(bunny, "320 --height 240", "--accel hybrid --cell-size 1e9 --stats-json one.json",
            "--accel kdtree", a, b);
  if (HasFatalFailure()) return;
  const auto st = json("one.json");
  ASSERT_TRUE(st.is_object());
  EXPECT_LT(st["state"]["built_cell_size"].get<double>(), 1.0) << "one cell of the scene's size";
  EXPECT_GT(luminance_variance(a), 1e-4) << "the bunny is drawn";
  EXPECT_EQ(changed_pixels_near(a, b, a.width / 2, a.height / 2, std::max(a.width, a.height)), 0)
      << "the one-cell hybrid's image differs from the kd-tree's";
}

TEST_F(Viewer, TooSmallCellSizeIsRefusedWithASizeThatBuilds) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb, bunny, "bunny/bun_zipper.ply");
  // The build is refused at once (no 300 s build), with the estimate and a size that fits.
  const RunResult r = run("'" + bunny +
                          "' --accel hybrid --cell-size 1e-8 --width 320 --height 240 "
                          "--frames 3 --threads 2 --timeout 60 --screenshot e.png");
  EXPECT_NE(r.output.find("use a cell size of at least"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("cells"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace kdgrid::test

#endif
