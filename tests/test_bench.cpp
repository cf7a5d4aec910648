// The benchmark runner and its reports: suite parsing, statistics, the agreement rule, a
// whole run over a small generated suite (every field for every structure and set), bad input
// (malformed suite, missing scene) and a smoke run of `kdgrid bench` through the CLI.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "accel/hybrid/records.h"
#include "accel/triangle_wide.h"
#include "bench/bench.h"
#include "bench/profile.h"
#include "bench/rayfile.h"
#include "bench/raysets.h"
#include "bench/suite.h"
#include "bench/sweep.h"
#include "math/simd.h"
#include "scene/procedural.h"
#include "temp_dir.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using test::TempDir;

/// A fresh directory under the system temp dir, removed at the end of the test.

void write_file(const fs::path& p, const std::string& text) {
  std::ofstream f(p, std::ios::binary);
  f << text;
}

/// A closed box whose faces are n x n grids of quads (two triangles each), so that rays
/// meet many shared edges and vertices, plus a separate open quad floating beside it.
Mesh gridded_box(int n, const Vec3& center, float half) {
  Mesh m;
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = 0; side < 2; ++side) {
      const uint32_t base = uint32_t(m.positions.size());
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      for (int j = 0; j <= n; ++j) {
        for (int i = 0; i <= n; ++i) {
          Vec3 p = center;
          p[axis] += side ? half : -half;
          p[u] += -half + 2 * half * float(i) / float(n);
          p[v] += -half + 2 * half * float(j) / float(n);
          m.positions.push_back(p);
        }
      }
      for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
          const uint32_t a = base + uint32_t(j * (n + 1) + i), b = a + 1, c = a + uint32_t(n + 1),
                         d = c + 1;
          if (side) {
            m.triangles.push_back({a, b, d});
            m.triangles.push_back({a, d, c});
          } else {
            m.triangles.push_back({a, d, b});
            m.triangles.push_back({a, c, d});
          }
        }
      }
    }
  }
  // A floor quad under the box, so shadow rays are sometimes occluded.
  const uint32_t b = uint32_t(m.positions.size());
  const float y = center.y - 2 * half, w = 4 * half;
  m.positions.push_back({center.x - w, y, center.z - w});
  m.positions.push_back({center.x + w, y, center.z - w});
  m.positions.push_back({center.x + w, y, center.z + w});
  m.positions.push_back({center.x - w, y, center.z + w});
  m.triangles.push_back({b, b + 2, b + 1});
  m.triangles.push_back({b, b + 3, b + 2});
  return m;
}

/// Writes an ASCII PLY (test data only; the project's reader parses it).
void write_ascii_ply(const Mesh& m, const fs::path& p) {
  std::ostringstream s;
  s << "ply\nformat ascii 1.0\nelement vertex " << m.positions.size()
    << "\nproperty float x\nproperty float y\nproperty float z\nelement face " << m.triangles.size()
    << "\nproperty list uchar int vertex_indices\nend_header\n";
  s.precision(9);
  for (const auto& v : m.positions) s << v.x << " " << v.y << " " << v.z << "\n";
  for (const auto& t : m.triangles) s << "3 " << t[0] << " " << t[1] << " " << t[2] << "\n";
  write_file(p, s.str());
}

/// Two small scenes (one with a suite camera) and the suite listing them.
fs::path write_small_suite(const TempDir& dir, const std::string& extra_entries = "") {
  fs::create_directories(dir / "meshes");
  write_ascii_ply(gridded_box(4, {0, 0, 0}, 1.0f), dir / "meshes/box.ply");
  write_ascii_ply(gridded_box(3, {100, 5, -3}, 0.5f), dir / "meshes/box2.ply");
  const fs::path suite = dir / "suite.json";
  write_file(suite, R"({"scenes": [
    {"name": "box", "file": "meshes/box.ply", "camera": null},
    {"name": "box2", "file": "meshes/box2.ply",
     "camera": {"eye": [103, 7, 1], "target": [100, 4.5, -3], "fov": 50}})" +
                        extra_entries + "]}");
  return suite;
}

// ---- suite files --------------------------------------------------------------------------

TEST(BenchSuite, ParsesScenesCamerasAndRelativePaths) {
  const Suite s = parse_suite(R"({"scenes": [
      {"name": "a", "file": "x/a.ply", "camera": null},
      {"file": "b.obj", "camera": {"eye": [1, 2, 3], "target": [0, 0, 0], "fov": 60}},
      {"name": "abs", "file": "/abs/c.gltf"}]})",
                              "/base/dir", "test.json");
  ASSERT_EQ(s.scenes.size(), 3u);
  EXPECT_EQ(s.scenes[0].name, "a");
  EXPECT_EQ(s.scenes[0].file, "/base/dir/x/a.ply");
  EXPECT_FALSE(s.scenes[0].camera.has_value());
  EXPECT_EQ(s.scenes[1].name, "b");  // defaults to the file's stem
  ASSERT_TRUE(s.scenes[1].camera.has_value());
  EXPECT_EQ(s.scenes[1].camera->eye, Vec3(1, 2, 3));
  EXPECT_EQ(s.scenes[1].camera->fov_deg, 60.0f);
  EXPECT_EQ(s.scenes[2].file, "/abs/c.gltf");
  for (const auto& e : s.scenes) EXPECT_TRUE(e.error.empty()) << e.error;
}

TEST(BenchSuite, BadEntriesKeepTheirErrorAndTheOthers) {
  const Suite s = parse_suite(R"({"scenes": [
      {"name": "nofile"},
      {"name": "badcam", "file": "a.ply", "camera": {"eye": [1, 2], "target": [0, 0, 0]}},
      {"name": "badfov", "file": "a.ply", "camera": {"eye": [1, 2, 3], "target": [0, 0, 0], "fov": 200}},
      42,
      {"name": "good", "file": "a.ply"}]})",
                              "/d", "suite.json");
  ASSERT_EQ(s.scenes.size(), 5u);
  EXPECT_NE(s.scenes[0].error.find("\"file\""), std::string::npos) << s.scenes[0].error;
  EXPECT_NE(s.scenes[1].error.find("eye"), std::string::npos) << s.scenes[1].error;
  EXPECT_NE(s.scenes[2].error.find("fov"), std::string::npos) << s.scenes[2].error;
  EXPECT_NE(s.scenes[3].error.find("not an object"), std::string::npos) << s.scenes[3].error;
  for (int i = 0; i < 4; ++i)
    EXPECT_NE(s.scenes[i].error.find("suite.json"), std::string::npos) << s.scenes[i].error;
  EXPECT_TRUE(s.scenes[4].error.empty());
}

TEST(BenchSuite, CameraOutsideTheRayRangeIsRefused) {
  // Past +-1.844e18 every ray is invalid: the scene would trace as all misses.
  const Suite s = parse_suite(R"({"scenes": [
      {"name": "far", "file": "a.ply", "camera": {"eye": [0, 0, 1e19], "target": [0, 0, 0]}},
      {"name": "same", "file": "a.ply", "camera": {"eye": [1, 1, 1], "target": [1, 1, 1]}}]})",
                              "/d", "suite.json");
  ASSERT_EQ(s.scenes.size(), 2u);
  EXPECT_NE(s.scenes[0].error.find("outside the supported coordinate range"), std::string::npos)
      << s.scenes[0].error;
  EXPECT_NE(s.scenes[1].error.find("same point"), std::string::npos) << s.scenes[1].error;
}

