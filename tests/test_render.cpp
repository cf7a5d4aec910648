// Renderer, robust ray offsets, image I/O and the `kdgrid render` command.
//
// Render regression reference: tests/data/cornell_ref.exr is assets/cornell.gltf rendered by
// this code at 64x48, 4 spp, seed 1, max depth 5, brute force. To regenerate it after an
// intended change of the shading (look at a large render first!):
//   KDGRID_UPDATE_REFERENCE=1 build/release/tests/kdgrid_tests --gtest_filter=RenderRegression.*
// which rewrites the file in the source tree; commit it with the change that explains it.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "accel/triangle.h"
#include "cli_util.h"
#include "image/image_io.h"
#include "math/rng.h"
#include "render/renderer.h"
#include "scene/load.h"
#include "scene/procedural.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;

using test::TempDir;

Scene cornell_scene(int level = 2) {
  ProceduralParams p;
  p.level = level;
  Scene s = generate_scene("cornell", p);
  s.finalize();
  return s;
}

/// A grey floor quad with a box floating above part of it, lit by a point light overhead:
/// only diffuse materials, so nothing reflects or refracts.
Scene floor_and_blocker() {
  Scene s;
  s.source = "test:floor";
  Mesh floor = make_box({0, -0.05f, 0}, {4, 0.05f, 4});
  s.mesh.append(floor);
  s.mesh.append(make_box({-1.0f, 1.0f, 0}, {0.5f, 0.2f, 0.5f}));
  Material grey;
  grey.name = "grey";
  grey.roughness = 1.0f;
  s.materials.push_back(grey);
  Light l;
  l.position = {-1.0f, 3.0f, 0.0f};
  l.intensity = 10.0f;
  s.lights.push_back(l);
  Camera cam;
  cam.eye = {0, 4, 6};
  cam.target = {0, 0, 0};
  s.camera = cam;
  s.finalize();
  return s;
}

/// Render settings of `width` x `height` pixels, the rest the defaults.
RenderSettings sized(int width, int height) {
  RenderSettings rs;
  rs.width = width;
  rs.height = height;
  return rs;
}

std::vector<float> render(const Scene& scene, const Accelerator& accel, RenderSettings rs,
                          int passes, RenderCounters* counters = nullptr) {
  Renderer r(scene, accel, rs);
  for (int i = 0; i < passes; ++i) EXPECT_TRUE(r.render_pass());
  std::vector<float> rgb;
  r.resolve(rgb);
  if (counters) *counters = r.counters();
  return rgb;
}

// ---- determinism, cancellation, ray kinds ------------------------------------------------

TEST(Renderer, SameSeedSameImageAcrossThreadCounts) {
  const Scene scene = cornell_scene();
  const auto accel = build_accelerator("brute", scene.mesh, {});
  RenderSettings rs = sized(40, 30);
  rs.tile_size = 8;
  std::vector<float> one, two, other_seed;
  {
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism, 1);
    one = render(scene, *accel, rs, 2);
  }
  {
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism, 2);
    two = render(scene, *accel, rs, 2);
  }
  EXPECT_EQ(one, two) << "the image must not depend on thread scheduling";
  rs.seed = 2;
  other_seed = render(scene, *accel, rs, 2);
  EXPECT_NE(one, other_seed) << "the seed must change the jitter pattern";
  // Tile size only changes the unit of work, never a pixel.
  rs.seed = 1;
  rs.tile_size = 7;
  EXPECT_EQ(one, render(scene, *accel, rs, 2));
}

