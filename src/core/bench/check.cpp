#include "bench/check.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <optional>
#include <random>
#include <sstream>

#include "accel/accelerator.h"
#include "bench/probes.h"
#include "math/segment.h"
#include "render/renderer.h"
#include "scene/procedural.h"
#include "util/enum_names.h"

namespace kdgrid {

namespace {

enum Family : uint8_t {
  kRandom,
  kAxisParallel,
  kSignedZero,
  kInPlane,
  kOnSurface,
  kOnBoundary,
  kGrazingEdge,
  kEdgeAimed,
  kNanInf,
  kAway,
  kNumFamilies
};

/// Relative barycentric margin separating "robust" hits from edge/vertex hits.
constexpr double kBaryMargin = 1e-6;
/// Triangles seen at a sine below this are grazing: the reference gives no verdict.
constexpr double kGrazingSine = 1e-6;

struct Rng {
  std::mt19937_64 g;
  explicit Rng(uint64_t seed) : g(seed) {}
  float uniform(float a, float b) { return std::uniform_real_distribution<float>(a, b)(g); }
  uint64_t below(uint64_t n) { return std::uniform_int_distribution<uint64_t>(0, n - 1)(g); }
  Vec3 in_box(const Box3& b) {
    return {uniform(b.lo.x, b.hi.x), uniform(b.lo.y, b.hi.y), uniform(b.lo.z, b.hi.z)};
  }
  Vec3 direction() {
    for (;;) {
      const Vec3 v(uniform(-1, 1), uniform(-1, 1), uniform(-1, 1));
      const float l = length(v);
      if (l > 0.05f && l <= 1.0f) return v / l;
    }
  }
  float signed_zero() { return below(2) ? 0.0f : -0.0f; }
};

Box3 grown(const Box3& b, float f) {
  const Vec3 e = b.extent() * f + Vec3(1e-30f);
  return {b.lo - e, b.hi + e};
}

// ---- the double-precision reference ------------------------------------------------------

struct Candidate {
  double t;
  uint32_t prim;
  double t_unc;             ///< how far a float traversal's t may lie from this t
  bool front;               ///< the triangle faces the ray (its determinant is positive)
  bool degenerate = false;  ///< a triangle lost in rounding (see degenerate_candidate)
};

struct Reference {
  bool valid = true;             ///< the ray itself is usable (else every answer must be a miss)
  double t_strict = kInf;        ///< closest robust hit
  double t_strict_unc = 0;       ///< its t uncertainty
  bool grazing = false;          ///< a triangle seen edge-on lies along the ray segment
  bool edge_before = false;      ///< a loose-only (edge/vertex) hit at or before t_strict
  std::vector<Candidate> loose;  ///< loose hits with t <= t_strict + tol, sorted
  double tol = 0;                ///< absolute t tolerance for this ray
};

double t_tolerance(const Ray& r, double scene_scale) {
  const double dl = std::sqrt(double(dot(r.dir, r.dir)));
  const double o = std::max({std::fabs(r.org.x), std::fabs(r.org.y), std::fabs(r.org.z)});
  // Float positions carry ~2^-23 relative error; allow a few ulps of the coordinates involved.
  return 16.0 * (o + scene_scale) * 1.1920929e-7 / dl;
}

/// A triangle lost in rounding (corners on a line or at one point, about the origin) as a
/// loose candidate: where the ray passes within `reach` of one of its edges. All its corners
/// lie on a line, along which depth is affine, so a float test's hit on it lies at the depth
/// of that closest approach, give or take the rounding seen along the segment (reach / sine).
std::optional<Candidate> degenerate_candidate(const Ray& r, uint32_t prim, const Vec3d& v0,
                                              const Vec3d& v1, const Vec3d& v2, double reach,
                                              double tol) {
  const Vec3d d(r.dir);
  const double dl = std::sqrt(dot(d, d));
  const double t0 = double(r.tmin) - tol, t1 = std::min(double(r.tmax), 1e300) + tol;
  const Vec3d* vs[3] = {&v0, &v1, &v2};
  std::optional<Candidate> best;
  double best_dist = kInf;
  for (int k = 0; k < 3; ++k) {
    const Vec3d &a = *vs[k], &b = *vs[(k + 1) % 3];
    const Approach ap = closest_approach(d, t0, t1, a, b);
    if (ap.dist > 4.0 * reach || ap.dist >= best_dist) continue;
    best_dist = ap.dist;
    // The corners' depths about the closest approach: the most the hit's t can be off when
    // the ray runs along the segment (all three edges lie on its line), and for a ray that
    // starts on the segment, where a test that is not watertight (Embree's) finds every edge
    // function lost in rounding and may report any depth along the triangle.
    double span = 0;
    for (const Vec3d* v : vs) span = std::max(span, std::fabs(dot(*v, d) / (dl * dl) - ap.t));
    const double along = ap.sine > 0 ? 4.0 * reach / (dl * ap.sine) : kInf;
    double unc = tol + std::min(along, span + 4.0 * reach / dl);
    if (closest_approach(d, t0, t0, a, b).dist <= 4.0 * reach) unc = std::max(unc, tol + span);
    best = Candidate{ap.t, prim, unc, false, true};
  }
  return best;
}

Reference compute_reference(const Mesh& mesh, const Ray& r, double scene_scale) {
  Reference ref;
  if (!ray_is_valid(r)) {
    ref.valid = false;
    return ref;
  }
  ref.tol = t_tolerance(r, scene_scale);
  const Vec3d o(r.org), d(r.dir);
  const double dl = std::sqrt(dot(d, d));
  // Absolute uncertainty of positions in a float traversal: a few ulps of the largest
  // coordinate involved. Seen by the ray at a grazing angle it grows by 1/cos; measured
  // along a triangle it becomes a barycentric margin of delta / altitude.
  const double delta = ref.tol * dl;
  std::vector<Candidate> loose;
  for (uint32_t i = 0; i < uint32_t(mesh.num_triangles()); ++i) {
    const auto c = mesh.corners(i);
    const Vec3d v0 = Vec3d(c[0]) - o, v1 = Vec3d(c[1]) - o, v2 = Vec3d(c[2]) - o;
    const Vec3d e1 = v1 - v0, e2 = v2 - v0, e3 = v2 - v1;
    const Vec3d nrm = cross(e1, e2);
    const double area2 = std::sqrt(dot(nrm, nrm));
    const double max_edge = std::sqrt(std::max({dot(e1, e1), dot(e2, e2), dot(e3, e3)}));
    const double altitude = max_edge > 0 ? area2 / max_edge : 0.0;
    const Vec3d p = cross(d, e2);
    const double det = dot(e1, p);
    const double cosn = area2 > 0 ? std::fabs(det) / (area2 * dl) : 0.0;
    // A triangle whose plane is lost in rounding (zero area, or a sliver whose altitude is
    // within a few deltas, longer than the rounding) is a segment or a point to a float test:
    // it may report a hit only where the ray passes within rounding of it, at that point's
    // depth. A small one that rounding swallows whole is grazing (below) wherever the ray
    // meets its box.
    const double reach = delta + altitude;
    if (area2 == 0.0 || (altitude <= 4.0 * delta && max_edge > 8.0 * reach)) {
      Box3 tb = mesh.triangle_bounds(i);
      tb = {tb.lo - Vec3(float(8.0 * reach)), tb.hi + Vec3(float(8.0 * reach))};
      if (!segment_overlaps_box(r, tb, r.tmin - ref.tol, r.tmax)) continue;
      if (const auto cnd = degenerate_candidate(r, i, v0, v1, v2, reach, ref.tol))
        loose.push_back(*cnd);
      continue;
    }
    // The plane of a sliver is itself uncertain by about delta / altitude: a ray that may be
    // parallel to it within that uncertainty is grazing.
    if (cosn <= kGrazingSine + 4.0 * delta / altitude) {
      Box3 tb = mesh.triangle_bounds(i);
      tb = grown(tb, 1e-6f);
      if (segment_overlaps_box(r, tb, r.tmin, r.tmax)) ref.grazing = true;
      continue;
    }
    const double inv = 1.0 / det;
    const Vec3d s = v0 * -1.0;
    const double u = dot(s, p) * inv;
    const Vec3d q = cross(s, e1);
    const double v = dot(d, q) * inv;
    const double w = 1.0 - u - v;
    const double t = dot(e2, q) * inv;
    const double margin = kBaryMargin + delta * max_edge / (area2 * cosn);
    if (u < -margin || v < -margin || w < -margin) continue;
    // A float test's barycentrics are off by up to the margin; t, interpolated from them, by
    // that much of the corners' depths about the hit (a thin triangle's long corners).
    const double dl2 = dl * dl;
    const double corner_depth =
        std::max({std::fabs(dot(v0, d) / dl2 - t), std::fabs(dot(v1, d) / dl2 - t),
                  std::fabs(dot(v2, d) / dl2 - t)});
    const double t_unc =
        ref.tol + delta / (dl * cosn) + 1e-5 * std::fabs(t) + std::min(1.0, margin) * corner_depth;
    if (t < r.tmin - t_unc || t > double(r.tmax) + t_unc) continue;
    const bool strict =
        u > margin && v > margin && w > margin && t > r.tmin + t_unc && t < double(r.tmax) - t_unc;
    if (strict && t < ref.t_strict) {
      ref.t_strict = t;
      ref.t_strict_unc = t_unc;
    }
    loose.push_back({t, i, t_unc, det > 0});
  }
  std::sort(loose.begin(), loose.end(), [](auto& a, auto& b) { return a.t < b.t; });
  for (const auto& cnd : loose) {
    if (cnd.t - cnd.t_unc > ref.t_strict + ref.t_strict_unc) continue;  // t_unc differ: no break
    ref.loose.push_back(cnd);
  }
  // Hits at the origin (t ~ tmin) may be reported or not. Beyond it, an edge/vertex-only hit
  // before the closest robust hit, or several hits tying with it, leave the answer ambiguous.
  int ties = 0;
  for (const auto& cnd : ref.loose) {
    if (cnd.t <= r.tmin + cnd.t_unc) continue;
    if (std::fabs(cnd.t - ref.t_strict) > cnd.t_unc + ref.t_strict_unc)
      ref.edge_before = true;
    else
      ++ties;
  }
  if (ties > 1) ref.edge_before = true;
  return ref;
}

enum class Verdict { Agree, Ambiguous, Disagree };

Verdict judge_closest(const Reference& ref, bool hit, const Hit& h, std::string* why) {
  if (!ref.valid) {
    if (hit && why) *why = "invalid (NaN/inf/zero) ray reported a hit";
    return hit ? Verdict::Disagree : Verdict::Agree;
  }
  bool wrong = false;
  if (!hit) {
    wrong = ref.t_strict < kInf;
    if (wrong && why) {
      std::ostringstream s;
      s << "missed a robust hit at t=" << ref.t_strict;
      *why = s.str();
    }
  } else {
    bool loose_ok = false;
    for (const auto& c : ref.loose)
      if (c.prim == h.prim && std::fabs(c.t - h.t) <= c.t_unc) loose_ok = true;
    const bool too_far = ref.t_strict + ref.t_strict_unc < double(h.t) - ref.t_strict_unc;
    wrong = !loose_ok || too_far;
    if (wrong && why) {
      std::ostringstream s;
      s << "hit prim " << h.prim << " at t=" << h.t << (loose_ok ? "" : " (not a hit there)")
        << (too_far ? " beyond the closest robust hit" : "") << "; reference t=" << ref.t_strict;
      *why = s.str();
    }
  }
  const bool ambiguous = ref.grazing || ref.edge_before;
  if (wrong) return ambiguous ? Verdict::Ambiguous : Verdict::Disagree;
  return ambiguous ? Verdict::Ambiguous : Verdict::Agree;
}

/// occluded() is wrong if it contradicts an unambiguous reference: no answer where a robust
/// hit exists, or an answer where nothing at all is hit.
bool judge_any_wrong(const Reference& ref, bool occluded) {
  if (!ref.valid) return occluded;
  if (ref.grazing || ref.edge_before) return false;
  if (!occluded) return ref.t_strict < kInf;
  return ref.t_strict == kInf && ref.loose.empty();
}

// ---- scenes ----------------------------------------------------------------------------------

Mesh transformed(Mesh m, double scale, const Vec3& shift) {
  for (auto& p : m.positions)
    p = Vec3(float(p.x * scale), float(p.y * scale), float(p.z * scale)) + shift;
  return m;
}

/// The procedural scene `name`'s mesh (count, seed), without material ids.
Mesh named_mesh(const std::string& name, int count, uint64_t seed) {
  ProceduralParams pp;
  pp.count = count;
  pp.seed = seed;
  Mesh m = generate_scene(name, pp).mesh;
  m.material_ids.clear();
  return m;
}

Mesh degenerate_mesh(uint64_t seed) {
  Mesh m = named_mesh("soup", 1500, seed);
  Rng rng(seed + 17);
  const size_t base_tris = m.num_triangles();
  for (int i = 0; i < 150; ++i) {  // zero-area: three equal vertices
    const uint32_t v = uint32_t(m.positions.size());
    const Vec3 p = rng.in_box({Vec3(-1), Vec3(1)});
    m.positions.insert(m.positions.end(), {p, p, p});
    m.triangles.push_back({v, v + 1, v + 2});
  }
  for (int i = 0; i < 150; ++i) {  // collinear
    const uint32_t v = uint32_t(m.positions.size());
    const Vec3 a = rng.in_box({Vec3(-1), Vec3(1)}), b = rng.in_box({Vec3(-1), Vec3(1)});
    m.positions.insert(m.positions.end(), {a, lerp(a, b, 0.5f), b});
    m.triangles.push_back({v, v + 1, v + 2});
  }
  for (int i = 0; i < 150; ++i) m.triangles.push_back(m.triangles[rng.below(base_tris)]);  // dups
  for (int i = 0; i < 50; ++i) {  // shared vertex index used twice
    const auto t = m.triangles[rng.below(base_tris)];
    m.triangles.push_back({t[0], t[0], t[1]});
  }
  if (!m.normals.empty()) m.normals.resize(m.positions.size(), Vec3(0, 0, 1));
  if (!m.uvs.empty()) m.uvs.resize(m.positions.size(), {0.f, 0.f});
  return m;
}

Mesh dense_cell_mesh(uint64_t seed) {
  Mesh m = transformed(named_mesh("soup", 3000, seed), 1e-3, Vec3(0.25f, 0.1f, -0.3f));
  m.append(make_box(Vec3(0.0f), Vec3(10.0f), 0.0f, true));
  m.material_ids.clear();
  return m;
}

Mesh coplanar_mesh(uint64_t seed) {
  Mesh m = named_mesh("soup", 2000, seed);
  for (auto& p : m.positions) p.z = 0.0f;  // every triangle in the plane z = 0
  m.normals.clear();
  return m;
}

// ---- rays ------------------------------------------------------------------------------------

void add_ray(CheckCase& c, const Ray& r, Family f) {
  c.rays.push_back(r);
  c.family.push_back(f);
}

void add_generic_rays(CheckCase& c, int n, uint64_t seed) {
  const Mesh& m = c.mesh;
  const Box3 b = m.bounds();
  const Box3 around = grown(b, 0.5f);
  const float size = length(b.extent());
  Rng rng(seed);
  auto random_vertex = [&] { return m.positions[rng.below(m.positions.size())]; };
  auto random_surface_point = [&](uint32_t& prim) {
    prim = uint32_t(rng.below(m.num_triangles()));
    const auto cr = m.corners(prim);
    float u = rng.uniform(0, 1), v = rng.uniform(0, 1);
    if (u + v > 1) {
      u = 1 - u;
      v = 1 - v;
    }
    return cr[0] * (1 - u - v) + cr[1] * u + cr[2] * v;
  };
  for (int i = 0; i < n; ++i) {
    Ray r{rng.in_box(around), 0.0f, rng.direction(), kInf};
    if (i % 5 == 0) r.tmax = rng.uniform(0.0f, 1.5f) * size;
    add_ray(c, r, kRandom);
  }
  for (int i = 0; i < n; ++i) {
    Vec3 o = rng.in_box(grown(b, 0.2f));
    const int axis = int(rng.below(3));
    // Half the rays pass exactly through vertex coordinates on the two other axes.
    if (i % 2) {
      const Vec3 v = random_vertex();
      for (int a = 0; a < 3; ++a)
        if (a != axis) o[a] = v[a];
    }
    Vec3 d(rng.signed_zero(), rng.signed_zero(), rng.signed_zero());
    d[axis] = rng.below(2) ? 1.0f : -1.0f;
    o[axis] = d[axis] > 0 ? around.lo[axis] : around.hi[axis];
    add_ray(c, {o, 0.0f, d, kInf}, kAxisParallel);
  }
  for (int i = 0; i < n; ++i) {
    Vec3 d = rng.direction();
    d[int(rng.below(3))] = rng.signed_zero();
    if (i % 3 == 0) d[int(rng.below(3))] = rng.signed_zero();
    if (d.x == 0 && d.y == 0 && d.z == 0) d.x = 1;
    add_ray(c, {rng.in_box(around), 0.0f, d, kInf}, kSignedZero);
  }
  for (int i = 0; i < n; ++i) {  // planes through vertex coordinates (perfect-split planes)
    const int axis = int(rng.below(3));
    Vec3 o = rng.in_box(around);
    o[axis] = random_vertex()[axis];
    Vec3 d = rng.direction();
    d[axis] = rng.signed_zero();
    if (d.x == 0 && d.y == 0 && d.z == 0) d[(axis + 1) % 3] = 1;
    add_ray(c, {o, 0.0f, d, kInf}, kInPlane);
  }
  for (int i = 0; i < n; ++i) {
    uint32_t prim;
    const Vec3 p = random_surface_point(prim);
    add_ray(c, {p, 0.0f, rng.direction(), kInf}, kOnSurface);
  }
  for (int i = 0; i < n; ++i) {
    Vec3 o = rng.in_box(b);
    const int axis = int(rng.below(3));
    o[axis] = rng.below(2) ? b.lo[axis] : b.hi[axis];
    Vec3 d = rng.direction();
    if (i % 2 == 0) d = normalize(b.center() - o + rng.direction() * (0.3f * size));
    add_ray(c, {o, 0.0f, d, kInf}, kOnBoundary);
  }
  for (int i = 0; i < n; ++i) {  // along a triangle edge
    const auto cr = m.corners(rng.below(m.num_triangles()));
    const int e = int(rng.below(3));
    const Vec3 a = cr[e], bb = cr[(e + 1) % 3];
    if (a == bb) continue;
    const Vec3 dir = bb - a;
    add_ray(c, {a - dir * rng.uniform(0.1f, 1.0f), 0.0f, dir, kInf}, kGrazingEdge);
  }
  for (int i = 0; i < n; ++i) {  // aimed exactly at an edge or vertex point
    const auto cr = m.corners(rng.below(m.num_triangles()));
    const int e = int(rng.below(3));
    const Vec3 target = i % 4 == 0 ? cr[e] : lerp(cr[e], cr[(e + 1) % 3], rng.uniform(0, 1));
    const Vec3 o = target + rng.direction() * size;
    add_ray(c, {o, 0.0f, target - o, kInf}, kEdgeAimed);
  }
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int i = 0; i < std::max(8, n / 20); ++i) {
    Ray r{rng.in_box(around), 0.0f, rng.direction(), kInf};
    switch (i % 8) {
      case 0:
        r.org.x = nan;
        break;
      case 1:
        r.dir.y = nan;
        break;
      case 2:
        r.org.z = kInf;
        break;
      case 3:
        r.dir.x = -kInf;
        break;
      case 4:
        r.tmin = nan;
        break;
      case 5:
        r.tmax = nan;
        break;
      case 6:
        r.dir = Vec3(0.0f, -0.0f, 0.0f);
        break;
      default:
        r.tmin = 5;
        r.tmax = 1;
        break;
    }
    add_ray(c, r, kNanInf);
  }
  for (int i = 0; i < n / 4; ++i) {
    const Vec3 d = rng.direction();
    const Vec3 o = b.center() + d * (size * 2.0f);
    add_ray(c, {o, 0.0f, d, kInf}, kAway);
  }
}

/// Rays lying exactly in the structure's own split planes and on the faces of its leaves.
void add_structure_plane_rays(const Accelerator& accel, CheckCase& c, int n, uint64_t seed) {
  Rng rng(seed);
  std::vector<SplitPlane> planes;
  accel.for_each_split([&](const SplitPlane& p) {
    if (planes.size() < 200000) planes.push_back(p);
  });
  std::vector<Box3> boxes;
  accel.for_each_box([&](const StructureBox& b) {
    if (b.leaf && boxes.size() < 200000) boxes.push_back(b.box);
  });
  if (planes.empty() && boxes.empty()) return;
  for (int i = 0; i < n; ++i) {
    int axis;
    float pos;
    Box3 region;
    if (!planes.empty() && (boxes.empty() || i % 2 == 0)) {
      const auto& p = planes[rng.below(planes.size())];
      axis = p.axis;
      pos = p.position;
      region = p.node_box;
    } else {
      region = boxes[rng.below(boxes.size())];
      axis = int(rng.below(3));
      pos = rng.below(2) ? region.lo[axis] : region.hi[axis];
    }
    Vec3 o = rng.in_box(region);
    o[axis] = pos;
    Vec3 d = rng.direction();
    d[axis] = rng.signed_zero();
    if (i % 3 == 0) {  // also axis-parallel inside the plane
      d = Vec3(rng.signed_zero(), rng.signed_zero(), rng.signed_zero());
      d[(axis + 1 + int(rng.below(2))) % 3] = rng.below(2) ? 1.0f : -1.0f;
    }
    if (d.x == 0 && d.y == 0 && d.z == 0) d[(axis + 1) % 3] = 1;
    // Start outside the region so the ray crosses the plane's whole node.
    add_ray(c, {o - d * length(region.extent()), 0.0f, d, kInf}, kInPlane);
  }
}

double scene_scale_of(const Mesh& m) {
  const Box3 b = m.bounds();
  return std::max(max_component(abs(b.lo)), max_component(abs(b.hi)));
}

}  // namespace

