// Hostile files and failing disks: every output is replaced whole or not at all (a full disk
// simulated with `ulimit -f`, a signal during the write), outputs that would destroy an input
// or do not match their extension are refused before any work, inputs are regular files of
// bounded size, and the loaders refuse malformed numbers, huge expansions and paths outside
// the scene's folder with messages that name the place and the fix.
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

#include "png_bytes.h"
#include "scene/load.h"
#include "temp_dir.h"
#include "test_util.h"
#include "util/atomic_file.h"
#include "util/error.h"
#include "util/input_file.h"
#include "util/memory.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;
using test::load_error;
using test::png_header_only;
using test::TempDir;

std::string read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

struct CliResult {
  int exit_code = -1;
  std::string out, err;
};

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kAddressSanitizer = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
constexpr bool kAddressSanitizer = true;
#else
constexpr bool kAddressSanitizer = false;
#endif
#else
constexpr bool kAddressSanitizer = false;
#endif

/// `prefix` without its `ulimit -v N;` under AddressSanitizer, which reserves terabytes of
/// address space for its shadow memory and cannot start under such a limit. The tests that
/// use it as a safety net (a reader that would grow without bound) still run; those that need
/// it to set the memory budget or to make a build run out of memory skip.
std::string without_address_limit(std::string prefix) {
  if (!kAddressSanitizer) return prefix;
  for (size_t at; (at = prefix.find("ulimit -v ")) != std::string::npos;) {
    const size_t end = prefix.find(';', at);
    prefix.erase(at, end == std::string::npos ? std::string::npos : end + 1 - at);
  }
  return prefix;
}

/// Runs the CLI through bash, after `prefix` (e.g. "ulimit -f 4;") in the same shell.
CliResult run_cli(const std::string& args, const TempDir& tmp, const std::string& prefix = "") {
  const std::string out = tmp.file("stdout.txt"), err = tmp.file("stderr.txt");
  const std::string script = without_address_limit(prefix) + " \"" + std::string(KDGRID_CLI_PATH) +
                             "\" " + args + " >\"" + out + "\" 2>\"" + err + "\"";
  std::string quoted;
  for (char c : script) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
  const int status = std::system(("bash -c '" + quoted + "'").c_str());
  CliResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = read_all(out);
  r.err = read_all(err);
  fs::remove(out);
  fs::remove(err);
  return r;
}

// A file-size limit of 4 KiB, with SIGXFSZ ignored as a full disk would give ENOSPC.
const std::string kFullDisk = "trap \"\" XFSZ; ulimit -f 4;";

// ---------------------------------------------------------------------------------------
// Outputs: atomic replacement

TEST(HostileFiles, FullDiskKeepsTheOldPngAndFails) {
  TempDir tmp;
  const std::string png = tmp.file("keep.png");
  ASSERT_EQ(run_cli("render gen:sphere -o \"" + png + "\" --res 32 --spp 1", tmp).exit_code, 0);
  const std::string before = read_all(png);
  ASSERT_GT(before.size(), 0u);
  const CliResult r =
      run_cli("render gen:sphere -o \"" + png + "\" --res 400 --spp 1", tmp, kFullDisk);
  EXPECT_NE(r.exit_code, 0) << r.out << r.err;
  EXPECT_CONTAINS(r.err, "keep.png");
  EXPECT_CONTAINS(r.err, "ulimit -f");
  EXPECT_EQ(read_all(png), before) << "the old image was replaced";
  EXPECT_TRUE(tmp.hidden().empty()) << "a temporary was left: " << tmp.hidden()[0];
}

