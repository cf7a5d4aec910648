// Outputs and resource knobs under hostile use: a failed write to standard output fails the
// run, suite scene names stay names (never paths) and never share a ray file, output names up
// to the file system's limit are written and longer ones refused before any work, and
// --threads and sample counts have limits checked before any work.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "accel/params.h"
#include "bench/bench.h"
#include "bench/suite.h"
#include "bench/sweep.h"
#include "cli_util.h"
#include "render/renderer.h"
#include "temp_dir.h"
#include "test_util.h"
#include "util/atomic_file.h"
#include "util/error.h"

namespace kdgrid::test {
namespace {

namespace fs = std::filesystem;

/// The message of the kdgrid::Error `f` throws (a failure if it throws none).
std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  ADD_FAILURE() << "no error";
  return "";
}

bool have_dev_full() {
  return fs::exists("/dev/full");
}

// ---------------------------------------------------------------------------------------
// Standard output

TEST(HostileOutputs, FailedWritesToStandardOutputFailTheRun) {
  if (!have_dev_full()) GTEST_SKIP() << "no /dev/full on this system";
  // One check at exit covers every command; a JSON report, a traversal print-out and a bench
  // table, each of which succeeds with a writable standard output.
  for (const std::string& args : std::vector<std::string>{
           "info gen:sphere --json", "trace gen:sphere --pixel 4,4 --res 8",
           "bench gen:sphere --res 4 --reps 1 --accel bvh --reference bvh --sets primary"}) {
    const CliResult r = run_cli_stdout_to(args, "/dev/full");
    EXPECT_EQ(r.code, 1) << args << ": " << r.output;
    EXPECT_CONTAINS(r.output, "writing to standard output failed (no space left on the device)");
  }
}

// ---------------------------------------------------------------------------------------
// Suite scene names

TEST(HostileOutputs, SuiteNamesThatArePathsOrRepeatedAreRefusedNamingTheEntry) {
  const Suite s = parse_suite(R"({"scenes": [
      {"name": "../../x", "file": "a.ply"},
      {"name": "/abs/path", "file": "a.ply"},
      {"name": "..", "file": "a.ply"},
      {"name": "tab\there", "file": "a.ply"},
      {"name": "ok", "file": "a.ply"},
      {"name": "ok", "file": "b.ply"},
      {"file": "c/ok.ply"},
      {"name": "", "file": "d/fine.ply"}]})",
                              "/base", "suite.json");
  ASSERT_EQ(s.scenes.size(), 8u);
  for (size_t i = 0; i < 4; ++i) {
    EXPECT_CONTAINS(s.scenes[i].error, "suite.json: scene " + std::to_string(i));
    EXPECT_CONTAINS(s.scenes[i].error, "plain name");
  }
  EXPECT_CONTAINS(s.scenes[0].error, "path separator '/'");
  EXPECT_CONTAINS(s.scenes[2].error, "folder reference");
  EXPECT_CONTAINS(s.scenes[3].error, "control character");
  EXPECT_CONTAINS(s.scenes[3].error, "tab\\x09here");  // printed escaped, not as a tab
  EXPECT_EQ(s.scenes[4].error, "");
  // The second and third "ok" (one named after its file) repeat the first.
  for (size_t i : {5, 6}) {
    EXPECT_CONTAINS(s.scenes[i].error, "suite.json: scene " + std::to_string(i));
    EXPECT_CONTAINS(s.scenes[i].error, "scene 4 has the same name");
  }
  // An empty name is the file's stem.
  EXPECT_EQ(s.scenes[7].name, "fine");
  EXPECT_EQ(s.scenes[7].error, "");
  EXPECT_NE(suite_name_problem(""), "");
  EXPECT_NE(suite_name_problem(std::string(kMaxSuiteNameBytes + 1, 'a')), "");
}

TEST(HostileOutputs, BenchWritesNoRayFileOutsideRaysDir) {
  TempDir tmp;
  const std::string mesh =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty "
      "float y\nproperty float z\nelement face 1\nproperty list uchar int "
      "vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  tmp.write("s/tri.ply", mesh);
  const std::string outside = tmp.file("outside");
  tmp.write("s/suite.json", R"({"scenes": [{"name": "../../outside", "file": "tri.ply"},
                                            {"name": ")" +
                                outside + R"(", "file": "tri.ply"},
                                            {"name": "tri", "file": "tri.ply"},
                                            {"name": "tri", "file": "tri.ply"}]})");
  const CliResult r = run_cli("bench --suite '" + tmp.file("s/suite.json") + "' --rays-dir '" +
                              tmp.file("s/rays/deep") +
                              "' --res 4 --reps 1 --accel bvh --reference bvh --sets primary -q");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_CONTAINS(r.output, "3 scene(s)/structure(s) failed");
  // The one usable scene wrote its own rays; nothing was written beside or above the folder.
  EXPECT_TRUE(fs::exists(tmp.file("s/rays/deep/tri.primary.rays")));
  size_t files = 0;
  for (const auto& e : fs::recursive_directory_iterator(tmp.path()))
    if (e.path().extension() == ".rays") ++files;
  EXPECT_EQ(files, 1u);
}

TEST(HostileOutputs, BenchRefusesTwoSceneFilesOfOneNameBeforeAnyWork) {
  Suite suite = single_scene_suite("/no/such/a/s.ply");
  suite.scenes.push_back(single_scene_suite("/no/such/b/s.ply").scenes[0]);
  BenchOptions o;
  o.width = o.height = 4;
  try {
    run_bench(suite, o);  // no scene is loaded: they do not exist
    ADD_FAILURE() << "two scenes named 's' were accepted";
  } catch (const ParamError& e) {
    EXPECT_CONTAINS(e.what(), "two scenes are named 's' (/no/such/a/s.ply and /no/such/b/s.ply)");
  }
}

