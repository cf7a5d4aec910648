// Rays that start on a surface (docs/RAYSETS.md): the starts_on_triangle rule, the generated
// secondary rays stepped past coincident layers (step_past_coincident) so that every structure
// answers them alike, surfaces at an angle never stepped through, and the benchmark's
// classification of differences on rays that do start on a surface.
#include <gtest/gtest.h>

#include <cmath>

#include "accel/accelerator.h"
#include "bench/probes.h"
#include "bench/raysets.h"
#include "render/offset.h"
#include "scene/procedural.h"

namespace kdgrid {
namespace {

constexpr float kFloorY = 0.25f;

/// A square floor at y = kFloorY of n x n tiles facing up, over [-4, 4]^2.
void add_tiles(Mesh& m, int n, float y) {
  for (int i = 0; i < n; ++i)
    for (int k = 0; k < n; ++k) {
      const float x0 = -4.0f + 8.0f * i / n, x1 = -4.0f + 8.0f * (i + 1) / n;
      const float z0 = -4.0f + 8.0f * k / n, z1 = -4.0f + 8.0f * (k + 1) / n;
      const uint32_t b = uint32_t(m.positions.size());
      for (const Vec3& p : {Vec3(x0, y, z0), Vec3(x0, y, z1), Vec3(x1, y, z1), Vec3(x1, y, z0)})
        m.positions.push_back(p);
      m.triangles.push_back({b, b + 1, b + 2});
      m.triangles.push_back({b, b + 2, b + 3});
    }
}

/// The point a ray leaving the floor at (x, z) starts from: the floor's offset point.
Vec3 floor_origin(const Mesh& m, float x, float z) {
  return offset_ray_origin({x, kFloorY, z}, {0, 1, 0}, m.corners(0));
}

/// Tiles, a slab exactly in their plane (one quad, split the other way), a layer exactly where
/// a ray leaving the floor starts (the floor's offset height), in a closed room 9 x 3 x 9.
Mesh layered_floor() {
  Mesh m;
  add_tiles(m, 4, kFloorY);
  const float layer = floor_origin(m, 0.0f, 0.0f).y;
  EXPECT_GT(layer, kFloorY);
  Mesh slab, top;
  add_tiles(slab, 1, kFloorY);
  slab.triangles = {{1, 2, 3}, {1, 3, 0}};
  add_tiles(top, 1, layer);
  m.append(slab);
  m.append(top);
  m.append(make_box({0.0f, 1.5f, 0.0f}, {4.5f, 1.5f, 4.5f}, 0.0f, /*inward=*/true));
  m.validate("layered floor");
  return m;
}

/// Rays leaving the floor of layered_floor() upwards, many of them grazing.
std::vector<Ray> rays_off_the_floor(const Mesh& m, int n) {
  std::vector<Ray> rays;
  for (int i = 0; i < n; ++i) {
    const float x = -3.5f + 7.0f * float(i % 17) / 16.0f,
                z = -3.5f + 7.0f * float(i / 17 % 13) / 12.0f;
    const float phi = 0.37f * float(i);
    const float up = i % 3 == 0 ? 1e-4f : (i % 3 == 1 ? 0.02f : 0.6f);  // grazing to steep
    rays.push_back(
        {floor_origin(m, x, z), 0.0f, normalize(Vec3(std::cos(phi), up, std::sin(phi))), kInf});
  }
  return rays;
}

TEST(CoincidentSurfaces, StartsOnTriangleIsWithinHalfTheOffset) {
  const std::array<Vec3, 3> tri = {Vec3(-4, kFloorY, -4), Vec3(-4, kFloorY, 4),
                                   Vec3(4, kFloorY, 4)};
  const Vec3 p(-1.0f, kFloorY, 1.0f);
  const Vec3 off = offset_ray_origin(p, {0, 1, 0}, tri);
  const float d = off.y - p.y;
  ASSERT_GT(d, 0.0f);
  EXPECT_TRUE(starts_on_triangle(p, tri));
  EXPECT_TRUE(starts_on_triangle({p.x, p.y + 0.4f * d, p.z}, tri));
  EXPECT_TRUE(starts_on_triangle({p.x, p.y - 0.4f * d, p.z}, tri));
  EXPECT_FALSE(starts_on_triangle({p.x, p.y + 0.6f * d, p.z}, tri));
  EXPECT_FALSE(starts_on_triangle(off, tri));
  // Outside the triangle's footprint the plane still counts: a grazing ray meets it anywhere.
  EXPECT_TRUE(starts_on_triangle({40.0f, kFloorY, -30.0f}, tri));
  // Zero area: no plane to start on.
  EXPECT_FALSE(starts_on_triangle(p, {Vec3(0, 0, 0), Vec3(1, 1, 1), Vec3(2, 2, 2)}));
  // The same answers at any scale (powers of two scale every quantity exactly).
  for (const float s : {0x1p-60f, 0x1p-20f, 0x1p20f, 0x1p60f}) {
    const std::array<Vec3, 3> st = {tri[0] * s, tri[1] * s, tri[2] * s};
    EXPECT_TRUE(starts_on_triangle(p * s, st)) << s;
    EXPECT_TRUE(starts_on_triangle(Vec3(p.x, p.y + 0.4f * d, p.z) * s, st)) << s;
    EXPECT_FALSE(starts_on_triangle(off * s, st)) << s;
  }
}

TEST(CoincidentSurfaces, SecondaryRaysStepPastLayersAndEveryStructureAgrees) {
  const Mesh m = layered_floor();
  std::vector<Ray> rays = rays_off_the_floor(m, 300);
  auto brute = build_accelerator("brute", m, BuildParams{});
  const uint32_t top_first = 4 * 4 * 2 + 2;  // the layer at the offset height
  for (Ray& r : rays) {
    ASSERT_TRUE(starts_on_triangle(r.org, m.corners(top_first)));  // the case under test
    EXPECT_GE(step_past_coincident(*brute, m, /*from=*/0, r), 1);
    EXPECT_GT(r.org.y, floor_origin(m, 0, 0).y);
    Hit h;
    ASSERT_TRUE(brute->intersect(r, h));
    EXPECT_FALSE(starts_on_triangle(r.org, m.corners(h.prim)));
    EXPECT_GE(h.prim, top_first + 2);  // the room, not a layer under the origin
  }
  std::vector<Hit> ref(rays.size());
  for (size_t i = 0; i < rays.size(); ++i) brute->intersect(rays[i], ref[i]);
  for (const std::string& name : accelerator_names()) {
    auto a = build_accelerator(name, m, BuildParams{});
    std::vector<Hit> hits(rays.size());
    for (size_t i = 0; i < rays.size(); ++i) a->intersect(rays[i], hits[i]);
    uint64_t differ = 0;
    hit_agreement(m, rays, hits, ref, false, 1e-5, &differ);
    EXPECT_EQ(differ, 0u) << name;
  }
}

TEST(CoincidentSurfaces, SurfacesAtAnAngleAreNeverSteppedThrough) {
  // A floor and a wall x = 1 meeting it; the ray leaves the floor on the corner line, heading
  // into the wall: it must stop there, not be moved through it.
  Mesh m;
  add_tiles(m, 1, kFloorY);
  const uint32_t b = uint32_t(m.positions.size());
  for (const Vec3& p : {Vec3(1, 0, -4), Vec3(1, 3, -4), Vec3(1, 3, 4), Vec3(1, 0, 4)})
    m.positions.push_back(p);
  m.triangles.push_back({b, b + 1, b + 2});
  m.triangles.push_back({b, b + 2, b + 3});
  auto brute = build_accelerator("brute", m, BuildParams{});
  Ray r{floor_origin(m, 1.0f - 1e-5f, 0.5f), 0.0f, normalize(Vec3(1.0f, 0.3f, 0.0f)), kInf};
  ASSERT_TRUE(starts_on_triangle(r.org, m.corners(2)));
  const Ray before = r;
  EXPECT_EQ(step_past_coincident(*brute, m, 0, r), 0);
  EXPECT_EQ(r.org.x, before.org.x);
  EXPECT_EQ(r.org.y, before.org.y);
  Hit h;
  ASSERT_TRUE(brute->intersect(r, h));
  EXPECT_GE(h.prim, 2u);  // the wall
}

TEST(CoincidentSurfaces, AShadowRayKeepsItsEndAtTheLight) {
  const Mesh m = layered_floor();
  auto brute = build_accelerator("brute", m, BuildParams{});
  const Vec3 light(0.5f, 2.5f, -0.25f);
  const Vec3 o = floor_origin(m, 1.0f, 1.5f);
  Ray r{o, 0.0f, light - o, 1.0f};
  ASSERT_EQ(step_past_coincident(*brute, m, 0, r, /*keep_end=*/true), 1);
  const Vec3 end = r.org + r.dir * r.tmax;
  EXPECT_NEAR(end.x, light.x, 1e-6f);
  EXPECT_NEAR(end.y, light.y, 1e-6f);
  EXPECT_NEAR(end.z, light.z, 1e-6f);
  EXPECT_FALSE(brute->occluded(r));  // nothing between the floor and the light
}

TEST(CoincidentSurfaces, GeneratedSetsOfAnInteriorStartOnNoSurface) {
  Scene s = generate_scene("interior");
  s.finalize();
  auto bvh = build_accelerator("bvh", s.mesh, BuildParams{});
  auto brute = build_accelerator("brute", s.mesh, BuildParams{});
  RaySetSpec spec;
  spec.camera = s.camera;
  spec.width = 96;
  spec.height = 60;
  const std::vector<Ray> primary = primary_rays(*s.camera, spec.width, spec.height);
  const std::vector<Hit> primary_hits = trace_hits(*bvh, primary);
  // The triangle each secondary ray leaves: the primary hits, in order, misses left out.
  std::vector<uint32_t> from;
  for (const Hit& h : primary_hits)
    if (h.valid()) from.push_back(h.prim);
  // Rays whose closest hit is a layer parallel to the surface they leave that they start on
  // (a corner, where a wall meets the floor within rounding, is not such a layer).
  auto on_layer = [&](const std::vector<Ray>& rays) {
    size_t n = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
      Hit h;
      if (!brute->intersect(rays[i], h) || !starts_on_triangle(rays[i].org, s.mesh.corners(h.prim)))
        continue;
      const float c = dot(normalize(s.mesh.geometric_normal(h.prim)),
                          normalize(s.mesh.geometric_normal(from[i])));
      n += std::fabs(c) > 0.999f;
    }
    return n;
  };
  for (const RaySetKind kind : {RaySetKind::Diffuse, RaySetKind::Shadow}) {
    spec.kind = kind;
    spec.seed = 3;
    const std::vector<Ray> rays = make_ray_set(spec, s.mesh, bvh.get());
    ASSERT_EQ(rays.size(), from.size());
    EXPECT_EQ(on_layer(rays), 0u) << to_string(kind);
    const bool any = kind == RaySetKind::Shadow;
    std::vector<Hit> ref, hits;
    trace_rays(*brute, rays, any, &ref);
    for (const std::string& name : accelerator_names()) {
      auto a = build_accelerator(name, s.mesh, BuildParams{});
      trace_rays(*a, rays, any, &hits);
      // Ties between a tile and the slab under it are judged on t relative to t, which is
      // rounded relative to the coordinates (about 250 here): hits 0.01 from their origin
      // need a looser tolerance than the bench's 1e-5.
      uint64_t differ = 0;
      hit_agreement(s.mesh, rays, hits, ref, any, 1e-4, &differ);
      if (is_embree(name))  // its own triangle test: shared edges may go the other way
        EXPECT_LE(differ, rays.size() / 2000) << name << " on the " << to_string(kind) << " set";
      else
        EXPECT_EQ(differ, 0u) << name << " on the " << to_string(kind) << " set";
    }
  }
}

TEST(CoincidentSurfaces, BenchAgreementClassifiesRaysThatStartOnASurface) {
  const Mesh m = layered_floor();
  // Two rays and two answers each: ray 0 starts on the layer that one answer reports at t = 0,
  // ray 1 starts well above every layer and the answers name different surfaces.
  const Vec3 on_layer = floor_origin(m, 0.3f, 0.3f);
  const std::vector<Ray> rays = {{on_layer, 0.0f, {0, 1, 0}, kInf},
                                 {{0.3f, 1.0f, 0.3f}, 0.0f, {0, 1, 0}, kInf}};
  const uint32_t layer = 4 * 4 * 2 + 2, wall = layer + 2;
  std::vector<Hit> a(2), b(2);
  a[0] = Hit{0.0f, layer, 0.1f, 0.1f};
  b[0] = Hit{2.75f, wall, 0.1f, 0.1f};
  a[1] = Hit{2.0f, wall, 0.1f, 0.1f};
  uint64_t differ = 0, on_surface = 0;
  const double agreement = hit_agreement(m, rays, a, b, false, 1e-5, &differ, &on_surface);
  EXPECT_EQ(differ, 2u);
  EXPECT_EQ(on_surface, 1u);
  EXPECT_DOUBLE_EQ(agreement, 0.0);
}

}  // namespace
}  // namespace kdgrid