TEST(HostileFiles, FullDiskKeepsTheOldSceneForEveryGenFormat) {
  TempDir tmp;
  for (const std::string ext : {".gltf", ".glb", ".ply", ".obj"}) {
    const std::string out = tmp.file("keep" + ext);
    ASSERT_EQ(run_cli("gen soup --triangles 10 -o \"" + out + "\"", tmp).exit_code, 0) << ext;
    const std::string before = read_all(out);
    const CliResult r = run_cli("gen soup --triangles 20000 -o \"" + out + "\"", tmp, kFullDisk);
    EXPECT_NE(r.exit_code, 0) << ext << ": " << r.out;
    EXPECT_CONTAINS(r.err, "the file was not changed");
    EXPECT_EQ(read_all(out), before) << ext << ": the old file was replaced";
    EXPECT_TRUE(tmp.hidden().empty()) << ext;
  }
  // And a .glb written without a limit is a binary glTF that loads.
  const std::string glb = tmp.file("ok.glb");
  ASSERT_EQ(run_cli("gen soup --triangles 10 -o \"" + glb + "\"", tmp).exit_code, 0);
  EXPECT_EQ(read_all(glb).substr(0, 4), "glTF");
  EXPECT_EQ(load_scene(glb).mesh.num_triangles(), 10u);
}

TEST(HostileFiles, FullDiskKeepsOldRaysAndHits) {
  TempDir tmp;
  const std::string rays = tmp.file("keep.rays"), hits = tmp.file("keep.hits");
  ASSERT_EQ(run_cli("rays gen:sphere --res 8 -o \"" + rays + "\"", tmp).exit_code, 0);
  ASSERT_EQ(
      run_cli("trace gen:sphere --repeat 1 --rays \"" + rays + "\" --hits \"" + hits + "\"", tmp)
          .exit_code,
      0);
  const std::string rays_before = read_all(rays), hits_before = read_all(hits);
  CliResult r = run_cli("rays gen:sphere --res 64 -o \"" + rays + "\"", tmp, kFullDisk);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(read_all(rays), rays_before);
  const std::string big = tmp.file("big.rays");
  ASSERT_EQ(run_cli("rays gen:sphere --res 64 -o \"" + big + "\"", tmp).exit_code, 0);
  r = run_cli("trace gen:sphere --repeat 1 --rays \"" + big + "\" --hits \"" + hits + "\"", tmp,
              kFullDisk);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(read_all(hits), hits_before);
  EXPECT_TRUE(tmp.hidden().empty());
}

TEST(HostileFiles, AtomicFileLeavesNothingWhenKilledBySignal) {
  TempDir tmp;
  const std::string target = tmp.file("sig.bin");
  for (int sig : {SIGINT, SIGTERM}) {
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      AtomicFile f(target);
      f.write(std::string(3 << 20, 'x'));  // past the buffer: the temporary exists on disk
      ::raise(sig);
      ::_exit(0);  // not reached: the signal kills the process
    }
    int status = 0;
    ASSERT_EQ(::waitpid(pid, &status, 0), pid);
    EXPECT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == sig) << "signal " << sig;
    EXPECT_TRUE(tmp.hidden().empty()) << "signal " << sig << " left " << tmp.hidden()[0];
    EXPECT_FALSE(fs::exists(target));
  }
}

TEST(HostileFiles, AtomicFileReplacesWholeOrNotAtAll) {
  TempDir tmp;
  const std::string p = tmp.write("a.txt", "old");
  {
    AtomicFile f(p);
    f.write("new contents");
    // Not committed: the destructor removes the temporary, the old file stays.
  }
  EXPECT_EQ(read_all(p), "old");
  EXPECT_TRUE(tmp.hidden().empty());
  write_file_atomically(p, "new");
  EXPECT_EQ(read_all(p), "new");
  EXPECT_THROW(write_file_atomically(tmp.file("no/such/dir/x.txt"), "x"), Error);
}

// ---------------------------------------------------------------------------------------
// Outputs: checked before the work

