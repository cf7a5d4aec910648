// Ray/triangle tests. Both accept a hit when tmin <= t < tmax; ties are broken by test
// order, so two structures may report different triangles at exactly the same t.
//
// Each test has a per-ray precomputation (RayData) done once per traversal, and an
// intersect() that is called per triangle. Barycentrics follow Hit: u weights v1, v weights v2.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>

#include "math/ray.h"
#include "math/vec.h"

namespace kdgrid {

/// Watertight ray/triangle intersection (Woop, Benthin, Wald, JCGT 2013). Vertices are
/// transformed into a ray-aligned shear space in which the 2D edge functions of two
/// triangles sharing an edge are exact negatives of each other, so a ray can never pass
/// between them. Edge functions that come out exactly zero are recomputed in double, as the
/// paper prescribes. Requires -ffp-contract=off (set in CMake) to keep that symmetry.
struct WatertightTest {
  /// The ray's origin is stored permuted (ox = org[kx], ...): intersect() reads each corner's
  /// coordinates on kx, ky, kz straight from memory (component()), so the permutation costs
  /// one indexed load per coordinate instead of a chain of selects (Vec3::operator[] with a
  /// run-time index: 45 of the test's 124 instructions under callgrind on the dragon).
  struct RayData {
    float ox, oy, oz;
    int kx, ky, kz;
    float sx, sy, sz;
  };

  static RayData prepare(const Ray& r) {
    RayData d;
    const Vec3 a = abs(r.dir);
    d.kz = max_dimension(a);
    d.kx = d.kz == 2 ? 0 : d.kz + 1;
    d.ky = d.kx == 2 ? 0 : d.kx + 1;
    if (r.dir[d.kz] < 0.0f) std::swap(d.kx, d.ky);  // keep winding
    d.ox = r.org[d.kx];
    d.oy = r.org[d.ky];
    d.oz = r.org[d.kz];
    d.sx = r.dir[d.kx] / r.dir[d.kz];
    d.sy = r.dir[d.ky] / r.dir[d.kz];
    d.sz = 1.0f / r.dir[d.kz];
    return d;
  }

  static bool intersect(const RayData& d, const Vec3& v0, const Vec3& v1, const Vec3& v2,
                        float tmin, float tmax, float& t_out, float& u_out, float& v_out) {
    // The corners about the origin, on the permuted axes (A = v0 - org, read as A[kx], ...).
    const float Az = component(v0, d.kz) - d.oz, Bz = component(v1, d.kz) - d.oz,
                Cz = component(v2, d.kz) - d.oz;
    const float ax = (component(v0, d.kx) - d.ox) - d.sx * Az,
                ay = (component(v0, d.ky) - d.oy) - d.sy * Az;
    const float bx = (component(v1, d.kx) - d.ox) - d.sx * Bz,
                by = (component(v1, d.ky) - d.oy) - d.sy * Bz;
    const float cx = (component(v2, d.kx) - d.ox) - d.sx * Cz,
                cy = (component(v2, d.ky) - d.oy) - d.sy * Cz;
    float U = cx * by - cy * bx;
    float V = ax * cy - ay * cx;
    float W = bx * ay - by * ax;
    if (U == 0.0f || V == 0.0f || W == 0.0f) {
      U = float(double(cx) * double(by) - double(cy) * double(bx));
      V = float(double(ax) * double(cy) - double(ay) * double(cx));
      W = float(double(bx) * double(ay) - double(by) * double(ax));
    }
    if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f)) return false;
    const float det = U + V + W;
    if (det == 0.0f) return false;
    const float az = d.sz * Az, bz = d.sz * Bz, cz = d.sz * Cz;
    const float T = U * az + V * bz + W * cz;
    const float inv_det = 1.0f / det;
    float t = T * inv_det;
    if (!(t >= tmin && t < tmax)) {  // also rejects NaN
      // T is of the order of the cube of the coordinates about the origin and overflows from
      // about 7e12 on (U, V, W, their squares, do not below kMaxRayCoordinate); t is then
      // inf or NaN. Only then is t recomputed in double, so finite results are unchanged.
      if (std::isfinite(T)) return false;
      t = depth_in_double(d, U, V, W, det, Az, Bz, Cz);
      if (!(t >= tmin && t < tmax)) return false;
    }
    t_out = t;
    u_out = V * inv_det;
    v_out = W * inv_det;
    return true;
  }

  /// t = (U sz Az + V sz Bz + W sz Cz) / det in double, for when the float sum overflowed.
  [[gnu::noinline, gnu::cold]] static float depth_in_double(const RayData& d, float U, float V,
                                                            float W, float det, float Az, float Bz,
                                                            float Cz) {
    const double sz = d.sz;
    return float((double(U) * (sz * Az) + double(V) * (sz * Bz) + double(W) * (sz * Cz)) /
                 double(det));
  }
};

