// kdgrid-viewer end to end (tests/support/viewer_run.h): the ImGui panel. It takes the mouse
// before the camera, keeps Ctrl+Q working with a text field focused, stays inside a shrunk
// window, resizes and collapses, lists the keys (F1) and hides (H), shows each structure's own
// knobs, fits a quarter of a 1280x720 window with no label cut, and keeps the widgets below its
// status area in place.
#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <fstream>
#include <set>
#include <string>
#include <vector>

#include "viewer_checks.h"
#include "viewer_run.h"

#ifdef KDGRID_VIEWER_PATH

namespace kdgrid::test {
namespace {

TEST_F(Viewer, InputImGuiPanelTakesTheMouseFirst) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  // The panel's title bar is at y 8..27 (13 px font) from x 8 to 338. Click it, drag it by
  // (100, 40), wheel over the panel: none of that may pick or move the camera. Then a click on
  // the image must pick (so the clicks above would have, had ImGui not taken them).
  const ViewerResult d =
      drive_default("click 150 16\ndrag 1 150 16 250 56\nmv 200 150\nwheel 3 4\nclick 560 400", "");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto& st = d.stats["state"];
  const auto [a, b] = start_and_end_cameras(d.stats);
  EXPECT_EQ(a.eye, b.eye) << "input on the panel moved the camera";
  EXPECT_EQ(a.target, b.target) << "input on the panel moved the camera";
  const auto& panel = d.stats["display"]["panel"];
  ASSERT_TRUE(panel.is_object());
  EXPECT_NEAR(panel["x"].get<float>(), 108.0f, 1.0f)
      << "the drag did not reach ImGui (panel not moved)";
  EXPECT_NEAR(panel["y"].get<float>(), 48.0f, 1.0f)
      << "the drag did not reach ImGui (panel not moved)";
  ASSERT_TRUE(st["pick"].is_object()) << "the click on the image did not pick";
  EXPECT_EQ(st["pick"]["x"], 560);
  EXPECT_EQ(st["pick"]["y"], 400);
}

TEST_F(Viewer, InputCtrlQExitsWithinASecondWithATextFieldFocused) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  const std::string args = "'" + kDefaultScene + "'" + kFieldArgs;
  const auto rects = field_rects(args, "cornell.gltf");
  ASSERT_TRUE(rects.is_object());
  // An interactive run: the field has the keyboard, a digit typed into it.
  const ViewerResult d =
      drive(args, "cornell.gltf", click_field(rects, "units") + "\nxdotool type 5\n" + kTimedCtrlQ);
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const int ms = exit_ms(d.output);
  EXPECT_GE(ms, 0) << d.output;
  EXPECT_LT(ms, 1000) << "Ctrl+Q took " << ms << " ms with a text field focused";
  EXPECT_EQ(d.stats["builds"].size(), 1u) << "the typed digit was built";
}

/// The position of [Window][name] in an imgui.ini ("Pos=x,y"); {-1e9, -1e9} if absent.
std::array<int, 2> ini_pos(const std::string& path, const std::string& name) {
  std::ifstream in(path);
  std::string line;
  bool in_window = false;
  while (std::getline(in, line)) {
    if (!line.empty() && line[0] == '[') in_window = line == "[Window][" + name + "]";
    int x, y;
    if (in_window && std::sscanf(line.c_str(), "Pos=%d,%d", &x, &y) == 2) return {x, y};
  }
  return {-1000000000, -1000000000};
}

/// The default scene with the bvh in a 1280x720 window: room for the whole panel.
const std::string kWide = " --accel bvh --width 1280 --height 720 --threads 1 --max-samples 1";

