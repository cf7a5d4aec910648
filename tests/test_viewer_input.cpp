// kdgrid-viewer end to end (tests/support/viewer_run.h): the camera's mouse and keyboard
// input, driven through the real window by xdotool (XTEST events through the X server, as a
// user's mouse and keyboard) on a display of its own; the camera, mode, speed and pick the
// viewer ends with come back through its --stats-json. And a content scale of 2 (HiDPI).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>

#include "scene/load.h"
#include "viewer_checks.h"
#include "viewer_run.h"

#ifdef KDGRID_VIEWER_PATH

namespace kdgrid::test {
namespace {

namespace fs = std::filesystem;

/// The angle between the parts of `a` and `b` normal to `up`.
float angle_about(const Vec3& up, const Vec3& a, const Vec3& b) {
  const Vec3 pa = a - up * dot(a, up), pb = b - up * dot(b, up);
  return std::acos(std::clamp(dot(normalize(pa), normalize(pb)), -1.0f, 1.0f));
}

TEST_F(Viewer, InputFlyModeWMovesForwardAlongTheViewDirection) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  const ViewerResult d = drive_default("mv 480 240\nkey Tab\nholdkey w 0.6");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto& st = d.stats["state"];
  EXPECT_EQ(st["camera_mode"], "fly") << "Tab did not switch orbit to fly";
  const auto [a, b] = start_and_end_cameras(d.stats);
  const Vec3 view = normalize(a.target - a.eye);
  const Vec3 moved = b.eye - a.eye;
  ASSERT_GT(length(moved), 1e-4f * length(a.target - a.eye)) << "W did not move the camera";
  // Along the view direction, forwards; the target travels with the eye (fly, not dolly).
  EXPECT_GT(dot(normalize(moved), view), 0.9999f);
  EXPECT_LT(length((b.target - a.target) - moved), 1e-4f * length(moved));
  EXPECT_NEAR(dot(normalize(b.target - b.eye), view), 1.0f, 1e-5f) << "W turned the view";
}

TEST_F(Viewer, InputLeftDragOrbitsAboutTheTargetKeepingTheDistance) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  // 80 units to the right: the eye turns 80 * 0.005 = 0.4 rad about the up axis.
  const ViewerResult d = drive_default("drag 1 420 240 500 240");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto& st = d.stats["state"];
  EXPECT_EQ(st["camera_mode"], "orbit");
  EXPECT_TRUE(st["pick"].is_null()) << "a drag was taken for a click (pick)";
  const auto [a, b] = start_and_end_cameras(d.stats);
  EXPECT_LT(length(b.target - a.target), 1e-6f * length(a.target - a.eye) + 1e-6f)
      << "the target moved";
  const float da = length(a.eye - a.target), db = length(b.eye - b.target);
  EXPECT_NEAR(db / da, 1.0f, 1e-4f) << "orbit changed the distance";
  // The angle between the start and end offsets, both projected on the plane normal to up.
  const Vec3 up = normalize(a.up);
  EXPECT_NEAR(angle_about(up, a.eye - a.target, b.eye - b.target), 0.4f, 0.02f);
  // A horizontal drag does not change the elevation.
  EXPECT_NEAR(dot(normalize(a.eye - a.target), up), dot(normalize(b.eye - b.target), up), 1e-4f);
}

TEST_F(Viewer, InputRightDragLooksAroundFromTheEye) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  const ViewerResult d = drive_default("key Tab\ndrag 3 420 240 480 240");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto [a, b] = start_and_end_cameras(d.stats);
  EXPECT_EQ(a.eye, b.eye) << "looking around moved the eye";
  // 60 units to the right turn the view 60 * 0.005 = 0.3 rad about the up axis.
  const Vec3 up = normalize(a.up);
  EXPECT_NEAR(angle_about(up, a.target - a.eye, b.target - b.eye), 0.3f, 0.02f);
  EXPECT_NEAR(length(b.target - b.eye), length(a.target - a.eye), 1e-4f * length(a.target - a.eye));
}

