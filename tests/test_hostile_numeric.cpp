// Hostile numbers: rays and scenes at the edges of float range, extreme render depths and
// degenerate cameras. Each must give a correct result or a clear refusal, never an abort, a
// hang or a silently wrong (black, flat) image. docs/LIMITS.md states the limits tested here.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "accel/accelerator.h"
#include "accel/grid.h"
#include "bench/rayfile.h"
#include "cli_util.h"
#include "render/camera.h"
#include "render/renderer.h"
#include "scene/load.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;

using test::CliResult;
using test::contains;
using test::run_cli;
using test::TempDir;

/// Writes an ASCII PLY of the given triangles.
void write_ply(const std::string& path, const std::vector<Vec3>& v,
               const std::vector<std::array<uint32_t, 3>>& tris) {
  FILE* f = std::fopen(path.c_str(), "w");
  ASSERT_NE(f, nullptr) << path;
  std::fprintf(f,
               "ply\nformat ascii 1.0\nelement vertex %zu\nproperty float x\nproperty float y\n"
               "property float z\nelement face %zu\nproperty list uchar int vertex_indices\n"
               "end_header\n",
               v.size(), tris.size());
  for (const Vec3& p : v)
    std::fprintf(f, "%.9g %.9g %.9g\n", double(p.x), double(p.y), double(p.z));
  for (const auto& t : tris) std::fprintf(f, "3 %u %u %u\n", t[0], t[1], t[2]);
  std::fclose(f);
}

/// A square [-s, s]^2 at z = 0, two triangles.
Mesh square(float s) {
  Mesh m;
  m.positions = {{-s, -s, 0}, {s, -s, 0}, {s, s, 0}, {-s, s, 0}};
  m.triangles = {{0, 1, 2}, {0, 2, 3}};
  return m;
}

/// Every structure, built over `mesh` with default parameters.
std::vector<std::unique_ptr<Accelerator>> all_structures(const Mesh& mesh) {
  std::vector<std::unique_ptr<Accelerator>> out;
  for (const std::string& name : accelerator_names())
    out.push_back(build_accelerator(name, mesh, {}));
  return out;
}

// ---- rays outside Embree's range -------------------------------------------------------------

// Rays Embree would abort on (its ray validation: coordinates up to 1.844e18, a finite start)
// are invalid for every structure, so all of them miss them alike instead of Embree killing
// the process; rays just inside the range still hit everywhere.
TEST(HostileNumeric, RaysBeyondEmbreeRangeAreInvalidForEveryStructure) {
  const Mesh mesh = square(1.0f);
  const std::vector<Ray> outside = {
      {{0, 0, 1e19f}, 0.0f, {0, 0, -1}, kInf},        // origin beyond the range
      {{0, 0, 1}, -kInf, {0, 0, -1}, kInf},           // starts at infinity behind the origin
      {{0, 0, 1}, -1e30f, {0, 0, -1}, kInf},          // starts at z = 1e30
      {{0, 0, 1}, 0.0f, {0, 0, -1e19f}, kInf},        // direction beyond the range
      {{0.1f, 0.1f, 3e38f}, 0.0f, {0, 0, -1}, kInf},  // origin near float's limit
  };
  for (const Ray& r : outside) EXPECT_FALSE(ray_is_valid(r)) << r.org.z << " " << r.tmin;
  const std::vector<Ray> inside = {
      {{0.1f, 0.2f, 1.8e18f}, 0.0f, {0, 0, -1}, kInf},
      {{0.1f, 0.2f, -1}, -1e18f, {0, 0, 1}, kInf},  // starts at z = -1e18, hits at t = 1
  };
  for (const Ray& r : inside) EXPECT_TRUE(ray_is_valid(r)) << r.org.z << " " << r.tmin;
  for (const auto& a : all_structures(mesh)) {
    for (const Ray& r : outside) {
      Hit h;
      EXPECT_FALSE(a->intersect(r, h)) << a->name() << " org.z " << r.org.z;
      EXPECT_FALSE(a->occluded(r)) << a->name() << " org.z " << r.org.z;
    }
    for (const Ray& r : inside) {
      Hit h;
      EXPECT_TRUE(a->intersect(r, h)) << a->name() << " org.z " << r.org.z;
      EXPECT_TRUE(a->occluded(r)) << a->name() << " org.z " << r.org.z;
    }
  }
}

