// Fail-fast guards shared by the acceleration structures. A structure estimates the peak
// bytes of its build from what it knows before allocating (triangle count, resolution, ...)
// and refuses with a ParamError naming the bytes, the budget and the fix when the estimate
// exceeds BuildParams::memory_budget, so a scene too big for the machine fails in
// milliseconds instead of swapping or being killed. Brute force, which needs no memory, has
// a work limit instead (BuildParams::brute_work_limit).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "accel/params.h"
#include "scene/mesh.h"
#include "util/format.h"

namespace kdgrid {

/// One term of an estimate, named for the message ("nodes", "events", ...).
struct MemoryPart {
  std::string name;
  double bytes = 0;
};

/// Sum of the parts, bytes.
double total_bytes(const std::vector<MemoryPart>& parts);

/// Throws ParamError when the parts sum above effective_memory_budget(params):
///   "<structure>: building over N triangles needs about X at its peak (part: bytes, ...),
///    above the memory budget of Y; <fix>, or raise --memory-budget-mb (0 = half of
///    physical memory)".
/// Returns the sum, rounded up, for BuildStats::peak_estimate.
uint64_t check_memory_budget(const std::string& structure, size_t triangles,
                             const std::vector<MemoryPart>& parts, const BuildParams& params,
                             const std::string& fix);

/// The peak a build may use, BuildStats::peak_estimate: `worst_case` bytes (an upper bound of
/// the build from what is known before it runs), at least `expected` (the guard's figure,
/// already within the budget), at most the memory budget, rounded up.
uint64_t build_peak_bound(double worst_case, uint64_t expected, const BuildParams& params);

/// Throws ParamError when `accel` is "brute" and primary_rays x triangles exceeds
/// params.brute_work_limit (0 = no limit); the message gives the largest square resolution
/// that fits and the alternatives. Other structures pass. `kdgrid render` passes the rays of
/// one progressive pass (later passes can be interrupted), `kdgrid bench` all its rays.
void check_brute_force_work(const std::string& accel, uint64_t primary_rays, size_t triangles,
                            const BuildParams& params);

/// Work guard of the grids (uniform and irregular): the references a grid of res[a] cells of
/// size cell[a] from lo[a] would hold for triangles tris[begin, end) (triangle i itself when
/// `tris` is null), estimated per triangle as the smaller of the cells of its box and a surface
/// estimate (its area projected on each axis plane over that plane's cell face, plus its extent
/// in cells along each axis, plus one).
double estimate_grid_references(const Mesh& mesh, const uint32_t* tris, size_t begin, size_t end,
                                const double lo[3], const double cell[3], const int32_t res[3]);

/// Whether `refs` estimated references pile up in a grid of `cells` cells over `triangles`
/// triangles: more than 64 per triangle and 8 per cell, or each triangle in more than a quarter
/// of the cells on average. A density heuristic assumes triangles
/// spread over the box; where they pile up (coincident or stacked copies, surfaces covering the
/// whole grid many times over) each overlaps a fixed fraction of the cells, the references
/// grow as triangles x cells, and a coarser grid answers every ray as well for far less work.
bool grid_references_pile_up(double refs, double triangles, double cells);

/// Throws ParamError saying that building `structure` over `triangles` triangles ran out of
/// memory (an allocation failed), with the memory budget, the memory available to the process
/// (util/memory.h: physical, cgroup, ulimit -v) and the fixes. Called where a build catches
/// std::bad_alloc.
[[noreturn]] void throw_build_out_of_memory(const std::string& structure, size_t triangles,
                                            const BuildParams& params);

}  // namespace kdgrid
