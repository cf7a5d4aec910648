// Procedural meshes, seeded rays, the brute-force agreement check and the check of refused
// build parameters, shared by the tests of the structures (test_structures.cpp, test_grid.cpp,
// test_kdtree.cpp, test_bvh.cpp, test_hybrid_*.cpp, test_embree.cpp).
#pragma once

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <functional>
#include <initializer_list>
#include <random>
#include <string>
#include <vector>

#include "accel/accelerator.h"
#include "accel/brute.h"
#include "util/error.h"

namespace kdgrid::test {

inline void add_tri(Mesh& m, const Vec3& a, const Vec3& b, const Vec3& c) {
  const uint32_t base = uint32_t(m.positions.size());
  m.positions.insert(m.positions.end(), {a, b, c});
  m.triangles.push_back({base, base + 1, base + 2});
}

/// A mesh of `n` triangles whose corners `make(rng)` returns, from one generator seeded with
/// `seed`.
template <class MakeTriangle>
Mesh generated_triangles(size_t n, uint32_t seed, MakeTriangle make) {
  std::mt19937 rng(seed);
  Mesh m;
  for (size_t i = 0; i < n; ++i) {
    const std::array<Vec3, 3> c = make(rng);
    add_tri(m, c[0], c[1], c[2]);
  }
  return m;
}

/// The quad a, b, c, d (in order around it) as the triangles abc and acd.
inline void add_quad(Mesh& m, const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  add_tri(m, a, b, c);
  add_tri(m, a, c, d);
}

/// A sphere of radius `r` about `c`: an octahedron subdivided `levels` times (8 * 4^levels
/// triangles), its first vertices on the axes. Each triangle has its own three vertices;
/// midpoints are computed symmetrically, so shared edges get bit-identical vertices.
inline Mesh octahedron_sphere(int levels, float r = 1.0f, Vec3 c = Vec3(0.0f)) {
  const Vec3 px(1, 0, 0), nx(-1, 0, 0), py(0, 1, 0), ny(0, -1, 0), pz(0, 0, 1), nz(0, 0, -1);
  std::vector<std::array<Vec3, 3>> tris = {{px, py, pz}, {py, nx, pz}, {nx, ny, pz}, {ny, px, pz},
                                           {py, px, nz}, {nx, py, nz}, {ny, nx, nz}, {px, ny, nz}};
  for (int l = 0; l < levels; ++l) {
    std::vector<std::array<Vec3, 3>> next;
    for (const auto& t : tris) {
      const Vec3 ab = normalize(t[0] + t[1]), bc = normalize(t[1] + t[2]),
                 ca = normalize(t[2] + t[0]);
      next.push_back({t[0], ab, ca});
      next.push_back({ab, t[1], bc});
      next.push_back({ca, bc, t[2]});
      next.push_back({ab, bc, ca});
    }
    tris.swap(next);
  }
  Mesh m;
  for (const auto& t : tris) add_tri(m, c + t[0] * r, c + t[1] * r, c + t[2] * r);
  return m;
}

/// `n` random triangles with corners inside the box [lo, hi]: each triangle's three corners
/// lie within `size` of a random centre in every coordinate (clamped to the box). With `size`
/// 0 each triangle draws its own size between 1e-3 and 0.5 (log-uniform), from tiny to large.
inline Mesh random_soup(int n, uint32_t seed, float size = 0.0f, Vec3 lo = Vec3(-1.0f),
                        Vec3 hi = Vec3(1.0f)) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f), s(-1.0f, 1.0f), lg(-3.0f, -0.3f);
  Mesh m;
  for (int i = 0; i < n; ++i) {
    const Vec3 c = lo + (hi - lo) * Vec3(u(rng), u(rng), u(rng));
    const float sz = size > 0.0f ? size : std::pow(10.0f, lg(rng));
    Vec3 p[3];
    for (auto& q : p) q = max(lo, min(hi, c + Vec3(s(rng), s(rng), s(rng)) * sz));
    add_tri(m, p[0], p[1], p[2]);
  }
  return m;
}