TEST(BenchSuite, MalformedFileNamesTheFile) {
  TempDir dir("malformed");
  write_file(dir / "bad.json", "{\"scenes\": [ {\"name\": \"x\", ");
  try {
    load_suite((dir / "bad.json").string());
    FAIL() << "a truncated suite must not parse";
  } catch (const LoadError& e) {
    EXPECT_NE(std::string(e.what()).find("bad.json"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("not valid JSON"), std::string::npos) << e.what();
  }
  write_file(dir / "noscenes.json", R"({"scene": []})");
  EXPECT_THROW(load_suite((dir / "noscenes.json").string()), LoadError);
  EXPECT_THROW(load_suite((dir / "absent.json").string()), LoadError);
}

TEST(BenchSuite, DefaultSuiteFallsBackToTheProjectAssets) {
  TempDir dir("defaultsuite");
  const char* old = std::getenv("KDGRID_SCENES");
  const std::string saved = old ? old : "";
  // A scenes folder without suite.json: the project's own assets/suite.json is next.
  ::setenv("KDGRID_SCENES", dir.path().c_str(), 1);
  const std::string fallback = default_suite_path(KDGRID_SOURCE_DIR);
  write_file(dir / "suite.json", R"({"scenes": []})");
  const std::string shared = default_suite_path(KDGRID_SOURCE_DIR);
  if (old)
    ::setenv("KDGRID_SCENES", saved.c_str(), 1);
  else
    ::unsetenv("KDGRID_SCENES");
  EXPECT_EQ(fs::path(fallback),
            fs::path(test::source_path("assets/suite.json")).lexically_normal());
  EXPECT_EQ(fs::path(shared), dir / "suite.json");
  const Suite own = load_suite(fallback);
  ASSERT_FALSE(own.scenes.empty());
  for (const auto& e : own.scenes) {
    EXPECT_TRUE(e.error.empty()) << e.error;
    EXPECT_TRUE(fs::exists(e.file)) << e.file << " listed by assets/suite.json";
  }
}

// An installed kdgrid (PREFIX/bin) finds its assets in PREFIX/share/kdgrid/assets, found at run
// time rather than through a source path compiled in: seen here from a working directory laid
// out like an install, which is searched before the executable's own checkout.
TEST(BenchSuite, DefaultSuiteFoundInAnInstalledLayout) {
  TempDir dir("installedsuite");
  fs::create_directories(dir / "bin");
  fs::create_directories(dir / "share" / "kdgrid" / "assets");
  write_file(dir / "share" / "kdgrid" / "assets" / "suite.json", R"({"scenes": []})");
  const char* old = std::getenv("KDGRID_SCENES");
  const std::string saved = old ? old : "";
  ::setenv("KDGRID_SCENES", dir.path().c_str(), 1);  // a scenes folder without suite.json
  const fs::path cwd = fs::current_path();
  fs::current_path(dir / "bin");
  const std::string found = default_suite_path();
  fs::current_path(cwd);
  if (old)
    ::setenv("KDGRID_SCENES", saved.c_str(), 1);
  else
    ::unsetenv("KDGRID_SCENES");
  EXPECT_EQ(fs::path(found),
            (dir / "share" / "kdgrid" / "assets" / "suite.json").lexically_normal());
}

// ---- statistics and memory -------------------------------------------------------------------

TEST(BenchStats, Median) {
  EXPECT_EQ(median({}), 0.0);
  EXPECT_EQ(median({3.0}), 3.0);
  EXPECT_EQ(median({5.0, 1.0, 3.0}), 3.0);
  EXPECT_EQ(median({4.0, 1.0, 3.0, 2.0}), 2.5);
}

TEST(BenchStats, PeakRssSeesAnAllocation) {
  EXPECT_GT(process_peak_rss_bytes(), 0u);
  if (!reset_peak_rss()) GTEST_SKIP() << "/proc/self/clear_refs is not writable here";
  const uint64_t before = peak_rss_since_reset();
  const size_t n = 48u << 20;
  std::vector<char> block(n);
  for (size_t i = 0; i < n; i += 4096) block[i] = char(i);  // touch every page
  const uint64_t after = peak_rss_since_reset();
  EXPECT_GE(after, before + (40u << 20)) << "before " << before << " after " << after;
  EXPECT_GE(process_peak_rss_bytes(), after - (1u << 20));
  volatile char sink = block[n / 2];
  (void)sink;
}

// ---- agreement rule ---------------------------------------------------------------------------

TEST(BenchAgreement, TiesOnSharedEdgesCountAsAgreement) {
  // Two triangles sharing the edge x = 0 in the plane z = 0, and a third one further away.
  Mesh m;
  m.positions = {{0, -1, 0}, {0, 1, 0}, {-1, 0, 0}, {1, 0, 0}, {-1, -1, 5}, {1, -1, 5}, {0, 1, 5}};
  m.triangles = {{0, 1, 2}, {0, 3, 1}, {4, 5, 6}};
  const Ray edge{{0, 0, -1}, 0.0f, {0, 0, 1}, kInf};  // hits the shared edge at t = 1
  const std::vector<Ray> rays = {edge, edge, edge, edge};
  const std::vector<Hit> ref = {
      {1, 0, 0, 0}, {1, 0, 0, 0}, {1, 0, 0, 0}, {kInf, kInvalidPrim, 0, 0}};
  // same triangle; the neighbour at the same t (a tie); the far triangle (wrong); a hit where
  // the reference missed (wrong).
  const std::vector<Hit> hits = {{1, 0, 0, 0}, {1, 1, 0, 0}, {6, 2, 0, 0}, {1, 1, 0, 0}};
  uint64_t bad = 0;
  EXPECT_DOUBLE_EQ(hit_agreement(m, rays, hits, ref, false, 1e-5, &bad), 0.5);
  EXPECT_EQ(bad, 2u);
  // A reported t that is off does not matter: the triangle's own t is recomputed.
  const std::vector<Hit> sloppy = {{1.5f, 1, 0, 0}};
  EXPECT_DOUBLE_EQ(hit_agreement(m, {edge}, sloppy, {ref[0]}, false, 1e-5), 1.0);
  // Any-hit sets compare only the occluded answer.
  EXPECT_DOUBLE_EQ(hit_agreement(m, rays, hits, ref, true, 1e-5, &bad), 0.75);
  EXPECT_EQ(bad, 1u);
  EXPECT_THROW(hit_agreement(m, rays, {hits[0]}, ref, false, 1e-5), Error);
}

// ---- a whole run --------------------------------------------------------------------------------

void expect_every_field(const BenchReport& rep, const std::vector<std::string>& accels,
                        const std::vector<std::string>& ok_scenes) {
  for (const auto& name : ok_scenes) {
    const auto it = std::find_if(rep.scenes.begin(), rep.scenes.end(),
                                 [&](const SceneFigures& s) { return s.name == name; });
    ASSERT_NE(it, rep.scenes.end()) << name;
    const SceneFigures& s = *it;
    ASSERT_TRUE(s.error.empty()) << s.error;
    EXPECT_GT(s.triangles, 0u);
    ASSERT_EQ(s.structures.size(), accels.size()) << name;
    EXPECT_EQ(s.structures.front().accel, s.reference) << "the reference runs first";
    for (const auto& a : s.structures) {
      SCOPED_TRACE(name + " / " + a.accel);
      EXPECT_TRUE(a.error.empty()) << a.error;
      EXPECT_GT(a.build_seconds, 0.0);
      EXPECT_GT(a.build_mtris_per_s, 0.0);
      EXPECT_GT(a.bytes, 0u);
      EXPECT_GT(a.bytes_per_triangle, 0.0);
      EXPECT_GT(a.peak_rss_bytes, 0u);
      EXPECT_GT(a.process_peak_rss_bytes, 0u);
      EXPECT_GT(a.rss_before_bytes, 0u);
      ASSERT_EQ(a.sets.size(), 3u);
      for (const auto& x : a.sets) {
        SCOPED_TRACE(x.set);
        EXPECT_GT(x.rays, 0u);
        EXPECT_EQ(x.mrays_reps.size(), size_t(rep.reps));
        EXPECT_GT(x.mrays_median, 0.0);
        EXPECT_LE(x.mrays_min, x.mrays_median);
        EXPECT_GE(x.mrays_max, x.mrays_median);
        EXPECT_GT(x.ratio_to_reference, 0.0);
        EXPECT_GT(x.reference_mrays, 0.0);
        EXPECT_EQ(x.paired, a.accel != s.reference) << "every ratio is paired by default";
        if (x.set != "shadow") {
          EXPECT_GT(x.hits, 0u);
        }
        EXPECT_EQ(x.counted, !is_embree(a.accel)) << "only Embree cannot count";
        if (x.counted) {
          EXPECT_GT(x.steps_per_ray, 0.0);
          EXPECT_GT(x.tests_per_ray, 0.0);
        }
        if (a.accel == s.reference) {
          EXPECT_LT(x.agreement, 0.0) << "the reference is not compared with itself";
        } else if (is_embree(a.accel)) {
          // Embree's own triangle test may decide grazing silhouette rays differently.
          EXPECT_GE(x.agreement, 0.999);
        } else {
          // Exact structures answer exactly like brute force, up to ties at shared edges.
          EXPECT_EQ(x.agreement, 1.0) << x.disagreements << " of " << x.rays << " rays differ";
        }
      }
    }
  }
}

BenchOptions small_options() {
  BenchOptions o;
  o.accels = accelerator_names();  // brute included: it is the reference here
  o.reference = "brute";
  o.width = 24;
  o.height = 20;
  o.reps = 2;
  o.threads = 2;
  return o;
}

TEST(Bench, SmallSuiteHasEveryFieldForEveryStructureAndSet) {
  TempDir dir("small");
  const Suite suite = load_suite(write_small_suite(dir).string());
  const BenchOptions o = small_options();
  const BenchReport rep = run_bench(suite, o);
  EXPECT_FALSE(rep.any_failed());
  EXPECT_EQ(rep.reps, 2);
  EXPECT_EQ(rep.threads, 2);
  EXPECT_FALSE(rep.machine.empty());
  ASSERT_EQ(rep.scenes.size(), 2u);
  expect_every_field(rep, o.accels, {"box", "box2"});
  // Sets are shared: every structure traced the same number of rays.
  for (const auto& s : rep.scenes) {
    EXPECT_EQ(s.set_sizes.at(0).second, 24u * 20u);
    for (const auto& a : s.structures)
      for (size_t k = 0; k < a.sets.size(); ++k) EXPECT_EQ(a.sets[k].rays, s.set_sizes[k].second);
  }

  // The JSON has one build object per scene x structure and one result per scene x structure
  // x set, each with every field.
  const json j = json::parse(bench_to_json(rep));
  EXPECT_EQ(j["builds"].size(), 2 * o.accels.size());
  EXPECT_EQ(j["results"].size(), 2 * o.accels.size() * 3);
  EXPECT_TRUE(j["errors"].empty());
  for (const char* k : {"machine", "date", "threads", "reps", "width", "height", "sets"})
    EXPECT_TRUE(j["meta"].contains(k)) << k;
  for (const auto& b : j["builds"])
    for (const char* k :
         {"scene", "accel", "build_seconds", "build_mtris_per_s", "bytes", "bytes_per_triangle",
          "bytes_by_part", "peak_rss_bytes", "rss_growth_bytes", "process_peak_rss_bytes"})
      EXPECT_TRUE(b.contains(k)) << k;
  for (const auto& r : j["results"])
    for (const char* k :
         {"scene", "accel", "set", "rays", "mrays", "mrays_min", "mrays_max", "ratio_to_reference",
          "reference_mrays", "steps_per_ray", "leaves_per_ray", "tests_per_ray", "agreement"})
      EXPECT_TRUE(r.contains(k)) << k;
  const std::string md = bench_to_markdown(rep);
  for (const auto& a : o.accels) EXPECT_NE(md.find("| " + a + " "), std::string::npos) << a;
}

TEST(Bench, PacketColumnTimesEveryStructuresPacketQueryBesideTheReferences) {
  TempDir dir("packets");
  const Suite suite = load_suite(write_small_suite(dir).string());
  BenchOptions o = small_options();
  o.reference = "embree";
  o.packet_tile = 4;
  const BenchReport rep = run_bench(suite, o);
  EXPECT_FALSE(rep.any_failed());
  EXPECT_EQ(rep.packet_tile, 4);
  int rows = 0;
  for (const auto& s : rep.scenes)
    for (const auto& a : s.structures)
      for (const auto& x : a.sets) {
        const std::string where = s.name + " " + a.accel + " " + x.set;
        if (x.set == "diffuse") {  // incoherent: no packet column
          EXPECT_EQ(x.packet_rays, 0) << where;
          continue;
        }
        ++rows;
        EXPECT_EQ(x.packet_rays, 16) << where;
        // Embree's native packets; the hybrid's packet walk (four packets of 16 lanes) where the
        // build has it; the other structures loop over single rays.
        const int own = a.accel == "hybrid" && hybrid::kSharedCorners ? 64 : 1;
        EXPECT_EQ(x.packet_width, is_embree(a.accel) ? embree_isa().native_packet : own) << where;
        EXPECT_EQ(x.packet_mrays_reps.size(), 2u) << where;
        EXPECT_GT(x.packet_mrays_median, 0.0) << where;
        EXPECT_GT(x.packet_single_mrays, 0.0) << where;
        EXPECT_GT(x.packet_speedup, 0.0) << where;
        EXPECT_GT(x.packet_ratio_to_reference, 0.0) << where;
        EXPECT_GT(x.packet_reference_mrays, 0.0) << where;
        // Every structure's packet answers are its single-ray answers; Embree's may only
        // differ on exact ties (none on these boxes' pixel-centre rays).
        EXPECT_EQ(x.packet_mismatches, x.packet_ties) << where;
        if (!is_embree(a.accel)) {
          EXPECT_EQ(x.packet_mismatches, 0u) << where;
        }
      }
  EXPECT_EQ(rows, 2 * int(o.accels.size()) * 2);
  const json j = json::parse(bench_to_json(rep));
  EXPECT_EQ(j["meta"]["packet_tile"], 4);
  for (const auto& r : j["results"]) {
    EXPECT_EQ(r.contains("packet"), r["set"] != "diffuse") << r["accel"] << " " << r["set"];
    if (!r.contains("packet")) continue;
    for (const char* k : {"rays_per_packet", "packet_width", "mrays", "ratio_to_reference",
                          "speedup_over_single_loop", "mismatches", "mismatched_ties"}) {
      EXPECT_TRUE(r["packet"].contains(k)) << k;
    }
  }
  const std::string md = bench_to_markdown(rep);
  EXPECT_NE(md.find("### Packets: 4x4 tiles"), std::string::npos) << md;
  EXPECT_NE(md.find("rtcIntersect" + std::to_string(embree_isa().native_packet)),
            std::string::npos);

  // --packet-tile 0: no packet column anywhere.
  o.packet_tile = 0;
  o.accels = {"bvh"};
  const BenchReport none = run_bench(suite, o);
  for (const auto& s : none.scenes)
    for (const auto& a : s.structures)
      for (const auto& x : a.sets) EXPECT_EQ(x.packet_rays, 0);
  EXPECT_EQ(bench_to_markdown(none).find("### Packets"), std::string::npos);
}

TEST(Bench, ExactStructuresAgreeWithEmbree) {
  const auto names = accelerator_names();
  if (std::find(names.begin(), names.end(), "embree") == names.end())
    GTEST_SKIP() << "embree is not registered in accel/factory.cpp yet";
  TempDir dir("embree");
  const Suite suite = load_suite(write_small_suite(dir).string());
  BenchOptions o = small_options();
  o.reference = "embree";
  o.reps = 1;
  const BenchReport rep = run_bench(suite, o);
  for (const auto& s : rep.scenes)
    for (const auto& a : s.structures)
      for (const auto& x : a.sets)
        if (!is_embree(a.accel)) {
          EXPECT_GE(x.agreement, 0.999) << s.name << " " << a.accel << " " << x.set;
        }
}

TEST(Bench, BadScenesAreReportedAndTheOthersRun) {
  TempDir dir("bad");
  write_file(dir / "broken.ply", "ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n");
  const Suite suite = load_suite(write_small_suite(dir, R"(,
    {"name": "missing", "file": "meshes/nope.ply", "camera": null},
    {"name": "broken", "file": "broken.ply"},
    {"name": "nofile", "camera": null})")
                                     .string());
  BenchOptions o = small_options();
  o.accels = {"brute"};
  o.reps = 1;
  const BenchReport rep = run_bench(suite, o);
  ASSERT_EQ(rep.scenes.size(), 5u);
  EXPECT_TRUE(rep.any_failed());
  expect_every_field(rep, o.accels, {"box", "box2"});
  EXPECT_NE(rep.scenes[2].error.find("nope.ply"), std::string::npos) << rep.scenes[2].error;
  EXPECT_NE(rep.scenes[3].error.find("broken.ply"), std::string::npos) << rep.scenes[3].error;
  EXPECT_NE(rep.scenes[4].error.find("file"), std::string::npos) << rep.scenes[4].error;
  const json j = json::parse(bench_to_json(rep));
  EXPECT_EQ(j["errors"].size(), 3u);
  EXPECT_NE(bench_to_markdown(rep).find("nope.ply"), std::string::npos);
}

TEST(Bench, UnpairedRatiosDivideByTheReferenceMedian) {
  TempDir dir("unpaired");
  const Suite suite = load_suite(write_small_suite(dir).string());
  BenchOptions o = small_options();
  o.accels = {"brute", "bvh"};
  o.interleave_reference = false;
  const BenchReport rep = run_bench(suite, o);
  ASSERT_FALSE(rep.any_failed());
  for (const auto& s : rep.scenes) {
    ASSERT_EQ(s.structures.size(), 2u);
    const auto& ref = s.structures[0];
    const auto& bvh = s.structures[1];
    for (size_t k = 0; k < bvh.sets.size(); ++k) {
      EXPECT_FALSE(bvh.sets[k].paired);
      EXPECT_EQ(bvh.sets[k].reference_mrays, ref.sets[k].mrays_median);
      EXPECT_DOUBLE_EQ(bvh.sets[k].ratio_to_reference,
                       bvh.sets[k].mrays_median / ref.sets[k].mrays_median);
    }
  }
}

TEST(Bench, CpuClockTimesTheTracingThreads) {
  // Brute force on a small mesh: slow enough per ray that the CPU time is well above the
  // clock's resolution. The CPU-clock time of a pass cannot exceed its wall time by more than
  // rounding (it is summed over threads, then divided by their number), and is positive.
  const Mesh m = make_icosphere(3);
  auto acc = make_accelerator("brute");
  acc->build(m, BuildParams{});
  std::vector<Ray> rays;
  for (int i = 0; i < 4000; ++i) {
    Ray r;
    r.org = Vec3(-3.0f, 0.001f * float(i % 100), 0.0f);
    r.dir = Vec3(1.0f, 0.0f, 0.0f);
    rays.push_back(r);
  }
  std::vector<Hit> a, b;
  const auto t0 = std::chrono::steady_clock::now();
  const double cpu = trace_rays(*acc, rays, false, &a, true);
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_GT(cpu, 0.0);
  EXPECT_LE(cpu, wall * 1.05 + 1e-3);
  trace_rays(*acc, rays, false, &b, false);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) EXPECT_EQ(a[i].prim, b[i].prim);

  TempDir dir("cpuclock");
  BenchOptions o = small_options();
  o.accels = {"bvh"};
  o.cpu_clock = true;
  const BenchReport rep = run_bench(load_suite(write_small_suite(dir).string()), o);
  ASSERT_FALSE(rep.any_failed());
  EXPECT_EQ(rep.clock, "cpu");
  EXPECT_NE(bench_to_markdown(rep).find("CPU clocks"), std::string::npos);
}

