// kdgrid-viewer end to end (tests/support/viewer_run.h): what it draws over the picture. The
// heat map and its raw export, the split-plane overlay at its default depths, and the split
// planes of the picked ray alone with their visit-order legend.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "viewer_checks.h"
#include "viewer_run.h"

#ifdef KDGRID_VIEWER_PATH

namespace kdgrid::test {
namespace {

TEST_F(Viewer, HeatMapExportsRawCountsAsExr) {
  KDGRID_REQUIRE_VIEWER(kNeedXvfb | kNeedSmallScene | kNeedFastAccel);
  const RunResult r = run(quoted(small_scene()) + " --accel " + fast_accel() + kSmall +
                          "--heatmap tests --export-heatmap tests.exr --screenshot shot.png");
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageRGB img = image("tests.exr");
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

TEST_F(Viewer, SplitOverlayAtItsDefaultDepthsLeavesTheModelVisible) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb, bunny, "bunny/bun_zipper.ply");
  ImageRGB a, b;
  two_shots(bunny, "480 --height 360", "--accel hybrid", "--accel hybrid --overlay splits", a, b);
  if (HasFatalFailure()) return;
  // Of the model's pixels (lit in the plain shot), most are still the model's under the
  // default split depths (0-6); with all 64 levels almost none were.
  int model = 0, kept = 0;
  for (int y = 0; y < a.height; ++y)
    for (int x = 0; x < a.width; ++x) {
      const size_t i = (size_t(y) * size_t(a.width) + size_t(x)) * 3;
      if (a.rgb[i] + a.rgb[i + 1] + a.rgb[i + 2] < 0.15f) continue;
      ++model;
      kept += changed_pixels_near(a, b, x, y, 0) == 0;
    }
  ASSERT_GT(model, 1000) << "no model in the plain shot";
  EXPECT_GT(kept, model * 6 / 10) << kept << " of " << model
                                  << " model pixels unchanged by the split overlay";
  EXPECT_LT(kept, model) << "the overlay drew nothing over the model";
}

/// Pixels that differ between a and b outside the rectangle `panel` ({x, y, w, h} of
/// --stats-json's display.panel; null = none).
int changed_outside(const ImageRGB& a, const ImageRGB& b, const nlohmann::json& panel) {
  int n = 0;
  for (int y = 0; y < a.height; ++y)
    for (int x = 0; x < a.width; ++x) {
      if (panel.is_object() && x >= panel["x"].get<float>() - 1 &&
          x <= panel["x"].get<float>() + panel["w"].get<float>() + 1 &&
          y >= panel["y"].get<float>() - 1 &&
          y <= panel["y"].get<float>() + panel["h"].get<float>() + 1)
        continue;
      n += changed_pixels_near(a, b, x, y, 0);
    }
  return n;
}

TEST_F(Viewer, SplitsOfThePickedRayDrawFarFewerPlanesWithAVisitOrderLegend) {
  KDGRID_REQUIRE_VIEWER_SCENE(kNeedXvfb, bunny, "bunny/bun_zipper.ply");
  const std::string base = "'" + bunny +
                           "' --accel kdtree --width 640 --height 360 --frames 3 --min-samples 1 "
                           "--max-samples 1 --threads 2 --timeout 120 --pick 320,180 ";
  // Without the overlay, with all split planes, with the picked ray's, and again with the
  // panels (for the legends).
  for (const char* args :
       {"--hide-ui --screenshot a.png",
        "--hide-ui --overlay splits --stats-json all.json --screenshot all.png",
        "--hide-ui --overlay splits --splits-of-pick --stats-json pick.json --screenshot pick.png",
        "--overlay splits --splits-of-pick --stats-json ui.json"}) {
    const RunResult r = run(base + args);
    ASSERT_EQ(r.code, 0) << args << "\n" << r.output;
  }
  const auto sa = json("all.json"), sp = json("pick.json"), su = json("ui.json");
  ASSERT_TRUE(sa.is_object() && sp.is_object() && su.is_object());
  const ImageRGB img_a = image("a.png");
  const int n_all = changed_outside(img_a, image("all.png"), nullptr);
  const int n_pick = changed_outside(img_a, image("pick.png"), nullptr);
  const size_t planes_all = sa["state"]["overlay"]["items"],
               planes_pick = sp["state"]["overlay"]["items"];
  EXPECT_EQ(sp["state"]["overlay"]["splits_of_pick"], true);
  EXPECT_GE(planes_pick, 1u) << "the picked ray crosses no split plane at depths 0-6";
  EXPECT_LT(planes_pick * 8, planes_all) << planes_pick << " of " << planes_all << " planes";
  EXPECT_GT(n_pick, 0) << "the crossed planes drew nothing";
  EXPECT_LT(n_pick * 4, n_all) << n_pick << " pixels for the crossed planes, " << n_all
                               << " for all";
  // The visit order's legend: first and last step numbers of the picked ray.
  const size_t steps = sp["state"]["pick"]["steps"];
  const std::string want = "visit order: step 0 .. " + std::to_string(steps - 1);
  bool found = false;
  for (const auto& l : su["ui"]["legends"]) found |= l.get<std::string>() == want;
  EXPECT_TRUE(found) << "no '" << want << "' in " << su["ui"]["legends"].dump();
  EXPECT_TRUE(sp["ui"]["legends"].empty()) << "legends recorded with the panels hidden";
}

}  // namespace
}  // namespace kdgrid::test

#endif
