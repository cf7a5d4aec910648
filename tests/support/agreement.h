// The differential agreement harness (docs/DESIGN.md, "Testing"): every structure must return what
// brute force returns on the same rays. Used by test_agreement.cpp and by any test that
// wants to check a structure against the reference.
//
// Rules, for each ray:
//   - miss iff the reference misses;
//   - the same closest t within rel_tol * |t| + abs_tol;
//   - the same triangle, unless the reported triangle ties with the reference at that t
//     (checked by intersecting the reported triangle alone: its own t must match too);
//   - occluded() iff the reference has a hit in [tmin, tmax) (brute any-hit is exactly
//     "brute closest hit exists": both test every triangle with the same test).
// A rule may accept a fraction of disagreeing rays (Embree uses its own triangle test).
//
// The brute reference costs rays x triangles tests (1e5 x 2e5 for the dragon), so it is cached
// on disk, keyed by a hash of the mesh, the rays and the triangle test, and written
// atomically (temporary file + rename) so that parallel ctest processes can share it.
#pragma once

#include <gtest/gtest.h>
#include <tbb/parallel_for.h>

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>
#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "accel/accelerator.h"
#include "accel/brute.h"
#include "accel/embree.h"
#include "bench/rayfile.h"
#include "bench/raysets.h"
#include "comparator_meshes.h"
#include "scene/mesh.h"

#ifndef KDGRID_REFERENCE_CACHE_DIR
#define KDGRID_REFERENCE_CACHE_DIR ""
#endif