/// A structure that answers through `inner` and counts the packet queries it is asked.
class PacketCounter final : public Accelerator {
 public:
  explicit PacketCounter(const Accelerator& inner) : inner_(inner) {}
  std::string name() const override { return "packet-counter"; }
  BuildStats build(const Mesh&, const BuildParams&) override { return {}; }
  bool intersect(const Ray& r, Hit& h) const override { return inner_.intersect(r, h); }
  bool occluded(const Ray& r) const override { return inner_.occluded(r); }
  bool intersect_counted(const Ray& r, Hit& h, RayCounters& c) const override {
    return inner_.intersect_counted(r, h, c);
  }
  bool occluded_counted(const Ray& r, RayCounters& c) const override {
    return inner_.occluded_counted(r, c);
  }
  Trace trace(const Ray& r) const override { return inner_.trace(r); }
  uint64_t memory_bytes() const override { return 0; }
  const BuildStats& stats() const override { return inner_.stats(); }
  void intersect_packet(const Ray* rays, int n, Hit* hits, bool* found) const override {
    packets += 1;
    packet_rays += n;
    max_packet = std::max(max_packet.load(), n);
    inner_.intersect_packet(rays, n, hits, found);
  }
  void occluded_packet(const Ray* rays, int n, bool* occluded_out) const override {
    shadow_packets += 1;
    shadow_packet_rays += n;
    max_shadow_packet = std::max(max_shadow_packet.load(), n);
    inner_.occluded_packet(rays, n, occluded_out);
  }
  mutable std::atomic<int> packets{0}, packet_rays{0}, max_packet{0};
  mutable std::atomic<int> shadow_packets{0}, shadow_packet_rays{0}, max_shadow_packet{0};

 private:
  const Accelerator& inner_;
};

TEST(Renderer, PacketRenderIsBitwiseTheSingleRayRender) {
  Scene scene = cornell_scene();
  // Six lights of every kind, so that a hit's shadow rays are several and their order in the
  // sum matters: a packet render that dropped, added or reordered one would differ (checked by
  // dropping a point light and by adding the lights in reverse). The box's ceiling blocks the
  // directional light everywhere, so every packet also holds shadow rays that are occluded.
  const Vec3 lo = scene.mesh.bounds().lo, hi = scene.mesh.bounds().hi;
  const Vec3 mid = (lo + hi) * 0.5f, ext = hi - lo;
  for (int k = 0; k < 5; ++k) {
    Light l;
    l.type = k < 3 ? LightType::Point : k == 3 ? LightType::Spot : LightType::Directional;
    l.position = mid + Vec3(ext.x * (0.1f * float(k) - 0.2f), ext.y * 0.3f, ext.z * 0.1f);
    l.direction = normalize(Vec3(0.2f * float(k) - 0.3f, -1.0f, 0.1f));
    l.color = Vec3(0.3f + 0.1f * float(k), 0.5f, 0.9f - 0.1f * float(k));
    l.intensity = k == 4 ? 0.5f : 0.4f * float(ext.y * ext.y);
    l.outer_cone = 0.6f;
    scene.lights.push_back(l);
  }
  ASSERT_EQ(scene.lights.size(), 6u);
  // 83 wide: tiles cut at the edges; 70-pixel tiles are wider than a packet.
  RenderSettings rs = sized(83, 37);
  for (const std::string name : {"hybrid", "embree", "bvh"}) {
    const auto accel = build_accelerator(name, scene.mesh, {});
    for (const int tile : {16, 8, 5, 70}) {
      rs.tile_size = tile;
      // Without reflection and refraction rays every shadow ray is a primary hit's.
      rs.max_depth = tile == 8 ? 0 : 5;
      rs.packets = false;
      PacketCounter single(*accel);
      RenderCounters single_counts, packed_counts;
      const std::vector<float> a = render(scene, single, rs, 2, &single_counts);
      EXPECT_EQ(single.packets.load(), 0);
      EXPECT_EQ(single.shadow_packets.load(), 0);
      rs.packets = true;
      PacketCounter packed(*accel);
      const std::vector<float> b = render(scene, packed, rs, 2, &packed_counts);
      // Every primary ray went through a packet of at most kRenderPacket rays.
      EXPECT_EQ(packed.packet_rays.load(), 2 * rs.width * rs.height) << name << " tile " << tile;
      EXPECT_LE(packed.max_packet.load(), kRenderPacket);
      EXPECT_GT(packed.max_packet.load(), tile >= 8 ? 32 : 24) << name << " tile " << tile;
      // Every shadow ray of a primary hit went through a packet; those of reflection and
      // refraction hits are traced one at a time.
      EXPECT_EQ(packed_counts.shadow, single_counts.shadow) << name << " tile " << tile;
      EXPECT_GT(packed.shadow_packet_rays.load(), 2 * rs.width * rs.height);
      if (rs.max_depth == 0)
        EXPECT_EQ(uint64_t(packed.shadow_packet_rays.load()), single_counts.shadow) << name;
      else
        EXPECT_LT(uint64_t(packed.shadow_packet_rays.load()), single_counts.shadow) << name;
      EXPECT_LE(packed.max_shadow_packet.load(), kShadowPacket);
      EXPECT_GT(packed.max_shadow_packet.load(), tile >= 8 ? 64 : 24) << name << " tile " << tile;
      ASSERT_EQ(a.size(), b.size());
      EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(float)), 0)
          << name << ", tiles of " << tile << ": the packet render differs from the single-ray one";
    }
  }
}

