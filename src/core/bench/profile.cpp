#include "bench/profile.h"

#include <algorithm>
#include <chrono>
#include <limits>
#include <vector>

#include "util/error.h"

// valgrind's client requests (package valgrind): a few no-op instructions outside valgrind.
#if __has_include(<valgrind/callgrind.h>)
#include <valgrind/callgrind.h>
#define KDGRID_CALLGRIND 1
#endif

namespace kdgrid {

namespace {

bool crosses_box(const Ray& r, const Box3& box) {
  double t0 = r.tmin, t1 = r.tmax;
  for (int a = 0; a < 3; ++a) {
    const double o = r.org[a], d = r.dir[a];
    if (d == 0.0) {
      if (o < box.lo[a] || o > box.hi[a]) return false;
      continue;
    }
    double ta = (double(box.lo[a]) - o) / d, tb = (double(box.hi[a]) - o) / d;
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  return t0 <= t1;
}

/// Seconds to trace every ray `times` times in a row (1: cold order, 2: each ray twice).
double time_pass(const Accelerator& accel, const std::vector<Ray>& rays, int times,
                 uint64_t& hits) {
  hits = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (const Ray& r : rays)
    for (int k = 0; k < times; ++k) {
      Hit h;
      hits += accel.intersect(r, h);
    }
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

uint64_t cache_sim_pass(const Accelerator& accel, const std::vector<Ray>& rays) {
  uint64_t hits = 0;
#ifdef KDGRID_CALLGRIND
  // Under `valgrind --tool=callgrind --instr-atstart=no`: simulate only this pass (the loading
  // and the builds run uninstrumented, several times faster) and write it as one profile part.
  CALLGRIND_START_INSTRUMENTATION;
  CALLGRIND_ZERO_STATS;
#endif
  time_pass(accel, rays, 1, hits);
#ifdef KDGRID_CALLGRIND
  CALLGRIND_DUMP_STATS_AT("kdgrid::cache_sim_pass");
  CALLGRIND_STOP_INSTRUMENTATION;
#endif
  return hits;
}

RayClasses classify_rays(const Accelerator& reference, const Box3& box,
                         const std::vector<Ray>& rays) {
  RayClasses c;
  for (const Ray& r : rays) {
    Hit h;
    if (reference.intersect(r, h))
      c.hit.push_back(r);
    else
      (crosses_box(r, box) ? c.miss_box : c.miss_out).push_back(r);
  }
  return c;
}

ProfileFigures profile_rays(const Accelerator& accel, const std::vector<Ray>& rays, int reps) {
  if (reps < 1) throw ParamError("profile: --reps must be at least 1");
  ProfileFigures f;
  f.rays = rays.size();
  if (rays.empty()) return f;
  // Cold: the fastest pass. Warm: the median over repetitions of (pair - cold) from passes
  // run back to back, so a burst of load on a shared machine that slows one pass moves one
  // sample instead of the difference of two minima taken at different times.
  double cold = std::numeric_limits<double>::infinity();
  std::vector<double> warm;
  uint64_t hits = 0, hits2 = 0;
  for (int rep = 0; rep < reps; ++rep) {
    const double c = time_pass(accel, rays, 1, hits);
    const double p = time_pass(accel, rays, 2, hits2);
    cold = std::min(cold, c);
    warm.push_back(p - c);
  }
  std::nth_element(warm.begin(), warm.begin() + warm.size() / 2, warm.end());
  const double n = double(rays.size());
  f.hits = hits;
  f.cold_ns = cold * 1e9 / n;
  f.warm_ns = std::max(0.0, warm[warm.size() / 2]) * 1e9 / n;
  count_rays(accel, rays, f);
  return f;
}

void count_rays(const Accelerator& accel, const std::vector<Ray>& rays, ProfileFigures& f) {
  f.rays = rays.size();
  if (rays.empty() || !accel.has_counters()) return;
  RayCounters c;
  for (const Ray& r : rays) {
    Hit h;
    accel.intersect_counted(r, h, c);
  }
  const double n = double(rays.size());
  f.counted = true;
  f.steps = double(c.steps) / n;
  f.leaves = double(c.leaves) / n;
  f.tests = double(c.tri_tests) / n;
  f.lookups = double(c.lookups) / n;
}

}  // namespace kdgrid