// ---------------------------------------------------------------------------------------
// Output names at the file system's limit

TEST(HostileOutputs, AtomicFileWritesNamesUpToTheLongestAFileSystemTakes) {
  TempDir tmp;
  for (size_t bytes : {241u, 250u, 255u}) {
    // A UTF-8 name (two bytes a letter) ending in a long extension: the temporary's name is
    // shortened without cutting a letter in two.
    std::string name;
    while (name.size() + 2 + 5 <= bytes) name += "\xC3\xA9";  // é
    name += std::string(bytes - 5 - name.size(), 'x') + ".json";
    ASSERT_EQ(name.size(), bytes);
    write_file_atomically(tmp.file(name), "{}");
    EXPECT_TRUE(fs::exists(tmp.file(name))) << bytes;
    EXPECT_TRUE(tmp.hidden().empty()) << bytes;
  }
}

TEST(HostileOutputs, LongOutputNamesAreWrittenAndTooLongOnesRefusedBeforeTheRender) {
  TempDir tmp;
  const std::string fits = tmp.file(std::string(251, 'a') + ".png");  // 255 bytes
  const CliResult r = run_cli("render gen:sphere --res 8 --spp 1 -o '" + fits + "'");
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_TRUE(fs::exists(fits));
  EXPECT_TRUE(tmp.hidden().empty());
  // One byte more: refused by the check every command makes before its work.
  const std::string too_long = tmp.file(std::string(252, 'a') + ".png");
  try {
    check_output_path(too_long, "-o", {".png"});
    ADD_FAILURE() << "a 256-byte file name was accepted";
  } catch (const ParamError& e) {
    EXPECT_CONTAINS(e.what(), "the file name is 256 bytes long");
    EXPECT_CONTAINS(e.what(), "choose a shorter name");
  }
  EXPECT_TRUE(tmp.hidden().empty()) << "the check left its probe behind";
}

// ---------------------------------------------------------------------------------------
// Resource knobs

TEST(HostileOutputs, ThreadCountsPastTheLimitAreRefusedBeforeAnyWork) {
  EXPECT_NO_THROW(check_threads(0));
  EXPECT_NO_THROW(check_threads(kMaxThreads));
  EXPECT_THROW(check_threads(kMaxThreads + 1), ParamError);
  EXPECT_THROW(check_threads(-1), ParamError);
  const std::string too_many = std::to_string(kMaxThreads + 1);
  const std::string says = "--threads " + too_many + " is out of range";
  // The bench and the sweeps refuse before loading anything (the scenes do not exist).
  BenchOptions b;
  b.threads = kMaxThreads + 1;
  EXPECT_CONTAINS(error_of([&] { run_bench(single_scene_suite("/no/such.ply"), b); }), says);
  SweepOptions sw;
  sw.kind = "lambda";
  sw.scene = "/no/such.ply";
  sw.threads = kMaxThreads + 1;
  EXPECT_CONTAINS(error_of([&] { run_sweep(sw); }), says);
  TempDir tmp;
  const std::string png = tmp.file("never-written.png");
  const CliResult r =
      run_cli("render gen:sphere --res 8 --spp 1 --threads " + too_many + " -o '" + png + "'");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_CONTAINS(r.output, says + ": give 0 (all");
  EXPECT_CONTAINS(r.output, "up to " + std::to_string(kMaxThreads));
  EXPECT_FALSE(fs::exists(png));
}

TEST(HostileOutputs, SampleCountsPastTheLimitAreRefusedBeforeAnyWork) {
  const std::string most = std::to_string(kMaxSamplesPerPixel);
  const auto sweep_error = [](int spp_max, int spp_reference, std::vector<double> values) {
    SweepOptions o;
    o.kind = "spp";
    o.scene = "/no/such.ply";  // never loaded: the counts are refused first
    o.spp_max = spp_max;
    o.spp_reference = spp_reference;
    o.values = std::move(values);
    return error_of([&] { run_sweep(o); });
  };
  // 2^30 and above overflowed the doubling loop, whose list of counts then grew without end.
  EXPECT_CONTAINS(sweep_error(1073741824, 16, {}),
                  "--spp-max 1073741824 must be between 1 and " + most);
  EXPECT_CONTAINS(sweep_error(2147483647, 16, {}), "--spp-max 2147483647");
  EXPECT_CONTAINS(sweep_error(kMaxSamplesPerPixel + 1, 16, {}), "--spp-max");
  EXPECT_CONTAINS(sweep_error(64, kMaxSamplesPerPixel + 1, {}), "--spp-reference");
  EXPECT_CONTAINS(sweep_error(64, 16, {1, 1e12}), "--values: 1e+12 is not a sample count");
  EXPECT_CONTAINS(sweep_error(64, 16, {1.5}), "--values: 1.5 is not a sample count");
  // kMaxSamplesPerPixel itself is a valid count: the sweep goes on to load the scene.
  EXPECT_CONTAINS(sweep_error(kMaxSamplesPerPixel, 16, {}), "/no/such.ply");
  TempDir tmp;
  const CliResult r = run_cli("render gen:sphere --spp " + std::to_string(kMaxSamplesPerPixel + 1) +
                              " -o '" + tmp.file("never-written.png") + "'");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_CONTAINS(r.output, "samples per pixel must be between 1 and " + most);
}

}  // namespace
}  // namespace kdgrid::test