TEST(Renderer, CancelledPassLeavesFilmUnchanged) {
  const Scene scene = cornell_scene();
  const auto accel = build_accelerator("brute", scene.mesh, {});
  RenderSettings rs = sized(48, 32);
  Renderer r(scene, *accel, rs);
  ASSERT_TRUE(r.render_pass());
  std::vector<float> before, after;
  r.resolve(before);
  const RenderCounters counters = r.counters();

  std::atomic<bool> cancel{true};
  EXPECT_FALSE(r.render_pass(&cancel));
  r.resolve(after);
  EXPECT_EQ(before, after);
  EXPECT_EQ(r.samples(), 1);
  EXPECT_EQ(r.counters().total(), counters.total());

  // Cancelled from another thread while the pass runs: either the pass finished (and counts)
  // or the film is exactly as before.
  rs.width = 160;
  rs.height = 120;
  Renderer big(scene, *accel, rs);
  ASSERT_TRUE(big.render_pass());
  big.resolve(before);
  cancel = false;
  std::thread canceller([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
    cancel = true;
  });
  const bool finished = big.render_pass(&cancel);
  canceller.join();
  big.resolve(after);
  if (finished) {
    EXPECT_EQ(big.samples(), 2);
  } else {
    EXPECT_EQ(big.samples(), 1);
    EXPECT_EQ(before, after);
  }
  // A cancelled renderer goes on normally afterwards.
  EXPECT_TRUE(big.render_pass());
}

TEST(Renderer, TracesOnlyTheRayKindsMaterialsNeed) {
  const Scene diffuse = floor_and_blocker();
  ASSERT_FALSE(diffuse.has_reflective_material());
  const auto accel = build_accelerator("brute", diffuse.mesh, {});
  RenderSettings rs = sized(32, 24);
  RenderCounters c;
  render(diffuse, *accel, rs, 1, &c);
  EXPECT_EQ(c.primary, 32u * 24u);
  EXPECT_GT(c.shadow, 0u);
  EXPECT_EQ(c.reflection, 0u);
  EXPECT_EQ(c.refraction, 0u);

  const Scene cornell = cornell_scene();
  const auto accel2 = build_accelerator("brute", cornell.mesh, {});
  render(cornell, *accel2, rs, 1, &c);
  EXPECT_GT(c.reflection, 0u);
  EXPECT_GT(c.refraction, 0u);

  // Shadows off: no shadow rays at all; depth 0: no secondary rays.
  rs.shadows = false;
  rs.max_depth = 0;
  render(cornell, *accel2, rs, 1, &c);
  EXPECT_EQ(c.shadow, 0u);
  EXPECT_EQ(c.reflection + c.refraction, 0u);
}

TEST(Renderer, HeatMapCountsPrimaryTraversal) {
  const Scene scene = floor_and_blocker();
  const auto accel = build_accelerator("brute", scene.mesh, {});
  RenderSettings rs = sized(8, 8);
  rs.mode = RenderMode::HeatTests;
  RenderCounters c;
  const auto rgb = render(scene, *accel, rs, 2, &c);
  // Brute force tests every triangle for every primary ray.
  for (float v : rgb) EXPECT_EQ(v, float(scene.mesh.num_triangles()));
  EXPECT_EQ(c.shadow, 0u);
}

TEST(Renderer, RejectsBadSettings) {
  const Scene scene = floor_and_blocker();
  const auto accel = build_accelerator("brute", scene.mesh, {});
  RenderSettings rs;
  rs.width = 0;
  EXPECT_THROW(Renderer(scene, *accel, rs), ParamError);
  rs.width = 4;
  rs.tile_size = 0;
  EXPECT_THROW(Renderer(scene, *accel, rs), ParamError);
}

// ---- shading ----------------------------------------------------------------------------