/// Closed UV sphere (shared vertices), `rings` x `segments`.
inline Mesh sphere(int rings, int segments, const Vec3& center = Vec3(0.0f), float r = 1.0f) {
  Mesh m;
  for (int i = 0; i <= rings; ++i) {
    const float th = 3.14159265f * float(i) / float(rings);
    for (int j = 0; j < segments; ++j) {
      const float ph = 2.0f * 3.14159265f * float(j) / float(segments);
      m.positions.push_back(
          center +
          Vec3(std::sin(th) * std::cos(ph), std::cos(th), std::sin(th) * std::sin(ph)) * r);
    }
  }
  auto id = [&](int i, int j) { return uint32_t(i * segments + (j % segments)); };
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      if (i > 0) m.triangles.push_back({id(i, j), id(i + 1, j), id(i, j + 1)});
      if (i + 1 < rings) m.triangles.push_back({id(i, j + 1), id(i + 1, j), id(i + 1, j + 1)});
    }
  return m;
}

/// Unit quads (two triangles each) on integer coordinates in the three axis planes, many
/// coplanar and sharing edges, plus exact duplicates of some quads: the worst case for
/// split planes and cell boundaries.
inline Mesh integer_quads(int n) {
  Mesh m;
  auto quad = [&](int axis, int a, int b, int c) {
    auto p = [&](int du, int dv) {
      Vec3 v;
      v[axis] = float(a);
      v[(axis + 1) % 3] = float(b + du);
      v[(axis + 2) % 3] = float(c + dv);
      return v;
    };
    add_tri(m, p(0, 0), p(1, 0), p(1, 1));
    add_tri(m, p(0, 0), p(1, 1), p(0, 1));
  };
  for (int axis = 0; axis < 3; ++axis)
    for (int a = 0; a <= n; a += 2)
      for (int b = 0; b < n; ++b)
        for (int c = 0; c < n; ++c)
          if ((a + b + c + axis) % 3 != 0) quad(axis, a, b, c);
  for (int b = 0; b < n; b += 2) quad(1, 1, b, b);  // duplicates of the plane y = 1
  for (int b = 0; b < n; b += 2) quad(1, 1, b, b);
  return m;
}

/// Long thin triangles (slivers) spanning the box in random directions.
inline Mesh slivers(uint32_t seed, int n) {
  Mesh m;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (int i = 0; i < n; ++i) {
    const Vec3 a(u(rng), u(rng), u(rng)), b(u(rng), u(rng), u(rng));
    const Vec3 w = Vec3(u(rng), u(rng), u(rng)) * 1e-3f;
    add_tri(m, a, b, a + w);
  }
  return m;
}

/// A tiny dense cluster of triangles near the origin inside a huge box spanned by a few big
/// triangles far away: the teapot-in-a-stadium case.
inline Mesh cluster_in_box(uint32_t seed) {
  Mesh m = random_soup(3000, seed);
  for (Vec3& p : m.positions) p = p * 1e-3f;
  const float s = 1000.0f;
  add_tri(m, Vec3(-s, -s, -s), Vec3(s, -s, -s), Vec3(s, -s, s));
  add_tri(m, Vec3(-s, s, -s), Vec3(s, s, s), Vec3(s, s, -s));
  add_tri(m, Vec3(-s, -s, s), Vec3(s, s, s), Vec3(-s, s, s));
  return m;
}

/// The mesh with every position scaled by `scale` then translated by `offset`.
inline Mesh transformed(Mesh m, float scale, const Vec3& offset) {
  for (Vec3& p : m.positions) p = p * scale + offset;
  return m;
}

/// A scale and offset that move a test mesh to where float precision is strained.
struct ScaleCase {
  const char* name;
  float scale;
  Vec3 offset;
};

