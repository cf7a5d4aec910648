// A pixel's Whitted ray tree (Renderer::trace_tree): the rays are the ones the render traces,
// `kdgrid trace --origin/--dir` replays any of them step for step, and the viewer's pick shows
// the tree with each ray's replay command (--stats-json).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "cli_util.h"
#include "render/renderer.h"
#include "scene/load.h"
#include "test_util.h"
#include "util/error.h"
#include "viewer_run.h"

namespace kdgrid::test {
namespace {

namespace fs = std::filesystem;

const std::string kCornell = source_path("assets/cornell.gltf");

#define KDGRID_REQUIRE_CORNELL() \
  if (!fs::exists(kCornell)) GTEST_SKIP() << "assets/cornell.gltf is missing"

/// The pixel of a w x h image of the scene's camera nearest the middle of the mirror
/// sphere's pixels (their mean position).
std::pair<int, int> mirror_pixel(const Scene& scene, const Accelerator& accel, int w, int h) {
  const CameraFrame f = CameraFrame::make(*scene.camera, w, h);
  double sx = 0, sy = 0;
  int n = 0;
  std::vector<std::pair<int, int>> px;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      Hit hit;
      if (!accel.intersect(f.ray(float(x) + 0.5f, float(y) + 0.5f), hit)) continue;
      if (scene.materials[scene.mesh.material_of(hit.prim)].name != "mirror") continue;
      sx += x;
      sy += y;
      ++n;
      px.emplace_back(x, y);
    }
  if (n == 0) return {-1, -1};
  std::pair<int, int> best = px.front();
  double bd = 1e30;
  for (const auto& [x, y] : px) {
    const double d = (x - sx / n) * (x - sx / n) + (y - sy / n) * (y - sy / n);
    if (d < bd) {
      bd = d;
      best = {x, y};
    }
  }
  return best;
}

size_t count_kind(const RayTree& t, RayKind k) {
  size_t n = 0;
  for (const auto& node : t.nodes) n += node.kind == k;
  return n;
}

TEST(RayTree, IsTheRaysTheRenderTracesForThePixel) {
  KDGRID_REQUIRE_CORNELL();
  const Scene scene = load_scene(kCornell);
  const auto accel = build_accelerator("bvh", scene.mesh, BuildParams{});
  RenderSettings rs;
  rs.width = 48;
  rs.height = 40;
  rs.jitter = false;  // pixel centres: the pick's ray
  Renderer r(scene, *accel, rs);
  ASSERT_TRUE(r.render_pass());
  std::vector<float> rgb;
  r.resolve(rgb);
  const auto [mx, my] = mirror_pixel(scene, *accel, rs.width, rs.height);
  ASSERT_GE(mx, 0) << "no pixel sees the mirror sphere";
  const CameraFrame f = CameraFrame::make(*scene.camera, rs.width, rs.height);
  // The tree's radiance is bitwise the rendered pixel's: the same rays, shaded the same way
  // (the render traces them in packets).
  for (const auto& [x, y] : std::vector<std::pair<int, int>>{{mx, my}, {5, 5}, {24, 35}}) {
    const RayTree t = r.trace_tree(f.ray(float(x) + 0.5f, float(y) + 0.5f));
    const float* px = &rgb[(size_t(y) * size_t(rs.width) + size_t(x)) * 3];
    EXPECT_EQ(t.radiance.x, px[0]) << x << "," << y;
    EXPECT_EQ(t.radiance.y, px[1]) << x << "," << y;
    EXPECT_EQ(t.radiance.z, px[2]) << x << "," << y;
    ASSERT_FALSE(t.nodes.empty());
    EXPECT_EQ(t.nodes[0].kind, RayKind::Primary);
    for (size_t k = 1; k < t.nodes.size(); ++k) {
      ASSERT_GE(t.nodes[k].parent, 0);
      ASSERT_LT(size_t(t.nodes[k].parent), k) << "a parent is traced before its children";
    }
  }
  const RayTree t = r.trace_tree(f.ray(float(mx) + 0.5f, float(my) + 0.5f));
  EXPECT_GE(count_kind(t, RayKind::Reflection), 1u);
  EXPECT_GE(count_kind(t, RayKind::Shadow), 1u);
  for (const auto& n : t.nodes) {
    EXPECT_GT(n.trace.steps.size(), 0u) << to_string(n.kind);
    EXPECT_GT(n.seconds, 0.0) << to_string(n.kind);
    EXPECT_EQ(n.trace.counters.steps, n.trace.steps.size());
  }
  // Every ray of the tree is a ray of the render: a 1-sample render of the same pixel counts
  // the same rays by kind.
  RenderCounters c;
  (void)r.radiance(f.ray(float(mx) + 0.5f, float(my) + 0.5f), 0, c);
  EXPECT_EQ(c.shadow, count_kind(t, RayKind::Shadow));
  EXPECT_EQ(c.reflection, count_kind(t, RayKind::Reflection));
  EXPECT_EQ(c.refraction, count_kind(t, RayKind::Refraction));
}

TEST(RayTree, SecondaryRaysStartWhereTheOffsetChoiceSays) {
  KDGRID_REQUIRE_CORNELL();
  const Scene scene = load_scene(kCornell);
  const auto accel = build_accelerator("bvh", scene.mesh, BuildParams{});
  const auto [mx, my] = mirror_pixel(scene, *accel, 48, 40);
  ASSERT_GE(mx, 0) << "no pixel sees the mirror sphere";
  const Ray primary =
      CameraFrame::make(*scene.camera, 48, 40).ray(float(mx) + 0.5f, float(my) + 0.5f);
  const auto tree = [&](SecondaryOffset o) {
    RenderSettings rs;
    rs.width = rs.height = 1;
    rs.offset = o;
    return Renderer(scene, *accel, rs).trace_tree(primary, false);
  };
  const RayTree robust = tree(SecondaryOffset::Robust), eps = tree(SecondaryOffset::Epsilon),
                none = tree(SecondaryOffset::None);
  // The rays leaving the primary hit (the trees below them differ: without an offset a ray
  // may hit the surface it leaves).
  ASSERT_GE(count_kind(none, RayKind::Reflection), 1u);
  ASSERT_GE(count_kind(none, RayKind::Shadow), 1u);
  size_t compared = 0;
  for (size_t k = 1; k < std::min(none.nodes.size(), eps.nodes.size()) &&
                     none.nodes[k].parent == 0 && eps.nodes[k].parent == 0;
       ++k, ++compared) {
    const Ray &n = none.nodes[k].ray, &e = eps.nodes[k].ray;
    // No offset: the hit point itself, nothing skipped; epsilon: the same point, a fixed
    // distance skipped.
    EXPECT_EQ(n.tmin, 0.0f) << k;
    EXPECT_EQ(n.org.x, e.org.x) << k;
    EXPECT_EQ(n.org.y, e.org.y) << k;
    EXPECT_EQ(n.org.z, e.org.z) << k;
    EXPECT_NEAR(e.tmin * length(e.dir), kSecondaryEpsilon, 1e-9f) << k;
  }
  EXPECT_GE(compared, 2u);
  // The robust offset moves the point off the surface and skips nothing.
  ASSERT_GE(robust.nodes.size(), 2u);
  EXPECT_EQ(robust.nodes[1].ray.tmin, 0.0f);
  EXPECT_NE(
      robust.nodes[1].ray.org.x + 2 * robust.nodes[1].ray.org.y + 4 * robust.nodes[1].ray.org.z,
      none.nodes[1].ray.org.x + 2 * none.nodes[1].ray.org.y + 4 * none.nodes[1].ray.org.z);
  EXPECT_EQ(parse_secondary_offset("none", "--offset"), SecondaryOffset::None);
  EXPECT_THROW(parse_secondary_offset("tiny", "--offset"), ParamError);
}

/// `kdgrid trace --json` of a ray-tree ray replayed through the command line.
nlohmann::json replay(const std::string& command_tail) {
  const CliResult r = run_cli(command_tail + " --json");
  EXPECT_EQ(r.code, 0) << command_tail << "\n" << r.output;
  try {
    return nlohmann::json::parse(r.output);
  } catch (const std::exception& e) {
    ADD_FAILURE() << command_tail << ": " << e.what() << "\n" << r.output;
    return {};
  }
}

std::string exact(float v) {
  if (std::isinf(v)) return "inf";
  char b[32];
  std::snprintf(b, sizeof b, "%.9g", double(v));
  return b;
}

TEST(RayTree, TraceOriginDirReplaysASecondaryRayStepForStep) {
  KDGRID_REQUIRE_CORNELL();
  const Scene scene = load_scene(kCornell);
  for (const char* name : {"bvh", "hybrid"}) {
    const auto accel = build_accelerator(name, scene.mesh, BuildParams{});
    RenderSettings rs;
    rs.width = 48;
    rs.height = 40;
    const Renderer r(scene, *accel, rs);
    const auto [mx, my] = mirror_pixel(scene, *accel, rs.width, rs.height);
    ASSERT_GE(mx, 0);
    const RayTree t = r.trace_tree(
        CameraFrame::make(*scene.camera, rs.width, rs.height).ray(mx + 0.5f, my + 0.5f));
    int checked = 0;
    for (const auto& n : t.nodes) {
      if (n.kind == RayKind::Primary) continue;
      const auto v = [](const Vec3& p) { return exact(p.x) + "," + exact(p.y) + "," + exact(p.z); };
      const nlohmann::json j =
          replay("trace '" + kCornell + "' --accel " + name + " --origin " + v(n.ray.org) +
                 " --dir " + v(n.ray.dir) + " --tmin " + exact(n.ray.tmin) + " --tmax " +
                 exact(n.ray.tmax) + (n.kind == RayKind::Shadow ? " --any" : ""));
      if (j.is_null()) continue;
      EXPECT_EQ(j["steps"].size(), n.trace.steps.size()) << name << " " << to_string(n.kind);
      EXPECT_EQ(j["counters"]["tri_tests"].get<uint64_t>(), n.trace.counters.tri_tests);
      if (n.kind == RayKind::Shadow) {
        EXPECT_EQ(j["occluded"].get<bool>(), n.trace.occluded);
      } else {
        ASSERT_EQ(j["hit"].is_null(), !n.trace.hit.valid());
        if (n.trace.hit.valid()) {
          EXPECT_EQ(j["hit"]["prim"].get<uint32_t>(), n.trace.hit.prim);
        }
      }
      for (size_t k = 0; k < std::min<size_t>(j["steps"].size(), n.trace.steps.size()); ++k)
        EXPECT_EQ(j["steps"][k]["id"].get<uint64_t>(), n.trace.steps[k].id) << "step " << k;
      ++checked;
    }
    EXPECT_GE(checked, 2) << name;
  }
}

TEST(RayTree, TraceOriginRefusesABadRayClearly) {
  KDGRID_REQUIRE_CORNELL();
  CliResult r = run_cli("trace '" + kCornell + "' --origin 0,1,2 --dir 0,0,0");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "--dir")) << r.output;
  r = run_cli("trace '" + kCornell + "' --origin 0,1,2");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "give both")) << r.output;
  r = run_cli("trace '" + kCornell + "' --origin 0,1,2 --dir 0,0,1 --tmin 2 --tmax 1");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "tmin < tmax")) << r.output;
}