/// Radiance seen along the ray from `eye` towards `target`.
Vec3 look(const Renderer& r, const Vec3& eye, const Vec3& target) {
  RenderCounters c;
  return r.radiance(Ray{eye, 0.0f, normalize(target - eye), kInf}, 0, c);
}

float luminance(const Vec3& c) {
  return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z;
}

TEST(Shading, LitSideBrighterThanShadowedSide) {
  const Scene scene = floor_and_blocker();
  const auto accel = build_accelerator("brute", scene.mesh, {});
  Renderer r(scene, *accel, {});
  const Vec3 eye(0, 5, 5);
  const Vec3 lit = look(r, eye, {0.5f, 0.0f, 0.0f});
  const Vec3 shadowed = look(r, eye, {-1.0f, 0.0f, 0.0f});  // under the blocker
  EXPECT_GT(luminance(lit), 4.0f * luminance(shadowed));
  EXPECT_GT(luminance(shadowed), 0.0f) << "the ambient term keeps shadows above black";
  // The blocker's top faces the light; its bottom does not.
  const Vec3 top = look(r, {-1.0f, 4.0f, 0.5f}, {-1.0f, 1.2f, 0.0f});
  const Vec3 bottom = look(r, {-1.0f, 0.5f, 2.0f}, {-1.0f, 0.8f, 0.0f});
  EXPECT_GT(luminance(top), 4.0f * luminance(bottom));
  // Without shadow rays the floor under the blocker is lit.
  RenderSettings no_shadows;
  no_shadows.shadows = false;
  Renderer r2(scene, *accel, no_shadows);
  EXPECT_GT(luminance(look(r2, eye, {-1.0f, 0.0f, 0.0f})), 4.0f * luminance(shadowed));
}

TEST(Shading, SpotConeAndDirectionalLight) {
  Scene scene = floor_and_blocker();
  scene.lights.clear();
  Light spot;
  spot.type = LightType::Spot;
  spot.position = {2.0f, 2.0f, 0.0f};
  spot.direction = {0, -1, 0};
  spot.inner_cone = 0.2f;
  spot.outer_cone = 0.4f;
  spot.intensity = 10.0f;
  scene.lights.push_back(spot);
  const auto accel = build_accelerator("brute", scene.mesh, {});
  Renderer r(scene, *accel, {});
  const Vec3 eye(2, 5, 5);
  const float inside = luminance(look(r, eye, {2.0f, 0.0f, 0.0f}));
  const float penumbra = luminance(look(r, eye, {2.0f + 2.0f * std::tan(0.3f), 0.0f, 0.0f}));
  const float outside = luminance(look(r, eye, {3.5f, 0.0f, 0.0f}));
  EXPECT_GT(inside, penumbra);
  EXPECT_GT(penumbra, outside);
  // Outside the outer cone only the ambient term remains.
  Material m = scene.materials[0];
  EXPECT_NEAR(outside, luminance(m.base_color * 0.03f), 1e-3f);

  scene.lights.clear();
  Light sun;
  sun.type = LightType::Directional;
  sun.direction = normalize(Vec3(0.0f, -1.0f, 0.0f));
  sun.intensity = 2.0f;
  scene.lights.push_back(sun);
  Renderer r2(scene, *accel, {});
  // Directional light: no falloff, so two unshadowed floor points look alike ...
  const float l1 = luminance(look(r2, eye, {2.0f, 0.0f, 0.0f}));
  EXPECT_NEAR(l1, luminance(look(r2, eye, {3.0f, 0.0f, 1.0f})), 0.03f * l1);
  // ... and the blocker shadows straight down.
  EXPECT_GT(luminance(look(r2, eye, {2.0f, 0.0f, 0.0f})),
            4.0f * luminance(look(r2, eye, {-1.0f, 0.0f, 0.0f})));
}

TEST(Shading, MirrorShowsWhatItFaces) {
  // A mirror floor under a red emissive ceiling looks red; a grey floor does not.
  Scene scene;
  scene.source = "test:mirror";
  scene.mesh.append(make_box({0, -0.05f, 0}, {4, 0.05f, 4}), 0);
  scene.mesh.append(make_box({0, 3.05f, 0}, {4, 0.05f, 4}), 1);
  Material mirror;
  mirror.name = "mirror";
  mirror.metallic = 1.0f;
  mirror.base_color = Vec3(0.9f);
  Material red;
  red.name = "red light";
  red.base_color = Vec3(0.0f);
  red.emission = {1.0f, 0.0f, 0.0f};
  scene.materials = {mirror, red};
  scene.finalize();
  const auto accel = build_accelerator("brute", scene.mesh, {});
  Renderer r(scene, *accel, {});
  const Vec3 c = look(r, {0, 1, 1}, {0, 0, 0});
  EXPECT_GT(c.x, 0.8f);
  EXPECT_LT(c.y, 0.1f);
  EXPECT_EQ(r.counters().total(), 0u) << "radiance() counts into the caller's counters only";
}

