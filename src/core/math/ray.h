// Rays and hits, exactly the quantities of the .rays/.hits files (docs/RAYSETS.md).
#pragma once

#include <cstdint>

#include "math/vec.h"

namespace kdgrid {

/// A ray segment org + t*dir for t in [tmin, tmax]. dir need not be normalized; t is in
/// units of dir. tmax may be +inf.
struct Ray {
  Vec3 org;
  float tmin = 0.0f;
  Vec3 dir;
  float tmax = kInf;

  Vec3 at(float t) const { return org + dir * t; }
};

constexpr uint32_t kInvalidPrim = 0xFFFFFFFFu;

/// Closest-hit result: t along the ray, triangle index in mesh order, barycentrics (u, v)
/// of vertices 1 and 2 (the hit point is (1-u-v)*v0 + u*v1 + v*v2).
struct Hit {
  float t = kInf;
  uint32_t prim = kInvalidPrim;
  float u = 0.0f, v = 0.0f;

  bool valid() const { return prim != kInvalidPrim; }
};

/// True if the ray's numbers are usable (finite origin, finite non-zero direction, tmin <=
/// tmax, tmin not NaN). Accelerators return a miss for invalid rays instead of traversing.
inline bool ray_is_valid(const Ray& r) {
  return is_finite(r.org) && is_finite(r.dir) && (r.dir.x != 0 || r.dir.y != 0 || r.dir.z != 0) &&
         r.tmin == r.tmin && r.tmax == r.tmax && r.tmin <= r.tmax && r.tmin < kInf;
}

}  // namespace kdgrid
