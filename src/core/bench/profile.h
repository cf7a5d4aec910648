// Per-class single-thread ray costs, behind `kdgrid profile`: where a structure's time goes.
//
// The benchmark gives one throughput per ray set; a structure can lose on the rays that hit
// (triangle tests near the surface) or on the rays that miss (empty space, per-ray set-up).
// This splits the rays by the reference's answer into three classes,
//   hit       the reference finds a hit,
//   miss-box  no hit, but the ray crosses the scene's box (it walks empty space),
//   miss-out  the ray misses the scene's box (per-ray set-up only),
// and times each class on the calling thread alone, twice:
//   cold  the rays in image order, as the benchmark traces them;
//   warm  each ray traced again right after itself (the pair's time minus the cold time of
//         the pass just before it, median over repetitions),
//         so that the structure's data it needs is in the caches: what remains is the
//         instructions, dependent latencies and branch mispredictions of the traversal.
// Cold minus warm is then the cost of cache and TLB misses. Counters come from one counted
// pass over the same class.
#pragma once

#include <string>
#include <vector>

#include "accel/accelerator.h"

namespace kdgrid {

struct RayClasses {
  std::vector<Ray> hit, miss_box, miss_out;
};

/// Splits `rays` by `reference`'s closest-hit answer and by `box` (slab test in double).
RayClasses classify_rays(const Accelerator& reference, const Box3& box,
                         const std::vector<Ray>& rays);

struct ProfileFigures {
  uint64_t rays = 0;
  uint64_t hits = 0;
  double cold_ns = 0;  ///< nanoseconds per ray, minimum over the repetitions
  double warm_ns = 0;  ///< nanoseconds per ray of the second, cache-warm trace
  bool counted = false;
  double steps = 0, leaves = 0, tests = 0, lookups = 0;  ///< per ray
};

/// Times `rays` through `accel` on the calling thread (closest hit), `reps` times each way.
/// Empty `rays` give zeros.
ProfileFigures profile_rays(const Accelerator& accel, const std::vector<Ray>& rays, int reps);

/// Fills `f`'s rays and, for a structure with counters, its per-ray counters from one counted
/// pass over `rays`.
void count_rays(const Accelerator& accel, const std::vector<Ray>& rays, ProfileFigures& f);

/// Traces `rays` once, in order, on the calling thread (closest hit); returns the hits. Built
/// where valgrind's headers are installed, it brackets the pass with callgrind client requests,
/// so that `valgrind --tool=callgrind --instr-atstart=no` simulates exactly this pass and writes
/// it as one profile part per call (scripts/cache-profile.sh); elsewhere, and outside valgrind,
/// it is a plain pass.
uint64_t cache_sim_pass(const Accelerator& accel, const std::vector<Ray>& rays);

}  // namespace kdgrid