TEST(HostileFiles, OutputThatIsAnInputIsRefused) {
  TempDir tmp;
  const std::string rays = tmp.file("same.rays");
  ASSERT_EQ(run_cli("rays gen:sphere --res 8 -o \"" + rays + "\"", tmp).exit_code, 0);
  const std::string before = read_all(rays);
  // The same file under the right extension (a link) is caught by equivalence...
  fs::create_symlink(rays, tmp.file("alias.hits"));
  CliResult r = run_cli("trace gen:sphere --repeat 1 --rays \"" + rays + "\" --hits \"" +
                            tmp.file("alias.hits") + "\"",
                        tmp);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_CONTAINS(r.err, "same file as the input");
  // ... and under the wrong one by the extension check.
  r = run_cli("trace gen:sphere --repeat 1 --rays \"" + rays + "\" --hits \"" + rays + "\"", tmp);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_CONTAINS(r.err, "does not match what is written");
  EXPECT_EQ(read_all(rays), before);

  const std::string ply = tmp.file("scene.ply");
  ASSERT_EQ(run_cli("gen sphere --level 1 -o \"" + ply + "\"", tmp).exit_code, 0);
  const std::string scene_before = read_all(ply);
  r = run_cli("rays \"" + ply + "\" --res 8 -o \"" + ply + "\"", tmp);
  EXPECT_NE(r.exit_code, 0);
  fs::create_symlink(ply, tmp.file("scene.rays"));
  r = run_cli("rays \"" + ply + "\" --res 8 -o \"" + tmp.file("scene.rays") + "\"", tmp);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_CONTAINS(r.err, "same file as the input");
  r = run_cli("render \"" + ply + "\" --res 8 --spp 1 -o \"" + tmp.file("x.png") +
                  "\" --stats-json \"" + ply + "\"",
              tmp);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(read_all(ply), scene_before);
}

TEST(HostileFiles, OutputDirectoryIsRefusedBeforeRendering) {
  TempDir tmp;
  fs::create_directories(tmp.file("out.png"));
  // brute force at this size would take minutes: the refusal must come first.
  const CliResult r = run_cli(
      "render gen:sphere --accel brute --brute-work-limit 0 --res 4096 "
      "--spp 1 -o \"" +
          tmp.file("out.png") + "\"",
      tmp, "ulimit -t 20;");
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_CONTAINS(r.err, "is a directory");
  const CliResult g = run_cli("gen sphere -o \"" + tmp.file("out.png") + "\"", tmp);
  EXPECT_NE(g.exit_code, 0);
  EXPECT_CONTAINS(g.err, "is a directory");
}

TEST(HostileFiles, SweepAndBenchOutputsAreCheckedBeforeRunning) {
  TempDir tmp;
  fs::create_directories(tmp.file("s.csv"));
  CliResult r = run_cli("sweep spp --spp-max 64 --res 64 -q -o \"" + tmp.file("s") + "\"", tmp,
                        "ulimit -t 20;");
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_CONTAINS(r.err, "is a directory");
  fs::create_directories(tmp.file("b.json"));
  r = run_cli("bench gen:sphere --accel bvh -q --json \"" + tmp.file("b.json") + "\"", tmp,
              "ulimit -t 20;");
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_CONTAINS(r.err, "is a directory");
}

TEST(HostileFiles, BadRaysPathIsReportedBeforeTheBuild) {
  TempDir tmp;
  fs::create_directories(tmp.file("dir.rays"));
  CliResult r = run_cli("trace gen:sphere --rays \"" + tmp.file("dir.rays") + "\"", tmp);
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_CONTAINS(r.err, "is a directory");
  EXPECT_EQ(r.err.find("bad_alloc"), std::string::npos);
  // A missing file with a scene that takes long to build: refused before the build.
  r = run_cli("trace gen:landscape:4000000 --accel hybrid --rays \"" + tmp.file("none.rays") + "\"",
              tmp, "ulimit -t 3;");
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_CONTAINS(r.err, "none.rays");
}

// ---------------------------------------------------------------------------------------
// Flags

TEST(HostileFiles, CheckRefusesNegativeThreadsAndAcneRays) {
  TempDir tmp;
  CliResult r = run_cli("check --threads -1 --rays 1 --accel bvh", tmp);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_CONTAINS(r.err, "--threads");
  r = run_cli("check --acne --acne-rays -5 --rays 1 --accel bvh", tmp);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_CONTAINS(r.err, "--acne-rays");
}

