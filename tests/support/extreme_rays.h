// The meshes and ray families of the extreme-ray tests (test_extreme_rays.cpp, and the step-bound
// tests of test_grid.cpp, test_hybrid_agreement.cpp and test_irregular.cpp): rays that are
// axis-parallel, have +0/-0 direction components, lie in cell or split planes, start on boundaries,
// miss the box or graze its edges, in scenes far from the unit scale.
#pragma once

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include "accel/accelerator.h"
#include "comparator_meshes.h"

namespace kdgrid::test {

// ---- meshes -------------------------------------------------------------------------------

/// Axis-aligned quads lying exactly on the boundaries of a lattice of `cell` (exact in float)
/// over [0, n*cell]^3: with cell_size = cell the quads sit on cell planes and split planes.
inline Mesh lattice_quads(float cell, int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> k(0, n), span(1, 3);
  Mesh m;
  for (int i = 0; i < 300; ++i) {
    const int axis = i % 3, b = (axis + 1) % 3, c = (axis + 2) % 3;
    const float plane = float(k(rng)) * cell;
    const int b0 = std::min(n - 1, k(rng)), c0 = std::min(n - 1, k(rng));
    const int b1 = std::min(n, b0 + span(rng)), c1 = std::min(n, c0 + span(rng));
    Vec3 p[4];
    const int corner[4][2] = {{b0, c0}, {b1, c0}, {b1, c1}, {b0, c1}};
    for (int q = 0; q < 4; ++q) {
      p[q][axis] = plane;
      p[q][b] = float(corner[q][0]) * cell;
      p[q][c] = float(corner[q][1]) * cell;
    }
    add_quad(m, p[0], p[1], p[2], p[3]);
  }
  return m;
}

/// The cell of extreme_scene(): its quads lie on the planes of this lattice.
constexpr float kExtremeCell = 0.25f;

/// A scene aligned on a lattice of kExtremeCell over [0, 2]^3 (quads on the lattice planes)
/// and a sphere about (1, 1, 1).
inline Mesh extreme_scene() {
  Mesh m = lattice_quads(kExtremeCell, 8, 11);
  m.append(octahedron_sphere(3, 0.6f, Vec3(1.0f)));
  return m;
}

/// Axis-aligned quads on the planes a = -1, -0.5, 0, 0.5, 1 of each axis, each plane a 4x4
/// grid of quads over [-1, 1]^2: coplanar triangles, shared edges and many rays in planes.
inline Mesh grid_quads() {
  Mesh m;
  for (int a = 0; a < 3; ++a) {
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    for (int k = 0; k <= 4; ++k)
      for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) {
          Vec3 p[4];
          const float ui[4] = {float(i), float(i + 1), float(i + 1), float(i)};
          const float vj[4] = {float(j), float(j), float(j + 1), float(j + 1)};
          for (int q = 0; q < 4; ++q) {
            p[q][a] = -1.0f + 0.5f * k;
            p[q][b] = -1.0f + 0.5f * ui[q];
            p[q][c] = -1.0f + 0.5f * vj[q];
          }
          add_quad(m, p[0], p[1], p[2], p[3]);
        }
  }
  return m;
}

/// The closed box [lo, hi] as 12 triangles: the mesh is its own scene box.
inline Mesh box_mesh(const Vec3& lo, const Vec3& hi) {
  Mesh m;
  for (int k = 0; k < 8; ++k)
    m.positions.push_back({(k & 1) ? hi.x : lo.x, (k & 2) ? hi.y : lo.y, (k & 4) ? hi.z : lo.z});
  const uint32_t quads[6][4] = {{0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1},
                                {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}};
  for (const auto& q : quads) {
    m.triangles.push_back({q[0], q[1], q[2]});
    m.triangles.push_back({q[0], q[2], q[3]});
  }
  return m;
}

// ---- rays ---------------------------------------------------------------------------------

/// A random direction, normally distributed (never shorter than 1e-3).
inline Vec3 random_dir(std::mt19937& rng) {
  std::normal_distribution<float> n(0.0f, 1.0f);
  for (;;) {
    const Vec3 d(n(rng), n(rng), n(rng));
    if (length(d) > 1e-3f) return d;
  }
}

/// A plane a structure is built on (split plane, cell or node face) and the box it bounds.
struct PlaneInBox {
  int axis = 0;
  float position = 0;
  Box3 box;
};