const std::vector<std::string>& check_ray_families() {
  static const std::vector<std::string> names = {
      "random",      "axis-parallel", "signed-zero", "in-plane", "on-surface",
      "on-boundary", "grazing-edge",  "edge-aimed",  "nan-inf",  "away"};
  return names;
}

CheckCase make_check_case(const std::string& name, Mesh mesh, int n, uint64_t seed) {
  CheckCase c;
  c.name = name;
  c.mesh = std::move(mesh);
  add_generic_rays(c, n, seed);
  return c;
}

std::vector<CheckCase> make_check_cases(int n, uint64_t seed) {
  std::vector<CheckCase> cases;
  auto add = [&](const std::string& name, Mesh m) {
    cases.push_back(make_check_case(name, std::move(m), n, seed + cases.size() * 7919));
  };
  const Mesh sphere = named_mesh("sphere", 0, seed);
  add("sphere", sphere);
  add("sphere-scaled-1e-6", transformed(sphere, 1e-6, Vec3(0.0f)));
  add("sphere-scaled-1e6", transformed(sphere, 1e6, Vec3(0.0f)));
  add("sphere-translated-1e5", transformed(sphere, 1.0, Vec3(1e5f, -1e5f, 1e5f)));
  add("coplanar-quads", named_mesh("coplanar-quads", 600, seed));
  add("all-coplanar", coplanar_mesh(seed));
  add("degenerate", degenerate_mesh(seed));
  add("dense-cell", dense_cell_mesh(seed));
  add("thin-triangles", named_mesh("thin-triangles", 2000, seed));
  add("teapot-in-stadium", named_mesh("teapot-in-stadium", 4000, seed));
  return cases;
}

