// Every builder on degenerate input: centroids equal to the last bit, denormal coordinates,
// all triangles coincident, all triangles on one line (and, beside them, a sphere). Each build
// finishes quickly without crashing, stays within the peak bound it records before allocating
// (BuildStats::peak_estimate), fits a small memory budget or refuses it (accel/guards.h), and
// the structure then answers rays as brute force does. A build over coincident triangles stops
// soon after a cancel.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include "accel/accelerator.h"
#include "scene/procedural.h"
#include "test_util.h"
#include "util/cancel.h"

namespace kdgrid::test {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

void add_triangle(Mesh& m, const Vec3& a, const Vec3& b, const Vec3& c) {
  const uint32_t i = uint32_t(m.positions.size());
  m.positions.push_back(a);
  m.positions.push_back(b);
  m.positions.push_back(c);
  m.triangles.push_back({i, i + 1, i + 2});
}

/// Twenty unit triangles, half in the plane x = 0, half in x = gap: their centroids differ by
/// `gap` along x only.
Mesh two_planes(float gap) {
  Mesh m;
  for (int i = 0; i < 20; ++i) {
    const float x = i % 2 ? gap : 0.0f;
    const float y = float(i / 2) * 0.1f;
    add_triangle(m, {x, y, 0.0f}, {x, y + 1.0f, 0.0f}, {x, y, 1.0f});
  }
  return m;
}

/// `n` copies of one triangle (each with its own vertices).
Mesh coincident(int n) {
  Mesh m;
  for (int i = 0; i < n; ++i) add_triangle(m, {0, 0, 0}, {1, 0, 0}, {0, 1, 0});
  return m;
}

/// `n` distinct triangles with one centroid: the triangle (1,0,0) (0,1,0) (-1,-1,0) rotated
/// about the z axis, and `n` more whose centroids step one ulp apart along x.
Mesh equal_centroids(int n) {
  Mesh m;
  for (int i = 0; i < n; ++i) {
    const float a = 6.2831853f * float(i) / float(n);
    const float c = std::cos(a), s = std::sin(a);
    auto rot = [&](float x, float y) { return Vec3(c * x - s * y, s * x + c * y, 0.25f); };
    // Corners symmetric about the origin's centroid to the last bit: v, w, -(v + w).
    const Vec3 v = rot(1.0f, 0.0f), w = rot(0.0f, 1.0f);
    add_triangle(m, v, w, Vec3(-(v.x + w.x), -(v.y + w.y), 0.25f));
  }
  float x = 0.5f;
  for (int i = 0; i < n; ++i) {
    add_triangle(m, {x, -0.5f, -0.5f}, {x, 0.5f, -0.5f}, {x, 0.0f, 0.5f});
    x = std::nextafter(x, 1.0f);
  }
  return m;
}

/// `n` zero-area triangles and `n` needles along the x axis.
Mesh on_a_line(int n) {
  Mesh m;
  for (int i = 0; i < n; ++i) {
    const float x0 = float(i) * 0.01f;
    add_triangle(m, {x0, 0, 0}, {x0 + 0.5f, 0, 0}, {x0 + 1.0f, 0, 0});
    add_triangle(m, {x0, 0, 0}, {x0 + 1.0f, 1e-7f, 0}, {x0 + 1.0f, 0, 1e-7f});
  }
  return m;
}

/// An icosphere of radius `scale` at the origin: every coordinate subnormal below ~1e-38.
Mesh tiny_sphere(float scale) {
  Mesh m = make_icosphere(3);
  for (Vec3& p : m.positions) p = p * scale;
  m.normals.clear();
  return m;
}

/// Rays from all around `box`, aimed at points inside it, in the box's own units.
std::vector<Ray> rays_through(const Box3& box, int n) {
  std::vector<Ray> rays;
  const Vec3 c = box.center();
  const float r = std::max(max_component(box.extent()), std::numeric_limits<float>::min());
  for (int i = 0; i < n; ++i) {
    const float u = (float(i) + 0.5f) / float(n);
    const float phi = 2.399963f * float(i), z = 1.0f - 2.0f * u, s = std::sqrt(1.0f - z * z);
    const Vec3 d(s * std::cos(phi), s * std::sin(phi), z);
    const Vec3 target = c + Vec3(0.3f * std::sin(3.1f * float(i)), 0.3f * std::cos(1.7f * float(i)),
                                 0.3f * std::sin(0.7f * float(i))) *
                                r;
    Ray ray;
    ray.org = target + d * (3.0f * r);
    ray.dir = normalize(target - ray.org);
    rays.push_back(ray);
  }
  return rays;
}

struct Case {
  std::string name;
  Mesh mesh;
};

/// What a finished build used (its structure, and the peak its own account saw) stays within
/// the bound it recorded before allocating, which is at least what it expected.
void expect_within_peak_bound(const std::string& name, const BuildStats& st) {
  if (name == "brute") return;  // nothing built, no estimate
  EXPECT_LE(st.bytes, st.peak_estimate);
  EXPECT_LE(st.peak_accounted, st.peak_estimate);
  EXPECT_LE(st.peak_expected, st.peak_estimate);
}

std::vector<Case> degenerate_cases() {
  std::vector<Case> cs;
  cs.push_back({"planes 1e-39 apart (denormal centroid gap)", two_planes(1e-39f)});
  cs.push_back({"planes 1e-45 apart (smallest denormal)", two_planes(1e-45f)});
  cs.push_back({"sphere scaled 1e-40 (denormal coordinates)", tiny_sphere(1e-40f)});
  cs.push_back({"sphere scaled 1e-30", tiny_sphere(1e-30f)});
  cs.push_back({"equal centroids, and one ulp apart", equal_centroids(300)});
  cs.push_back({"3000 coincident triangles", coincident(3000)});
  cs.push_back({"all on a line", on_a_line(300)});
  cs.push_back({"sphere of 5120 triangles (no degeneracy)", make_icosphere(4)});
  return cs;
}

class DegenerateBuild : public ::testing::TestWithParam<std::string> {};

TEST_P(DegenerateBuild, BuildsQuicklyWithinItsEstimateAndAgreesWithBruteForce) {
  const std::string name = GetParam();
  // Speed is relative: a degenerate case may take no longer than twice (or a second) the same
  // structure's build of a 5120-triangle sphere in this process, so a loaded or sanitized
  // machine moves both sides alike while a quadratic build still fails.
  const Mesh yardstick = make_icosphere(4);
  const auto y0 = Clock::now();
  make_accelerator(name)->build(yardstick, BuildParams{});
  const double limit = std::max(1.0, 2.0 * seconds_since(y0));
  for (const Case& c : degenerate_cases()) {
    SCOPED_TRACE(c.name);
    auto a = make_accelerator(name);
    const auto t0 = Clock::now();
    const BuildStats st = a->build(c.mesh, BuildParams{});
    const double seconds = seconds_since(t0);
    std::printf(
        "[ degen    ] %-13s %-44s %.3f s, %llu references, %llu bytes, account peak %llu "
        "(bound %llu, expected %llu)\n",
        name.c_str(), c.name.c_str(), seconds, (unsigned long long)st.references,
        (unsigned long long)st.bytes, (unsigned long long)st.peak_accounted,
        (unsigned long long)st.peak_estimate, (unsigned long long)st.peak_expected);
    EXPECT_LT(seconds, limit) << "the sphere took " << limit / 2.0 << " s";
    expect_within_peak_bound(name, st);

    // Bounded: under a small memory budget the build either fits it or refuses with a
    // ParamError (accel/guards.h), whatever the degeneracy does to its estimate.
    BuildParams tight;
    tight.memory_budget = 96 * 1024;
    try {
      const BuildStats ts = make_accelerator(name)->build(c.mesh, tight);
      EXPECT_LE(ts.bytes, tight.memory_budget);
      expect_within_peak_bound(name, ts);
      EXPECT_LE(ts.peak_estimate, tight.memory_budget);
    } catch (const ParamError&) {
    }

    const auto brute = build_accelerator("brute", c.mesh, BuildParams{});
    int differ = 0;
    for (const Ray& r : rays_through(c.mesh.bounds(), 200)) {
      Hit ha, hb;
      const bool ia = a->intersect(r, ha), ib = brute->intersect(r, hb);
      const bool oa = a->occluded(r);
      // Coincident triangles tie to within an ulp or two of t (the agreement harness's rule).
      if (ia != ib || oa != ib || (ia && std::fabs(ha.t - hb.t) > 1e-5f * hb.t)) {
        if (++differ <= 3)
          ADD_FAILURE() << "ray org " << r.org.x << " " << r.org.y << " " << r.org.z << " dir "
                        << r.dir.x << " " << r.dir.y << " " << r.dir.z << ": " << name << " " << ia
                        << " t=" << ha.t << " prim " << ha.prim << " occluded " << oa << "; brute "
                        << ib << " t=" << hb.t << " prim " << hb.prim;
      }
    }
    EXPECT_EQ(differ, 0) << differ << " of 200 rays differ from brute force";
  }
}

TEST(DegenerateBuilds, GridOverCoincidentTrianglesIsCoarsenedNotQuadratic) {
  // 20000 copies of one triangle: the density heuristic asks for 80000 cells, each copy
  // overlaps about half of them, so the references would be 8e8 (minutes, gigabytes).
  const Mesh m = coincident(20000);
  auto a = make_accelerator("grid");
  const auto t0 = Clock::now();
  const BuildStats st = a->build(m, BuildParams{});
  std::printf("[ degen    ] grid over 20000 coincident triangles: %.3f s, %llu references\n",
              seconds_since(t0), (unsigned long long)st.references);
  EXPECT_LE(st.references, 64u * m.num_triangles());
  bool coarsened = false;
  for (const auto& [k, v] : st.extra) coarsened |= k == "coarsened from";
  EXPECT_TRUE(coarsened);
  const auto brute = build_accelerator("brute", m, BuildParams{});
  for (const Ray& r : rays_through(m.bounds(), 50)) {
    Hit ha, hb;
    ASSERT_EQ(a->intersect(r, ha), brute->intersect(r, hb));
  }
}

TEST(DegenerateBuilds, EveryBuildOverCoincidentTrianglesStopsSoonAfterACancel) {
  const Mesh m = coincident(100000);
  for (const std::string& name : accelerator_names()) {
    SCOPED_TRACE(name);
    CancelToken token;
    BuildParams p;
    p.cancel = &token;
    auto a = make_accelerator(name);
    Clock::time_point cancelled_at{};
    std::thread canceller([&] {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
      cancelled_at = Clock::now();
      token.cancel();
    });
    try {
      a->build(m, p);
    } catch (const BuildCancelled&) {
    }
    const auto done = Clock::now();
    canceller.join();
    // A build that finished before the cancel also passes: what may not happen is work
    // going on long after it.
    EXPECT_LT(std::chrono::duration<double>(done - cancelled_at).count(), 1.0);
  }
}

INSTANTIATE_TEST_SUITE_P(All, DegenerateBuild, ::testing::ValuesIn(accelerator_names()),
                         [](const auto& test_info) { return test_name(test_info.param); });

}  // namespace
}  // namespace kdgrid::test