TEST(Shading, GlassSphereRefractsAndReflects) {
  // Looking through a glass sphere at an emissive wall: the centre shows the wall (refraction
  // straight through), and without refraction (depth 0) it would be dark.
  Scene scene;
  scene.source = "test:glass";
  scene.mesh.append(make_icosphere(3, {0, 0, 0}, 1.0f), 0);
  scene.mesh.append(make_box({0, 0, -3}, {5, 5, 0.05f}), 1);
  Material glass;
  glass.name = "glass";
  glass.transmission = 1.0f;
  glass.ior = 1.5f;
  glass.base_color = Vec3(1.0f);
  Material wall;
  wall.name = "wall";
  wall.base_color = Vec3(0.0f);
  wall.emission = Vec3(1.0f);
  scene.materials = {glass, wall};
  Light off;  // a dark light, so that finalize() adds no default one
  off.position = {0, 50, 50};
  off.intensity = 0.0f;
  scene.lights.push_back(off);
  scene.finalize();
  const auto accel = build_accelerator("brute", scene.mesh, {});
  Renderer r(scene, *accel, {});
  RenderCounters c;
  const Vec3 through = r.radiance(Ray{{0, 0, 5}, 0.0f, {0, 0, -1}, kInf}, 0, c);
  EXPECT_GT(through.x, 0.8f) << "refracted light of the wall behind the sphere";
  EXPECT_LT(through.x, 1.0f) << "Fresnel reflection takes a few percent";
  EXPECT_GE(c.refraction, 2u);  // in and out of the sphere
  EXPECT_GE(c.reflection, 1u);  // Fresnel
  RenderSettings shallow;
  shallow.max_depth = 0;
  Renderer r0(scene, *accel, shallow);
  EXPECT_LT(r0.radiance(Ray{{0, 0, 5}, 0.0f, {0, 0, -1}, kInf}, 0, c).x, 0.1f);
}

TEST(Shading, Tonemap) {
  std::vector<uint8_t> out;
  tonemap_srgb8({0.0f, 1.0f, 0.5f, 2.0f, -1.0f, std::nanf("")}, out);
  ASSERT_EQ(out.size(), 6u);
  EXPECT_EQ(out[0], 0);
  EXPECT_EQ(out[1], 255);
  EXPECT_EQ(out[2], 188);  // sRGB(0.5) = 0.7354
  EXPECT_EQ(out[3], 255);
  EXPECT_EQ(out[4], 0);
  EXPECT_EQ(out[5], 0);
  tonemap_srgb8({0.25f}, out, 2.0f);
  EXPECT_EQ(out[0], 188);
}

// ---- robust offsets ----------------------------------------------------------------------

