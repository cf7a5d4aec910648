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
#include "bench_scenes.h"
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

using test::gridded_box;
using test::run_cli;
using test::slurp;
using test::write_ascii_ply;
using test::write_file;

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

/// Every structure on the small suite at 24x20, two repetitions on two threads, against
/// `reference` (brute force by default: it is among the structures).
/// The small suite (write_small_suite) written to `dir` and loaded.
Suite small_suite(const TempDir& dir) {
  return load_suite(write_small_suite(dir).string());
}

BenchOptions small_options(const std::string& reference = "brute") {
  BenchOptions o;
  o.accels = accelerator_names();
  o.reference = reference;
  o.width = 24;
  o.height = 20;
  o.reps = 2;
  o.threads = 2;
  return o;
}

/// Calls `f(scene, structure, set)` for each ray set of each structure of each scene of `rep`.
template <class F>
void for_each_set(const BenchReport& rep, F f) {
  for (const auto& s : rep.scenes)
    for (const auto& a : s.structures)
      for (const auto& x : a.sets) f(s, a, x);
}

TEST(Bench, SmallSuiteHasEveryFieldForEveryStructureAndSet) {
  TempDir dir("small");
  const Suite suite = small_suite(dir);
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
  const Suite suite = small_suite(dir);
  BenchOptions o = small_options("embree");
  o.packet_tile = 4;
  const BenchReport rep = run_bench(suite, o);
  EXPECT_FALSE(rep.any_failed());
  EXPECT_EQ(rep.packet_tile, 4);
  int rows = 0;
  for_each_set(rep, [&](const SceneFigures& s, const StructureFigures& a, const SetFigures& x) {
    const std::string where = s.name + " " + a.accel + " " + x.set;
    if (x.set == "diffuse") {  // incoherent: no packet column
      EXPECT_EQ(x.packet_rays, 0) << where;
      return;
    }
    ++rows;
    EXPECT_EQ(x.packet_rays, 16) << where;
    // Embree's native packets; the hybrid's packet walk (four packets of 16 lanes, or of 8 with
    // AVX2) where the build has it; the other structures loop over single rays.
    const int own = a.accel == "hybrid" && hybrid::kPacketLanes != 0 ? 4 * hybrid::kPacketLanes : 1;
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
  });
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
  for_each_set(none, [](const SceneFigures&, const StructureFigures&, const SetFigures& x) {
    EXPECT_EQ(x.packet_rays, 0);
  });
  EXPECT_EQ(bench_to_markdown(none).find("### Packets"), std::string::npos);
}

TEST(Bench, ExactStructuresAgreeWithEmbree) {
  const auto names = accelerator_names();
  if (std::find(names.begin(), names.end(), "embree") == names.end())
    GTEST_SKIP() << "embree is not registered in accel/factory.cpp yet";
  TempDir dir("embree");
  const Suite suite = small_suite(dir);
  BenchOptions o = small_options("embree");
  o.reps = 1;
  const BenchReport rep = run_bench(suite, o);
  for_each_set(rep, [](const SceneFigures& s, const StructureFigures& a, const SetFigures& x) {
    if (!is_embree(a.accel)) {
      EXPECT_GE(x.agreement, 0.999) << s.name << " " << a.accel << " " << x.set;
    }
  });
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
  const Suite suite = small_suite(dir);
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
  const BenchReport rep = run_bench(small_suite(dir), o);
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
  o = BenchOptions{};
  o.params.embree_isa = "avx3";
  EXPECT_THROW(run_bench(s, o), ParamError);
  for (const int tile : {-1, kMaxPacketTile + 1}) {
    o = BenchOptions{};
    o.packet_tile = tile;
    EXPECT_THROW(run_bench(s, o), ParamError) << tile;
  }
}

TEST(Bench, RaysDirWritesThenReadsTheSameRays) {
  TempDir dir("raysdir");
  const Suite suite = small_suite(dir);
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

// --embree-isa restricts Embree's kernels (rtcNewDevice "isa="): the report names the ISA it
// ran and the restriction, and Embree's packets are that ISA's; a name Embree does not take is
// refused with the names it does, exit 1.
TEST(BenchCli, EmbreeIsaRestrictsEmbreeAndIsReported) {
  TempDir dir("cliisa");
  const fs::path log = dir / "log.txt";
  EXPECT_EQ(run_cli("bench --accel embree --suite nosuch.json --embree-isa avx3", log), 1);
  EXPECT_NE(slurp(log).find("'avx3' is not an ISA Embree can be restricted to: use sse4.2, avx, "
                            "avx2, avx512 or native"),
            std::string::npos)
      << slurp(log);
  if (!__builtin_cpu_supports("avx2")) GTEST_SKIP() << "this CPU runs no AVX2";
  BenchOptions o = small_options("embree");
  o.accels = {"embree"};
  o.sets = {"primary"};
  o.reps = 1;
  o.params.embree_isa = "avx2";
  const BenchReport rep = run_bench(small_suite(dir), o);
  ASSERT_FALSE(rep.any_failed());
  int packet_rows = 0;
  for_each_set(rep, [&](const SceneFigures&, const StructureFigures&, const SetFigures& x) {
    packet_rows += x.packet_rays > 0;
    if (x.packet_rays > 0) {
      EXPECT_EQ(x.packet_width, 8) << "rtcIntersect8, AVX2's packets";
    }
  });
  EXPECT_GT(packet_rows, 0);
  const json j = json::parse(bench_to_json(rep));
  const json& e = j["meta"]["simd"]["embree"];
  EXPECT_EQ(e["isa"], "AVX2");
  EXPECT_EQ(e["restricted_to"], "avx2");
  EXPECT_EQ(e["native_packet"], 8);
  ASSERT_FALSE(j["builds"].empty());
  for (const auto& b : j["builds"]) EXPECT_EQ(b["extra"]["isa"], "AVX2");
  EXPECT_NE(
      bench_to_markdown(rep).find("with its AVX2 kernels (restricted with --embree-isa avx2)"),
      std::string::npos)
      << bench_to_markdown(rep);
}

}  // namespace
}  // namespace kdgrid
