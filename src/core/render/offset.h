// Origins of secondary rays: off the surface they leave (offset_ray_origin) and past the
// coincident surfaces they would otherwise start on (step_past_coincident).
//
// A ray starts on a surface when its origin lies on that triangle's plane within rounding,
// closer to it than half the distance offset_ray_origin moves a point off it. Where such a
// triangle lies in the ray's path, whether a structure reports it (at t = -0 or a few ULPs)
// depends on rounding in its triangle test and clipping: the answer is implementation-defined
// (docs/RAYSETS.md, "Rays that start on a surface"). The ray sets kdgrid generates never start
// on a layer parallel to the surface they leave: their origins are stepped past such layers.
#pragma once

#include <array>
#include <cstdint>

#include "accel/accelerator.h"
#include "math/vec.h"
#include "scene/mesh.h"

namespace kdgrid {

/// Offsets a hit point p on the triangle with the given corners along its geometric normal
/// so that a ray leaving it cannot re-hit the same surface (Wächter & Binder, Ray Tracing
/// Gems ch. 6: an integer ULP offset of each coordinate, and a fixed offset where a
/// coordinate is near 0). The fixed offset and the threshold are relative to the corners'
/// magnitude on each axis, so the offset is scale invariant: scaling the triangle and p by a
/// power of two scales the result by it exactly.
Vec3 offset_ray_origin(const Vec3& p, const Vec3& geometric_normal,
                       const std::array<Vec3, 3>& corners);

/// Whether `org` lies on the plane of the triangle with these corners within rounding: closer
/// to it than half the distance offset_ray_origin moves a point of the triangle off it. False
/// for a triangle of zero area (it has no plane).
bool starts_on_triangle(const Vec3& org, const std::array<Vec3, 3>& corners);

/// Most coincident surfaces step_past_coincident steps past for one ray.
constexpr int kMaxCoincidentSteps = 4;

/// Moves the origin of `ray`, a secondary ray leaving triangle `from` of `mesh`, past the
/// surfaces it starts on that are parallel to `from` (coincident and near-coincident layers:
/// duplicated floors, decals, a slab under its tiles). A probe along `from`'s normal through
/// the origin finds the layer it lies on; the origin becomes offset_ray_origin of its
/// projection onto that layer, on the side the ray travels; repeated for the next layer. The
/// probe is steep, so the answer does not depend on rounding in the ray's own direction or on
/// the structure. Surfaces at an angle to `from` (a wall meeting the floor) are never stepped
/// past, so no ray leaks through a corner. With `keep_end` the ray's end point
/// org + dir * tmax stays where it was (a shadow ray aimed at a light): dir is recomputed from
/// the new origin. Returns the number of layers stepped past (at most kMaxCoincidentSteps).
int step_past_coincident(const Accelerator& accel, const Mesh& mesh, uint32_t from, Ray& ray,
                         bool keep_end = false);

}  // namespace kdgrid