TEST(Offset, SecondaryRaysNeverReHitTheirTriangle) {
  SplitMix64 rng{12345};
  int tested = 0;
  for (int i = 0; i < 100000; ++i) {
    // Scales 1e-4 .. 1e4; centres near the origin or far from it (up to 1e5 + scale).
    const float scale = std::pow(10.0f, rng.uniform(-4.0f, 4.0f));
    const float far = (i % 3 == 0) ? 0.0f : std::pow(10.0f, rng.uniform(0.0f, 5.0f));
    const Vec3 centre = rng.unit_vector() * far;
    const Vec3 a = centre + rng.unit_vector() * scale, b = centre + rng.unit_vector() * scale,
               c = centre + rng.unit_vector() * scale;
    const Vec3 ng = cross(b - a, c - a);
    if (!(length(ng) > 1e-6f * scale * scale)) continue;  // degenerate sliver: skip
    float u = rng.uniform(), v = rng.uniform();
    if (u + v > 1.0f) {
      u = 1.0f - u;
      v = 1.0f - v;
    }
    // Hit point the way the renderer computes it.
    const Vec3 p = a * (1.0f - u - v) + b * u + c * v;
    // Leave on the front side (reflection/shadow) and on the back side (refraction).
    const Vec3 n = normalize(ng);
    for (const float side : {1.0f, -1.0f}) {
      const Vec3 sn = n * side;
      Vec3 dir = rng.unit_vector();
      if (dot(dir, sn) < 0.0f) dir = -dir;
      if (i % 5 == 0) dir = normalize(dir - sn * (dot(dir, sn) * 0.999f));  // grazing
      if (!(dot(dir, sn) > 0.0f)) continue;
      const Ray ray{offset_ray_origin(p, sn, {a, b, c}), 0.0f, dir, kInf};
      float t, hu, hv;
      const bool wt = WatertightTest::intersect(WatertightTest::prepare(ray), a, b, c, ray.tmin,
                                                ray.tmax, t, hu, hv);
      ASSERT_FALSE(wt) << "ray " << i << " re-hit its own triangle: scale " << scale
                       << ", distance from origin " << far << ", t " << t;
      ++tested;
    }
  }
  EXPECT_GT(tested, 190000);
}

TEST(Offset, MovesTowardsTheNormalSideByAFewUlps) {
  const Vec3 n(0, 0, 1);
  // A unit right triangle in the plane z = p.z with one corner at p.
  auto tri = [](const Vec3& p) {
    return std::array<Vec3, 3>{p, p + Vec3(1, 0, 0), p + Vec3(0, 1, 0)};
  };
  const Vec3 p(1000.0f, -1000.0f, 1000.0f);
  const Vec3 q = offset_ray_origin(p, n, tri(p));
  EXPECT_EQ(q.x, p.x);
  EXPECT_EQ(q.y, p.y);
  EXPECT_GT(q.z, p.z);
  EXPECT_LT(q.z - p.z, 1e-1f);
  const Vec3 below(0, 0, -1000.0f), above(0, 0, 1000.0f);
  EXPECT_LT(offset_ray_origin(below, n, tri(below)).z - -1000.0f, 1e-1f);
  EXPECT_GT(offset_ray_origin(below, n, tri(below)).z, -1000.0f);
  EXPECT_LT(offset_ray_origin(above, -n, tri(above)).z, 1000.0f);
  // In the plane z = 0 (exact there) any step leaves the plane.
  EXPECT_GT(offset_ray_origin({0, 0, 0}, n, tri({0, 0, 0})).z, 0.0f);
  EXPECT_GT(offset_ray_origin({0, 0, 0}, n * 1e6f, tri({0, 0, 0})).z, 0.0f)
      << "normal need not be unit";
}

// ---- image I/O ---------------------------------------------------------------------------

TEST(ImageIO, ExrRoundTripKeepsValuesAndMetadata) {
  TempDir dir;
  std::vector<float> rgb = {0.0f, 0.5f, 1.0f, 2.5f, 1e-3f, 100.0f};
  const std::string path = dir.file("a.exr");
  write_image(path, 2, 1, rgb, {{"samples", "4"}, {"accelerator", "brute"}});
  const ImageRGB img = read_image(path);
  EXPECT_EQ(img.width, 2);
  EXPECT_EQ(img.height, 1);
  EXPECT_EQ(img.rgb, rgb);
  EXPECT_EQ(img.metadata.at("samples"), "4");
  EXPECT_EQ(img.metadata.at("accelerator"), "brute");
  // Only the image is left: the temporary file was renamed.
  int files = 0;
  for (const auto& e : fs::directory_iterator(dir.path())) files += e.is_regular_file();
  EXPECT_EQ(files, 1);
}

TEST(ImageIO, PngIsToneMapped) {
  TempDir dir;
  const std::string path = dir.file("a.png");
  write_image(path, 2, 1, {0.0f, 0.5f, 1.0f, 4.0f, 0.2f, 0.0f});
  const ImageRGB img = read_image(path);  // linearised on read
  ASSERT_EQ(img.rgb.size(), 6u);
  EXPECT_NEAR(img.rgb[1], 0.5f, 0.005f);
  EXPECT_NEAR(img.rgb[3], 1.0f, 1e-6f) << "values above 1 clamp";
  EXPECT_NEAR(img.rgb[4], 0.2f, 0.005f);
}