CheckResult run_check(const std::string& structure, const CheckCase& base,
                      const BuildParams& params) {
  const auto t0 = std::chrono::steady_clock::now();
  CheckResult res;
  try {
    auto accel = build_accelerator(structure, base.mesh, params);
    res = judge_accelerator(*accel, base);
  } catch (const std::exception& e) {
    res.error = e.what();
  }
  res.structure = structure;
  res.case_name = base.name;
  res.disagree_by_family.resize(kNumFamilies, 0);
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

CheckResult judge_accelerator(const Accelerator& accel, const CheckCase& base) {
  CheckResult res;
  res.structure = accel.name();
  res.case_name = base.name;
  res.disagree_by_family.assign(kNumFamilies, 0);
  CheckCase c;  // the case's rays plus rays in this structure's own planes
  c.rays = base.rays;
  c.family = base.family;
  add_structure_plane_rays(
      accel, c, int(std::count(base.family.begin(), base.family.end(), uint8_t(kRandom))),
      0x5eed ^ base.rays.size());
  const double scale = scene_scale_of(base.mesh);
  const size_t n = c.rays.size();
  std::vector<uint8_t> verdict(n), any_wrong(n);
  std::vector<uint64_t> steps(n);
  std::vector<std::string> why(n);
  tbb::parallel_for(size_t(0), n, [&](size_t i) {
    const Ray& r = c.rays[i];
    const Reference ref = compute_reference(base.mesh, r, scale);
    Hit h;
    RayCounters rc;
    const bool hit = accel.intersect_counted(r, h, rc);
    steps[i] = rc.steps;
    const Verdict v = judge_closest(ref, hit, h, &why[i]);
    verdict[i] = uint8_t(v);
    any_wrong[i] = judge_any_wrong(ref, accel.occluded(r));
    if (v != Verdict::Disagree) why[i].clear();
  });
  for (size_t i = 0; i < n; ++i) {
    ++res.rays;
    res.max_steps = std::max(res.max_steps, steps[i]);
    const Verdict v = Verdict(verdict[i]);
    if (v == Verdict::Agree) ++res.agree;
    if (v == Verdict::Ambiguous) ++res.ambiguous;
    if (v == Verdict::Disagree) {
      ++res.disagree;
      ++res.disagree_by_family[c.family[i]];
      if (res.examples.size() < 5) {
        const Ray& r = c.rays[i];
        std::ostringstream s;
        s.precision(9);
        s << check_ray_families()[c.family[i]] << " ray org (" << r.org.x << "," << r.org.y << ","
          << r.org.z << ") dir (" << r.dir.x << "," << r.dir.y << "," << r.dir.z << ") [" << r.tmin
          << "," << r.tmax << "]: " << why[i];
        res.examples.push_back(s.str());
      }
    }
    if (any_wrong[i]) ++res.any_disagree;
  }
  return res;
}

const char* to_string(AccuracyVerdict v) {
  static constexpr EnumName<AccuracyVerdict> kNames[] = {{AccuracyVerdict::Agree, "agree"},
                                                         {AccuracyVerdict::Ambiguous, "ambiguous"},
                                                         {AccuracyVerdict::Disagree, "disagree"},
                                                         {AccuracyVerdict::Leak, "leak"}};
  return enum_name(v, kNames);
}

namespace {
uint64_t edge_key(uint32_t a, uint32_t b) {
  return (uint64_t(std::min(a, b)) << 32) | std::max(a, b);
}
}  // namespace

AccuracyReference::AccuracyReference(const Mesh& mesh)
    : mesh_(&mesh), scale_(scene_scale_of(mesh)) {
  std::vector<uint64_t> keys;
  keys.reserve(mesh.num_triangles() * 3);
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) keys.push_back(edge_key(t[k], t[(k + 1) % 3]));
  std::sort(keys.begin(), keys.end());
  for (size_t i = 0; i < keys.size();) {
    size_t j = i;
    while (j < keys.size() && keys[j] == keys[i]) ++j;
    edge_faces_.emplace_back(keys[i], uint32_t(j - i));
    i = j;
  }
  closed_vertex_.assign(mesh.num_vertices(), 1);
  for (const auto& [key, faces] : edge_faces_)
    if (faces != 2) {
      closed_vertex_[size_t(key >> 32)] = 0;
      closed_vertex_[size_t(key & 0xffffffffu)] = 0;
    }
}