// The fuzz corpus entry of such rays goes through every structure, Embree included.
TEST(HostileNumeric, OutOfRangeRayFileTracesWithoutAbort) {
  const std::vector<Ray> rays = read_rays(test::source_path("fuzz/corpus/rays/out_of_range.rays"));
  ASSERT_GE(rays.size(), 5u);
  const Mesh mesh = square(1.0f);
  for (const auto& a : all_structures(mesh))
    for (const Ray& r : rays) {
      Hit h;
      const bool hit = a->intersect(r, h);
      EXPECT_EQ(hit, ray_is_valid(r)) << a->name() << " org " << r.org.x << "," << r.org.y << ","
                                      << r.org.z << " tmin " << r.tmin;
    }
}

TEST(HostileNumeric, CliRefusesCameraBeyondRangeInsteadOfAborting) {
  TempDir dir;
  const std::string scene = test::source_path("assets/cornell.gltf");
  const CliResult r = run_cli("render " + scene + " -o " + dir.file("x.png") +
                              " --res 8 --spp 1 --accel embree --eye 0,0,1e19 --target 0,0,0");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "outside the supported coordinate range")) << r.output;
  EXPECT_TRUE(contains(r.output, "1.844e+18")) << r.output;
  EXPECT_FALSE(fs::exists(dir.file("x.png")));
}

// ---- large coordinates -----------------------------------------------------------------------

// A square 2e13 across seen from 3e13 away: the watertight test's depth term (the cube of the
// coordinates) overflows float; every structure must still find the hits brute force in
// double finds (about the 41% Embree reports for the view).
TEST(HostileNumeric, TrianglesAt1e13HitInEveryStructure) {
  for (const float s : {1e13f, 1e16f, kMaxSceneCoordinate}) {
    const Mesh mesh = square(s);
    std::vector<Ray> rays;
    int expected = 0;
    for (int i = 0; i < 20; ++i)
      for (int j = 0; j < 20; ++j) {
        // Aim at a 2s x 2s grid of points over [-1.5s, 1.5s]^2 from (0, 0, 3s).
        const float x = (-1.5f + 3.0f * (i + 0.5f) / 20) * s,
                    y = (-1.5f + 3.0f * (j + 0.5f) / 20) * s;
        rays.push_back({{0, 0, 3 * s}, 0.0f, normalize(Vec3(x, y, -3 * s)), kInf});
        expected += std::fabs(x) < s && std::fabs(y) < s;
      }
    for (const auto& a : all_structures(mesh)) {
      int hits = 0;
      for (const Ray& r : rays) {
        Hit h;
        if (!a->intersect(r, h)) continue;
        ++hits;
        EXPECT_NEAR(r.at(h.t).z, 0.0, 1e-5 * s) << a->name();
      }
      EXPECT_EQ(hits, expected) << a->name() << " at scale " << s;
    }
  }
}

TEST(HostileNumeric, ScenesBeyondTheCoordinateRangeAreRefused) {
  TempDir dir;
  // 1e19 across: the canonical camera and light would be at infinity (a black image).
  write_ply(dir.file("quad1e19.ply"), square(1e19f).positions, square(1e19f).triangles);
  try {
    load_scene(dir.file("quad1e19.ply"));
    FAIL() << "a scene 1e19 across loaded";
  } catch (const LoadError& e) {
    EXPECT_TRUE(contains(e.what(), "quad1e19.ply")) << e.what();
    EXPECT_TRUE(contains(e.what(), "vertex 0")) << e.what();
    EXPECT_TRUE(contains(e.what(), "+-1e+17")) << e.what();
  }
  const CliResult r = run_cli("render " + dir.file("quad1e19.ply") + " -o " + dir.file("q.png") +
                              " --res 8 --spp 1");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "scale the scene down")) << r.output;
  // Inside the range the same square renders: not one flat colour.
  write_ply(dir.file("quad1e13.ply"), square(1e13f).positions, square(1e13f).triangles);
  const CliResult ok = run_cli("render " + dir.file("quad1e13.ply") + " -o " + dir.file("q.exr") +
                               " --res 16 --spp 1 --accel kdtree");
  ASSERT_EQ(ok.code, 0) << ok.output;
}

