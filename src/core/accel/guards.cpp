#include "accel/guards.h"

#include <cmath>
#include <cstdio>

#include "util/error.h"
#include "util/memory.h"

namespace kdgrid {

double total_bytes(const std::vector<MemoryPart>& parts) {
  double sum = 0;
  for (const MemoryPart& p : parts) sum += p.bytes;
  return sum;
}

uint64_t check_memory_budget(const std::string& structure, size_t triangles,
                             const std::vector<MemoryPart>& parts, const BuildParams& params,
                             const std::string& fix) {
  const double need = total_bytes(parts);
  const uint64_t budget = effective_memory_budget(params);
  if (need > double(budget)) {
    std::string detail;
    for (const MemoryPart& p : parts) {
      if (p.bytes <= 0) continue;
      detail += (detail.empty() ? "" : ", ") + p.name + " " + format_bytes_iec(p.bytes);
    }
    throw ParamError(structure + ": building over " + std::to_string(triangles) +
                     " triangles needs about " + format_bytes_iec(need) + " at its peak (" +
                     detail + "), above the memory budget of " + format_bytes_iec(double(budget)) +
                     (params.memory_budget > 0 ? "" : " (half of the memory available to kdgrid)") +
                     "; " + fix + (fix.empty() ? "" : ", or ") +
                     "raise --memory-budget-mb (BuildParams::memory_budget; 0 = half of the "
                     "memory available) if the machine has the memory");
  }
  return uint64_t(std::ceil(need));
}

void throw_build_out_of_memory(const std::string& structure, size_t triangles,
                               const BuildParams& params) {
  throw ParamError(structure + ": building over " + std::to_string(triangles) +
                   " triangles ran out of memory (an allocation failed) with a memory budget of " +
                   format_bytes_iec(double(effective_memory_budget(params))) + " and " +
                   format_bytes_iec(double(available_memory_bytes())) +
                   " available to the process (the smallest of physical memory, the cgroup "
                   "limit and ulimit -v); lower --memory-budget-mb so the estimate refuses "
                   "first, use a leaner structure (--accel bvh), or run with more memory");
}

void check_brute_force_work(const std::string& accel, uint64_t primary_rays, size_t triangles,
                            const BuildParams& params) {
  if (accel != "brute" || !(params.brute_work_limit > 0)) return;
  const double work = double(primary_rays) * double(triangles);
  if (work <= params.brute_work_limit) return;
  char buf[512];
  // At ~5e7 ray/triangle tests per second per core (measured on the 10M landscape).
  const int side =
      int(std::floor(std::sqrt(params.brute_work_limit / std::max(1.0, double(triangles)))));
  std::snprintf(buf, sizeof buf,
                "brute: %llu primary rays x %zu triangles = %.3g ray/triangle tests before any "
                "shadow ray (about %.0f core-minutes at ~5e7 tests/s), above the brute-force "
                "work limit of %.3g; ",
                static_cast<unsigned long long>(primary_rays), triangles, work, work / 5e7 / 60.0,
                params.brute_work_limit);
  std::string msg = buf;
  if (side >= 1) msg += "render at --res " + std::to_string(side) + " or smaller, ";
  msg +=
      "use a structure (--accel bvh, kdtree, hybrid, ...), or raise --brute-work-limit (0 = "
      "no limit) if you mean to wait";
  throw ParamError(msg);
}

}  // namespace kdgrid
