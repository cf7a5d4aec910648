// kdgrid-viewer's box overlay of a structure with more boxes than the overlay's cap: the lines
// go up to the GPU and into the overlay's picture a bounded part per frame until all are
// there, and the panel says how many boxes are drawn of how many there are. Runs the real
// binary under Xvfb (tests/support/viewer_run.h) and reads its --stats-json.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "image/image_io.h"
#include "test_util.h"
#include "viewer_run.h"

#ifdef KDGRID_VIEWER_PATH

namespace kdgrid::test {
namespace {

TEST_F(Viewer, BoxOverlayGoesUpAndIsDrawnABoundedPartPerFrameAndSaysHowManyBoxes) {
  KDGRID_REQUIRE_XVFB();
  KDGRID_REQUIRE_SCENE(bunny, "bunny/bun_zipper.ply");
  const auto names = accelerator_names();
  if (std::find(names.begin(), names.end(), "bvh") == names.end())
    GTEST_SKIP() << "the BVH is not built into this binary";
  // The bunny's BVH has about 35k boxes, more than the 250k-line cap allows (20,833 boxes).
  const RunResult r =
      run("'" + bunny +
          "' --accel bvh --overlay boxes --width 320 --height 240 --frames 2 "
          "--min-samples 1 --max-samples 1 --stats-json stats.json --screenshot shot.png");
  ASSERT_EQ(r.code, 0) << r.output;
  const nlohmann::json s = json("stats.json");
  const nlohmann::json& o = s["state"]["overlay"];
  const size_t items = o["items"], wanted = o["wanted"], lines = o["lines"];
  const size_t upload_limit = o["upload_limit"], draw_limit = o["draw_limit"];
  EXPECT_LT(items, wanted) << "the cap should leave some of the bunny's boxes out";
  EXPECT_EQ(lines, 12 * items);
  // More than one frame's worth: the bounds below are what is tested.
  ASSERT_GT(2 * lines, upload_limit);
  ASSERT_GT(lines, draw_limit);

  // Every box arrived, a bounded part per frame, and all of it is in the picture shown.
  EXPECT_EQ(size_t(o["vertices_uploaded"]), 2 * lines);
  EXPECT_LE(size_t(o["max_vertices_uploaded_per_frame"]), upload_limit);
  EXPECT_GE(size_t(o["upload_frames"]), (2 * lines + upload_limit - 1) / upload_limit);
  EXPECT_LE(size_t(o["max_lines_drawn_per_frame"]), draw_limit);
  EXPECT_GE(size_t(o["draw_frames"]), (lines + draw_limit - 1) / draw_limit);
  EXPECT_EQ(o["complete"], true);

  // The panel says that the cap left boxes out (and how many it drew).
  const auto& ui = s["ui"]["items"];
  EXPECT_NE(std::find(ui.begin(), ui.end(), "capped"), ui.end()) << ui.dump();

  // The picture is shown: the overlay's saturated colours cover the model, right of the panel.
  const ImageRGB img = image("shot.png");
  int coloured = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = img.width * 6 / 10; x < img.width; ++x) {
      const float* p = &img.rgb[(size_t(y) * size_t(img.width) + size_t(x)) * 3];
      coloured += std::max({p[0], p[1], p[2]}) - std::min({p[0], p[1], p[2]}) > 0.4f;
    }
  EXPECT_GT(coloured, 100) << "no box lines in the screenshot";
}

}  // namespace
}  // namespace kdgrid::test

#endif