TEST(HostileFiles, MemoryBudgetThatWouldOverflowIsRefused) {
  TempDir tmp;
  const CliResult r = run_cli("render gen:sphere --res 8 --spp 1 -o \"" + tmp.file("x.png") +
                                  "\" --memory-budget-mb 17592186044417",
                              tmp);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_CONTAINS(r.err, "--memory-budget-mb 17592186044417 is too large");
}

TEST(HostileFiles, BuildRunningOutOfMemorySaysSoWithTheBudget) {
  if (kAddressSanitizer)
    GTEST_SKIP() << "needs ulimit -v, under which AddressSanitizer cannot start";
  TempDir tmp;
  // A budget far above what ulimit -v leaves: the estimate passes, the allocations fail (on
  // the machine this was written on, 600 MB leave the hybrid build of 500000 triangles short).
  const CliResult r = run_cli(
      "render gen:landscape:500000 --accel hybrid --memory-budget-mb "
      "100000 --res 8 --spp 1 -o \"" +
          tmp.file("m.png") + "\"",
      tmp, "ulimit -v 600000;");
  EXPECT_EQ(r.err.find("internal error"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("bad_alloc"), std::string::npos) << r.err;
  if (r.exit_code != 0) {
    EXPECT_EQ(r.exit_code, 1) << r.err;
    EXPECT_CONTAINS(r.err, "ran out of memory");
    EXPECT_CONTAINS(r.err, "available to");
  }
}

TEST(HostileFiles, DefaultMemoryBudgetHonoursUlimit) {
  // In a child (the limit cannot be raised again): with ulimit -v at 3 GiB the default budget
  // is at most half of it, whatever the machine's physical memory.
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    struct rlimit r {};
    ::getrlimit(RLIMIT_AS, &r);
    r.rlim_cur = rlim_t(3) << 30;
    if (::setrlimit(RLIMIT_AS, &r) != 0) ::_exit(3);
    ::_exit(default_memory_budget_bytes() <= (uint64_t(3) << 30) / 2 ? 0 : 1);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0) << "the default budget ignores ulimit -v";
}

TEST(HostileFiles, ZeroSizeSceneDoesNotBlameFlagsThatWereNotGiven) {
  TempDir tmp;
  const std::string ply = tmp.write(
      "point.ply",
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
      "1 1 1\n1 1 1\n1 1 1\n3 0 1 2\n");
  const CliResult r =
      run_cli("render \"" + ply + "\" --res 8 --spp 1 -o \"" + tmp.file("p.png") + "\"", tmp);
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_EQ(r.err.find("--eye and --target are the same point"), std::string::npos) << r.err;
  EXPECT_CONTAINS(r.err, "zero size");
}

// ---------------------------------------------------------------------------------------
// Inputs: regular files of bounded size

TEST(HostileFiles, FifoAndDevicesAreRefusedAsScenes) {
  TempDir tmp;
  const std::string fifo = tmp.file("fifo.ply");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  // Run through the CLI with a CPU/time bound: before the check the FIFO blocked forever.
  CliResult r = run_cli("info \"" + fifo + "\"", tmp, "ulimit -t 10;");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_CONTAINS(r.err, "is not a regular file");
  fs::create_symlink("/dev/zero", tmp.file("zero.obj"));
  EXPECT_CONTAINS(load_error([&] { load_scene(tmp.file("zero.obj")); }), "not a regular file");
  fs::create_symlink("/dev/zero", tmp.file("zero.rays"));
  r = run_cli("trace gen:sphere --rays \"" + tmp.file("zero.rays") + "\"", tmp, "ulimit -t 10;");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_CONTAINS(r.err, "not a regular file");
  EXPECT_CONTAINS(load_error([] { check_input_file("/etc/hostname", "", 1); }),
                  "larger than the input file limit");
}

