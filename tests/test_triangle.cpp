// Properties of the ray/triangle tests over seeded random triangles and rays.
#include <gtest/gtest.h>

#include <cstring>
#include <limits>
#include <random>

#include "accel/brute.h"
#include "accel/triangle.h"

namespace kdgrid {
namespace {

Vec3 random_point(std::mt19937& rng, float scale) {
  std::uniform_real_distribution<float> u(-scale, scale);
  return {u(rng), u(rng), u(rng)};
}

template <class TriangleTest>
bool hit_tri(const Ray& r, const Vec3& a, const Vec3& b, const Vec3& c, float& t, float& u,
             float& v) {
  return TriangleTest::intersect(TriangleTest::prepare(r), a, b, c, r.tmin, r.tmax, t, u, v);
}

// A ray aimed at a random barycentric point inside a random triangle hits it at the right t,
// and the reported barycentrics reproduce the hit point.
template <class TriangleTest>
void check_interior_hits(uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> unit(0.05f, 0.9f);
  int hits = 0;
  for (int i = 0; i < 5000; ++i) {
    const Vec3 a = random_point(rng, 1), b = random_point(rng, 1), c = random_point(rng, 1);
    const Vec3 n = cross(b - a, c - a);
    if (length(n) < 1e-3f) continue;
    float bu = unit(rng), bv = unit(rng);
    if (bu + bv > 0.95f) {
      bu *= 0.5f;
      bv *= 0.5f;
    }
    const Vec3 target = a * (1 - bu - bv) + b * bu + c * bv;
    const Vec3 org = target + normalize(random_point(rng, 1) + n * 0.0f) * 3.0f;
    Ray r{org, 0.0f, target - org, kInf};
    float t, u, v;
    ASSERT_TRUE(hit_tri<TriangleTest>(r, a, b, c, t, u, v)) << "ray " << i;
    EXPECT_NEAR(t, 1.0f, 1e-3f);
    const Vec3 p = a * (1 - u - v) + b * u + c * v;
    EXPECT_LT(length(p - target), 1e-3f);
    // The same ray limited to before the triangle misses it.
    Ray short_ray = r;
    short_ray.tmax = 0.9f;
    EXPECT_FALSE(hit_tri<TriangleTest>(short_ray, a, b, c, t, u, v));
    ++hits;
  }
  EXPECT_GT(hits, 4000);
}

TEST(Triangle, WatertightHitsInteriorPoints) {
  check_interior_hits<WatertightTest>(1);
}
TEST(Triangle, MollerHitsInteriorPoints) {
  check_interior_hits<MollerTest>(2);
}

// Both tests agree with the double-precision reference away from edges.
TEST(Triangle, AgreesWithDoubleReference) {
  std::mt19937 rng(7);
  int disagreements = 0, total = 0;
  for (int i = 0; i < 20000; ++i) {
    const Vec3 a = random_point(rng, 1), b = random_point(rng, 1), c = random_point(rng, 1);
    Ray r{random_point(rng, 3), 0.0f, random_point(rng, 1), kInf};
    double td, ud, vd;
    const bool ref = intersect_triangle_double(r, a, b, c, 0.0, kInf, td, ud, vd);
    // Skip rays within a hair of an edge, where float and double may legitimately differ.
    if (ref && (ud < 1e-4 || vd < 1e-4 || ud + vd > 1 - 1e-4)) continue;
    float t, u, v;
    const bool wt = hit_tri<WatertightTest>(r, a, b, c, t, u, v);
    if (wt != ref) ++disagreements;
    if (wt && ref) {
      EXPECT_NEAR(t, td, 1e-4 * std::max(1.0, std::abs(td)));
    }
    const bool mt = hit_tri<MollerTest>(r, a, b, c, t, u, v);
    if (mt != ref) ++disagreements;
    ++total;
  }
  EXPECT_EQ(disagreements, 0) << "of " << total;
}

// A planar convex quad split into two triangles along its diagonal: rays aimed at points of
// the shared edge from directions that are not grazing must hit at least one of the two
// triangles (watertightness). Möller-Trumbore is allowed to leak; the sweep measures it.
TEST(Triangle, WatertightNeverLeaksThroughSharedEdge) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  int leaks = 0, tested = 0;
  for (int i = 0; i < 20000; ++i) {
    const Vec3 center = random_point(rng, 100);
    const Vec3 n = normalize(random_point(rng, 1));
    const Vec3 ax = normalize(cross(n, std::abs(n.x) > 0.5f ? Vec3(0, 1, 0) : Vec3(1, 0, 0)));
    const Vec3 ay = cross(n, ax);
    Vec3 p[4];
    for (int k = 0; k < 4; ++k) {
      const float ang = (k + 0.1f + 0.8f * u01(rng)) * 1.5707963f;
      p[k] = center + (ax * std::cos(ang) + ay * std::sin(ang)) * 5.0f;
    }
    const Vec3 target = lerp(p[0], p[2], 0.02f + 0.96f * u01(rng));
    const Vec3 org = target + normalize(random_point(rng, 1)) * 40.0f;
    Ray r{org, 0.0f, target - org, kInf};
    if (std::abs(dot(normalize(r.dir), n)) < 0.1f) continue;
    float t, u, v;
    const bool h1 = hit_tri<WatertightTest>(r, p[0], p[1], p[2], t, u, v);
    const bool h2 = hit_tri<WatertightTest>(r, p[0], p[2], p[3], t, u, v);
    if (!h1 && !h2) ++leaks;
    ++tested;
  }
  EXPECT_GT(tested, 15000);
  EXPECT_EQ(leaks, 0);
}

// component(v, k), the watertight test's and the kd traversals' read of a run-time axis, is
// v[k] bit for bit (signed zeros and NaN payloads included), on every axis.
TEST(Triangle, ComponentReadsTheAxisBitForBit) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (const Vec3 v :
       {Vec3(1.5f, -2.25f, 3e-38f), Vec3(-0.0f, 0.0f, -0.0f), Vec3(nan, -1e30f, 7.0f)})
    for (int k = 0; k < 3; ++k) {
      const float a = component(v, k), b = v[k];
      uint32_t ba, bb;
      std::memcpy(&ba, &a, sizeof a);
      std::memcpy(&bb, &b, sizeof b);
      EXPECT_EQ(ba, bb) << "axis " << k;
    }
}

}  // namespace
}  // namespace kdgrid
