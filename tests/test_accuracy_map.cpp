// The accuracy map's judge (AccuracyReference, bench/check.h): with the Möller-Trumbore test
// a closed mesh leaks through shared edges and vertices, as `kdgrid sweep triangle` counts,
// and with the watertight test it does not; and the viewer's accuracy map over a closed mesh.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <tuple>

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "bench/check.h"
#include "bench/sweep.h"
#include "render/camera.h"
#include "scene/procedural.h"
#include "temp_dir.h"
#include "test_util.h"
#include "viewer_run.h"

namespace kdgrid::test {
namespace {

namespace fs = std::filesystem;

struct Tally {
  size_t misses = 0;
  size_t by[4] = {};
};

Tally judge_edge_rays(const Mesh& mesh, TriangleTestKind test) {
  BuildParams p;
  p.triangle_test = test;
  const auto accel = build_accelerator("bvh", mesh, p);
  const AccuracyReference ref(mesh);
  Tally t;
  // The rays `sweep triangle` aims at shared edges and vertices, from outside, ending just
  // past them: a miss is a leak there.
  for (const Ray& r : edge_vertex_rays(mesh, 2, 7)) {
    Hit h;
    const bool hit = accel->intersect(r, h);
    t.misses += !hit;
    ++t.by[size_t(ref.judge_closest(r, hit, h))];
  }
  return t;
}

TEST(AccuracyMap, JudgeFindsExactlyTheLeaksSweepTriangleCounts) {
  for (const Mesh& mesh : {make_icosphere(3), make_torus(48, 24)}) {
    const Tally m = judge_edge_rays(mesh, TriangleTestKind::Moller);
    EXPECT_GT(m.misses, 0u) << "Möller-Trumbore leaks nowhere on these rays";
    EXPECT_EQ(m.by[size_t(AccuracyVerdict::Leak)], m.misses);
    EXPECT_EQ(m.by[size_t(AccuracyVerdict::Disagree)], 0u);
    const Tally w = judge_edge_rays(mesh, TriangleTestKind::Watertight);
    EXPECT_EQ(w.misses, 0u);
    EXPECT_EQ(w.by[size_t(AccuracyVerdict::Leak)], 0u);
    EXPECT_EQ(w.by[size_t(AccuracyVerdict::Disagree)], 0u);
  }
}

/// A closed cube [-1,1]^3 whose faces are fans of 8 triangles around their centres (edges to
/// the corners and to the edge midpoints), outward facing. Seen head on from the +z axis, the
/// pixels on the image's centre lines and diagonals look along those edges.
Mesh fan_cube() {
  Mesh m;
  std::map<std::tuple<int, int, int>, uint32_t> index;
  const auto vid = [&](int x, int y, int z) {
    const auto k = std::make_tuple(x, y, z);
    auto it = index.find(k);
    if (it != index.end()) return it->second;
    m.positions.push_back(Vec3(float(x), float(y), float(z)));
    return index[k] = uint32_t(m.positions.size() - 1);
  };
  // The ring of corners and midpoints, counter-clockwise about +axis in (u, v).
  const int ring[8][2] = {{1, 0}, {1, 1}, {0, 1}, {-1, 1}, {-1, 0}, {-1, -1}, {0, -1}, {1, -1}};
  for (int axis = 0; axis < 3; ++axis)
    for (int sign : {-1, 1}) {
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      const auto point = [&](int a, int b) {
        int p[3];
        p[axis] = sign;
        p[u] = a;
        p[v] = b;
        return vid(p[0], p[1], p[2]);
      };
      const uint32_t c = point(0, 0);
      for (int k = 0; k < 8; ++k) {
        uint32_t a = point(ring[k][0], ring[k][1]);
        uint32_t b = point(ring[(k + 1) % 8][0], ring[(k + 1) % 8][1]);
        if (sign < 0) std::swap(a, b);
        m.triangles.push_back({c, a, b});
      }
    }
  return m;
}

/// `p` turned 0.05 radians about +y (cosine and sine as 9-digit float literals, so every
/// platform gets the same floats).
[[maybe_unused]] Vec3 turn_y(const Vec3& p) {  // unused in builds without the viewer
  const float c = 0.99875026f, s = 0.0499791693f;
  return Vec3(c * p.x + s * p.z, p.y, -s * p.x + c * p.z);
}

TEST(AccuracyMap, OnlyACrossingOfAClosedSurfaceIsALeak) {
  const Mesh cube = fan_cube();
  const AccuracyReference closed(cube);
  const Hit none;
  const Vec3 down(0, 0, -1);
  // The verdict on a closest-hit query straight down from `org` that missed.
  const auto missed_down = [&](const AccuracyReference& ref, const Vec3& org) {
    return ref.judge_closest(Ray{org, 0, down, kInf}, false, none);
  };
  // Through a diagonal edge and through the centre vertex of the top face: a miss leaked, and
  // so did an any-hit query that answers "not occluded".
  EXPECT_EQ(missed_down(closed, {0.5f, 0.5f, 3}), AccuracyVerdict::Leak);
  EXPECT_EQ(missed_down(closed, {0.0f, 0.0f, 3}), AccuracyVerdict::Leak);
  EXPECT_EQ(closed.judge_occluded(Ray{{0.5f, 0.5f, 3}, 0, down, kInf}, false),
            AccuracyVerdict::Leak);
  // A hit on the far side instead of the top face: beyond the crossing, a leak as well.
  Hit far;
  far.t = 4.0f;
  far.prim = 0;
  far.u = far.v = 0.25f;
  EXPECT_EQ(closed.judge_closest(Ray{{0.5f, 0.5f, 3}, 0, down, kInf}, true, far),
            AccuracyVerdict::Leak);
  // A ray touching the cube's top-right edge from outside (a silhouette) may miss.
  EXPECT_EQ(closed.judge_closest(Ray{{0.0f, 0.3f, 2}, 0, {1, 0, -1}, kInf}, false, none),
            AccuracyVerdict::Ambiguous);
  // An open quad: a miss at its outer edge or corner is no leak, the interior is a plain miss.
  Mesh quad;
  quad.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  quad.triangles = {{0, 1, 2}, {0, 2, 3}};
  const AccuracyReference open(quad);
  EXPECT_EQ(missed_down(open, {1.0f, 0.5f, 1}), AccuracyVerdict::Ambiguous);
  EXPECT_EQ(missed_down(open, {1.0f, 1.0f, 1}), AccuracyVerdict::Ambiguous);
  EXPECT_EQ(missed_down(open, {0.25f, 0.5f, 1}), AccuracyVerdict::Disagree);
  EXPECT_EQ(open.judge_occluded(Ray{{0.25f, 0.5f, 1}, 0, down, kInf}, false),
            AccuracyVerdict::Disagree);
}

#ifdef KDGRID_VIEWER_PATH
/// fan_cube() turned 0.05 radians about +y, written with every float exact (9 digits).
Mesh turned_fan_cube() {
  Mesh m = fan_cube();
  for (Vec3& p : m.positions) p = turn_y(p);
  return m;
}

void write_obj(const Mesh& m, const std::string& path) {
  std::ofstream out(path);
  out.precision(9);
  for (const Vec3& p : m.positions) out << "v " << p.x << " " << p.y << " " << p.z << "\n";
  for (const auto& t : m.triangles)
    out << "f " << t[0] + 1 << " " << t[1] + 1 << " " << t[2] + 1 << "\n";
}

/// The accuracy map of a 129 x 129 view of the turned fan cube, seen head on along its turned
/// +z axis, as --stats-json reports it.
nlohmann::json viewer_accuracy(const std::string& d, const std::string& flags) {
  const Vec3 eye = turn_y(Vec3(0, 0, 4));
  char cam[160];
  std::snprintf(cam, sizeof cam, "--eye %.9g,%.9g,%.9g --target 0,0,0 --fov 40 ", eye.x, eye.y,
                eye.z);
  const RunResult r = run_viewer(d, "cube.obj --accel bvh " + std::string(cam) + flags +
                                        " --width 129 --height 129 --frames 2 --min-samples 1 "
                                        "--max-samples 1 --accuracy --hide-ui --stats-json "
                                        "stats.json");
  EXPECT_EQ(r.code, 0) << r.output;
  std::ifstream in(d + "/stats.json");
  return nlohmann::json::parse(in)["state"]["accuracy"];
}

TEST(AccuracyMap, ViewerShowsTheMollerLeaksOfAClosedMeshAndNoneWatertight) {
  KDGRID_REQUIRE_XVFB();
  TempDir dir("accuracy_map");
  const std::string d = dir.path().string();
  const Mesh cube = turned_fan_cube();
  write_obj(cube, d + "/cube.obj");
  // The pixels on the image's centre lines and diagonals look along shared edges: turned off
  // the axes, their rays pass the edges within rounding, where Möller-Trumbore can miss both
  // triangles. The leaks the map must show: the pixels whose ray Möller-Trumbore misses, or
  // hits beyond the watertight test's hit (through the surface, on the far side).
  size_t leaks = 0;
  {
    BuildParams p;
    p.triangle_test = TriangleTestKind::Moller;
    const auto moller = build_accelerator("bvh", cube, p);
    p.triangle_test = TriangleTestKind::Watertight;
    const auto watertight = build_accelerator("bvh", cube, p);
    Camera c;
    c.eye = turn_y(Vec3(0, 0, 4));
    c.target = Vec3(0, 0, 0);
    c.fov_deg = 40;
    const CameraFrame f = CameraFrame::make(c, 129, 129);
    for (int y = 0; y < 129; ++y)
      for (int x = 0; x < 129; ++x) {
        const Ray r = f.ray(float(x) + 0.5f, float(y) + 0.5f);
        Hit hm, hw;
        const bool m = moller->intersect(r, hm);
        if (watertight->intersect(r, hw)) leaks += !m || hm.t > hw.t + 1e-3f;
      }
  }
  ASSERT_GT(leaks, 0u) << "Möller-Trumbore leaks nowhere in this view";
  const nlohmann::json m = viewer_accuracy(d, "--triangle-test moller --offset epsilon");
  ASSERT_TRUE(m.is_object());
  EXPECT_TRUE(m["complete"].get<bool>()) << m.dump();
  EXPECT_EQ(m["triangle_test"], "moller");
  EXPECT_EQ(m["offset"], "epsilon");
  EXPECT_EQ(m["rays_by_kind"]["primary"]["leak"], leaks) << m.dump();
  EXPECT_GT(m["pixels_by_verdict"]["leak"].get<int>(), 0) << m.dump();
  EXPECT_GT(m["disagreement_rate"].get<double>(), 0.0);

  const nlohmann::json w = viewer_accuracy(d, "--triangle-test watertight");
  ASSERT_TRUE(w.is_object());
  EXPECT_TRUE(w["complete"].get<bool>()) << w.dump();
  EXPECT_EQ(w["judged"], 129 * 129);
  EXPECT_EQ(w["triangle_test"], "watertight");
  EXPECT_EQ(w["offset"], "robust");
  EXPECT_EQ(w["pixels_by_verdict"]["leak"], 0) << w.dump();
  EXPECT_EQ(w["pixels_by_verdict"]["disagree"], 0) << w.dump();
  // The edges seen head on are ambiguous for the reference; the faces agree.
  EXPECT_GT(w["pixels_by_verdict"]["ambiguous"].get<int>(), 0) << w.dump();
  EXPECT_GT(w["pixels_by_verdict"]["agree"].get<int>(), 129 * 129 / 2) << w.dump();
  EXPECT_EQ(w["disagreement_rate"].get<double>(), 0.0);
  EXPECT_GT(w["mrays"].get<double>(), 0.0);
}
#endif

}  // namespace
}  // namespace kdgrid::test
