// Helpers of the hybrid's tests (test_hybrid_*.cpp): build parameters, the meshes only they
// use, agreement with brute force that also checks the step bound, coherent rays, and the
// lane-by-lane walk's queries that the mailbox serves.
#pragma once

#include <gtest/gtest.h>

#include <random>
#include <string>
#include <vector>

#include "accel/hybrid/hybrid.h"
#include "comparator_meshes.h"

namespace kdgrid::test {

inline BuildParams params_with(float cell, bool dense) {
  BuildParams p;
  p.cell_size = cell;
  p.hybrid_dense_matrix = dense;
  p.threads = 2;
  return p;
}

/// The value of `key` in the build statistics' extra lines.
inline std::string extra_value(const BuildStats& st, const std::string& key) {
  for (const auto& [k, v] : st.extra)
    if (k == key) return v;
  return "(no " + key + " in BuildStats::extra)";
}

/// Long thin slivers crossing the whole box in random directions, plus a few small ones.
inline Mesh long_thin(uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  Mesh m;
  for (int i = 0; i < 400; ++i) {
    const Vec3 a(u(rng), u(rng), u(rng)), b(u(rng), u(rng), u(rng));
    const Vec3 w = Vec3(u(rng), u(rng), u(rng)) * 0.01f;
    add_tri(m, a, b, b + w);
  }
  const Mesh small = random_soup(300, seed + 1, 0.03f);
  m.append(small);
  return m;
}

/// A tiny dense sphere (the teapot) in the middle of a huge empty box (the stadium).
inline Mesh teapot_in_stadium(float stadium, int sphere_levels) {
  Mesh m = octahedron_sphere(sphere_levels, 1.0f, Vec3(0.0f));
  const float s = stadium;
  // Floor and the four walls and the roof of the stadium.
  add_quad(m, {-s, -s, -s}, {s, -s, -s}, {s, -s, s}, {-s, -s, s});
  add_quad(m, {-s, s, -s}, {-s, s, s}, {s, s, s}, {s, s, -s});
  add_quad(m, {-s, -s, -s}, {-s, s, -s}, {s, s, -s}, {s, -s, -s});
  add_quad(m, {-s, -s, s}, {s, -s, s}, {s, s, s}, {-s, s, s});
  add_quad(m, {-s, -s, -s}, {-s, -s, s}, {-s, s, s}, {-s, s, -s});
  add_quad(m, {s, -s, -s}, {s, s, -s}, {s, s, s}, {s, -s, s});
  return m;
}

/// Agreement of the hybrid `h` with brute force's answers `ref` on `rays` (count_disagreements),
/// and no ray at the step bound. Returns the number of rays that disagree.
inline int compare_hybrid(const GridKdHybrid& h, const Mesh& m, const std::vector<Ray>& rays,
                          const BruteReference& ref, const std::string& label) {
  SCOPED_TRACE(label);
  const int failures = count_disagreements(m, h, rays, ref);
  EXPECT_EQ(h.step_bound_errors(), 0u) << label;
  return failures;
}

// n x n rays from one eye through a square window over the test sphere, in image order:
// neighbours cross the same leaves.
inline std::vector<Ray> coherent_rays(int n) {
  std::vector<Ray> rays;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      Ray r;
      r.org = Vec3(0.2f, 0.1f, 4.0f);
      r.dir = normalize(Vec3(-1.3f + 2.6f * float(i) / float(n - 1),
                             -1.3f + 2.6f * float(j) / float(n - 1), -4.0f));
      rays.push_back(r);
    }
  return rays;
}

// The mailbox serves the lane-by-lane walk (WatertightScalar here; MollerTest); the wide walk
// tests its groups without it (docs/HYBRID.md, "Wide leaves"), and tests/test_wide.cpp holds its
// hits to these. The queries below are the lane-by-lane walk's.
inline bool scalar_closest(const GridKdHybrid& h, const Ray& r, Hit& hit) {
  NoProbe s;
  return h.traverse<WatertightScalar, NoProbe, false>(r, &hit, s);
}
inline bool scalar_any(const GridKdHybrid& h, const Ray& r) {
  NoProbe s;
  return h.traverse<WatertightScalar, NoProbe, true>(r, nullptr, s);
}
inline bool scalar_counted(const GridKdHybrid& h, const Ray& r, Hit& hit, RayCounters& c) {
  CountProbe s;
  const bool got = h.traverse<WatertightScalar, CountProbe, false>(r, &hit, s);
  c += s.c;
  return got;
}
inline Trace scalar_trace(const GridKdHybrid& h, const Ray& r) {
  Trace t;
  TraceProbe s(&t);
  Hit hit;
  h.traverse<WatertightScalar, TraceProbe, false>(r, &hit, s);
  t.hit = hit;
  return t;
}

}  // namespace kdgrid::test