bool AccuracyReference::closed_edge(uint32_t a, uint32_t b) const {
  const uint64_t k = edge_key(a, b);
  const auto it =
      std::lower_bound(edge_faces_.begin(), edge_faces_.end(), std::pair<uint64_t, uint32_t>(k, 0));
  return it != edge_faces_.end() && it->first == k && it->second == 2;
}

namespace {

/// Where the ray first crosses the surface through a closed edge or vertex after tmin (two
/// loose candidates at the same t, facing the ray alike, sharing that edge or vertex): its t
/// and uncertainty, or t = kInf.
std::pair<double, double> first_crossing(const AccuracyReference& acc, const Reference& ref,
                                         const Ray& r) {
  const auto& tris = acc.mesh().triangles;
  for (size_t i = 0; i < ref.loose.size(); ++i) {
    const Candidate& a = ref.loose[i];
    if (a.t <= r.tmin + a.t_unc) continue;
    for (size_t j = i + 1; j < ref.loose.size(); ++j) {
      const Candidate& b = ref.loose[j];
      if (b.t - a.t > a.t_unc + b.t_unc) break;              // sorted by t
      if (a.front != b.front || a.prim == b.prim) continue;  // a silhouette: the ray grazes
      if (a.degenerate || b.degenerate) continue;            // no surface to cross
      uint32_t shared[3];
      int n = 0;
      for (int p = 0; p < 3; ++p)
        for (int q = 0; q < 3; ++q)
          if (n < 3 && tris[a.prim][p] == tris[b.prim][q]) shared[n++] = tris[a.prim][p];
      // An edge counts only between closed vertices: near an open end the two triangles need
      // not cover the crossing point (conservative: fewer leaks, never a false one).
      if ((n == 2 && acc.closed_edge(shared[0], shared[1]) && acc.closed_vertex(shared[0]) &&
           acc.closed_vertex(shared[1])) ||
          (n == 1 && acc.closed_vertex(shared[0])))
        return {a.t, a.t_unc + b.t_unc};
    }
  }
  return {kInf, 0.0};
}

}  // namespace

