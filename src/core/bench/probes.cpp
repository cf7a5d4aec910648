#include "bench/probes.h"

#include <malloc.h>
#include <sys/resource.h>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <fstream>

#include "accel/triangle.h"
#include "render/offset.h"
#include "util/error.h"

namespace kdgrid {

using Clock = std::chrono::steady_clock;

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

uint64_t process_peak_rss_bytes() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return uint64_t(ru.ru_maxrss) * 1024;  // Linux reports kilobytes
}

bool reset_peak_rss() {
#ifdef __GLIBC__
  // Hand freed heap pages back to the kernel first; otherwise what the previous structure
  // freed stays resident and is counted against the next one.
  malloc_trim(0);
#endif
  // Writing 5 to clear_refs resets VmHWM to the current RSS (Linux >= 4.0).
  std::ofstream f("/proc/self/clear_refs");
  if (!f) return false;
  f << "5";
  f.flush();
  return bool(f);
}

namespace {
/// A "Vm...:  N kB" field of /proc/self/status in bytes, 0 if absent.
uint64_t proc_status_bytes(const char* field) {
  std::ifstream f("/proc/self/status");
  std::string line;
  const std::string key = std::string(field) + ":";
  while (std::getline(f, line)) {
    if (line.rfind(key, 0) == 0) {
      std::istringstream ss(line.substr(key.size()));
      uint64_t kb = 0;
      if (ss >> kb) return kb * 1024;
    }
  }
  return 0;
}
}  // namespace

uint64_t peak_rss_since_reset() {
  const uint64_t b = proc_status_bytes("VmHWM");
  return b ? b : process_peak_rss_bytes();
}

uint64_t current_rss_bytes() {
  return proc_status_bytes("VmRSS");
}

std::string cpu_model_name() {
  std::ifstream f("/proc/cpuinfo");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("model name", 0) == 0) {
      const auto c = line.find(':');
      if (c != std::string::npos) {
        std::string m = line.substr(c + 1);
        m.erase(0, m.find_first_not_of(" \t"));
        return m;
      }
    }
  }
  return "unknown";
}

namespace {
double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}
}  // namespace

double trace_rays(const Accelerator& accel, const std::vector<Ray>& rays, bool any_hit,
                  std::vector<Hit>* out, bool cpu_clock) {
  if (out) out->resize(rays.size());
  Hit* dst = out ? out->data() : nullptr;
  std::atomic<int64_t> cpu_ns{0};
  const auto t0 = Clock::now();
  tbb::parallel_for(tbb::blocked_range<size_t>(0, rays.size(), kTraceChunk),
                    [&](const tbb::blocked_range<size_t>& r) {
                      const double c0 = cpu_clock ? thread_cpu_seconds() : 0.0;
                      for (size_t i = r.begin(); i < r.end(); ++i) {
                        Hit h;
                        if (any_hit) {
                          if (accel.occluded(rays[i])) h = {0.0f, 0, 0, 0};
                        } else {
                          accel.intersect(rays[i], h);
                        }
                        if (dst) dst[i] = h;
                      }
                      if (cpu_clock)
                        cpu_ns.fetch_add(int64_t((thread_cpu_seconds() - c0) * 1e9),
                                         std::memory_order_relaxed);
                    });
  if (!cpu_clock) return seconds_since(t0);
  const size_t threads =
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  return double(cpu_ns.load()) * 1e-9 /
         double(std::max<size_t>(1, std::min(threads, rays.size() / kTraceChunk + 1)));
}

