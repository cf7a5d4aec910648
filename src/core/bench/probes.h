// Measuring primitives of the benchmark runner, the sweeps and the profiles: timed and counted
// passes of a ray set through a structure, medians, resident memory and the CPU's name.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "accel/accelerator.h"
#include "scene/mesh.h"

namespace kdgrid {

/// Rays per unit of parallel work: large enough that scheduling costs nothing next to the
/// traversals, small enough that 2..64 threads stay balanced on a 1 M-ray set.
constexpr size_t kTraceChunk = 1024;

/// Seconds on the steady clock since `t0`.
inline double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

/// Median of the values (mean of the middle two for an even count); 0 for none.
double median(std::vector<double> v);
/// Process peak resident set size in bytes, getrusage(RUSAGE_SELF).ru_maxrss.
uint64_t process_peak_rss_bytes();
/// Returns freed heap pages to the kernel (glibc malloc_trim), then resets the kernel's
/// peak-RSS mark (VmHWM) to the current RSS; false if the reset is not possible.
bool reset_peak_rss();
/// VmHWM from /proc/self/status in bytes (peak since the last reset), else ru_maxrss.
uint64_t peak_rss_since_reset();
/// VmRSS from /proc/self/status in bytes (0 if unavailable).
uint64_t current_rss_bytes();
/// The CPU's model name from /proc/cpuinfo ("model name"), or "unknown".
std::string cpu_model_name();

/// Times `rays` through `accel` (intersect or occluded) with tbb::parallel_for over chunks;
/// returns seconds. Hits (or occluded flags as t = 0 / inf) are written to `out` if given.
/// cpu_clock: instead of wall time, the tracing threads' summed CPU time divided by the
/// thread count, i.e. the wall time an otherwise idle machine would show. Time slices lost
/// to other processes on a shared machine do not count (their cache pollution still does).
double trace_rays(const Accelerator& accel, const std::vector<Ray>& rays, bool any_hit,
                  std::vector<Hit>* out, bool cpu_clock = false);
/// Times `rays` through `accel`'s packet query (intersect_packet or occluded_packet) in
/// consecutive packets of `packet` rays (at most 256), tbb::parallel_for over chunks of whole
/// packets; returns seconds, as trace_rays does, and writes hits to `out` the same way.
/// single_rays: the same packets through Accelerator's default packet query instead (its loop
/// over intersect() / occluded()), the structure's own single-ray walk on the same work.
double trace_packets(const Accelerator& accel, const std::vector<Ray>& rays, int packet,
                     bool any_hit, std::vector<Hit>* out, bool cpu_clock = false,
                     bool single_rays = false);
/// One counted pass; returns the summed counters.
RayCounters count_rays(const Accelerator& accel, const std::vector<Ray>& rays, bool any_hit);

/// Agreement of `hits` with `ref` on `rays` (rule of SetFigures::agreement); returns the
/// fraction and sets `disagreements`, and `on_surface` to how many of those are rays that
/// start on a triangle one of the two answers hit (starts_on_triangle): differences that
/// rounding decides (docs/RAYSETS.md). For any-hit sets only validity is compared, and the
/// answers name no triangle to classify.
double hit_agreement(const Mesh& mesh, const std::vector<Ray>& rays, const std::vector<Hit>& hits,
                     const std::vector<Hit>& ref, bool any_hit, double tie_tolerance,
                     uint64_t* disagreements = nullptr, uint64_t* on_surface = nullptr);

}  // namespace kdgrid