/// The scales and offsets of the extreme-scale tests: unit, 1e-6, 1e6 and translated by 1e5.
inline std::vector<ScaleCase> extreme_scale_cases() {
  return {{"unit", 1.0f, Vec3(0.0f)},
          {"scale 1e-6", 1e-6f, Vec3(0.0f)},
          {"scale 1e6", 1e6f, Vec3(0.0f)},
          {"translated 1e5", 1.0f, Vec3(1e5f, 1e5f, -1e5f)}};
}

/// Seeded rays, four kinds in turn, from origins around and inside the mesh box: random
/// directions, aimed at points on random triangles (hits), axis-parallel, and segments with
/// a finite [tmin, tmax] (for any-hit).
inline std::vector<Ray> random_rays(const Mesh& m, int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f), s(-1.0f, 1.0f);
  const Box3 b = m.bounds();
  const Vec3 c = b.center(), e = b.extent() * 0.75f + Vec3(1e-3f * max_component(b.extent()));
  std::vector<Ray> rays;
  rays.reserve(size_t(n));
  for (int i = 0; i < n; ++i) {
    Ray r;
    r.org = c + e * Vec3(s(rng), s(rng), s(rng)) * 1.5f;
    switch (i % 4) {
      case 0:
        r.dir = Vec3(s(rng), s(rng), s(rng));
        break;
      case 1: {
        const auto t = m.corners(size_t(rng() % m.num_triangles()));
        float a = u(rng), bb = u(rng);
        if (a + bb > 1) {
          a = 1 - a;
          bb = 1 - bb;
        }
        r.dir = t[0] * (1 - a - bb) + t[1] * a + t[2] * bb - r.org;
        break;
      }
      case 2: {
        r.dir = Vec3(0.0f);
        r.dir[int(rng() % 3)] = (rng() & 1) ? 1.0f : -1.0f;
        break;
      }
      default:
        r.dir = Vec3(s(rng), s(rng), s(rng));
        r.tmin = u(rng) * 0.5f;
        r.tmax = r.tmin + u(rng) * 2.0f;
        break;
    }
    if (r.dir == Vec3(0.0f)) r.dir = Vec3(1, 0, 0);
    rays.push_back(r);
  }
  return rays;
}

/// Brute force's answers for a ray set: closest hit and any-hit per ray.
struct BruteReference {
  std::vector<Hit> hits;
  std::vector<char> occluded;
};

inline BruteReference brute_answers(const Mesh& mesh, const std::vector<Ray>& rays) {
  BruteForce brute;
  brute.build(mesh, BuildParams{});
  BruteReference ref;
  ref.hits.resize(rays.size());
  ref.occluded.resize(rays.size());
  for (size_t i = 0; i < rays.size(); ++i) {
    brute.intersect(rays[i], ref.hits[i]);
    ref.occluded[i] = brute.occluded(rays[i]);
  }
  return ref;
}

/// Agreement of `acc` with brute force's answers `ref` on `rays`: closest t within `t_tol`
/// relative, the same triangle unless tied (the reported triangle's own t equals the reference
/// t), identical any-hit. Returns the number of rays that disagree; reports the first `report`.
inline int count_disagreements(const Mesh& mesh, const Accelerator& acc,
                               const std::vector<Ray>& rays, const BruteReference& ref,
                               int report = 5, int* hits_out = nullptr, double t_tol = 1e-5) {
  int bad = 0, hits = 0;
  for (size_t i = 0; i < rays.size(); ++i) {
    const Ray& r = rays[i];
    const Hit& hr = ref.hits[i];
    Hit ha;
    const bool br = hr.valid(), ba = acc.intersect(r, ha);
    bool ok = br == ba;
    if (ok && br) {
      ++hits;
      const double tol = t_tol * std::max(1.0, std::fabs(double(hr.t)));
      ok = std::fabs(double(ha.t) - double(hr.t)) <= tol;
      if (ok && ha.prim != hr.prim) {
        // A tie: the reported triangle must itself be hit at the reference t.
        const auto c = mesh.corners(ha.prim);
        float t, u, v;
        const auto rd = WatertightTest::prepare(r);
        ok = WatertightTest::intersect(rd, c[0], c[1], c[2], r.tmin, kInf, t, u, v) &&
             std::fabs(double(t) - double(hr.t)) <= tol;
      }
    }
    const bool oa = acc.occluded(r), orf = ref.occluded[i];
    if (oa != orf) ok = false;
    if (!ok) {
      if (bad < report)
        ADD_FAILURE() << acc.name() << " ray " << i << " org (" << r.org.x << "," << r.org.y << ","
                      << r.org.z << ") dir (" << r.dir.x << "," << r.dir.y << "," << r.dir.z
                      << ") tmin " << r.tmin << " tmax " << r.tmax << ": brute " << br << " t "
                      << hr.t << " prim " << hr.prim << " occ " << orf << "; " << acc.name() << " "
                      << ba << " t " << ha.t << " prim " << ha.prim << " occ " << oa;
      ++bad;
    }
  }
  if (hits_out) *hits_out = hits;
  return bad;
}

