// The benchmark ray sets of docs/RAYSETS.md, generated deterministically from a mesh:
//
//   primary  one ray per pixel centre of a camera (canonical unless given), row by row.
//   shadow   from each primary hit, offset off the surface, towards the benchmark point light
//            c + (0, 2r, 0) + 0.5 r d. The direction is (light - origin), so t = 1 is the
//            light; tmax = 1 and the half-open [tmin, tmax) of every intersector keeps the
//            light itself out. Any-hit queries.
//   diffuse  from each primary hit, one cosine-distributed direction about the geometric
//            normal turned towards the camera; seeded per ray, so independent of threads.
//   random   seeded rays for tests: origins in and around the scene box, uniform directions,
//            some aimed at the box, some with a finite tmax or a positive tmin.
//
// Shadow and diffuse rays exist only for primary rays that hit, so those sets are smaller
// than W x H; their order follows the primary rays'. Origins are offset with
// offset_ray_origin (Wächter & Binder, RTG ch. 6) on the side of the geometric normal that
// faces the primary ray's origin, then stepped past coincident surfaces (layers parallel to
// the hit triangle whose plane the origin lies on within rounding), so no generated ray starts
// on a surface.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "accel/accelerator.h"
#include "math/ray.h"
#include "scene/scene.h"

namespace kdgrid {

enum class RaySetKind { Primary, Shadow, Diffuse, Random };

/// "primary", "shadow", "diffuse" or "random" (ParamError otherwise).
RaySetKind parse_ray_set(const std::string& s);
const char* to_string(RaySetKind k);

/// Default image size of the primary set (docs/RAYSETS.md).
constexpr int kDefaultRaySetResolution = 1024;

/// One ray per pixel centre of `cam`, rows top to bottom.
std::vector<Ray> primary_rays(const Camera& cam, int width, int height);

/// The pixels of a width x height image (row-major indices) in tile order: tiles of tile x tile
/// pixels left to right, top to bottom, each tile's pixels row by row (edge tiles are cut to
/// the image). Consecutive runs of tile^2 indices are the packets of a packet query.
std::vector<uint32_t> tile_order(int width, int height, int tile);

/// Closest hits of `rays`, in parallel over rays (TBB), `grain` rays per task at the least: a
/// smaller grain spreads slow queries (brute force over a large mesh) over more threads.
std::vector<Hit> trace_hits(const Accelerator& accel, const std::vector<Ray>& rays,
                            size_t grain = 1024);

/// Shadow rays from the hits of `primary` towards `light` (misses produce no ray). With
/// `accel` (built over `mesh`), each origin is stepped past the coincident surfaces it would
/// start on (step_past_coincident), so that no ray starts on a surface.
std::vector<Ray> shadow_rays(const Mesh& mesh, const std::vector<Ray>& primary,
                             const std::vector<Hit>& hits, const Vec3& light,
                             const Accelerator* accel = nullptr);
/// Cosine-distributed bounce rays from the hits of `primary` (misses produce no ray);
/// `accel` as for shadow_rays.
std::vector<Ray> diffuse_rays(const Mesh& mesh, const std::vector<Ray>& primary,
                              const std::vector<Hit>& hits, uint64_t seed,
                              const Accelerator* accel = nullptr);
/// `count` seeded random rays about `bounds`.
std::vector<Ray> random_rays(const Box3& bounds, size_t count, uint64_t seed);

/// Everything needed to generate one set.
struct RaySetSpec {
  RaySetKind kind = RaySetKind::Primary;
  int width = kDefaultRaySetResolution, height = kDefaultRaySetResolution;
  /// Camera of the primary rays (and of the primary hits of shadow/diffuse); if unset, the
  /// canonical camera of the mesh's bounds.
  std::optional<Camera> camera;
  uint64_t seed = 1;
  /// Random set only: number of rays.
  size_t count = 100000;
};

/// Generates a set. Shadow and diffuse sets trace the primary rays with `accel`, which must
/// be built over `mesh` (ParamError if it is null for those sets).
std::vector<Ray> make_ray_set(const RaySetSpec& spec, const Mesh& mesh, const Accelerator* accel);

}  // namespace kdgrid