/// The planes of `acc` as built: its split planes, then the faces of its boxes (nodes, leaves,
/// cells), then the faces of the mesh box; each (axis, position) once, at most `max` of the
/// structure's own, spread over all of them. Structures without splits or boxes (brute force,
/// Embree) give the mesh box faces only.
inline std::vector<PlaneInBox> structure_planes(const Accelerator& acc, const Mesh& m, size_t max) {
  std::vector<PlaneInBox> all;
  std::set<std::pair<int, float>> seen;
  auto add = [&](int axis, float pos, const Box3& box, std::vector<PlaneInBox>& to) {
    if (seen.insert({axis, pos}).second) to.push_back({axis, pos, box});
  };
  acc.for_each_split([&](const SplitPlane& sp) { add(sp.axis, sp.position, sp.node_box, all); });
  acc.for_each_box([&](const StructureBox& sb) {
    for (int a = 0; a < 3; ++a) {
      add(a, sb.box.lo[a], sb.box, all);
      add(a, sb.box.hi[a], sb.box, all);
    }
  });
  std::vector<PlaneInBox> out;
  const size_t every = std::max<size_t>(1, (all.size() + max - 1) / std::max<size_t>(1, max));
  for (size_t i = 0; i < all.size(); i += every) out.push_back(all[i]);
  const Box3 b = m.bounds();
  for (int a = 0; a < 3; ++a) {
    add(a, b.lo[a], b, out);
    add(a, b.hi[a], b, out);
  }
  return out;
}

/// (axis, position) of each plane, as extreme_rays() takes them.
inline std::vector<std::pair<int, float>> axis_positions(const std::vector<PlaneInBox>& planes) {
  std::vector<std::pair<int, float>> out;
  for (const auto& p : planes) out.push_back({p.axis, p.position});
  return out;
}

/// The planes x, y, z = lo + k * step for k = 0 .. n.
inline std::vector<std::pair<int, float>> lattice_planes(float lo, float step, int n) {
  std::vector<std::pair<int, float>> out;
  for (int a = 0; a < 3; ++a)
    for (int k = 0; k <= n; ++k) out.push_back({a, lo + float(k) * step});
  return out;
}

/// `n` rays made by `make(i, rng)` for i = 0 .. n-1 from one generator seeded with `seed`.
template <class MakeRay>
std::vector<Ray> generated_rays(int n, uint32_t seed, MakeRay make) {
  std::mt19937 rng(seed);
  std::vector<Ray> rays;
  rays.reserve(size_t(std::max(n, 0)));
  for (int i = 0; i < n; ++i) rays.push_back(make(i, rng));
  return rays;
}

/// Rays lying in the given planes, inside the plane's box or starting outside it in the
/// plane, with a +0 or -0 normal component; every fifth also lies in a plane of another axis.
inline std::vector<Ray> rays_in_planes(const std::vector<PlaneInBox>& planes, int n,
                                       uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f), s(-1.0f, 1.0f);
  std::vector<Ray> rays;
  for (int i = 0; i < n && !planes.empty(); ++i) {
    const PlaneInBox& sp = planes[size_t(rng()) % planes.size()];
    Ray r;
    r.org = sp.box.lo + sp.box.extent() * Vec3(u(rng), u(rng), u(rng));
    r.org[sp.axis] = sp.position;
    r.dir = Vec3(s(rng), s(rng), s(rng));
    r.dir[sp.axis] = i % 4 == 3 ? -0.0f : 0.0f;
    if (i % 5 == 0) {  // and in a plane of another axis: along the line where they meet
      for (int tries = 0; tries < 8; ++tries) {
        const PlaneInBox& q = planes[size_t(rng()) % planes.size()];
        if (q.axis == sp.axis) continue;
        r.org[q.axis] = q.position;
        r.dir[q.axis] = 0.0f;
        break;
      }
    }
    if (i % 2) r.org = r.org - r.dir * 3.0f;  // start outside the box, still in the plane
    if (r.dir == Vec3(0.0f)) r.dir[(sp.axis + 1) % 3] = 1.0f;
    rays.push_back(r);
  }
  return rays;
}

/// Axis-parallel rays, both signs in turn on each axis, from origins in [lo, hi]^3.
inline std::vector<Ray> axis_parallel_rays(float lo, float hi, int n, uint32_t seed) {
  std::uniform_real_distribution<float> u(lo, hi);
  return generated_rays(n, seed, [&](int i, std::mt19937& rng) {
    Ray r;
    r.org = Vec3(u(rng), u(rng), u(rng));
    r.dir = Vec3(0.0f);
    r.dir[i % 3] = (i / 3) % 2 ? 1.0f : -1.0f;
    return r;
  });
}