/// count_disagreements against a brute-force reference computed here.
inline int count_disagreements(const Mesh& mesh, const Accelerator& acc,
                               const std::vector<Ray>& rays, int report = 5,
                               int* hits_out = nullptr, double t_tol = 1e-5) {
  return count_disagreements(mesh, acc, rays, brute_answers(mesh, rays), report, hits_out, t_tol);
}

/// Expects building `acc` on `mesh` to throw ParamError with each of `bad`'s changes to the
/// default parameters.
inline void expect_params_refused(Accelerator& acc, const Mesh& mesh,
                                  std::initializer_list<std::function<void(BuildParams&)>> bad) {
  for (const auto& change : bad) {
    BuildParams p;
    change(p);
    EXPECT_THROW(acc.build(mesh, p), ParamError);
  }
}

/// The named procedural meshes every structure is checked on.
struct NamedMesh {
  std::string name;
  Mesh mesh;
};
inline std::vector<NamedMesh> test_meshes() {
  std::vector<NamedMesh> v;
  v.push_back({"soup", random_soup(4000, 1)});
  v.push_back({"sphere", sphere(40, 80)});
  v.push_back({"integer_quads", integer_quads(8)});
  v.push_back({"slivers", slivers(2, 1500)});
  v.push_back({"cluster_in_box", cluster_in_box(3)});
  Mesh dup = sphere(10, 20);
  dup.append(sphere(10, 20));
  v.push_back({"duplicates", dup});
  v.push_back({"sphere_1e-6", transformed(sphere(20, 40), 1e-6f, Vec3(0.0f))});
  v.push_back({"sphere_1e6", transformed(sphere(20, 40), 1e6f, Vec3(0.0f))});
  v.push_back({"quads_at_1e5", transformed(integer_quads(6), 1.0f, Vec3(1e5f, -1e5f, 1e5f))});
  return v;
}

/// Rays with +0 and -0 direction components from origins inside, outside and on the box of
/// the unit sphere: the zero components give +inf / -inf reciprocals in every traversal.
inline std::vector<Ray> signed_zero_rays() {
  std::vector<Ray> rays;
  const float zs[2] = {0.0f, -0.0f};
  for (float z0 : zs)
    for (float z1 : zs)
      for (float o : {-3.0f, -1.0f, 0.0f, 0.25f, 1.0f, 3.0f}) {
        rays.push_back({Vec3(o, 0.1f, 0.2f), 0.0f, Vec3(1.0f, z0, z1), kInf});
        rays.push_back({Vec3(0.1f, o, 0.2f), 0.0f, Vec3(z0, -1.0f, z1), kInf});
        rays.push_back({Vec3(0.3f, 0.2f, o), 0.0f, Vec3(z0, z1, 1.0f), kInf});
        rays.push_back({Vec3(o, 1.0f, 0.0f), 0.0f, Vec3(z0, z1, -1.0f), kInf});
      }
  return rays;
}