AccuracyVerdict AccuracyReference::judge_closest(const Ray& r, bool hit, const Hit& h) const {
  const Reference ref = compute_reference(*mesh_, r, scale_);
  const Verdict v = kdgrid::judge_closest(ref, hit, h, nullptr);
  if (v == Verdict::Agree) return AccuracyVerdict::Agree;
  if (v == Verdict::Disagree) return AccuracyVerdict::Disagree;
  // Ambiguous for check: still a leak when the answer lies beyond a closed crossing.
  if (ref.valid) {
    const auto [tc, unc] = first_crossing(*this, ref, r);
    if (tc < kInf && (!hit || double(h.t) - tc > unc)) return AccuracyVerdict::Leak;
  }
  return AccuracyVerdict::Ambiguous;
}

AccuracyVerdict AccuracyReference::judge_occluded(const Ray& r, bool occluded) const {
  const Reference ref = compute_reference(*mesh_, r, scale_);
  if (judge_any_wrong(ref, occluded)) return AccuracyVerdict::Disagree;
  const bool ambiguous = ref.valid && (ref.grazing || ref.edge_before);
  if (!occluded && ref.valid && first_crossing(*this, ref, r).first < kInf)
    return AccuracyVerdict::Leak;
  return ambiguous ? AccuracyVerdict::Ambiguous : AccuracyVerdict::Agree;
}