namespace kdgrid::test {

/// How strictly a structure must agree with the reference.
struct AgreementRule {
  float rel_tol = 1e-5f;        ///< relative tolerance on t
  float abs_tol_scene = 1e-6f;  ///< absolute tolerance, times the scene diagonal / |dir|
  double min_fraction = 1.0;    ///< fraction of rays that must agree on every criterion
  int max_examples = 5;         ///< disagreements printed
  /// Rays whose reference hit lies at their start (t within the absolute tolerance of tmin: a
  /// secondary ray leaving a surface, or an overlapping coplanar neighbour of it) are not
  /// judged: whether a hit at the very start counts is the triangle test's convention.
  bool start_hits_ambiguous = false;
};

/// Structures that are not held to exact agreement: Embree intersects with its own triangle
/// test, so rays through shared edges may legitimately pick the other triangle or slip. Camera
/// rays must agree on 99.99% of rays. Secondary rays start on surfaces, where Embree
/// reports t = 0 hits on overlapping coplanar neighbours of the surface the ray leaves (2% of
/// the diffuse rays of the coplanar-quads scene, measured), so they are held to 97%.
/// Without RTC_SCENE_FLAG_ROBUST (`embree`, `embree-high`) Embree does not report those t = 0
/// hits at all, where the reference does: 392 of the 7234 shadow rays of the coplanar-quads
/// scene (measured), all starting on a surface the reference hits at t = 0. Such rays are not
/// judged for those configurations (start_hits_ambiguous); `embree-robust` is held to all.
inline AgreementRule rule_for(const std::string& structure, const std::string& set = "primary") {
  AgreementRule r;
  if (const EmbreeConfig* c = embree_config(structure)) {
    r.rel_tol = 1e-4f;
    r.min_fraction = (set == "primary" || set == "random") ? 0.9999 : 0.97;
    r.start_hits_ambiguous = !c->robust;
  }
  return r;
}

// ---- hashing and the on-disk reference cache ----------------------------------------------

/// 64-bit FNV-1a over raw bytes; two differently seeded passes make the 128-bit cache key.
inline uint64_t fnv1a(const void* data, size_t n, uint64_t h) {
  const auto* p = static_cast<const uint8_t*>(data);
  for (size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= 0x100000001B3ull;
  }
  return h;
}

inline std::string reference_key(const Mesh& mesh, const std::vector<Ray>& rays,
                                 TriangleTestKind test) {
  char buf[40];
  uint64_t h[2] = {0xCBF29CE484222325ull, 0x84222325CBF29CE4ull};
  for (uint64_t& x : h) {
    const uint32_t version = 1, kind = uint32_t(test);
    x = fnv1a(&version, sizeof version, x);
    x = fnv1a(&kind, sizeof kind, x);
    x = fnv1a(mesh.positions.data(), mesh.positions.size() * sizeof(Vec3), x);
    x = fnv1a(mesh.triangles.data(), mesh.triangles.size() * sizeof(mesh.triangles[0]), x);
    x = fnv1a(rays.data(), rays.size() * sizeof(Ray), x);
  }
  std::snprintf(buf, sizeof buf, "%016llx%016llx", (unsigned long long)h[0],
                (unsigned long long)h[1]);
  return buf;
}

/// Closest hits of brute force over `rays`, parallel over rays; cached on disk when the
/// cache directory is configured (KDGRID_REFERENCE_CACHE_DIR). Barycentrics are not cached.
inline std::vector<Hit> brute_reference(const Mesh& mesh, const std::vector<Ray>& rays,
                                        TriangleTestKind test = TriangleTestKind::Watertight) {
  namespace fs = std::filesystem;
  // $KDGRID_REFERENCE_CACHE lets builds share one cache (CI's sanitizer builds reuse the
  // release build's references instead of recomputing them).
  const char* env = std::getenv("KDGRID_REFERENCE_CACHE");
  const std::string dir = env && *env ? env : KDGRID_REFERENCE_CACHE_DIR;
  fs::path file;
  int lock_fd = -1;
  if (!dir.empty()) {
    file = fs::path(dir) / (reference_key(mesh, rays, test) + ".hits");
    std::error_code ec;
    // ctest runs tests in parallel processes: the first to need a reference computes it
    // while the others wait on this lock and then read the cache, instead of all computing.
    fs::create_directories(file.parent_path(), ec);
    lock_fd = ::open((file.string() + ".lock").c_str(), O_CREAT | O_RDWR, 0644);
    if (lock_fd >= 0) ::flock(lock_fd, LOCK_EX);
    if (fs::exists(file, ec)) {
      try {
        auto cached = read_hits(file.string(), int64_t(rays.size()));
        if (lock_fd >= 0) ::close(lock_fd);
        return cached;
      } catch (const std::exception&) {
        // A damaged cache file is recomputed and replaced below.
      }
    }
  }
  BruteForce brute;
  BuildParams p;
  p.triangle_test = test;
  brute.build(mesh, p);
  std::vector<Hit> hits = trace_hits(brute, rays, 64);
  if (!file.empty()) {
    std::error_code ec;
    fs::create_directories(file.parent_path(), ec);
    std::random_device rd;
    const fs::path tmp = file.string() + ".tmp" + std::to_string(rd()) + std::to_string(rd());
    try {
      write_hits(tmp.string(), hits);
      fs::rename(tmp, file, ec);  // atomic on POSIX: readers see the old or the new file
      if (ec) fs::remove(tmp, ec);
    } catch (const std::exception&) {
      fs::remove(tmp, ec);
    }
  }
  if (lock_fd >= 0) ::close(lock_fd);  // releases the lock
  // Drop barycentrics so cached and fresh references compare the same way.
  for (Hit& h : hits) h.u = h.v = 0.0f;
  return hits;
}

// ---- comparison ---------------------------------------------------------------------------

struct AgreementReport {
  std::string structure, set;
  size_t rays = 0;
  size_t miss_mismatch = 0;  ///< hit vs miss
  size_t t_mismatch = 0;     ///< both hit, t differs beyond tolerance
  size_t prim_mismatch = 0;  ///< same t, different triangle that does not tie
  size_t any_mismatch = 0;   ///< occluded() differs from the reference
  size_t disagreeing = 0;    ///< rays failing at least one criterion
  size_t ties = 0;           ///< different triangle accepted as a tie
  size_t start_hits = 0;     ///< not judged: reference hit at the ray's start (the rule allows)
  double min_fraction = 1.0;
  std::vector<std::string> examples;