/// No test: never a hit (TriangleTestKind::None). The traversals call it where they would test
/// a triangle; it reads nothing, so the compiler drops the loads of the triangle's corners and
/// what remains is the traversal itself: its nodes, cells and loops over the leaves' triangles.
/// The empty volatile asm is a side effect the compiler must keep, once per triangle: without
/// it a traversal that can never hit has no effect at all and would be deleted whole.
struct NullTest {
  struct RayData {};
  static RayData prepare(const Ray&) { return {}; }
  static bool intersect(const RayData&, const Vec3&, const Vec3&, const Vec3&, float, float, float&,
                        float&, float&) {
    asm volatile("");
    return false;
  }
};

/// Möller-Trumbore (1997): the common fast test. Not watertight: rays through shared edges
/// or vertices can slip between triangles (measured by `kdgrid sweep triangle`).
struct MollerTest {
  struct RayData {
    Vec3 org, dir;
  };
  static RayData prepare(const Ray& r) { return {r.org, r.dir}; }

  static bool intersect(const RayData& d, const Vec3& v0, const Vec3& v1, const Vec3& v2,
                        float tmin, float tmax, float& t_out, float& u_out, float& v_out) {
    const Vec3 e1 = v1 - v0, e2 = v2 - v0;
    const Vec3 p = cross(d.dir, e2);
    const float det = dot(e1, p);
    if (det == 0.0f) return false;
    const float inv = 1.0f / det;
    const Vec3 s = d.org - v0;
    const float u = dot(s, p) * inv;
    if (u < 0.0f || u > 1.0f) return false;
    const Vec3 q = cross(s, e1);
    const float v = dot(d.dir, q) * inv;
    if (v < 0.0f || u + v > 1.0f) return false;
    const float t = dot(e2, q) * inv;
    if (!(t >= tmin && t < tmax)) return false;
    t_out = t;
    u_out = u;
    v_out = v;
    return true;
  }
};

/// Double-precision reference test, for the extreme-ray suite's brute force: edge functions
/// in double about the ray; returns t in double. Not watertight by construction but exact
/// enough (53-bit) that disagreements with float structures are attributable to them.
bool intersect_triangle_double(const Ray& ray, const Vec3& v0, const Vec3& v1, const Vec3& v2,
                               double tmin, double tmax, double& t, double& u, double& v);

/// One triangle of a scalar leaf loop: triangle `prim`, corners `tri` of `pos`, against the
/// prepared ray over [tmin, best). True on a hit; a closest-hit query (kAny false) then
/// narrows `best` to it and writes it to `*hit` (an any-hit query writes nothing).
template <class TriangleTest, bool kAny, class Positions, class Corners>
[[gnu::always_inline]] inline bool hit_triangle(const typename TriangleTest::RayData& rd,
                                                const Positions& pos, const Corners& tri,
                                                uint32_t prim, float tmin, float& best, Hit* hit) {
  float t, u, v;
  if (!TriangleTest::intersect(rd, pos[tri[0]], pos[tri[1]], pos[tri[2]], tmin, best, t, u, v))
    return false;
  if constexpr (!kAny) {
    best = t;
    *hit = {t, prim, u, v};
  }
  return true;
}

/// The leaf loop of the mailboxed grids: the triangles refs[begin, end) against the prepared ray
/// over [tmin, best), each one skipped while the ray's direct-mapped `mailbox` (N slots, a
/// power of two) still holds it, since testing it again cannot change the answer. True on a
/// hit, as hit_triangle: a closest-hit query tests them all, narrowing `best`; an any-hit query
/// stops at the first.
template <class TriangleTest, bool kAny, class Probe, class Positions, class Triangles, size_t N>
[[gnu::always_inline]] inline bool hit_triangles_mailboxed(
    const typename TriangleTest::RayData& rd, const Positions& pos, const Triangles& tris,
    const uint32_t* refs, uint32_t begin, uint32_t end, uint32_t (&mailbox)[N], float tmin,
    float& best, Hit* hit, Probe& s) {
  static_assert((N & (N - 1)) == 0, "the mailbox is indexed by the triangle's low bits");
  bool found = false;
  for (uint32_t r = begin; r < end; ++r) {
    const uint32_t prim = refs[r];
    uint32_t& slot = mailbox[prim & (N - 1)];
    if (slot == prim) {
      s.mailbox_skip();
      continue;
    }
    slot = prim;
    s.tri_test(prim);
    if (hit_triangle<TriangleTest, kAny>(rd, pos, tris[prim], prim, tmin, best, hit)) {
      if constexpr (kAny) return true;
      found = true;
    }
  }
  return found;
}

}  // namespace kdgrid