namespace {
/// A point on a triangle and a direction leaving it on one side (the side ng faces).
struct AcneSample {
  Vec3 p, ng, d;
  uint32_t prim;
};
/// `count` seeded points on random triangles of `m`, each leaving the front or the back.
std::vector<AcneSample> acne_samples(const Mesh& m, int count, Rng& rng) {
  std::vector<AcneSample> samples;
  samples.reserve(size_t(std::max(count, 0)));
  for (int i = 0; i < count; ++i) {
    const uint32_t prim = uint32_t(rng.below(m.num_triangles()));
    const auto cr = m.corners(prim);
    Vec3 ng = cross(cr[1] - cr[0], cr[2] - cr[0]);
    if (length(ng) == 0 || !is_finite(ng)) continue;
    ng = normalize(ng);
    float u = rng.uniform(0, 1), v = rng.uniform(0, 1);
    if (u + v > 1) {
      u = 1 - u;
      v = 1 - v;
    }
    Vec3 d = rng.direction();
    if (dot(d, ng) < 0) d = -d;
    const bool back = rng.below(2) != 0;
    samples.push_back(
        {cr[0] * (1 - u - v) + cr[1] * u + cr[2] * v, back ? -ng : ng, back ? -d : d, prim});
  }
  return samples;
}
/// How many of the rays make_ray makes of the samples hit their own triangle first.
template <class MakeRay>
uint64_t self_hits(const Accelerator& accel, const std::vector<AcneSample>& samples,
                   MakeRay make_ray) {
  uint64_t n = 0;
  for (const AcneSample& s : samples) {
    Hit h;
    n += accel.intersect(make_ray(s), h) && h.prim == s.prim;
  }
  return n;
}
}  // namespace