#ifdef KDGRID_VIEWER_PATH
TEST(RayTree, ViewerPickOnTheMirrorSphereReportsTheTreeAndReplaysIt) {
  KDGRID_REQUIRE_XVFB();
  KDGRID_REQUIRE_CORNELL();
  const Scene scene = load_scene(kCornell);
  const auto accel = build_accelerator("bvh", scene.mesh, BuildParams{});
  const int w = 320, h = 240;
  const auto [mx, my] = mirror_pixel(scene, *accel, w, h);
  ASSERT_GE(mx, 0);
  TempDir dir("ray_tree");
  const std::string d = dir.path().string();
  const RunResult run = run_viewer(
      d, "'" + kCornell + "' --accel bvh --width 320 --height 240 --frames 3 --min-samples 1 " +
             "--max-samples 1 --pick " + std::to_string(mx) + "," + std::to_string(my) +
             " --pick-ray 1 --stats-json stats.json --screenshot shot.png");
  ASSERT_EQ(run.code, 0) << run.output;
  std::ifstream in(d + "/stats.json");
  const nlohmann::json stats = nlohmann::json::parse(in);
  const auto& pick = stats["state"]["pick"];
  ASSERT_TRUE(pick.is_object()) << stats["state"].dump();
  EXPECT_EQ(pick["selected"], 1);
  const auto& tree = pick["tree"];
  std::map<std::string, int> kinds;
  for (const auto& n : tree) {
    ++kinds[n["kind"].get<std::string>()];
    EXPECT_GT(n["steps"].get<int>(), 0) << n.dump();
    if (n["kind"] != "shadow") {
      EXPECT_GT(n["tests"].get<int>(), 0) << n.dump();
    }
  }
  EXPECT_EQ(kinds["primary"], 1) << tree.dump();
  EXPECT_GE(kinds["reflection"], 1) << tree.dump();
  EXPECT_GE(kinds["shadow"], 1) << tree.dump();
  // The selected ray is the one the panel's command and the step count describe.
  EXPECT_EQ(pick["command"], tree[1]["command"]);
  EXPECT_EQ(pick["steps"], tree[1]["steps"]);
  // Every secondary ray's printed command replays it: the same steps and tests.
  int replayed = 0;
  for (const auto& n : tree) {
    if (n["kind"] == "primary") continue;
    std::string cmd = n["command"].get<std::string>();
    ASSERT_EQ(cmd.rfind("kdgrid trace ", 0), 0u) << cmd;
    const nlohmann::json j = replay(cmd.substr(std::string("kdgrid ").size()));
    if (j.is_null()) continue;
    EXPECT_EQ(j["steps"].size(), n["steps"].get<size_t>()) << cmd;
    EXPECT_EQ(j["counters"]["tri_tests"], n["tests"]) << cmd;
    ++replayed;
  }
  EXPECT_GE(replayed, 2);
}
#endif

}  // namespace
}  // namespace kdgrid::test