  bool ok() const {
    return rays == 0 || double(rays - disagreeing) >= min_fraction * double(rays) - 1e-9;
  }
  std::string summary() const {
    std::ostringstream o;
    o << structure << " on " << set << ": " << rays << " rays, " << disagreeing
      << " disagree (hit/miss " << miss_mismatch << ", t " << t_mismatch << ", triangle "
      << prim_mismatch << ", any-hit " << any_mismatch << "; " << ties << " ties accepted; "
      << start_hits << " rays hitting at their start not judged); required agreement "
      << min_fraction * 100.0 << "%";
    for (const auto& e : examples) o << "\n  " << e;
    return o.str();
  }
};

inline std::string describe(const Ray& r) {
  char buf[200];
  std::snprintf(buf, sizeof buf, "org (%.9g %.9g %.9g) dir (%.9g %.9g %.9g) t [%.9g %.9g]", r.org.x,
                r.org.y, r.org.z, r.dir.x, r.dir.y, r.dir.z, r.tmin, r.tmax);
  return buf;
}

/// Intersects triangle `prim` alone with the structure's triangle test.
inline bool intersect_one(const Mesh& mesh, const Ray& ray, uint32_t prim, TriangleTestKind test,
                          float& t) {
  const auto c = mesh.corners(prim);
  float u, v;
  if (test == TriangleTestKind::Watertight)
    return WatertightTest::intersect(WatertightTest::prepare(ray), c[0], c[1], c[2], ray.tmin,
                                     ray.tmax, t, u, v);
  return MollerTest::intersect(MollerTest::prepare(ray), c[0], c[1], c[2], ray.tmin, ray.tmax, t, u,
                               v);
}

/// Compares `accel` (built over `mesh`) with the reference hits of `rays`.
inline AgreementReport compare_with_reference(
    const Accelerator& accel, const Mesh& mesh, const std::vector<Ray>& rays,
    const std::vector<Hit>& ref, const AgreementRule& rule, const std::string& set,
    TriangleTestKind test = TriangleTestKind::Watertight) {
  AgreementReport rep;
  rep.structure = accel.name();
  rep.set = set;
  rep.rays = rays.size();
  rep.min_fraction = rule.min_fraction;
  const float diag = length(mesh.bounds().extent());
  std::atomic<size_t> miss{0}, tm{0}, pm{0}, am{0}, dis{0}, ties{0}, starts{0};
  std::mutex mu;
  std::vector<std::pair<size_t, std::string>> examples;
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, rays.size(), 256),
      [&](const tbb::blocked_range<size_t>& range) {
        for (size_t i = range.begin(); i < range.end(); ++i) {
          const Ray& ray = rays[i];
          const Hit& want = ref[i];
          Hit got;
          const bool hit = accel.intersect(ray, got);
          const bool occ = accel.occluded(ray);
          const float dl = length(ray.dir);
          const float abs_tol = rule.abs_tol_scene * (dl > 0 ? diag / dl : 1.0f);
          auto close = [&](float a, float b) {
            return std::fabs(a - b) <= rule.rel_tol * std::fabs(b) + abs_tol;
          };
          if (rule.start_hits_ambiguous && want.valid() && want.t <= ray.tmin + abs_tol) {
            ++starts;
            continue;
          }
          std::string why;
          if (hit != want.valid() || (hit && !got.valid())) {
            ++miss;
            why = hit ? "structure hits, reference misses" : "structure misses, reference hits";
          } else if (hit) {
            if (!close(got.t, want.t)) {
              ++tm;
              why = "t differs";
            } else if (got.prim != want.prim) {
              float t_own;
              if (got.prim < mesh.num_triangles() &&
                  intersect_one(mesh, ray, got.prim, test, t_own) && close(t_own, want.t)) {
                ++ties;
              } else {
                ++pm;
                why = "different triangle, not a tie";
              }
            }
          }
          if (occ != want.valid()) {
            ++am;
            why += why.empty() ? "" : "; ";
            why += occ ? "occluded() true, reference misses" : "occluded() false, reference hits";
          }
          if (!why.empty()) {
            ++dis;
            std::lock_guard<std::mutex> lock(mu);
            if (examples.size() < 64) {
              char buf[160];
              std::snprintf(buf, sizeof buf, " | got t %.9g prim %d, want t %.9g prim %d",
                            hit ? got.t : kInf, hit ? int(got.prim) : -1, want.t,
                            want.valid() ? int(want.prim) : -1);
              examples.push_back(
                  {i, "ray " + std::to_string(i) + ": " + why + buf + " | " + describe(ray)});
            }
          }
        }
      });
  std::sort(examples.begin(), examples.end());
  for (size_t k = 0; k < examples.size() && int(k) < rule.max_examples; ++k)
    rep.examples.push_back(examples[k].second);
  rep.miss_mismatch = miss;
  rep.t_mismatch = tm;
  rep.prim_mismatch = pm;
  rep.any_mismatch = am;
  rep.disagreeing = dis;
  rep.ties = ties;
  rep.start_hits = starts;
  return rep;
}