TEST_F(Viewer, InputWheelDolliesTowardsTheTarget) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  // Three notches in, one out: 0.9^3 / 0.9 of the distance.
  const ViewerResult d = drive_default("mv 480 240\nwheel 3 4\nwheel 1 5");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto [a, b] = start_and_end_cameras(d.stats);
  EXPECT_EQ(a.target, b.target);
  EXPECT_NEAR(length(b.eye - b.target) / length(a.eye - a.target), 0.81f, 1e-4f);
  EXPECT_NEAR(dot(normalize(a.target - a.eye), normalize(b.target - b.eye)), 1.0f, 1e-6f);
}

TEST_F(Viewer, InputSpeedKeysAndHomeFramesTheScene) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  const ViewerResult d = drive_default(
      "mv 480 240\nkey plus plus minus equal\nwheel 2 4\ndrag 1 420 240 480 200\nkey Home");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const auto& st = d.stats["state"];
  // + + - = : 1.25^3 / 1.25 (= is + without shift).
  EXPECT_NEAR(st["speed_scale"].get<float>(), 1.5625f, 1e-5f);
  // Home: the canonical framing of the scene's bounds (docs/RAYSETS.md), with the fov kept.
  const Scene scene = load_scene(kDefaultScene);
  const auto [start, end] = start_and_end_cameras(d.stats);
  const Camera want = canonical_camera(scene.mesh.bounds(), start.fov_deg);
  const float r = length(scene.mesh.bounds().extent());
  EXPECT_LT(length(end.eye - want.eye), 1e-5f * r);
  EXPECT_LT(length(end.target - want.target), 1e-5f * r);
  EXPECT_GT(length(start.eye - want.eye), 1e-3f * r)
      << "the scene's own camera is already the framing: "
         "this test cannot tell Home did anything";
}

TEST_F(Viewer, InputCPrintsTheCameraAsFlagsThatRenderReproduces) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault);
  const ViewerResult d = drive_default("drag 1 420 240 470 270\nwheel 2 4\nkey c",
                                       "--hide-ui --screenshot viewer.png");
  ASSERT_TRUE(d.ended_by_ctrl_q());
  const std::string flags = d.stats["state"]["camera_flags"];
  const size_t at = d.viewer_log.find("--eye ");
  ASSERT_NE(at, std::string::npos) << "C printed nothing\n" << d.viewer_log;
  const std::string printed = d.viewer_log.substr(at, d.viewer_log.find('\n', at) - at);
  EXPECT_EQ(printed, flags) << "C printed a different camera from the one the viewer ended with";
  const auto [start, end] = start_and_end_cameras(d.stats);
  EXPECT_NE(start.eye, end.eye) << "the camera did not move";

  // The same view through `kdgrid render`: the viewer shows one jittered sample per pixel of the
  // same renderer, seed and size, so the images agree up to 8-bit rounding.
  const std::string render = quoted(KDGRID_CLI_PATH) + " render '" + kDefaultScene +
                             "' --accel bvh --res 640x480 --spp 1 --threads 1 ";
  const RunResult r = run_command(render + printed + " -o '" + path("render.png") + "'");
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageRGB viewer = image("viewer.png"), cli = image("render.png");
  ASSERT_EQ(viewer.width, cli.width);
  ASSERT_EQ(viewer.height, cli.height);
  const double same = rmse(viewer, cli);
  // And the comparison can fail: the start camera gives a clearly different picture.
  char start_flags[256];
  std::snprintf(start_flags, sizeof start_flags,
                "--eye %.9g,%.9g,%.9g --target %.9g,%.9g,%.9g --fov %.9g", start.eye.x, start.eye.y,
                start.eye.z, start.target.x, start.target.y, start.target.z, start.fov_deg);
  const RunResult r0 = run_command(render + start_flags + " -o '" + path("start.png") + "'");
  ASSERT_EQ(r0.code, 0) << r0.output;
  const double other = rmse(viewer, image("start.png"));
  EXPECT_LT(same, 0.01) << "kdgrid render with the printed flags does not reproduce the view";
  EXPECT_GT(other, 10 * same + 0.01);
  // In fact byte for byte: the viewer's table-driven sRGB encoder (image_view.h) must give
  // exactly the bytes of tonemap_srgb8, which the PNG writer uses.
  EXPECT_EQ(same, 0.0)
      << "the viewer shows other bytes than kdgrid render writes for the same samples";
}