double trace_packets(const Accelerator& accel, const std::vector<Ray>& rays, int packet,
                     bool any_hit, std::vector<Hit>* out, bool cpu_clock, bool single_rays) {
  constexpr int kMax = 256;
  if (packet < 1 || packet > kMax)
    throw ParamError("packets of " + std::to_string(packet) + " rays: use 1 to " +
                     std::to_string(kMax));
  if (out) out->resize(rays.size());
  Hit* dst = out ? out->data() : nullptr;
  const size_t packets = (rays.size() + size_t(packet) - 1) / size_t(packet);
  const size_t grain = std::max<size_t>(1, kTraceChunk / size_t(packet));
  std::atomic<int64_t> cpu_ns{0};
  const auto t0 = Clock::now();
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, packets, grain), [&](const tbb::blocked_range<size_t>& r) {
        const double c0 = cpu_clock ? thread_cpu_seconds() : 0.0;
        Hit hits[kMax];
        bool found[kMax];
        for (size_t p = r.begin(); p < r.end(); ++p) {
          const size_t base = p * size_t(packet);
          const int n = int(std::min(rays.size() - base, size_t(packet)));
          if (any_hit) {
            if (single_rays)  // the base class's loop, not the structure's override
              accel.Accelerator::occluded_packet(rays.data() + base, n, found);
            else
              accel.occluded_packet(rays.data() + base, n, found);
            if (dst)
              for (int i = 0; i < n; ++i) dst[base + i] = found[i] ? Hit{0.0f, 0, 0, 0} : Hit{};
          } else {
            if (single_rays)
              accel.Accelerator::intersect_packet(rays.data() + base, n, hits, found);
            else
              accel.intersect_packet(rays.data() + base, n, hits, found);
            if (dst)
              for (int i = 0; i < n; ++i) dst[base + i] = found[i] ? hits[i] : Hit{};
          }
        }
        if (cpu_clock)
          cpu_ns.fetch_add(int64_t((thread_cpu_seconds() - c0) * 1e9), std::memory_order_relaxed);
      });
  if (!cpu_clock) return seconds_since(t0);
  const size_t threads =
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  return double(cpu_ns.load()) * 1e-9 /
         double(std::max<size_t>(1, std::min(threads, rays.size() / kTraceChunk + 1)));
}

RayCounters count_rays(const Accelerator& accel, const std::vector<Ray>& rays, bool any_hit) {
  return tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, rays.size(), kTraceChunk), RayCounters{},
      [&](const tbb::blocked_range<size_t>& r, RayCounters c) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
          if (any_hit) {
            accel.occluded_counted(rays[i], c);
          } else {
            Hit h;
            accel.intersect_counted(rays[i], h, c);
          }
        }
        return c;
      },
      [](RayCounters a, const RayCounters& b) { return a += b; });
}

double hit_agreement(const Mesh& mesh, const std::vector<Ray>& rays, const std::vector<Hit>& hits,
                     const std::vector<Hit>& ref, bool any_hit, double tie_tolerance,
                     uint64_t* disagreements, uint64_t* on_surface) {
  if (hits.size() != ref.size() || hits.size() != rays.size())
    throw Error("hit_agreement: " + std::to_string(hits.size()) + " hits, " +
                std::to_string(ref.size()) + " reference hits and " + std::to_string(rays.size()) +
                " rays: the sets differ");
  // Whether ray i starts on the triangle a hit names (a difference there is rounding).
  auto starts_on = [&](size_t i, const Hit& h) {
    return h.valid() && h.prim < mesh.num_triangles() &&
           starts_on_triangle(rays[i].org, mesh.corners(h.prim));
  };
  struct Counts {
    uint64_t differ = 0, on_surface = 0;
  };
  const Counts counts = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, rays.size(), kTraceChunk), Counts{},
      [&](const tbb::blocked_range<size_t>& r, Counts n) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
          const Hit& a = hits[i];
          const Hit& b = ref[i];
          bool differ = a.valid() != b.valid();
          if (!differ && !any_hit && a.valid() && a.prim != b.prim) {
            // Different triangles: a tie if this triangle, intersected on its own, lies at the
            // reference's t (both sides of a shared edge, coplanar duplicates).
            float t = a.t;
            if (a.prim < mesh.num_triangles()) {
              const auto c = mesh.corners(a.prim);
              const auto rd = WatertightTest::prepare(rays[i]);
              float tt, u, v;
              if (WatertightTest::intersect(rd, c[0], c[1], c[2], rays[i].tmin, kInf, tt, u, v))
                t = tt;
            }
            const double diff = std::fabs(double(t) - double(b.t));
            differ =
                !(diff <= tie_tolerance * std::max(std::fabs(double(t)), std::fabs(double(b.t))));
          }
          if (!differ) continue;
          ++n.differ;
          if (starts_on(i, a) || starts_on(i, b)) ++n.on_surface;
        }
        return n;
      },
      [](Counts x, const Counts& y) {
        x.differ += y.differ;
        x.on_surface += y.on_surface;
        return x;
      });
  if (disagreements) *disagreements = counts.differ;
  if (on_surface) *on_surface = counts.on_surface;
  return rays.empty() ? 1.0 : 1.0 - double(counts.differ) / double(rays.size());
}

}  // namespace kdgrid