/// Axis-parallel rays from outside [-1.3, 1.3]^3 (at +-1.5 on their axis) through it, every
/// fourth starting on a line of grid_quads() (a multiple of 0.5) in one other coordinate.
inline std::vector<Ray> axis_parallel_rays_from_outside(int n, uint32_t seed) {
  std::uniform_real_distribution<float> u(-1.3f, 1.3f);
  return generated_rays(n, seed, [&](int i, std::mt19937& rng) {
    Ray r;
    r.org = Vec3(u(rng), u(rng), u(rng));
    const int a = i % 3;
    r.org[a] = (i / 3) % 2 ? -1.5f : 1.5f;
    r.dir = Vec3(0.0f);
    r.dir[a] = r.org[a] > 0 ? -1.0f : 1.0f;
    if (i % 4 == 0) r.org[(a + 1) % 3] = 0.5f * float(int(u(rng) * 2.0f));
    return r;
  });
}

/// Axis-parallel rays with +0/-0 in their other components from outside the integer quads
/// (integer_quads(8)) through them; with `on_edges`, every fourth starts on an integer line,
/// so it runs along the quads' edges (ill-posed for a triangle test: only brute force and the
/// structures sharing its test agree exactly there).
inline std::vector<Ray> signed_zero_axis_rays(int n, uint32_t seed, bool on_edges) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.05f, 7.95f);
  std::vector<Ray> rays;
  for (int k = 0; k < n; ++k) {
    const int axis = k % 3;
    const float sign = (k / 3) % 2 ? 1.0f : -1.0f;
    Ray r;
    r.org = Vec3(u(rng), u(rng), u(rng));
    const bool on_edge = k % 4 == 0;
    if (on_edge) r.org[(axis + 1) % 3] = std::round(r.org[(axis + 1) % 3]);
    r.org[axis] = sign > 0 ? -3.5f : 11.5f;
    r.dir = Vec3((k & 8) ? -0.0f : 0.0f, (k & 16) ? -0.0f : 0.0f, (k & 32) ? -0.0f : 0.0f);
    r.dir[axis] = sign;
    if (on_edge == on_edges) rays.push_back(r);
  }
  return rays;
}

/// Random rays with one or two direction components +0 or -0, from origins in [lo, hi]^3;
/// `two_every` picks which rays zero a second component (the sign of which alternates).
inline std::vector<Ray> zero_component_rays(float lo, float hi, int n, uint32_t seed,
                                            int two_every) {
  std::uniform_real_distribution<float> u(lo, hi), s(-1.0f, 1.0f);
  return generated_rays(n, seed, [&](int i, std::mt19937& rng) {
    Ray r;
    r.org = Vec3(u(rng), u(rng), u(rng));
    r.dir = Vec3(s(rng), s(rng), s(rng));
    const int a = i % 3;
    r.dir[a] = (i / 3) % 2 ? 0.0f : -0.0f;
    if (i % two_every == 0) r.dir[(a + 1) % 3] = (i / two_every) % 2 ? -0.0f : 0.0f;
    if (r.dir == Vec3(0.0f)) r.dir[(a + 2) % 3] = 1.0f;
    return r;
  });
}

/// Rays along the lines of coplanar_quads(8) (agreement.h): axis-parallel with +0/-0 in the
/// other components, on lines, faces and between them, and on the faces of the root box.
inline std::vector<Ray> coplanar_quad_line_rays() {
  std::vector<Ray> rays;
  const float zeros[2] = {0.0f, -0.0f};
  for (int axis = 0; axis < 3; ++axis)
    for (float sgn : {1.0f, -1.0f})
      for (float z1 : zeros)
        for (float z2 : zeros)
          for (int a = -5; a <= 5; ++a)
            for (int b = -5; b <= 5; ++b)
              for (float off : {0.0f, 0.5f, 0.25f}) {
                Ray r;
                r.dir[axis] = sgn;
                r.dir[(axis + 1) % 3] = z1;
                r.dir[(axis + 2) % 3] = z2;
                r.org[axis] = -10.0f * sgn;
                r.org[(axis + 1) % 3] = float(a) * 0.5f + off;
                r.org[(axis + 2) % 3] = float(b) * 0.5f;
                rays.push_back(r);
              }
  for (float face : {-4.0f, 4.0f})
    for (float z : zeros) rays.push_back({{face, 0.5f, -10.0f}, 0.0f, {z, 0.0f, 1.0f}, kInf});
  return rays;
}