TEST_F(Viewer, InputThePanelStaysInsideAWindowShrunkTo50x50AndRResetsTheLayout) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  const std::string args = "'" + kDefaultScene + "'" + kWide;
  // An interactive run (it writes imgui.ini): the panel dragged by its title bar 140 units
  // past the window's left edge, the window shrunk to 50x50 and back.
  ViewerResult d = drive(args, "cornell.gltf",
                         "drag 1 150 17 10 17\n"
                         "xdotool windowsize $wid 50 50; sleep 1\n"
                         "xdotool windowsize $wid 1280 720; sleep 1");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto& p = d.stats["display"]["panel"];
  EXPECT_GE(p["x"].get<double>(), 0.0) << p.dump();
  EXPECT_GE(p["y"].get<double>(), 0.0) << p.dump();
  const auto pos = ini_pos(path("kdgrid/imgui.ini"), "kdgrid");
  EXPECT_GE(pos[0], 0) << "imgui.ini remembers the panel outside the window";
  EXPECT_GE(pos[1], 0);
  // Dragged by its title bar to the middle, then R: back at (8, 8).
  d = drive(args, "cornell.gltf", "drag 1 150 17 650 317\nmv 900 500\nkey r");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  EXPECT_NEAR(d.stats["display"]["panel"]["x"].get<double>(), 8.0, 1.0)
      << d.stats["display"]["panel"].dump();
  EXPECT_NEAR(d.stats["display"]["panel"]["y"].get<double>(), 8.0, 1.0);
}

TEST_F(Viewer, InputPanelIsResizableAndCollapsible) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  const std::string args = "'" + kDefaultScene + "'" + kWide + " --hold 90";
  // The panel starts at (8, 8), 320 x 704: drag its bottom-right grip 120 right and 100 up.
  ViewerResult d = drive(args, "cornell.gltf", "drag 1 325 709 445 609");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto& p = d.stats["display"]["panel"];
  EXPECT_NEAR(p["w"].get<double>(), 440.0, 8.0) << p.dump();
  EXPECT_NEAR(p["h"].get<double>(), 604.0, 8.0) << p.dump();
  // The title bar's arrow collapses it to the title bar.
  d = drive(args, "cornell.gltf", "click 18 17");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  EXPECT_LT(d.stats["display"]["panel"]["h"].get<double>(), 40.0)
      << d.stats["display"]["panel"].dump();
}

TEST_F(Viewer, InputF1ListsEscAndTheRenderSectionShowsPreviewsPerSecond) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  const ViewerResult d = drive_default("mv 500 400; key F1", "");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  for (const char* k : {"Esc", "L", "R", "Ctrl+Q", "F1"})
    EXPECT_TRUE(has_item(d.stats, std::string("key ") + k)) << k << d.stats["ui"].dump();
  EXPECT_TRUE(has_item(d.stats, "previews/s")) << d.stats["ui"].dump();
}

TEST_F(Viewer, InputF1ShowsTheKeyListAndHHidesThePanels) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  ViewerResult d = drive_default("mv 500 400; key F1", "--screenshot keys.png");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  EXPECT_EQ(d.stats["state"]["keys_shown"], true);
  EXPECT_EQ(d.stats["state"]["ui_hidden"], false);
  EXPECT_FALSE(d.stats["display"]["panel"].is_null());
  d = drive_default("mv 500 400; key h", "");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  EXPECT_EQ(d.stats["state"]["ui_hidden"], true);
  EXPECT_TRUE(d.stats["display"]["panel"].is_null()) << d.stats["display"].dump();
}

TEST_F(Viewer, EachStructureShowsTheKnobsItsBuildReads) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  // The irregular grid has no cell size: a cell-size slider there would rebuild the same
  // structure. It shows its two densities; the uniform grid shows its cell size (as lambda).
  for (const char* accel : {"irregular", "grid"}) {
    SCOPED_TRACE(accel);
    const ViewerResult r = run_stats("'" + kDefaultScene + "' --accel " + accel +
                                     " --width 1280 --height 720 --frames 3 --min-samples 1 "
                                     "--max-samples 1 --timeout 120");
    ASSERT_TRUE(r.ok());
    const auto& st = r.stats;
    std::set<std::string> items;
    for (const auto& i : st["ui"]["items"]) items.insert(i.get<std::string>());
    const bool irregular = std::string(accel) == "irregular";
    EXPECT_EQ(items.count("top density"), irregular ? 1u : 0u) << st["ui"]["items"].dump();
    EXPECT_EQ(items.count("sub density"), irregular ? 1u : 0u) << st["ui"]["items"].dump();
    EXPECT_EQ(items.count("cell size"), irregular ? 0u : 1u) << st["ui"]["items"].dump();
    const std::string cut = clipped_list(st);
    EXPECT_TRUE(cut.empty()) << "cut labels or values:" << cut;
  }
}