// Near float's limit the uniform grid's extent overflowed to inf and its cell count wrapped
// to 0 (writes out of bounds); it refuses such a mesh, as do the irregular grid and
// Scene::finalize.
TEST(HostileNumeric, GridsRefuseCoordinatesNearFloatLimit) {
  Mesh m;
  m.positions = {{-3e38f, -3e38f, 0}, {3e38f, -3e38f, 0}, {0, 3e38f, 0}};
  m.triangles = {{0, 1, 2}};
  for (const char* name : {"grid", "irregular"}) {
    try {
      build_accelerator(name, m, {});
      FAIL() << name << " built a mesh 6e38 across";
    } catch (const ParamError& e) {
      EXPECT_TRUE(contains(e.what(), "supported range")) << e.what();
      EXPECT_TRUE(contains(e.what(), name)) << e.what();
    }
  }
  TempDir dir;
  write_ply(dir.file("big1e38.ply"), m.positions, m.triangles);
  const CliResult r = run_cli("render " + dir.file("big1e38.ply") + " -o " + dir.file("x.png") +
                              " --res 8 --spp 1 --accel grid");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "big1e38.ply")) << r.output;
}

// ---- render depth ----------------------------------------------------------------------------

TEST(HostileNumeric, MaxDepthAboveTheLimitIsRefused) {
  const Mesh mesh = square(1.0f);
  Scene scene;
  scene.mesh = mesh;
  scene.finalize();
  const auto accel = build_accelerator("brute", scene.mesh, {});
  RenderSettings s;
  s.max_depth = kMaxRenderDepth;
  EXPECT_NO_THROW(Renderer(scene, *accel, s));
  s.max_depth = kMaxRenderDepth + 1;
  EXPECT_THROW(Renderer(scene, *accel, s), ParamError);
  // The command overflowed the stack (exit 139).
  TempDir dir;
  const CliResult r = run_cli("render " + test::source_path("assets/cornell.gltf") + " -o " +
                              dir.file("c.png") + " --res 64 --spp 1 --max-depth 20000");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "--max-depth 20000 must be between 0 and 256")) << r.output;
}

// Glass splits every path in two at each bounce: at depth 256 the Cornell box's glass
// traced tens of thousands of rays for one camera sample (minutes per pass, Ctrl-C unheard).
// The path weight cutoff and the per-sample budget bound each sample's ray tree.
TEST(HostileNumeric, DeepGlassRayTreeIsBounded) {
  const Scene scene = load_scene(test::source_path("assets/cornell.gltf"));
  const auto accel = build_accelerator("bvh", scene.mesh, {});
  RenderSettings s;
  s.max_depth = kMaxRenderDepth;
  Renderer r(scene, *accel, s);
  const CameraFrame f = CameraFrame::make(*scene.camera, 16, 16);
  uint64_t most = 0, total = 0;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x) {
      RenderCounters c;
      const Vec3 v = r.radiance(f.ray(x + 0.5f, y + 0.5f), 0, c);
      EXPECT_TRUE(is_finite(v));
      most = std::max(most, c.reflection + c.refraction);
      total += c.reflection + c.refraction;
    }
  EXPECT_LE(most, uint64_t(kMaxSecondaryRaysPerSample));
  EXPECT_GT(total, 0u) << "the view shows no glass or mirror: the test lost its point";
}