TEST(Bench, RejectsBadOptions) {
  Suite s;
  BenchOptions o;
  o.reps = 0;
  EXPECT_THROW(run_bench(s, o), ParamError);
  o = BenchOptions{};
  o.sets = {"primary", "sideways"};
  EXPECT_THROW(run_bench(s, o), ParamError);
  o = BenchOptions{};
  o.accels = {"nonexistent"};
  EXPECT_THROW(run_bench(s, o), ParamError);
  for (const int tile : {-1, kMaxPacketTile + 1}) {
    o = BenchOptions{};
    o.packet_tile = tile;
    EXPECT_THROW(run_bench(s, o), ParamError) << tile;
  }
}

TEST(Bench, RaysDirWritesThenReadsTheSameRays) {
  TempDir dir("raysdir");
  const Suite suite = load_suite(write_small_suite(dir).string());
  BenchOptions o = small_options();
  o.accels = {"brute"};
  o.reps = 1;
  o.rays_dir = (dir / "rays").string();
  const BenchReport first = run_bench(suite, o);
  for (const char* set : {"primary", "shadow", "diffuse"})
    EXPECT_TRUE(fs::exists(dir / ("rays/box." + std::string(set) + ".rays"))) << set;
  // A second run at another resolution must take the files, not generate new rays.
  o.width = o.height = 8;
  const BenchReport second = run_bench(suite, o);
  ASSERT_FALSE(second.any_failed());
  EXPECT_EQ(second.scenes[0].set_sizes, first.scenes[0].set_sizes);
  EXPECT_NE(second.scenes[0].set_sources[0].second.find("box.primary.rays"), std::string::npos);
}