/// Checks that the counted and traced traversals return exactly the hits of the fast path
/// (same policy template, so any difference is a bug in a stats hook). Returns the number of
/// disagreeing rays; examples go to `examples`. `trace_stride` traces every k-th ray only.
inline size_t compare_instrumented(const Accelerator& accel, const std::vector<Ray>& rays,
                                   size_t trace_stride, std::vector<std::string>& examples) {
  std::atomic<size_t> bad{0};
  std::mutex mu;
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, rays.size(), 256),
      [&](const tbb::blocked_range<size_t>& range) {
        for (size_t i = range.begin(); i < range.end(); ++i) {
          Hit fast, counted;
          const bool hf = accel.intersect(rays[i], fast);
          RayCounters c;
          const bool hc = accel.intersect_counted(rays[i], counted, c);
          const bool of = accel.occluded(rays[i]);
          RayCounters c2;
          const bool oc = accel.occluded_counted(rays[i], c2);
          bool same = hf == hc && of == oc &&
                      (!hf || (fast.t == counted.t && fast.prim == counted.prim &&
                               fast.u == counted.u && fast.v == counted.v));
          if (same && trace_stride > 0 && i % trace_stride == 0) {
            const Trace tr = accel.trace(rays[i]);
            same =
                tr.hit.valid() == hf && (!hf || (tr.hit.t == fast.t && tr.hit.prim == fast.prim));
            // The trace counts exactly what the counted traversal counts.
            same = same && (!accel.has_counters() || tr.counters == c);
            same = same && tr.tested.size() == tr.counters.tri_tests;
          }
          if (!same) {
            ++bad;
            std::lock_guard<std::mutex> lock(mu);
            if (examples.size() < 5)
              examples.push_back("ray " + std::to_string(i) + ": " + describe(rays[i]));
          }
        }
      });
  return bad;
}

// ---- procedural meshes for tests ----------------------------------------------------------

/// `n` random triangles of random size and orientation in [-1, 1]^3.
inline Mesh triangle_soup(size_t n, uint32_t seed) {
  std::uniform_real_distribution<float> pos(-1.0f, 1.0f), size(0.01f, 0.3f);
  return generated_triangles(n, seed, [&](std::mt19937& rng) {
    const Vec3 c(pos(rng), pos(rng), pos(rng));
    const float s = size(rng);
    std::array<Vec3, 3> v;
    for (Vec3& corner : v) corner = c + Vec3(pos(rng), pos(rng), pos(rng)) * s;
    return v;
  });
}