// ---- HiDPI ----------------------------------------------------------------------------------

/// Makes GLFW report a content scale of 2 on this virtual display (Xft.dpi 192 = 2 x 96).
const std::string kHiDpiSetup =
    "echo 'Xft.dpi: 192' | xrdb -nocpp -merge || echo 'driver: xrdb failed'";

TEST_F(Viewer, HiDpiContentScaleScalesTheUiAndPicksTheRightPixel) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault | kNeedXrdb);
  // 400x300 screen units at scale 2: an 800x600 window; half resolution renders 400x300, so
  // a click at window (700, 500) is image pixel (350, 250).
  const std::string args = "'" + kDefaultScene +
                           "' --accel bvh --width 400 --height 300 --threads 1 "
                           "--max-samples 1 --hold 90 --resolution-scale 0.5 --screenshot shot.png";
  const ViewerResult hi = drive(args, "cornell.gltf", "click 700 500", kHiDpiSetup);
  ASSERT_TRUE(hi.ended_by_ctrl_q());
  const auto& disp = hi.stats["display"];
  EXPECT_EQ(disp["content_scale"][0], 2.0f) << "GLFW did not pick up Xft.dpi 192";
  EXPECT_EQ(disp["ui_scale"], 2.0f);
  EXPECT_EQ(disp["font_size"], 26.0f);
  EXPECT_EQ(disp["window"][0], 800);
  EXPECT_EQ(disp["framebuffer"][0], 800);
  EXPECT_EQ(disp["framebuffer"][1], 600);
  EXPECT_EQ(disp["image"][0], 400);
  EXPECT_EQ(disp["image"][1], 300);
  const ImageRGB shot = image("shot.png");
  EXPECT_EQ(shot.width, 800) << "the screenshot is not the framebuffer";
  ASSERT_TRUE(hi.stats["state"]["pick"].is_object()) << hi.viewer_log;
  EXPECT_EQ(hi.stats["state"]["pick"]["x"], 350);
  EXPECT_EQ(hi.stats["state"]["pick"]["y"], 250);

  // The same run at 96 dpi: the panel is half as wide.
  const std::string dir1 = path("dpi96");
  fs::create_directories(dir1);
  const ViewerResult lo = drive(args, "cornell.gltf", "click 350 250", "", "1600x1200", dir1);
  ASSERT_TRUE(lo.ended_by_ctrl_q());
  EXPECT_EQ(lo.stats["display"]["content_scale"][0], 1.0f);
  EXPECT_EQ(lo.stats["display"]["window"][0], 400);
  EXPECT_NEAR(disp["panel"]["w"].get<float>() / lo.stats["display"]["panel"]["w"].get<float>(),
              2.0f, 0.02f);
  EXPECT_EQ(lo.stats["state"]["pick"]["x"], 175);
}

TEST_F(Viewer, HiDpiRemembersTheWindowSizeInScreenUnits) {
  KDGRID_REQUIRE_VIEWER(kNeedDrivenDefault | kNeedXrdb);
  // An interactive run (no --hold): it remembers its window size when closed. At scale 2 the
  // 400x300 window is 800x600 pixels; remembering 800 would double it at every start.
  const ViewerResult d = drive("'" + kDefaultScene +
                                   "' --accel bvh --width 400 --height 300 --threads 1 "
                                   "--max-samples 1",
                               "cornell.gltf", "mv 300 200", kHiDpiSetup);
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(d.stats["display"]["window"][0], 800);
  const auto settings = json("kdgrid/viewer.json");
  ASSERT_TRUE(settings.is_object()) << "no remembered settings in " << dir << "/kdgrid";
  EXPECT_EQ(settings["window_width"], 400);
  EXPECT_EQ(settings["window_height"], 300);
}

}  // namespace
}  // namespace kdgrid::test

#endif