// Ctrl-C during a deep render stops within a pass and writes the finished passes.
TEST(HostileNumeric, InterruptDuringDeepRenderWritesWhatIsDone) {
  TempDir dir;
  const std::string out = dir.file("c.png");
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    const std::string scene = test::source_path("assets/cornell.gltf");
    const int null = ::open("/dev/null", O_WRONLY);
    ::dup2(null, 1);
    ::dup2(null, 2);
    ::execl(KDGRID_CLI_PATH, KDGRID_CLI_PATH, "render", scene.c_str(), "-o", out.c_str(), "--res",
            "128", "--spp", "100000", "--max-depth", "256", static_cast<char*>(nullptr));
    ::_exit(127);
  }
  // Long enough to load, build and finish passes on a loaded machine.
  std::this_thread::sleep_for(std::chrono::seconds(4));
  ::kill(pid, SIGINT);
  const auto t0 = std::chrono::steady_clock::now();
  int status = 0;
  pid_t done = 0;
  while ((done = ::waitpid(pid, &status, WNOHANG)) == 0 &&
         std::chrono::steady_clock::now() - t0 < std::chrono::seconds(30))
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  const double waited =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (done == 0) {
    ::kill(pid, SIGKILL);
    ::waitpid(pid, &status, 0);
    FAIL() << "render still running " << waited << " s after Ctrl-C";
  }
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 130);
  EXPECT_LT(waited, 5.0) << "Ctrl-C must be honoured within a tile of bounded work";
  EXPECT_TRUE(fs::exists(out)) << "the finished passes were not written";
}

// ---- cameras ---------------------------------------------------------------------------------

// Looking straight down the world up vector: cross(fwd, up) vanishes. The frame must stay
// orthonormal, and the image must not be one flat colour.
TEST(HostileNumeric, CameraLookingAlongUpHasAFrame) {
  for (const Vec3 eye : {Vec3(0, 5, 0), Vec3(0, -5, 0)}) {
    Camera cam;
    cam.eye = eye;
    cam.target = {0, 0, 0};
    const CameraFrame f = CameraFrame::make(cam, 8, 8);
    EXPECT_TRUE(is_finite(f.right) && is_finite(f.up));
    EXPECT_NEAR(length(f.right), 1.0f, 1e-6f);
    EXPECT_NEAR(length(f.up), 1.0f, 1e-6f);
    EXPECT_NEAR(dot(f.right, f.fwd), 0.0f, 1e-6f);
    EXPECT_NEAR(dot(f.up, f.fwd), 0.0f, 1e-6f);
    EXPECT_NEAR(f.right.x, 1.0f, 1e-6f) << "looking along -y or +y, +x is on the right";
    const Ray corner = f.ray(0.5f, 0.5f), centre = f.ray(4.0f, 4.0f);
    EXPECT_GT(length(corner.dir - centre.dir), 0.1f);
  }
  // Any other camera keeps docs/RAYSETS.md's frame bit for bit.
  Camera cam;
  cam.eye = {1, 2, 3};
  cam.target = {0, 0.5f, 0};
  const CameraFrame f = CameraFrame::make(cam, 8, 8);
  const Vec3 fwd = normalize(cam.target - cam.eye);
  EXPECT_EQ(f.right, normalize(cross(fwd, cam.up)));

  TempDir dir;
  const CliResult r =
      run_cli("render " + test::source_path("assets/cornell.gltf") + " -o " + dir.file("down.exr") +
              " --res 16 --spp 1 --eye 0,5,0 --target 0,0,0");
  ASSERT_EQ(r.code, 0) << r.output;
}

TEST(HostileNumeric, FovOutsideOpenRangeIsRefused) {
  TempDir dir;
  const std::string base = "render " + test::source_path("assets/cornell.gltf") + " -o " +
                           dir.file("f.png") + " --res 8 --spp 1";
  for (const char* fov : {"0", "180", "-5"}) {
    const CliResult r = run_cli(base + " --fov " + fov);
    EXPECT_EQ(r.code, 1) << fov << ": " << r.output;
    EXPECT_TRUE(contains(r.output, "--fov")) << r.output;
  }
  EXPECT_EQ(run_cli(base + " --fov 30").code, 0);
  Camera cam;
  cam.fov_deg = 0.0f;
  EXPECT_THROW(check_camera(cam, "test"), ParamError);
}

}  // namespace
}  // namespace kdgrid