/// Rays starting exactly on a plane of a lattice of `cell` (k = kmin .. kmax) and moving inside
/// it; every fifth also lies in a second lattice plane (along a lattice line).
inline std::vector<Ray> rays_in_lattice_planes(float cell, int kmin, int kmax, float lo, float hi,
                                               int n, uint32_t seed) {
  std::uniform_real_distribution<float> u(lo, hi), s(-1.0f, 1.0f);
  std::uniform_int_distribution<int> k(kmin, kmax);
  return generated_rays(n, seed, [&](int i, std::mt19937& rng) {
    Ray r;
    r.org = Vec3(u(rng), u(rng), u(rng));
    r.dir = Vec3(s(rng), s(rng), s(rng));
    const int a = i % 3;
    r.org[a] = float(k(rng)) * cell;
    r.dir[a] = (i / 3) % 2 ? 0.0f : -0.0f;
    if (i % 5 == 0) {
      const int b = (a + 1) % 3;
      r.org[b] = float(k(rng)) * cell;
      r.dir[b] = 0.0f;
    }
    if (r.dir == Vec3(0.0f)) r.dir[(a + 2) % 3] = 1.0f;
    return r;
  });
}

/// Rays from the points of a lattice of `cell` (k = kmin .. kmax), a third of them along the
/// diagonal through the cell corners.
inline std::vector<Ray> rays_from_lattice_points(float cell, int kmin, int kmax, int n,
                                                 uint32_t seed) {
  std::uniform_int_distribution<int> k(kmin, kmax);
  std::uniform_real_distribution<float> s(-1.0f, 1.0f);
  return generated_rays(n, seed, [&](int i, std::mt19937& rng) {
    Ray r;
    r.org = Vec3(float(k(rng)), float(k(rng)), float(k(rng))) * cell;
    r.dir = Vec3(s(rng), s(rng), s(rng));
    if (i % 3 == 0) r.dir = Vec3(1.0f, 1.0f, 1.0f) * (i % 2 ? 1.0f : -1.0f);
    return r;
  });
}

/// Rays starting on the boundaries of a structure: on one of its planes (a face of a node, a
/// cell or the box), on a corner where planes of the three axes meet, far outside aimed at the
/// mesh, and on the mesh's vertices.
inline std::vector<Ray> rays_from_structure_boundaries(const std::vector<PlaneInBox>& planes,
                                                       const Mesh& m, int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f), s(-1.0f, 1.0f);
  const Box3 b = m.bounds();
  auto plane = [&](int axis) {
    for (int tries = 0; tries < 64; ++tries) {
      const PlaneInBox& p = planes[size_t(rng()) % planes.size()];
      if (p.axis == axis) return p.position;
    }
    return axis % 2 ? b.lo[axis] : b.hi[axis];
  };
  std::vector<Ray> rays;
  for (int i = 0; i < n && !planes.empty(); ++i) {
    Ray r;
    r.dir = random_dir(rng);
    if (i % 3 == 0) {
      const PlaneInBox& p = planes[size_t(rng()) % planes.size()];
      r.org = p.box.lo + p.box.extent() * Vec3(u(rng), u(rng), u(rng));
      r.org[p.axis] = p.position;
    } else if (i % 3 == 1) {
      for (int a = 0; a < 3; ++a) r.org[a] = plane(a);
    } else {
      r.org = b.center() + normalize(random_dir(rng)) * (25.0f * max_component(b.extent()));
      r.dir = b.center() + b.extent() * Vec3(s(rng), s(rng), s(rng)) * 0.15f - r.org;
    }
    rays.push_back(r);
  }
  for (int i = 0; i < n / 8; ++i)
    rays.push_back(
        {m.positions[(size_t(i) * 7) % m.positions.size()], 0.0f, random_dir(rng), kInf});
  return rays;
}

/// Rays from inside the box [in_lo, in_hi]^3, and from 4-10 units around `center` aimed at
/// points near it.
inline std::vector<Ray> rays_inside_and_outside(const Vec3& center, float in_lo, float in_hi, int n,
                                                uint32_t seed) {
  std::uniform_real_distribution<float> in(in_lo, in_hi), out(4.0f, 10.0f), s(-1.0f, 1.0f);
  return generated_rays(n, seed, [&](int i, std::mt19937& rng) {
    Ray r;
    if (i % 2) {
      r.org = Vec3(in(rng), in(rng), in(rng));
      r.dir = Vec3(s(rng), s(rng), s(rng));
    } else {
      r.org = center + normalize(Vec3(s(rng), s(rng), s(rng))) * out(rng);
      r.dir = center + Vec3(s(rng), s(rng), s(rng)) - r.org;
    }
    return r;
  });
}