TEST(HostileFiles, ObjMaterialLibraryAndTextureOnDevicesAreWarnings) {
  TempDir tmp;
  fs::create_symlink("/dev/zero", tmp.file("zero.mtl"));
  fs::create_symlink("/dev/zero", tmp.file("zero.png"));
  tmp.write("t.mtl", "newmtl a\nKd 1 1 1\nmap_Kd zero.png\n");
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  const std::string a = tmp.write("a.obj", "mtllib zero.mtl\n" + tri + "f 1 2 3\n");
  const std::string b = tmp.write("b.obj", "mtllib t.mtl\n" + tri + "usemtl a\nf 1 2 3\n");
  CliResult r = run_cli("info \"" + a + "\"", tmp, "ulimit -t 10; ulimit -v 4000000;");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_CONTAINS(r.err, "zero.mtl (material library): is not a regular file");
  r = run_cli("info \"" + b + "\"", tmp, "ulimit -t 10; ulimit -v 4000000;");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_CONTAINS(r.err, "zero.png (texture): is not a regular file");
}

TEST(HostileFiles, HugeTextureIsRefusedFromItsHeaderBeforeDecoding) {
  if (kAddressSanitizer)
    GTEST_SKIP()
        << "its memory budget comes from ulimit -v, under which AddressSanitizer cannot start";
  TempDir tmp;
  tmp.write("big.png", png_header_only(40000, 40000));
  tmp.write("t.mtl", "newmtl a\nKd 1 1 1\nmap_Kd big.png\n");
  const std::string obj = tmp.write(
      "a.obj", "mtllib t.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nusemtl a\nf 1/1 2/1 3/1\n");
  // Under a 4 GB address-space limit the budget is 2 GB: 40000^2 pixels need 11 GB.
  const CliResult r = run_cli("info \"" + obj + "\"", tmp, "ulimit -v 4000000;");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_CONTAINS(r.err, "40000x40000 pixels would take");
  EXPECT_CONTAINS(r.err, "above the memory budget");
}

// ---------------------------------------------------------------------------------------
// OBJ numbers and indices

TEST(HostileFiles, ObjNonNumbersAndHugeIndicesAreRefusedWithTheLine) {
  TempDir tmp;
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  auto err = [&](const std::string& text) {
    const std::string p = tmp.write("x.obj", text);
    return load_error([&] { load_scene(p); });
  };
  std::string e = err("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  EXPECT_CONTAINS(e, "line 1");
  EXPECT_CONTAINS(e, "'nan' is not a finite number");
  EXPECT_CONTAINS(err("v 0 0 0\nv abc def ghi\nv 0 1 0\nf 1 2 3\n"), "line 2: vertex");
  EXPECT_CONTAINS(err(tri + "vn 0 0 inf\nf 1//1 2//1 3//1\n"), "'inf' is not a finite number");
  e = err(tri + "f 1 2 99999999999999999999\n");
  EXPECT_CONTAINS(e, "line 4");
  EXPECT_CONTAINS(e, "'99999999999999999999' is not a whole number");
  e = err(tri + "v 1 1 0\nf -1 -2 -5\n");
  EXPECT_CONTAINS(e, "line 5");
  EXPECT_CONTAINS(e, "index -5 counts back past the first vertex: only 4 are defined");
  EXPECT_CONTAINS(err(tri + "f 1 2 0\n"), "index 0");
  e = err(tri + "\nf 1 2 7\n");
  EXPECT_CONTAINS(e, "line 5: face references vertex 7 but the file has 3 vertices");
  // Valid relative indices still load.
  const std::string ok = tmp.write("ok.obj", tri + "f -3 -2 -1\n");
  EXPECT_EQ(load_scene(ok).mesh.num_triangles(), 1u);
}

// ---------------------------------------------------------------------------------------
// PLY messages

TEST(HostileFiles, PlyLineEndingsNulBytesAndMissingEndHeader) {
  TempDir tmp;
  const std::string body =
      "ply|format ascii 1.0|element vertex 3|property float x|property float y|property float z|"
      "element face 1|property list uchar int vertex_indices|end_header|0 0 0|1 0 0|0 1 0|3 0 1 2|";
  for (const std::string eol : {"\r", "\r\n"}) {
    std::string text;
    for (char c : body) text += c == '|' ? eol : std::string(1, c);
    const std::string p = tmp.write("cr.ply", text);
    EXPECT_EQ(load_scene(p).mesh.num_triangles(), 1u) << (eol == "\r" ? "CR" : "CRLF");
  }
  const std::string noend =
      tmp.write("noend.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n0\n");
  EXPECT_CONTAINS(load_error([&] { load_scene(noend); }), "no 'end_header' line came before it");
  static const char kNulPly[] =
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty fl\0at x\nend_header\n0\n";
  const std::string nul = tmp.write("nul.ply", std::string(kNulPly, sizeof kNulPly - 1));
  const std::string e = load_error([&] { load_scene(nul); });
  EXPECT_CONTAINS(e, "fl\\x00at");
  EXPECT_EQ(e.size(), std::strlen(e.c_str())) << "a NUL byte cuts the message";
}

// ---------------------------------------------------------------------------------------
// glTF

/// A glTF with one triangle in tri.bin (written beside it) and the given nodes.
std::string gltf_text(const std::string& nodes, const std::string& buffer_uri = "tri.bin",
                      const std::string& extra = "") {
  return R"({"asset":{"version":"2.0"},"buffers":[{"uri":")" + buffer_uri +
         R"(","byteLength":36}],"bufferViews":[{"buffer":0,"byteLength":36}],)"
         R"("accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",)"
         R"("min":[0,0,0],"max":[1,1,0]}],"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],)"
         R"("nodes":)" +
         nodes + R"(,"scenes":[{"nodes":[0]}],"scene":0)" + extra + "}";
}