/// Builds `acc` and brute force with the Möller-Trumbore test over a seeded soup and counts
/// rays on which they differ (hit/miss or t): the fast triangle test must be wired through
/// the structure's traversal exactly as through brute force.
inline int moller_mismatches(Accelerator& acc) {
  const Mesh mesh = random_soup(2000, 5);
  BuildParams p;
  p.triangle_test = TriangleTestKind::Moller;
  acc.build(mesh, p);
  BruteForce b;
  b.build(mesh, p);
  int bad = 0;
  for (const Ray& r : random_rays(mesh, 10000, 9)) {
    Hit ha, hb;
    const bool a = acc.intersect(r, ha), c = b.intersect(r, hb);
    if (a != c || (a && ha.t != hb.t)) ++bad;
  }
  return bad;
}

}  // namespace kdgrid::test

namespace kdgrid::test {

/// Rays that stress the numerics of stepping: for each (axis, position) plane given (cell
/// boundaries, split planes, box faces), rays lying exactly in it with a +0 or -0 direction
/// component, axis-parallel rays with origins on it, and rays starting exactly on it;
/// plus axis-parallel rays from outside, rays from box corners, and rays missing the box.
inline std::vector<Ray> extreme_rays(const Mesh& m,
                                     const std::vector<std::pair<int, float>>& planes,
                                     uint32_t seed, int per_plane) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  const Box3 b = m.bounds();
  const Vec3 e = b.extent();
  auto in_box = [&] {
    return Vec3(b.lo.x + e.x * u01(rng), b.lo.y + e.y * u01(rng), b.lo.z + e.z * u01(rng));
  };
  auto rand_dir = [&] {
    Vec3 d(2 * u01(rng) - 1, 2 * u01(rng) - 1, 2 * u01(rng) - 1);
    return d == Vec3(0.0f) ? Vec3(1, 0, 0) : d;
  };
  std::vector<Ray> rays;
  for (const auto& [axis, pos] : planes) {
    for (int k = 0; k < per_plane; ++k) {
      Ray r;
      r.org = in_box();
      // Some origins outside the box, still in the plane.
      if (k % 4 == 1) r.org[(axis + 1) % 3] = b.lo[(axis + 1) % 3] - e[(axis + 1) % 3] * 0.5f;
      r.org[axis] = pos;
      r.dir = rand_dir();
      switch (k % 5) {
        case 0:
          r.dir[axis] = 0.0f;
          break;  // in the plane, +0
        case 1:
          r.dir[axis] = -0.0f;
          break;   // in the plane, -0
        case 2: {  // axis-parallel within the plane
          const int other = (axis + 1 + int(rng() % 2)) % 3;
          r.dir = Vec3(0.0f);
          r.dir[other] = (rng() % 2) ? 1.0f : -1.0f;
          if (rng() % 2) r.dir[axis] = -0.0f;
          break;
        }
        case 3:
          break;  // leaves the plane in a random direction
        case 4:   // crosses the plane along its normal
          r.dir = Vec3(-0.0f, 0.0f, -0.0f);
          r.dir[axis] = (rng() % 2) ? 1.0f : -1.0f;
          r.org[axis] = pos - r.dir[axis] * e[axis] * 0.25f * u01(rng);
          break;
      }
      if (r.dir == Vec3(0.0f)) r.dir[(axis + 1) % 3] = 1.0f;
      rays.push_back(r);
    }
  }
  // Axis-parallel rays from outside the box through its interior, both signs, and rays
  // starting on the box corners and faces.
  for (int k = 0; k < 6 * per_plane; ++k) {
    const int axis = k % 3;
    const float sign = (k / 3) % 2 ? 1.0f : -1.0f;
    Ray r;
    r.org = in_box();
    r.org[axis] = sign > 0 ? b.lo[axis] - e[axis] : b.hi[axis] + e[axis];
    r.dir = Vec3(0.0f);
    r.dir[axis] = sign;
    rays.push_back(r);
    Ray c;
    c.org = Vec3((k & 1) ? b.lo.x : b.hi.x, (k & 2) ? b.lo.y : b.hi.y, (k & 4) ? b.lo.z : b.hi.z);
    if (k % 3 == 0) c.org = in_box(), c.org[axis] = (k & 8) ? b.lo[axis] : b.hi[axis];
    c.dir = in_box() - c.org;
    if (c.dir == Vec3(0.0f)) c.dir = Vec3(1, 0, 0);
    rays.push_back(c);
    // A ray missing the box: from outside, pointing away.
    Ray miss;
    miss.org = b.center() + rand_dir() * 0.0f;
    miss.org[axis] = b.hi[axis] + e[axis] + 1.0f;
    miss.dir = rand_dir();
    miss.dir[axis] = std::fabs(miss.dir[axis]) + 0.1f;
    rays.push_back(miss);
  }
  return rays;
}

}  // namespace kdgrid::test