TEST_F(Viewer, PanelCoversAQuarterOfA1280x720WindowWithNoLabelCut) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  // Every section open and populated: the hybrid's cell controls, a heat map, both overlays
  // with their depth sliders and legends, a pick.
  const std::string every_section =
      "--accel hybrid --heatmap steps --overlay splits --overlay boxes --pick 640,360";
  const ViewerResult r = run_stats("'" + kDefaultScene +
                                   "' --width 1280 --height 720 --frames 3 --min-samples 1 "
                                   "--max-samples 1 --threads 2 " +
                                   every_section + " --screenshot shot.png");
  ASSERT_TRUE(r.ok());
  const auto& st = r.stats;
  const auto& panel = st["display"]["panel"];
  ASSERT_TRUE(panel.is_object());
  const double area = panel["w"].get<double>() * panel["h"].get<double>();
  EXPECT_LE(area, 1280.0 * 720.0 / 4.0) << panel.dump();
  EXPECT_GE(panel["h"].get<double>(), 360.0) << "the panel uses the window's height";
  const std::string cut = clipped_list(st);
  EXPECT_TRUE(cut.empty()) << "cut labels:" << cut;
  // The UI thread's frame cost, whole and without the swap, summarised for every frame.
  const auto& frames = st["frames"];
  ASSERT_EQ(frames["ui_ms"].size(), frames["work_ms"].size());
  for (const char* k : {"work_ms_summary", "ui_ms_summary"}) {
    const auto& f = frames[k];
    ASSERT_EQ(f["frames"], frames["work_ms"].size()) << k;
    EXPECT_GE(f["max"].get<double>(), f["p95"].get<double>()) << k;
    EXPECT_GE(f["p95"].get<double>(), f["p50"].get<double>()) << k;
  }
  EXPECT_LE(frames["ui_ms_summary"]["max"].get<double>(),
            frames["work_ms_summary"]["max"].get<double>());
  // Each phase of the loop names its largest time and the frame it was taken in.
  for (const char* phase : {"events", "tasks", "input", "render_job", "image", "overlay",
                            "accuracy", "script", "draw", "swap"}) {
    const auto& p = frames["phases"][phase];
    ASSERT_TRUE(p.is_object()) << phase << ": " << frames["phases"].dump();
    EXPECT_GE(p["max_ms"].get<double>(), 0.0) << phase;
    EXPECT_LE(p["frame"].get<int>(), frames["count"].get<int>()) << phase;
  }
  EXPECT_GT(frames["phases"]["draw"]["max_ms"].get<double>(), 0.0) << "no frame was drawn";
}

TEST_F(Viewer, StatusAreaKeepsTheWidgetsBelowItInPlace) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedDefaultScene);
  // A rebuild (progress bar), then a dropped file that fails to load (an error message).
  const ViewerResult r = run_stats("'" + kDefaultScene +
                                   "' --accel bvh --width 1280 --height 720 --frames 3 "
                                   "--max-samples 1 --rebuild-cell-size 0.5 --drop '" +
                                   write_bad_ply() + "' --screenshot shot.png");
  EXPECT_EQ(r.code, 1) << "the failed load is the scripted run's error\n" << r.output;
  const auto& st = r.stats;
  ASSERT_TRUE(st.is_object()) << r.output;
  const auto& by_state = st["ui"]["below_status_y_by_state"];
  std::vector<double> ys;
  for (const char* state : {"idle", "build", "error"}) {
    ASSERT_TRUE(by_state.contains(state))
        << "no frame drawn in state " << state << ": " << by_state.dump();
    for (const auto& y : by_state[state]) ys.push_back(y.get<double>());
  }
  ASSERT_FALSE(ys.empty());
  for (double y : ys)
    EXPECT_EQ(y, ys.front()) << "the widgets under the status area moved: " << by_state.dump();
  // Without a pick, and with the error shown: no label cut either.
  const std::string cut = clipped_list(st);
  EXPECT_TRUE(cut.empty()) << "cut labels:" << cut;
}

}  // namespace
}  // namespace kdgrid::test

#endif