std::string triangle_bin() {
  const float v[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
  return std::string(reinterpret_cast<const char*>(v), sizeof v);
}

TEST(HostileFiles, GltfUriOutsideTheSceneFolderIsNotRead) {
  TempDir tmp;
  fs::create_directories(tmp.file("scene"));
  tmp.write("outside.bin", triangle_bin());
  tmp.write("scene/tri.bin", triangle_bin());
  const std::string ok = tmp.write("scene/ok.gltf", gltf_text(R"([{"mesh":0}])"));
  EXPECT_EQ(load_scene(ok).mesh.num_triangles(), 1u);
  const std::string up = tmp.write("scene/up.gltf", gltf_text(R"([{"mesh":0}])", "../outside.bin"));
  EXPECT_CONTAINS(load_error([&] { load_scene(up); }), "outside the scene's folder");
  const std::string passwd =
      tmp.write("scene/pw.gltf", gltf_text(R"([{"mesh":0}])", "../../../../../../../etc/passwd"));
  const std::string e = load_error([&] { load_scene(passwd); });
  EXPECT_CONTAINS(e, "outside the scene's folder");
  EXPECT_EQ(e.find("but got"), std::string::npos) << "the error reveals the file's size: " << e;
}

TEST(HostileFiles, GltfInstanceExplosionAndDeepChainsAreRefused) {
  TempDir tmp;
  tmp.write("tri.bin", triangle_bin());
  // 41 nodes, each listing the next one twice: 2^41 instances of the last node's mesh.
  std::string nodes = "[";
  for (int i = 0; i < 40; ++i)
    nodes += R"({"children":[)" + std::to_string(i + 1) + "," + std::to_string(i + 1) + "]},";
  nodes += R"({"mesh":0}])";
  const std::string boom = tmp.write("boom.gltf", gltf_text(nodes));
  const auto t0 = std::chrono::steady_clock::now();
  std::string e = load_error([&] { load_scene(boom); });
  EXPECT_CONTAINS(e, "node instances");
  EXPECT_CONTAINS(e, "above the limit of 1048576");
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 5.0);
  // 24 levels of nodes listing the next one twice and no mesh at all: 2^24 - 1 instances, each
  // a matrix product; loading them took 11.6 s under AddressSanitizer (a fuzzer timeout).
  nodes = "[";
  for (int i = 0; i < 23; ++i)
    nodes += R"({"children":[)" + std::to_string(i + 1) + "," + std::to_string(i + 1) + "]},";
  nodes += R"({}])";
  const std::string empty_tree = tmp.write("empty_tree.gltf", gltf_text(nodes));
  EXPECT_CONTAINS(load_error([&] { load_scene(empty_tree); }),
                  "expands to 1.678e+07 node instances");
  // A chain of 1100 nodes: too deep, which is not a cycle.
  nodes = "[";
  for (int i = 0; i < 1100; ++i) nodes += R"({"children":[)" + std::to_string(i + 1) + "]},";
  nodes += R"({"mesh":0}])";
  const std::string deep = tmp.write("deep.gltf", gltf_text(nodes));
  e = load_error([&] { load_scene(deep); });
  EXPECT_CONTAINS(e, "more than 1000 levels deep");
  EXPECT_EQ(e.find("own ancestor"), std::string::npos) << e;
}