namespace kdgrid::test {

/// Counted and traced traversals return exactly the fast path's hits; trace steps come in
/// order of t_in and a hit lies in the interval of the last step. Returns failures.
inline int check_counted_and_trace(const Accelerator& acc, const std::vector<Ray>& rays,
                                   int report = 5) {
  int bad = 0;
  for (size_t i = 0; i < rays.size(); ++i) {
    const Ray& r = rays[i];
    Hit fast, counted;
    RayCounters c;
    const bool bf = acc.intersect(r, fast), bc = acc.intersect_counted(r, counted, c);
    const bool of = acc.occluded(r);
    RayCounters oc;
    const bool ocd = acc.occluded_counted(r, oc);
    const Trace tr = acc.trace(r);
    std::string why;
    if (bf != bc || (bf && (fast.t != counted.t || fast.prim != counted.prim ||
                            fast.u != counted.u || fast.v != counted.v)))
      why = "counted closest differs from fast";
    else if (of != ocd)
      why = "counted any-hit differs from fast";
    else if (tr.hit.prim != fast.prim || (bf && tr.hit.t != fast.t))
      why = "trace hit differs from fast";
    else if (acc.has_counters() && !(tr.counters == c))
      why = "trace counters differ from counted";
    else if (acc.has_counters() && r.dir != Vec3(0.0f) && c.steps == 0 && bf)
      why = "a hit without a step";
    else {
      // Intervals are computed in float from coordinates as large as the origin's (and
      // widened by that much), so tolerances are relative to the coordinates in units of t.
      const float scale = max_component(abs(r.org)) / max_component(abs(r.dir));
      const float tol_order = 1e-5f * (std::fabs(fast.valid() ? fast.t : 0.0f) + scale);
      for (size_t k = 1; k < tr.steps.size(); ++k)
        if (tr.steps[k].t_in < tr.steps[k - 1].t_in - tol_order &&
            tr.steps[k].t_in < tr.steps[k - 1].t_in * (1 - 1e-5f))
          why = "trace steps out of t order";
      uint64_t tested = 0;
      for (const auto& st : tr.steps) tested += st.num_tested;
      if (tested != tr.tested.size() || tr.tested.size() != c.tri_tests)
        why = "trace tested triangles do not add up";
      if (bf && acc.has_counters()) {
        // The hit lies in the last leaf/cell that tested triangles.
        const TraceStep* last = nullptr;
        for (const auto& st : tr.steps)
          if (st.kind != StepKind::Inner) last = &st;
        const float tol = 1e-5f * (std::max(1.0f, std::fabs(fast.t)) + scale);
        if (!last || fast.t > last->t_out + tol || fast.t < last->t_in - tol)
          why = "hit t outside the last leaf's interval";
      }
    }
    if (!why.empty()) {
      if (bad < report)
        ADD_FAILURE() << acc.name() << " ray " << i << ": " << why << " (org " << r.org.x << ","
                      << r.org.y << "," << r.org.z << " dir " << r.dir.x << "," << r.dir.y << ","
                      << r.dir.z << ")";
      ++bad;
    }
  }
  return bad;
}

}  // namespace kdgrid::test