TEST(ImageIO, ErrorsNameThePath) {
  TempDir dir;
  try {
    write_image(dir.file("a.jpg"), 1, 1, {0, 0, 0});
    FAIL() << "jpg accepted";
  } catch (const ParamError& e) {
    EXPECT_NE(std::string(e.what()).find("a.jpg"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find(".png"), std::string::npos);
  }
  const std::string missing = dir.file("no/such/dir/a.png");
  try {
    write_image(missing, 1, 1, {0, 0, 0});
    FAIL() << "wrote into a missing directory";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(missing), std::string::npos) << e.what();
  }
  EXPECT_THROW(read_image(dir.file("none.exr")), LoadError);
  EXPECT_THROW(write_image(dir.file("a.exr"), 2, 2, {0, 0, 0}), ParamError);
  ImageRGB a, b;
  a.width = b.width = 1;
  a.height = 1;
  b.height = 2;
  a.rgb = {0, 0, 0};
  b.rgb = {0, 0, 0, 0, 0, 0};
  EXPECT_THROW(rmse(a, b), ParamError);
  b = a;
  b.rgb = {0.3f, 0.0f, 0.4f};
  EXPECT_NEAR(rmse(a, b), std::sqrt((0.09 + 0.16) / 3.0), 1e-6);
}

// ---- render regression -------------------------------------------------------------------

/// RMSE over colours clamped to [0, 1], so that the bright emissive panel (radiance 6) does
/// not dominate and the number measures what one sees.
double display_rmse(ImageRGB a, ImageRGB b) {
  for (float& v : a.rgb) v = std::min(1.0f, std::max(0.0f, v));
  for (float& v : b.rgb) v = std::min(1.0f, std::max(0.0f, v));
  return rmse(a, b);
}

TEST(RenderRegression, CornellMatchesReference) {
  const std::string scene_path = test::source_path("assets/cornell.gltf");
  const std::string ref_path = test::source_path("tests/data/cornell_ref.exr");
  const Scene scene = load_scene(scene_path);
  const auto accel = build_accelerator("brute", scene.mesh, {});
  RenderSettings rs = sized(64, 48);
  rs.seed = 1;
  rs.max_depth = 5;
  ImageRGB img;
  img.width = rs.width;
  img.height = rs.height;
  img.rgb = render(scene, *accel, rs, 4);
  if (std::getenv("KDGRID_UPDATE_REFERENCE")) {
    write_image(ref_path, img.width, img.height, img.rgb,
                {{"samples", "4"}, {"accelerator", "brute"}, {"scene", "assets/cornell.gltf"}});
    GTEST_SKIP() << "reference rewritten: " << ref_path;
  }
  ASSERT_TRUE(fs::exists(ref_path)) << "missing " << ref_path << "; see the top of this file";
  const ImageRGB ref = read_image(ref_path);
  // The render is deterministic, so on the machine that wrote the reference the difference
  // is 0; the threshold leaves room for other compilers and CPUs (-march=native, libm).
  const double e = display_rmse(img, ref);
  EXPECT_LT(e, 0.01) << "render differs from the reference; if intended, regenerate it";
  // The threshold can fail: a dimmer light gives a clearly larger error.
  Scene dim = scene;
  for (Light& l : dim.lights) l.intensity *= 0.7f;
  ImageRGB dimmed = img;
  dimmed.rgb = render(dim, *accel, rs, 4);
  EXPECT_GT(display_rmse(dimmed, ref), 0.01);
}

// ---- the `kdgrid render` command ---------------------------------------------------------

using test::CliResult;
using test::contains;
using test::run_cli;

TEST(RenderCli, ReportsBadArgumentsBeforeRendering) {
  TempDir dir;
  const std::string scene = test::source_path("assets/cornell.gltf");
  const std::string out = dir.file("out.png");

  CliResult r = run_cli("render " + dir.file("missing.gltf") + " -o " + out + " --accel brute");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "missing.gltf")) << r.output;

  r = run_cli("render " + scene + " -o " + dir.file("out.jpg") + " --accel brute");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "out.jpg") && contains(r.output, ".exr")) << r.output;

  r = run_cli("render " + scene + " -o " + out + " --accel brute --spp 0");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "--spp")) << r.output;

  r = run_cli("render " + scene + " -o " + out + " --accel brute --res 12xq");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "12xq")) << r.output;

  r = run_cli("render " + scene + " -o " + dir.file("nodir/out.png") + " --accel brute");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "does not exist")) << r.output;

  r = run_cli("render " + scene + " -o " + out + " --accel brute --heatmap nodes");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "steps, tests or time")) << r.output;

  r = run_cli("render " + scene + " -o " + out + " --accel nope");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "nope") && contains(r.output, "brute")) << r.output;

  EXPECT_FALSE(fs::exists(out)) << "no image may be written when the arguments are wrong";
}

