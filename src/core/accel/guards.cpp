#include "accel/guards.h"

#include <algorithm>
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

uint64_t build_peak_bound(double worst_case, uint64_t expected, const BuildParams& params) {
  const double budget = double(effective_memory_budget(params));
  const double bound = std::max(double(expected), std::ceil(worst_case));
  return bound >= budget || !std::isfinite(bound) ? uint64_t(budget) : uint64_t(bound);
}

double estimate_grid_references(const Mesh& mesh, const uint32_t* tris, size_t begin, size_t end,
                                const double lo[3], const double cell[3], const int32_t res[3]) {
  double sum = 0;
  for (size_t k = begin; k < end; ++k) {
    const size_t i = tris ? tris[k] : k;
    const auto c = mesh.corners(i);
    const Vec3d e1 = Vec3d(c[1]) - Vec3d(c[0]), e2 = Vec3d(c[2]) - Vec3d(c[0]);
    const Vec3d nrm = cross(e1, e2);
    double in_box = 1.0, surface = 1.0;
    for (int a = 0; a < 3; ++a) {
      const int b = (a + 1) % 3, d = (a + 2) % 3;
      const double mn = std::min({double(c[0][a]), double(c[1][a]), double(c[2][a])});
      const double mx = std::max({double(c[0][a]), double(c[1][a]), double(c[2][a])});
      const double top = double(res[a] - 1);
      in_box *= std::clamp(std::floor((mx - lo[a]) / cell[a]), 0.0, top) -
                std::clamp(std::floor((mn - lo[a]) / cell[a]), 0.0, top) + 1.0;
      surface += 0.5 * std::fabs(nrm[a]) / (cell[b] * cell[d]) + (mx - mn) / cell[a];
    }
    if (std::isfinite(surface)) sum += std::min(in_box, surface);
  }
  return sum;
}

bool grid_references_pile_up(double refs, double triangles, double cells) {
  return refs > std::max(64.0 * triangles, 8.0 * cells) || refs > 0.25 * triangles * cells;
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
  // At the brute-force rate of docs/LIMITS.md, "The guards' constants".
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