/// Rays from beside the box of extreme_scene() (x about 5) that miss it: pointing away,
/// parallel to it outside its slab, or pointing at it but ending before it.
inline std::vector<Ray> rays_beside_the_box(int n, uint32_t seed) {
  std::uniform_real_distribution<float> s(-1.0f, 1.0f);
  return generated_rays(n, seed, [&](int i, std::mt19937& rng) {
    Ray r;
    r.org = Vec3(5.0f + s(rng), s(rng), s(rng));
    r.dir = Vec3(std::abs(s(rng)) + 0.01f, s(rng), s(rng));
    if (i % 3 == 0) r.dir = Vec3(0.0f, 1.0f, -0.0f);
    if (i % 3 == 1) {
      r.dir = Vec3(-1.0f, 0.0f, 0.0f);
      r.org = Vec3(5.0f, 1.0f, 1.0f);
      r.tmax = 2.0f;
    }
    return r;
  });
}

/// Rays from 5 units around the unit sphere in threes: pointing away, passing by, and aimed
/// at the centre but stopping 1.25 from it.
inline std::vector<Ray> rays_missing_the_sphere(int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<Ray> rays;
  for (int i = 0; i < n; ++i) {
    const Vec3 o = normalize(random_dir(rng)) * 5.0f;
    rays.push_back({o, 0.0f, o, kInf});
    rays.push_back({o, 0.0f, cross(o, random_dir(rng)) + o * 0.001f, kInf});
    rays.push_back({o, 0.0f, -o, 0.75f});
  }
  return rays;
}

/// Invalid rays (zero or NaN direction, NaN origin, infinite direction, empty segment), which
/// miss, and one valid ray along x from (-5, 0, 0).
inline std::vector<Ray> invalid_rays() {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  return {
      {Vec3(0.0f), 0.0f, Vec3(0.0f), kInf},          {Vec3(nan, 0, 0), 0.0f, Vec3(1, 0, 0), kInf},
      {Vec3(-5, 0, 0), 0.0f, Vec3(1, nan, 0), kInf}, {Vec3(-5, 0, 0), 0.0f, Vec3(kInf, 0, 0), kInf},
      {Vec3(-5, 0, 0), 2.0f, Vec3(1, 0, 0), 2.0f},   {Vec3(-5, 0, 0), 0.0f, Vec3(1, 0, 0), kInf}};
}

/// Rays from `distance` (plus a thousandth of `offset`) away aimed at points on the edges
/// (two coordinates on the box's bounds) and corners (three) of the box [lo, hi]: they touch
/// the box in a point or segment, where the rounding of a float pre-clip matters.
inline std::vector<Ray> rays_at_box_edges(const Vec3& lo, const Vec3& hi, float distance,
                                          float offset, int n, uint32_t seed) {
  std::uniform_real_distribution<float> u(0.0f, 1.0f), s(-1.0f, 1.0f);
  return generated_rays(n, seed, [&](int i, std::mt19937& rng) {
    Vec3 target;
    for (int a = 0; a < 3; ++a) target[a] = lo[a] + (hi[a] - lo[a]) * u(rng);
    const int fixed = i % 4 == 0 ? 3 : 2, skip = i % 3;
    for (int a = 0, k = 0; a < 3 && k < fixed; ++a) {
      if (fixed == 2 && a == skip) continue;
      target[a] = (rng() & 1) ? hi[a] : lo[a];
      ++k;
    }
    Ray r;
    r.org = target + Vec3(s(rng), s(rng), s(rng)) * (distance + offset * 1e-3f);
    r.dir = target - r.org;
    return r;
  });
}

/// The rays with origins scaled by `scale` and moved by `offset`, directions scaled (t keeps
/// its meaning).
inline std::vector<Ray> transformed_rays(std::vector<Ray> rays, float scale, const Vec3& offset) {
  for (Ray& r : rays) {
    r.org = r.org * scale + offset;
    r.dir = r.dir * scale;
  }
  return rays;
}

}  // namespace kdgrid::test