/// An icosphere of radius `r` about `c`, `levels` times subdivided (20 * 4^levels triangles),
/// with shared vertices so edges are exactly shared (watertight).
inline Mesh subdivided_sphere(int levels, float r = 1.0f, Vec3 c = Vec3(0.0f)) {
  const float t = (1.0f + std::sqrt(5.0f)) / 2.0f;
  Mesh m;
  m.positions = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                 {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  m.triangles = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                 {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                 {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                 {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (auto& p : m.positions) p = normalize(p);
  for (int l = 0; l < levels; ++l) {
    std::vector<std::array<uint32_t, 3>> next;
    std::map<uint64_t, uint32_t> cache;  // edge (sorted vertex pair) -> midpoint vertex
    auto mid = [&](uint32_t a, uint32_t b) {
      const uint64_t key = (uint64_t(std::min(a, b)) << 32) | std::max(a, b);
      auto it = cache.find(key);
      if (it != cache.end()) return it->second;
      const uint32_t idx = uint32_t(m.positions.size());
      m.positions.push_back(normalize((m.positions[a] + m.positions[b]) * 0.5f));
      cache[key] = idx;
      return idx;
    };
    for (const auto& tri : m.triangles) {
      const uint32_t a = mid(tri[0], tri[1]), b = mid(tri[1], tri[2]), cc = mid(tri[2], tri[0]);
      next.push_back({tri[0], a, cc});
      next.push_back({tri[1], b, a});
      next.push_back({tri[2], cc, b});
      next.push_back({a, b, cc});
    }
    m.triangles = std::move(next);
  }
  for (auto& p : m.positions) p = c + p * r;
  return m;
}

/// Coplanar axis-aligned quads: an n x n grid of unit quads (two triangles each) in the plane
/// y = 0, plus the same grid at x = 0 and z = 0 — rays in or along those planes and through
/// shared edges and vertices stress ties and zero-thickness boxes.
inline Mesh coplanar_quads(int n) {
  Mesh m;
  for (int axis = 0; axis < 3; ++axis) {
    const uint32_t base = uint32_t(m.positions.size());
    for (int j = 0; j <= n; ++j)
      for (int i = 0; i <= n; ++i) {
        const float a = float(i) - n * 0.5f, b = float(j) - n * 0.5f;
        Vec3 p;
        p[(axis + 1) % 3] = a;
        p[(axis + 2) % 3] = b;
        m.positions.push_back(p);
      }
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const uint32_t v = base + uint32_t(j * (n + 1) + i);
        m.triangles.push_back({v, v + 1, v + uint32_t(n) + 2});
        m.triangles.push_back({v, v + uint32_t(n) + 2, v + uint32_t(n) + 1});
      }
  }
  return m;
}

/// Long thin triangles (length 0.2-0.8, width ~1e-3) in random directions in [-1, 1]^3:
/// boxes far larger than the triangles, the worst case for bounding volumes.
inline Mesh thin_triangles(size_t n, uint32_t seed) {
  std::uniform_real_distribution<float> u(-1.0f, 1.0f), len(0.2f, 0.8f);
  return generated_triangles(n, seed, [&](std::mt19937& rng) {
    const Vec3 a(u(rng), u(rng), u(rng));
    const Vec3 b = a + normalize(Vec3(u(rng), u(rng), u(rng))) * len(rng);
    const Vec3 side = normalize(cross(b - a, Vec3(u(rng), u(rng), u(rng)))) * 1e-3f;
    return std::array<Vec3, 3>{a, b, (a + b) * 0.5f + side};
  });
}

/// A random soup in which every triangle appears twice (same vertices, separate indices) and
/// a third of them a third time with rotated winding: exact ties at every hit.
inline Mesh duplicated_triangles(size_t n, uint32_t seed) {
  const Mesh soup = triangle_soup(n, seed);
  Mesh m = soup;
  for (size_t i = 0; i < soup.num_triangles(); ++i) {
    const auto& t = soup.triangles[i];
    m.triangles.push_back(t);
    if (i % 3 == 0) m.triangles.push_back({t[1], t[2], t[0]});
  }
  return m;
}

}  // namespace kdgrid::test
