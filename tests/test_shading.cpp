// Shading without scene light (RenderSettings::shading): the eye light and the normals, and
// the lit-hit counts that tell whether the scene's lights reach the view.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "accel/accelerator.h"
#include "closed_room.h"
#include "render/renderer.h"
#include "scene/load.h"
#include "temp_dir.h"
#include "util/error.h"

namespace kdgrid::test {
namespace {

/// The closed room of closed_room.h, loaded.
Scene closed_room(const TempDir& dir) {
  return load_scene(write_closed_room((dir / "room.obj").string()));
}

struct Rendered {
  std::vector<float> rgb;
  RenderCounters counters;
};

Rendered render_room(const Scene& scene, Shading shading) {
  const auto accel = build_accelerator("bvh", scene.mesh, {});
  RenderSettings rs;
  rs.width = 32;
  rs.height = 24;
  rs.jitter = false;
  rs.shading = shading;
  Renderer r(scene, *accel, rs);
  Camera cam;
  cam.eye = {3, 3, 8};
  cam.target = {0, 2, 0};
  cam.fov_deg = 70;
  r.set_camera(cam);
  EXPECT_TRUE(r.render_pass());
  Rendered out;
  r.resolve(out.rgb);
  out.counters = r.counters();
  return out;
}

/// Distinct values of the red channel, rounded to 1e-3.
size_t distinct_reds(const std::vector<float>& rgb) {
  std::vector<int> v;
  for (size_t i = 0; i < rgb.size(); i += 3) v.push_back(int(rgb[i] * 1000.0f + 0.5f));
  std::sort(v.begin(), v.end());
  return size_t(std::unique(v.begin(), v.end()) - v.begin());
}

TEST(Shading, TheLightsOfAClosedRoomLitFromOutsideReachNoneOfItsHits) {
  const TempDir dir("kdgrid_shading_lights");
  const Scene scene = closed_room(dir);
  const Rendered lights = render_room(scene, Shading::Lights);
  EXPECT_EQ(lights.counters.probed, 32u * 24u) << "every primary hit is checked";
  EXPECT_EQ(lights.counters.lit, 0u);
  // Ambient light alone: one grey over the whole picture.
  EXPECT_EQ(distinct_reds(lights.rgb), 1u);
}

TEST(Shading, TheEyeLightShowsAClosedRoomWithoutSceneLight) {
  const TempDir dir("kdgrid_shading_eye");
  const Scene scene = closed_room(dir);
  const Rendered eye = render_room(scene, Shading::EyeLight);
  EXPECT_GT(distinct_reds(eye.rgb), 20u) << "the walls' brightness follows the view angle";
  // One pixel in kLitProbeStride^2 asks whether a scene light reaches it.
  EXPECT_EQ(eye.counters.probed, (32u / kLitProbeStride) * (24u / kLitProbeStride));
  EXPECT_EQ(eye.counters.lit, 0u);
  EXPECT_LE(eye.counters.shadow, eye.counters.probed) << "at most one shadow ray per probe";
}

TEST(Shading, NormalsShowTheNormalAsAColour) {
  const TempDir dir("kdgrid_shading_normals");
  const Scene scene = closed_room(dir);
  const Rendered n = render_room(scene, Shading::Normals);
  EXPECT_EQ(n.counters.lit, 0u);
  // Every value is (n + 1) / 2 of an axis-aligned face: 0, 0.5 or 1 per channel.
  for (float v : n.rgb)
    EXPECT_TRUE(v == 0.0f || v == 0.5f || v == 1.0f || v == scene.background.x) << v;
  EXPECT_GT(distinct_reds(n.rgb), 1u);
}

TEST(Shading, ParseNamesTheOptionAndTheChoices) {
  EXPECT_EQ(parse_shading("eye", "--shading"), Shading::EyeLight);
  EXPECT_EQ(std::string(to_string(parse_shading("normals", "--shading"))), "normals");
  try {
    parse_shading("headlamp", "--shading");
    FAIL() << "accepted";
  } catch (const ParamError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("--shading 'headlamp'"), std::string::npos) << m;
    EXPECT_NE(m.find("lights"), std::string::npos) << m;
  }
}

}  // namespace
}  // namespace kdgrid::test