TEST(HostileFiles, GltfLightIntensityOutOfRangeIsRefused) {
  TempDir tmp;
  tmp.write("tri.bin", triangle_bin());
  for (const std::string value : {"1e300", "-2"}) {
    const std::string extra =
        R"(,"extensionsUsed":["KHR_lights_punctual"],"extensions":{"KHR_lights_punctual":)"
        R"({"lights":[{"type":"point","name":"lamp","intensity":)" +
        value + "}]}}";
    const std::string p = tmp.write(
        "light.gltf",
        gltf_text(
            R"([{"mesh":0,"children":[1]},{"extensions":{"KHR_lights_punctual":{"light":0}}}])",
            "tri.bin", extra));
    const std::string e = load_error([&] { load_scene(p); });
    EXPECT_CONTAINS(e, "light 0 'lamp' has intensity");
    EXPECT_CONTAINS(e, "between 0 and 3.4e38");
  }
}

std::string le32s(uint32_t v) {
  return {char(v), char(v >> 8), char(v >> 16), char(v >> 24)};
}

TEST(HostileFiles, BrokenGlbHeadersNameTheField) {
  TempDir tmp;
  std::string json = R"({"asset":{"version":"2.0"}})";
  while (json.size() % 4) json += ' ';
  auto glb = [&](uint32_t version, int32_t length_delta, const std::string& type) {
    const std::string chunk = le32s(uint32_t(json.size())) + type + json;
    return "glTF" + le32s(version) + le32s(uint32_t(12 + chunk.size() + length_delta)) + chunk;
  };
  auto err = [&](const std::string& bytes) {
    const std::string p = tmp.write("x.glb", bytes);
    return load_error([&] { load_scene(p); });
  };
  EXPECT_CONTAINS(err(glb(1, 0, "JSON")), "header version (bytes 4-7) is 1");
  EXPECT_CONTAINS(err(glb(2, 8, "JSON")), "truncated .glb: its header length (bytes 8-11)");
  EXPECT_CONTAINS(err(glb(2, -4, "JSON")), "bytes follow the end");
  EXPECT_CONTAINS(err(glb(2, 0, "JSOX")), "type (bytes 16-19) is 'JSOX', not 'JSON'");
  EXPECT_CONTAINS(err("glTF" + le32s(2) + le32s(20) + le32s(999) + "JSON"),
                  "length (bytes 12-15) is 999");
  EXPECT_CONTAINS(err(json), "not the magic 'glTF' (this is JSON: rename it to .gltf)");
}

TEST(HostileFiles, GltfHugeImageIsRefusedFromItsHeader) {
  if (kAddressSanitizer)
    GTEST_SKIP()
        << "its memory budget comes from ulimit -v, under which AddressSanitizer cannot start";
  TempDir tmp;
  tmp.write("tri.bin", triangle_bin());
  tmp.write("big.png", png_header_only(20000, 20000));
  const std::string extra =
      R"(,"images":[{"uri":"big.png"}],"textures":[{"source":0}],)"
      R"("materials":[{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}])";
  std::string text = gltf_text(R"([{"mesh":0}])", "tri.bin", extra);
  const std::string p = tmp.write("tex.gltf", text);
  // Under a 4 GB address-space limit the budget is 2 GB: 20000^2 pixels need 2.8 GB.
  const CliResult r = run_cli("info \"" + p + "\"", tmp, "ulimit -v 4000000;");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_CONTAINS(r.err, "20000x20000 pixels would take");
  EXPECT_EQ(r.err.find("Unknown image format"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace kdgrid
