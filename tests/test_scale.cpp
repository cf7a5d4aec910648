// Scale invariance of the whole pipeline: a scene scaled by 10^k inside the range of
// docs/LIMITS.md renders the picture it renders at scale 1; outside it, it is refused.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <string>

#include "accel/accelerator.h"
#include "bench/sweep.h"
#include "image/image_io.h"
#include "math/ray.h"
#include "render/camera.h"
#include "render/renderer.h"
#include "scene/load.h"
#include "support/cli_util.h"
#include "support/temp_dir.h"
#include "support/test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

// The offset's constants are relative to the triangle's magnitude: scaling the point and the
// triangle by a power of two scales the offset point by it exactly, down to 2^-100 and up
// to 2^80 (beyond, the fixed offset of the smallest scales is a denormal). With absolute
// constants a triangle of size 2^-40 was moved by 2^-16.
TEST(Scale, RayOffsetIsScaleInvariant) {
  const std::array<Vec3, 3> tri = {Vec3(0.3f, -0.2f, 0.01f), Vec3(1.1f, 0.4f, -0.02f),
                                   Vec3(-0.5f, 0.9f, 0.7f)};
  const Vec3 n = cross(tri[1] - tri[0], tri[2] - tri[0]);
  const Vec3 p = tri[0] * 0.2f + tri[1] * 0.5f + tri[2] * 0.3f;
  const Vec3 q = offset_ray_origin(p, n, tri);
  EXPECT_NE(q, p);
  for (int k = -80; k <= 80; k += 5) {
    const float s = std::ldexp(1.0f, k);
    const Vec3 qs = offset_ray_origin(p * s, n, {tri[0] * s, tri[1] * s, tri[2] * s});
    EXPECT_EQ(qs, q * s) << "scale 2^" << k;
  }
}

// Lengths and directions of vectors whose squared length leaves float's normal range.
TEST(Scale, LengthAndNormalizeDoNotUnderflowOrOverflow) {
  for (const float s : {1e-30f, 1e-22f, 1e-19f, 1.0f, 1e19f, 1e30f}) {
    const Vec3 v(3 * s, 0, -4 * s);
    EXPECT_FLOAT_EQ(length(v), 5 * s) << s;
    const Vec3 u = normalize(v);
    EXPECT_FLOAT_EQ(u.x, 0.6f) << s;
    EXPECT_FLOAT_EQ(u.z, -0.8f) << s;
  }
  EXPECT_EQ(normalize(Vec3(0.0f)), Vec3(0.0f));
}

// An eye and a target 1e-31 apart are two points, not "the same point".
TEST(Scale, CameraAcceptsATinyButNonZeroViewDistance) {
  Camera c;
  c.eye = Vec3(0, 0, 1e-31f);
  c.target = Vec3(0.0f);
  EXPECT_NO_THROW(check_camera(c, "test"));
  const CameraFrame f = CameraFrame::make(c, 4, 4);
  EXPECT_FLOAT_EQ(f.fwd.z, -1.0f);
}

std::string cornell() {
  return test::source_path("assets/cornell.gltf");
}

// The Cornell box (glass, mirror, point light) at 10^k for every k whose scene size is
// accepted renders its scale-1 picture with bvh and hybrid.
TEST(Scale, CornellRendersTheSamePictureAtEveryAcceptedScale) {
  const int w = 32, h = 32, spp = 1;
  for (const std::string accel : {"bvh", "hybrid"}) {
    const ScaledRender ref = render_scaled(load_scene(cornell()), accel, w, h, spp, {});
    // The box is 2 units across: 1e-9 (kMinSceneSize) up to 1e17 / 2 (kMaxSceneCoordinate).
    for (int k = -9; k <= 16; ++k) {
      if (k == 0) continue;
      const Scene scene = load_scene(cornell(), std::pow(10.0, k));
      const ScaledRender r = render_scaled(scene, accel, w, h, spp, {});
      const ImageDifference d = srgb8_difference(ref.srgb8, r.srgb8);
      EXPECT_LT(d.pixels_differing, 0.01) << accel << " at 1e" << k;
      EXPECT_LT(d.mean_abs, 1.0 / 255) << accel << " at 1e" << k;
    }
  }
}

TEST(Scale, ScenesOutsideTheRangeAreRefusedNamingTheSizeAndTheFix) {
  const std::string small = test::load_error([] { load_scene(cornell(), 1e-10); });
  EXPECT_NE(small.find("below the supported minimum 1e-09"), std::string::npos) << small;
  EXPECT_NE(small.find("by a factor of 10 or more"), std::string::npos) << small;
  const std::string large = test::load_error([] { load_scene(cornell(), 1e17); });
  EXPECT_NE(large.find("outside the supported range"), std::string::npos) << large;
}

TEST(Scale, CliRefusesATooSmallScaleWithExit1) {
  test::TempDir tmp;
  const std::string out = tmp.file("c.png");
  const std::string base = "render \"" + cornell() + "\" --res 8 --spp 1 -o \"" + out + "\"";
  const test::CliResult small = test::run_cli(base + " --scale 1e-12");
  EXPECT_EQ(small.code, 1) << small.output;
  EXPECT_NE(small.output.find("below the supported minimum"), std::string::npos) << small.output;
}

TEST(Scale, ScaleFactorsOutsideFloatsRangeAreRefused) {
  for (const double bad : {1e-40, 0.0, -2.0, std::nan(""), 1e39}) {
    Scene s;
    try {
      s.scale_by(bad, "--scale");
      ADD_FAILURE() << bad << " accepted";
    } catch (const ParamError& e) {
      EXPECT_NE(std::string(e.what()).find("--scale"), std::string::npos) << e.what();
    }
  }
}

// The benchmark's scale sweep: a refused row outside the range, a measured one inside.
TEST(Scale, SweepReportsRefusalsAndImageDifferences) {
  SweepOptions o;
  o.kind = "scale";
  o.scene = cornell();
  o.values = {1e-12, 1e3};
  o.accels = {"bvh"};
  o.width = o.height = 16;
  o.reps = 1;
  const SweepTable t = run_sweep(o);
  ASSERT_EQ(t.rows.size(), 2u);
  auto cell = [&](size_t row, const std::string& col) {
    const auto it = std::find(t.columns.begin(), t.columns.end(), col);
    return it == t.columns.end() ? SweepValue{} : t.rows[row][size_t(it - t.columns.begin())];
  };
  EXPECT_EQ(std::get<std::string>(cell(0, "status")), "refused");
  EXPECT_EQ(std::get<std::string>(cell(1, "status")), "rendered");
  EXPECT_LT(std::get<double>(cell(1, "pixels_differing")), 0.01);
  EXPECT_GT(std::get<double>(cell(1, "hit_fraction")), 0.5);
}

}  // namespace
}  // namespace kdgrid