TEST(RenderCli, RendersAndSummarises) {
  TempDir dir;
  const std::string scene = test::source_path("assets/cornell.gltf");
  const std::string out = dir.file("out.exr");
  CliResult r = run_cli("render " + scene + " -o " + out +
                        " --accel brute --res 24x16 --spp 2 --threads 2 --seed 3");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_TRUE(contains(r.output, "Mrays/s")) << r.output;
  EXPECT_TRUE(contains(r.output, "reflection")) << r.output;
  const ImageRGB img = read_image(out);
  EXPECT_EQ(img.width, 24);
  EXPECT_EQ(img.height, 16);
  EXPECT_EQ(img.metadata.at("samples"), "2");
  EXPECT_EQ(img.metadata.at("accelerator"), "brute");
  EXPECT_EQ(img.metadata.at("seed"), "3");

  r = run_cli("render " + scene + " -o " + dir.file("heat.png") +
              " --accel brute --res 16x12 --spp 1 --heatmap tests --eye 0,1,3 --target 0,1,0");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_TRUE(fs::exists(dir.file("heat.png")));
}

TEST(RenderCli, NoPacketsRendersTheSameImageOneRayAtATime) {
  TempDir dir;
  const std::string scene = test::source_path("assets/cornell.gltf");
  std::vector<float> images[2];
  for (const bool packets : {true, false}) {
    const std::string out = dir.file(packets ? "packets.exr" : "single.exr");
    const std::string stats = dir.file(packets ? "packets.json" : "single.json");
    const CliResult r =
        run_cli("render " + scene + " -o " + out + " --accel hybrid --res 24x16 --spp 2 " +
                "--threads 2 --stats-json " + stats + (packets ? "" : " --no-packets"));
    ASSERT_EQ(r.code, 0) << r.output;
    std::ifstream f(stats);
    EXPECT_EQ(nlohmann::json::parse(f)["packets"], packets);
    images[packets] = read_image(out).rgb;
  }
  ASSERT_EQ(images[0].size(), 24u * 16u * 3u);
  EXPECT_EQ(images[0], images[1]);
}

TEST(RenderCli, InterruptWritesWhatIsDone) {
  TempDir dir;
  const std::string scene = test::source_path("assets/cornell.gltf");
  const std::string out = dir.file("out.exr");
  // Far too many passes to finish, SIGINT every half second until the process ends (a
  // background job of sh starts with SIGINT ignored, so signals that arrive before the
  // renderer installs its handler are lost): it must stop, write the image of the finished
  // passes and say so, with exit code 130. After 60 s it is killed and the test fails.
  const std::string cmd =
      "sh -c '" + std::string(KDGRID_CLI_PATH) + " render " + scene + " -o " + out +
      " --accel brute --brute-work-limit 0 --res 32x24 --spp 100000 --threads 1 & pid=$!; "
      "i=0; while kill -0 $pid 2>/dev/null && [ $i -lt 120 ]; do sleep 0.5; "
      "kill -INT $pid 2>/dev/null; i=$((i+1)); done; kill -KILL $pid 2>/dev/null; "
      "wait $pid; echo rc=$?' 2>&1";
  const std::string output = test::run_shell_command(cmd).output;
  EXPECT_TRUE(contains(output, "rc=130")) << output;
  EXPECT_TRUE(contains(output, "interrupted")) << output;
  if (contains(output, "wrote the")) {
    const ImageRGB img = read_image(out);
    EXPECT_GT(std::stoi(img.metadata.at("samples")), 0);
    EXPECT_LT(std::stoi(img.metadata.at("samples")), 100000);
  } else {
    EXPECT_TRUE(contains(output, "no image written")) << output;
  }
}

}  // namespace
}  // namespace kdgrid