uint64_t count_self_hits(const Accelerator& accel, const Mesh& mesh, int rays, uint64_t seed) {
  Rng rng(seed);
  return self_hits(accel, acne_samples(mesh, rays, rng), [&mesh](const AcneSample& s) {
    return Ray{offset_ray_origin(s.p, s.ng, mesh.corners(s.prim)), 0.0f, s.d, kInf};
  });
}

std::vector<AcneResult> run_acne_study(int rays_per_scale, uint64_t seed, float epsilon) {
  std::vector<AcneResult> out;
  const Mesh base = named_mesh("soup", 2000, seed);
  const double scales[] = {1e-4, 1e-2, 1.0, 1e2, 1e4};
  const double shifts[] = {0.0, 1e3, 1e5};
  for (double shift : shifts) {
    for (double scale : scales) {
      const Mesh m = transformed(base, scale, Vec3(float(shift)));
      auto accel = build_accelerator("bvh", m, BuildParams{});
      AcneResult r;
      r.scale = scale;
      r.translation = shift;
      r.epsilon = epsilon;
      Rng rng(seed ^ uint64_t(scale * 1e6) ^ uint64_t(shift));
      const std::vector<AcneSample> samples = acne_samples(m, rays_per_scale, rng);
      // Policies: robust moves the origin off the surface; epsilon skips hits before tmin.
      auto robust_ray = [&m](const AcneSample& s) {
        return Ray{offset_ray_origin(s.p, s.ng, m.corners(s.prim)), 0.0f, s.d, kInf};
      };
      auto epsilon_ray = [epsilon](const AcneSample& s) { return Ray{s.p, epsilon, s.d, kInf}; };
      r.rays = samples.size();
      r.robust_self_hits = self_hits(*accel, samples, robust_ray);
      r.epsilon_self_hits = self_hits(*accel, samples, epsilon_ray);
      // Speed of each policy: making the ray and its closest-hit query, one thread.
      volatile uint64_t sink = 0;  // keeps the traced answers alive
      auto timed = [&](auto make_ray) {
        const auto t0 = std::chrono::steady_clock::now();
        sink = sink + self_hits(*accel, samples, make_ray);
        return seconds_since(t0);
      };
      std::vector<double> robust_s, epsilon_s;
      for (int rep = 0; rep < kAcneTimingReps; ++rep) {  // which policy goes first alternates
        if (rep % 2 == 1) epsilon_s.push_back(timed(epsilon_ray));
        robust_s.push_back(timed(robust_ray));
        if (rep % 2 == 0) epsilon_s.push_back(timed(epsilon_ray));
      }
      r.robust_seconds = median(robust_s);
      r.epsilon_seconds = median(epsilon_s);
      out.push_back(r);
    }
  }
  return out;
}

}  // namespace kdgrid