// ---- the CLI ---------------------------------------------------------------------------------

int run_cli(const std::string& args, const fs::path& log) {
  const std::string cmd =
      std::string("\"") + KDGRID_CLI_PATH + "\" " + args + " > \"" + log.string() + "\" 2>&1";
  const int rc = std::system(cmd.c_str());
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

std::string slurp(const fs::path& p) {
  std::ifstream f(p);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

TEST(BenchCli, SmokeRunWritesJsonWithEveryField) {
  TempDir dir("cli");
  const fs::path suite = write_small_suite(dir);
  const fs::path out = dir / "out.json", md = dir / "out.md", log = dir / "log.txt";
  const int rc = run_cli("bench --suite \"" + suite.string() +
                             "\" --res 16 --reps 1 --threads 2 "
                             "--json \"" +
                             out.string() + "\" --md \"" + md.string() + "\"",
                         log);
  ASSERT_EQ(rc, 0) << slurp(log);
  const json j = json::parse(slurp(out));
  // Every default structure (and the reference, run first) on both scenes and all sets.
  EXPECT_EQ(j["results"].size(), j["builds"].size() * 3);
  for (const char* scene : {"box", "box2"})
    for (const auto& accel : default_bench_accels())
      for (const char* set : {"primary", "shadow", "diffuse"})
        EXPECT_EQ(std::count_if(j["results"].begin(), j["results"].end(),
                                [&](const json& r) {
                                  return r["scene"] == scene && r["accel"] == accel &&
                                         r["set"] == set;
                                }),
                  1)
            << scene << " " << accel << " " << set;
  for (const auto& r : j["results"]) {
    for (const char* k : {"scene", "accel", "set", "rays", "mrays", "mrays_min", "mrays_max",
                          "ratio_to_reference", "steps_per_ray", "tests_per_ray", "agreement"})
      EXPECT_TRUE(r.contains(k)) << k;
    EXPECT_GT(r["mrays"].get<double>(), 0.0);
  }
  EXPECT_NE(slurp(md).find("Throughput"), std::string::npos);
  EXPECT_NE(slurp(log).find("[2/2] box2"), std::string::npos) << "progress on stderr";

  // The reference is Embree as a user runs it (default flags, medium quality), beside its
  // robust and high-quality configurations; every row says which Embree it is.
  for (const auto& s : j["scenes"]) EXPECT_EQ(s["reference"], "embree");
  std::map<std::string, std::pair<std::string, std::string>> embree;  // flags, quality
  for (const auto& b : j["builds"])
    if (is_embree(b["accel"].get<std::string>()))
      embree[b["accel"]] = {b["extra"]["flags"], b["extra"]["quality"]};
  EXPECT_EQ(embree["embree"], std::make_pair(std::string("default"), std::string("medium")));
  EXPECT_EQ(embree["embree-robust"], std::make_pair(std::string("robust"), std::string("medium")));
  EXPECT_EQ(embree["embree-high"], std::make_pair(std::string("default"), std::string("high")));
  EXPECT_NE(slurp(md).find("| box | embree (default flags, medium quality) (ref) |"),
            std::string::npos)
      << slurp(md);
  EXPECT_NE(slurp(md).find("| box | embree-high (default flags, high quality) |"),
            std::string::npos);
  // The SIMD each side used: kdgrid's from the build, Embree's as it reports it.
  const json& simd = j["meta"]["simd"];
  EXPECT_EQ(simd["kdgrid"]["isa"], kBuildIsa);
  EXPECT_EQ(simd["kdgrid"]["lanes"], kTraversalLanes);
  EXPECT_EQ(simd["kdgrid"]["leaf_lanes"], kWideLanes);
  EXPECT_EQ(simd["embree"]["isa"], embree_isa().isa);
  EXPECT_EQ(simd["embree"]["native_packet"], embree_isa().native_packet);
  EXPECT_EQ(simd["embree"]["version"], embree_isa().version);
  EXPECT_NE(embree_isa().isa, "unknown");
  EXPECT_NE(slurp(md).find("SIMD: kdgrid built for " + std::string(kBuildIsa)), std::string::npos);
  EXPECT_NE(slurp(md).find("Embree " + embree_isa().version + " with its " + embree_isa().isa +
                           " kernels"),
            std::string::npos);
}

TEST(BenchCli, MalformedSuiteFailsAtTheEndAfterTheOthersRan) {
  TempDir dir("clibad");
  const fs::path good = write_small_suite(dir);
  write_file(dir / "broken.json", "{\"scenes\": [ oops ]");
  const fs::path out = dir / "out.json", log = dir / "log.txt";
  const int rc =
      run_cli("bench --accel brute --suite \"" + (dir / "broken.json").string() + "\" --suite \"" +
                  good.string() + "\" --res 8 --reps 1 --json \"" + out.string() + "\"",
              log);
  EXPECT_NE(rc, 0) << slurp(log);
  EXPECT_NE(slurp(log).find("broken.json"), std::string::npos) << slurp(log);
  const json j = json::parse(slurp(out));
  EXPECT_EQ(j["errors"].size(), 1u);
  size_t box_results = 0;
  for (const auto& r : j["results"]) box_results += r["scene"] == "box" || r["scene"] == "box2";
  EXPECT_GE(box_results, 2u * 3u) << "the good suite still ran";
}

// --only keeps the named scenes of a suite (with their cameras), so that one scene of the
// shared suite can be timed alone; a name the suite lacks is refused with the names it has.
TEST(BenchCli, OnlyRunsTheNamedScenesAndRefusesUnknownNames) {
  TempDir dir("clionly");
  const fs::path suite = write_small_suite(dir);
  const fs::path out = dir / "out.json", log = dir / "log.txt";
  ASSERT_EQ(run_cli("bench --accel brute --sets primary --suite \"" + suite.string() +
                        "\" --only box2 --res 8 --reps 1 --json \"" + out.string() + "\"",
                    log),
            0)
      << slurp(log);
  const json j = json::parse(slurp(out));
  ASSERT_FALSE(j["results"].empty());
  for (const auto& r : j["results"]) EXPECT_EQ(r["scene"], "box2");
  const int rc = run_cli(
      "bench --accel brute --suite \"" + suite.string() + "\" --only nosuch --res 8 --reps 1", log);
  EXPECT_NE(rc, 0);
  const std::string text = slurp(log);
  EXPECT_NE(text.find("no scene named 'nosuch'"), std::string::npos) << text;
  EXPECT_NE(text.find("box, box2"), std::string::npos) << "lists the suite's scenes: " << text;
  // A list of no names is refused too, not taken as "run nothing".
  EXPECT_NE(
      run_cli("bench --accel brute --suite \"" + suite.string() + "\" --only , --res 8 --reps 1",
              log),
      0);
  EXPECT_NE(slurp(log).find("names no scene"), std::string::npos) << slurp(log);
}

// ---- sweeps ------------------------------------------------------------------------------------

// ---- profile: per-class single-thread costs -------------------------------------------------

TEST(Profile, ClassesPartitionTheRaysByTheReferenceAndTheBox) {
  const Mesh m = make_icosphere(3, Vec3(0.0f), 1.0f);
  BuildParams p;
  const auto ref = build_accelerator("bvh", m, p);
  // A camera close enough that some rays miss the sphere inside its box (near the box's
  // corners) and far enough that the image's corners miss the box.
  Camera cam;
  cam.eye = Vec3(0.0f, 0.0f, 4.0f);
  cam.target = Vec3(0.0f);
  cam.fov_deg = 50.0f;
  const std::vector<Ray> rays = primary_rays(cam, 48, 48);
  const RayClasses c = classify_rays(*ref, m.bounds(), rays);
  EXPECT_EQ(c.hit.size() + c.miss_box.size() + c.miss_out.size(), rays.size());
  ASSERT_FALSE(c.hit.empty());
  ASSERT_FALSE(c.miss_box.empty());
  ASSERT_FALSE(c.miss_out.empty());
  const Box3 b = m.bounds();
  for (const Ray& r : c.hit) {
    Hit h;
    EXPECT_TRUE(ref->intersect(r, h));
  }
  for (const auto* set : {&c.miss_box, &c.miss_out})
    for (const Ray& r : *set) {
      Hit h;
      EXPECT_FALSE(ref->intersect(r, h));
    }
  // miss-out rays never enter the box: a float slab test agrees (to rounding).
  for (const Ray& r : c.miss_out) {
    float t0 = 0.0f, t1 = std::numeric_limits<float>::infinity();
    for (int a = 0; a < 3; ++a) {
      float ta = (b.lo[a] - r.org[a]) / r.dir[a], tb = (b.hi[a] - r.org[a]) / r.dir[a];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
    EXPECT_GT(t0 * (1.0f + 1e-5f), t1);
  }
}

TEST(Profile, FiguresMatchTheCountedPassAndHitCounts) {
  const Mesh m = make_icosphere(3, Vec3(0.0f), 1.0f);
  BuildParams p;
  const auto kd = build_accelerator("kdtree", m, p);
  Camera cam;
  cam.eye = Vec3(0.3f, 0.2f, 4.0f);
  const std::vector<Ray> rays = primary_rays(cam, 32, 32);
  const ProfileFigures f = profile_rays(*kd, rays, 2);
  EXPECT_EQ(f.rays, rays.size());
  RayCounters c;
  uint64_t hits = 0;
  for (const Ray& r : rays) {
    Hit h;
    hits += kd->intersect_counted(r, h, c);
  }
  EXPECT_EQ(f.hits, hits);
  EXPECT_GT(f.hits, 0u);
  EXPECT_TRUE(f.counted);
  EXPECT_DOUBLE_EQ(f.steps, double(c.steps) / double(rays.size()));
  EXPECT_DOUBLE_EQ(f.tests, double(c.tri_tests) / double(rays.size()));
  EXPECT_GT(f.cold_ns, 0.0);
  EXPECT_GE(f.warm_ns, 0.0);
  const ProfileFigures empty = profile_rays(*kd, {}, 1);
  EXPECT_EQ(empty.rays, 0u);
  EXPECT_THROW(profile_rays(*kd, rays, 0), ParamError);
}

// ---- traversal alone (TriangleTestKind::None, `kdgrid trace --traversal-only`) --------------

// Without triangle tests every ray misses and crosses the whole structure: each structure then
// visits, ray by ray, at least the nodes, cells and triangles it visits when it can stop at a
// hit. Embree cannot run without its own tests and says so.
TEST(TraversalOnly, EveryRayMissesAndEachStructureVisitsAtLeastAsMuch) {
  const Mesh m = make_icosphere(3, Vec3(0.0f), 1.0f);
  Camera cam;
  cam.eye = Vec3(0.3f, 0.2f, 4.0f);
  const std::vector<Ray> rays = primary_rays(cam, 24, 24);
  BuildParams none;
  none.triangle_test = TriangleTestKind::None;
  for (const std::string name : {"brute", "bvh", "grid", "kdtree", "hybrid", "irregular"}) {
    SCOPED_TRACE(name);
    const auto full = build_accelerator(name, m, BuildParams{});
    const auto bare = build_accelerator(name, m, none);
    uint64_t hits = 0, more = 0;
    for (const Ray& r : rays) {
      Hit h;
      RayCounters cf, cb;
      hits += full->intersect_counted(r, h, cf);
      ASSERT_FALSE(bare->intersect_counted(r, h, cb));
      ASSERT_FALSE(bare->occluded(r));
      ASSERT_GE(cb.steps, cf.steps);
      ASSERT_GE(cb.tri_tests, cf.tri_tests);
      ASSERT_GE(cb.lookups, cf.lookups);
      more += cb.steps + cb.tri_tests > cf.steps + cf.tri_tests;
    }
    ASSERT_GT(hits, 0u);
    if (name != "brute") {
      EXPECT_GT(more, 0u) << "rays that hit stop early with the tests on";
    }
  }
  EXPECT_THROW(build_accelerator("embree", m, none), ParamError);
}

TEST(TraceCli, TraversalOnlyReportsTimePerStepAndRefusesEmbree) {
  TempDir dir("trace");
  const fs::path ply = dir / "sphere.ply", rays = dir / "r.rays", log = dir / "log.txt";
  write_ascii_ply(make_icosphere(2, Vec3(0.0f), 1.0f), ply);
  Camera cam;
  cam.eye = Vec3(0.3f, 0.2f, 4.0f);
  write_rays(rays.string(), primary_rays(cam, 16, 16));
  const std::string base =
      "trace \"" + ply.string() + "\" --rays \"" + rays.string() + "\" --repeat 1 ";
  ASSERT_EQ(run_cli(base + "--accel hybrid --traversal-only", log), 0) << slurp(log);
  EXPECT_NE(slurp(log).find("hit fraction 0.0000"), std::string::npos) << slurp(log);
  EXPECT_NE(slurp(log).find("ns per lookup"), std::string::npos) << slurp(log);
  // The next leaves taken from the next-leaf cache, counted: neighbouring rays of a finer
  // image take some, and none without the cache.
  const fs::path fine = dir / "fine.rays";
  write_rays(fine.string(), primary_rays(cam, 128, 128));
  const std::string fine_base =
      "trace \"" + ply.string() + "\" --rays \"" + fine.string() + "\" --repeat 1 ";
  ASSERT_EQ(run_cli(fine_base + "--accel hybrid --threads 1", log), 0) << slurp(log);
  EXPECT_NE(slurp(log).find("of the lookups per ray answered by the next-leaf cache"),
            std::string::npos)
      << slurp(log);
  EXPECT_EQ(slurp(log).find("leaf cache   0.00 "), std::string::npos)
      << "coherent rays take cached leaves\n"
      << slurp(log);
  ASSERT_EQ(run_cli(fine_base + "--accel hybrid --threads 1 --json", log), 0) << slurp(log);
  EXPECT_GT(json::parse(slurp(log))["per_ray"]["next_leaves_from_cache"].get<double>(), 0.0)
      << slurp(log);
  ASSERT_EQ(run_cli(fine_base + "--accel hybrid --threads 1 --hybrid-no-next-leaf-cache", log), 0)
      << slurp(log);
  EXPECT_NE(slurp(log).find("leaf cache   0.00 "), std::string::npos) << slurp(log);
  ASSERT_EQ(
      run_cli(fine_base + "--accel hybrid --threads 1 --hybrid-no-next-leaf-cache --json", log), 0)
      << slurp(log);
  EXPECT_EQ(json::parse(slurp(log))["per_ray"]["next_leaves_from_cache"].get<double>(), 0.0)
      << slurp(log);
  ASSERT_EQ(run_cli(base + "--accel kdtree --traversal-only --json", log), 0) << slurp(log);
  const json j = json::parse(slurp(log));
  EXPECT_TRUE(j["traversal_only"].get<bool>());
  EXPECT_EQ(j["hit_fraction"].get<double>(), 0.0);
  EXPECT_GT(j["thread_ns_per_step"].get<double>(), 0.0);
  ASSERT_EQ(run_cli(base + "--accel kdtree", log), 0) << slurp(log);
  EXPECT_EQ(slurp(log).find("traversal    alone"), std::string::npos) << slurp(log);
  EXPECT_NE(run_cli(base + "--accel embree --traversal-only", log), 0);
  EXPECT_NE(slurp(log).find("no traversal-only timing"), std::string::npos) << slurp(log);
  EXPECT_NE(
      run_cli(base + "--accel kdtree --traversal-only --hits \"" + (dir / "h.hits").string() + "\"",
              log),
      0);
  EXPECT_NE(slurp(log).find("finds no hits: drop --hits"), std::string::npos) << slurp(log);
  EXPECT_NE(
      run_cli("trace \"" + ply.string() + "\" --pixel 8,8 --res 16 --accel kdtree --traversal-only",
              log),
      0);
  EXPECT_NE(slurp(log).find("use it with --rays, not --pixel"), std::string::npos) << slurp(log);
}

// `kdgrid rays --pixel X,Y`: copies of the very primary ray that the set has for that pixel
// (the same-ray timing of the README); a pixel outside the image, another set or no copies
// are refused with the fix.
TEST(RaysCli, PixelWritesCopiesOfThatPixelsPrimaryRay) {
  TempDir dir("rays");
  const fs::path ply = dir / "sphere.ply", all = dir / "all.rays", one = dir / "one.rays",
                 log = dir / "log.txt";
  write_ascii_ply(make_icosphere(2, Vec3(0.0f), 1.0f), ply);
  const std::string base = "rays \"" + ply.string() + "\" --res 16x12 ";
  ASSERT_EQ(run_cli(base + "-o \"" + all.string() + "\"", log), 0) << slurp(log);
  ASSERT_EQ(run_cli(base + "--pixel 5,7 --count 10 -o \"" + one.string() + "\"", log), 0)
      << slurp(log);
  EXPECT_NE(slurp(log).find("wrote 10 copies of the primary ray through pixel 5,7"),
            std::string::npos)
      << slurp(log);
  const std::vector<Ray> set = read_rays(all.string()), copies = read_rays(one.string());
  ASSERT_EQ(set.size(), 16u * 12u);
  ASSERT_EQ(copies.size(), 10u);
  const Ray& want = set[7 * 16 + 5];
  for (const Ray& r : copies) {
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(r.org[a], want.org[a]);
      EXPECT_EQ(r.dir[a], want.dir[a]);
    }
    EXPECT_EQ(r.tmin, want.tmin);
    EXPECT_EQ(r.tmax, want.tmax);
  }
  EXPECT_NE(run_cli(base + "--pixel 16,0 -o \"" + one.string() + "\"", log), 0);
  EXPECT_NE(slurp(log).find("must be X,Y inside the 16x12 image"), std::string::npos) << slurp(log);
  EXPECT_NE(run_cli(base + "--set shadow --pixel 1,1 -o \"" + one.string() + "\"", log), 0);
  EXPECT_NE(slurp(log).find("--pixel repeats one primary ray"), std::string::npos) << slurp(log);
  EXPECT_NE(run_cli(base + "--pixel 1,1 --count 0 -o \"" + one.string() + "\"", log), 0);
  EXPECT_NE(slurp(log).find("--count must be at least 1"), std::string::npos) << slurp(log);
  EXPECT_NE(run_cli(base + "--pixel 1,1 --count 100000000000 -o \"" + one.string() + "\"", log), 0);
  EXPECT_NE(slurp(log).find("GiB of rays: use at most 134217728"), std::string::npos) << slurp(log);
  EXPECT_NE(run_cli(base + "--set random --count 100000000000 -o \"" + one.string() + "\"", log),
            0);
  EXPECT_NE(slurp(log).find("GiB of rays: use at most 134217728"), std::string::npos) << slurp(log);
}

TEST(ProfileCli, PrintsEveryStructureAndClass) {
  TempDir dir("profile");
  const fs::path ply = dir / "sphere.ply", log = dir / "log.txt";
  write_ascii_ply(make_icosphere(2, Vec3(0.0f), 1.0f), ply);
  const int rc = run_cli(
      "profile \"" + ply.string() + "\" --res 24 --reps 1 --accel kdtree,hybrid --reference bvh",
      log);
  ASSERT_EQ(rc, 0) << slurp(log);
  const std::string out = slurp(log);
  for (const char* s :
       {"| kdtree | all |", "| kdtree | hit |", "| hybrid | miss-box |", "| hybrid | miss-out |"})
    EXPECT_NE(out.find(s), std::string::npos) << s << "\n" << out;
  EXPECT_NE(run_cli("profile \"" + ply.string() + "\" --reps 0", log), 0);
  EXPECT_NE(slurp(log).find("--reps must be at least 1"), std::string::npos) << slurp(log);
  // A misspelt structure fails before the scene is loaded and the reference built.
  EXPECT_NE(run_cli("profile \"" + ply.string() + "\" --accel kdtree,hybird", log), 0);
  EXPECT_NE(slurp(log).find("unknown accelerator 'hybird'"), std::string::npos) << slurp(log);
  EXPECT_EQ(slurp(log).find("| structure |"), std::string::npos) << "nothing measured\n"
                                                                 << slurp(log);
}

TEST(Profile, CacheSimPassTracesEachRayOnceAndCountRaysMatchesTheCountedPass) {
  const Mesh m = make_icosphere(3, Vec3(0.0f), 1.0f);
  const auto hy = build_accelerator("hybrid", m, BuildParams{});
  Camera cam;
  cam.eye = Vec3(0.3f, 0.2f, 4.0f);
  const std::vector<Ray> rays = primary_rays(cam, 32, 32);
  uint64_t hits = 0;
  RayCounters c;
  for (const Ray& r : rays) {
    Hit h;
    hits += hy->intersect_counted(r, h, c);
  }
  ASSERT_GT(hits, 0u);
  ASSERT_LT(hits, rays.size());
  EXPECT_EQ(cache_sim_pass(*hy, rays), hits);
  EXPECT_EQ(cache_sim_pass(*hy, {}), 0u);
  ProfileFigures f;
  count_rays(*hy, rays, f);
  EXPECT_EQ(f.rays, rays.size());
  EXPECT_TRUE(f.counted);
  EXPECT_DOUBLE_EQ(f.lookups, double(c.lookups) / double(rays.size()));
  EXPECT_DOUBLE_EQ(f.tests, double(c.tri_tests) / double(rays.size()));
  ProfileFigures e;
  count_rays(*build_accelerator("embree", m, BuildParams{}), rays, e);
  EXPECT_FALSE(e.counted);  // Embree has no counters
  EXPECT_EQ(e.rays, rays.size());
}

TEST(ProfileCli, CacheSimNumbersItsPassesInCallOrder) {
  // scripts/cache-profile.sh maps callgrind's k-th profile part (one per cache_sim_pass call)
  // to the k-th line of this table, so the numbers must run 1..N over the non-empty classes.
  TempDir dir("profile-cache");
  const fs::path ply = dir / "sphere.ply", log = dir / "log.txt";
  write_ascii_ply(make_icosphere(2, Vec3(0.0f), 1.0f), ply);
  const int rc = run_cli("profile \"" + ply.string() +
                             "\" --res 24 --accel kdtree,hybrid --reference bvh --cache-sim --eye "
                             "0,0,4 --target 0,0,0 --fov 50",
                         log);
  ASSERT_EQ(rc, 0) << slurp(log);
  const std::string out = slurp(log);
  EXPECT_NE(out.find("one untimed pass per class"), std::string::npos) << out;
  EXPECT_EQ(out.find("cold ns/ray"), std::string::npos) << out;
  // This camera sees the sphere in the middle, the box around it and space beyond: every
  // class is present for both structures, in structure then class order.
  const char* expected[] = {"| 1 | kdtree | hit |",      "| 2 | kdtree | miss-box |",
                            "| 3 | kdtree | miss-out |", "| 4 | hybrid | hit |",
                            "| 5 | hybrid | miss-box |", "| 6 | hybrid | miss-out |"};
  size_t at = 0;
  for (const char* s : expected) {
    const size_t pos = out.find(s, at);
    ASSERT_NE(pos, std::string::npos) << s << "\n" << out;
    at = pos;
  }
  EXPECT_EQ(out.find("| 7 |"), std::string::npos) << out;
}

TEST(Sweep, EdgeVertexRaysAllHitAClosedMeshWithTheWatertightTest) {
  const Mesh m = make_icosphere(2);  // 320 triangles, 480 edges, 162 vertices
  const std::vector<Ray> rays = edge_vertex_rays(m, 2, 3);
  EXPECT_EQ(rays.size(), 2u * (3u * 480u + 162u));
  auto brute = build_accelerator("brute", m, BuildParams{});
  for (const Ray& r : rays) {
    Hit h;
    ASSERT_TRUE(brute->intersect(r, h)) << "watertight test leaked";
    EXPECT_NEAR(h.t, 1.0f, 1e-4f) << "the ray must stop at its target";
  }
  // The same rays with tmax = inf would be caught by the far side; with the short segment
  // they are not: a ray aimed past the sphere misses.
  Ray outside = rays[0];
  outside.dir = outside.dir + Vec3(0, 0, 5);
  Hit h;
  EXPECT_FALSE(brute->intersect(outside, h));
}

TEST(Sweep, LambdaRowsAndBothOutputs) {
  TempDir dir("sweep");
  write_ascii_ply(gridded_box(6, {0, 0, 0}, 1.0f), dir / "box.ply");
  SweepOptions o;
  o.kind = "lambda";
  o.scene = (dir / "box.ply").string();
  o.values = {1, 8};
  o.reps = 1;
  o.width = o.height = 32;
  const SweepTable t = run_sweep(o);
  ASSERT_EQ(t.rows.size(), 2u);
  auto col = [&](const std::string& c) {
    const auto it = std::find(t.columns.begin(), t.columns.end(), c);
    EXPECT_NE(it, t.columns.end()) << c;
    return size_t(it - t.columns.begin());
  };
  for (const char* c : {"lambda", "build_s", "bytes", "mrays", "steps_per_ray", "tests_per_ray"})
    col(c);
  const auto num = [&](size_t r, const std::string& c) {
    return std::get<double>(t.rows[r][col(c)]);
  };
  EXPECT_GT(num(0, "mrays"), 0.0);
  EXPECT_GT(num(1, "bytes"), num(0, "bytes")) << "a denser grid must take more memory";
  const json j = json::parse(sweep_to_json(t));
  EXPECT_EQ(j["rows"].size(), 2u);
  EXPECT_EQ(j["meta"]["kind"], "lambda");
  const std::string csv = sweep_to_csv(t);
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 3);
  EXPECT_EQ(csv.rfind("label,lambda,", 0), 0u) << csv;
}

TEST(Sweep, TriangleLeaksWatertightNever) {
  SweepOptions o;
  o.kind = "triangle";
  o.accels = {"bvh"};
  o.leak_rays_per_target = 1;
  const SweepTable t = run_sweep(o);  // no scene: the leak part only
  const size_t part =
      size_t(std::find(t.columns.begin(), t.columns.end(), "part") - t.columns.begin());
  const size_t test =
      size_t(std::find(t.columns.begin(), t.columns.end(), "test") - t.columns.begin());
  const size_t leaks =
      size_t(std::find(t.columns.begin(), t.columns.end(), "leaks") - t.columns.begin());
  ASSERT_LT(leaks, t.columns.size());
  size_t rows = 0;
  for (const auto& r : t.rows) {
    ASSERT_EQ(std::get<std::string>(r[part]), "leak");
    ++rows;
    if (std::get<std::string>(r[test]) == "watertight") {
      EXPECT_EQ(std::get<double>(r[leaks]), 0.0);
    }
  }
  EXPECT_EQ(rows, 2u * 4u * 2u * 2u) << "sphere and torus x 4 scales x {brute, bvh} x 2 tests";
}

TEST(Sweep, SppErrorFallsWithSamples) {
  SweepOptions o;
  o.kind = "spp";
  o.width = o.height = 24;
  o.spp_max = 16;
  o.spp_reference = 64;
  const SweepTable t = run_sweep(o);
  ASSERT_EQ(t.rows.size(), 5u);  // 1, 2, 4, 8, 16
  const size_t e =
      size_t(std::find(t.columns.begin(), t.columns.end(), "rmse_display") - t.columns.begin());
  ASSERT_LT(e, t.columns.size());
  const double first = std::get<double>(t.rows.front()[e]),
               last = std::get<double>(t.rows.back()[e]);
  EXPECT_GT(first, 0.0);
  EXPECT_LT(last, first) << "16 spp must be closer to the reference than 1 spp";
}

TEST(Sweep, CellsizeHasAnAutoRow) {
  const auto names = accelerator_names();
  if (std::find(names.begin(), names.end(), "hybrid") == names.end())
    GTEST_SKIP() << "hybrid is not registered in accel/factory.cpp yet";
  TempDir dir("cellsize");
  write_ascii_ply(gridded_box(6, {0, 0, 0}, 1.0f), dir / "box.ply");
  SweepOptions o;
  o.kind = "cellsize";
  o.scene = (dir / "box.ply").string();
  o.values = {0.5, 2};
  o.reps = 1;
  o.width = o.height = 32;
  const SweepTable t = run_sweep(o);
  ASSERT_EQ(t.rows.size(), 3u);
  EXPECT_EQ(std::get<std::string>(t.rows[0][0]), "auto");
  // Accuracy beside speed: every cell size judged by check's reference, none contradicting it.
  auto col = [&](const std::string& n) {
    return size_t(std::find(t.columns.begin(), t.columns.end(), n) - t.columns.begin());
  };
  for (const auto& row : t.rows) {
    EXPECT_GT(std::get<double>(row.at(col("check_rays"))), 0.0);
    EXPECT_GT(std::get<double>(row.at(col("check_agree"))), 0.0);
    EXPECT_EQ(std::get<double>(row.at(col("check_disagree"))), 0.0);
    EXPECT_EQ(std::get<double>(row.at(col("check_leaks"))), 0.0) << "a closed box, watertight";
    EXPECT_GT(std::get<double>(row.at(col("acne_rays"))), 0.0);
    EXPECT_EQ(std::get<double>(row.at(col("acne_self_hits"))), 0.0) << "the robust offset";
  }
}

TEST(Sweep, RejectsBadInput) {
  SweepOptions o;
  o.kind = "sideways";
  EXPECT_THROW(run_sweep(o), ParamError);
  o.kind = "lambda";
  EXPECT_THROW(run_sweep(o), ParamError) << "lambda needs a scene";
  o.scene = "/nonexistent/scene.ply";
  EXPECT_THROW(run_sweep(o), LoadError);
  o.values = {-1};
  EXPECT_THROW(run_sweep(o), ParamError);
}

}  // namespace
}  // namespace kdgrid
