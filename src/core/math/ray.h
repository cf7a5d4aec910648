// Rays and hits, exactly the quantities of the .rays/.hits files (docs/RAYSETS.md).
#pragma once

#include <cmath>
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

/// Largest magnitude of any coordinate of a ray's origin, of its start point org + tmin * dir
/// (when tmin < 0) and of its direction that every structure accepts. It is Embree's limit
/// (FLT_LARGE = 1.844e18 in its ray validation; Embree asserts and aborts beyond it), applied
/// to all structures so that they agree: a ray outside it is invalid, a miss everywhere.
/// docs/LIMITS.md.
constexpr float kMaxRayCoordinate = 1.844e18f;

/// Largest magnitude of a scene's vertex coordinates (Scene::finalize refuses more). The
/// canonical camera and light lie within 6 times the largest coordinate of the scene, so
/// they and every ray the renderer traces stay inside kMaxRayCoordinate. docs/LIMITS.md.
constexpr float kMaxSceneCoordinate = 1e17f;

/// Smallest size of a scene (the largest side of its bounding box) that Scene::finalize
/// accepts. The watertight test's depth term is a product of three coordinate differences
/// about the ray origin; for the triangles of a scene smaller than this it leaves float's
/// normal range (1.2e-38) and loses its bits in denormals (Embree's test as well), and the
/// squared distances of shading follow. docs/LIMITS.md.
constexpr float kMinSceneSize = 1e-9f;

/// True if every coordinate of v lies in [-limit, limit] (false for NaN and infinities).
inline bool within(const Vec3& v, float limit) {
  return std::fabs(v.x) <= limit && std::fabs(v.y) <= limit && std::fabs(v.z) <= limit;
}

/// True if the ray's numbers are usable: origin, direction and, for a negative tmin, the
/// start point org + tmin * dir within kMaxRayCoordinate (hence finite), a non-zero
/// direction, tmin <= tmax, tmin not NaN. Accelerators return a miss for invalid rays instead
/// of traversing.
inline bool ray_is_valid(const Ray& r) {
  return within(r.org, kMaxRayCoordinate) && within(r.dir, kMaxRayCoordinate) &&
         (r.dir.x != 0 || r.dir.y != 0 || r.dir.z != 0) && r.tmin == r.tmin && r.tmax == r.tmax &&
         r.tmin <= r.tmax && r.tmin < kInf &&
         (r.tmin >= 0.0f || within(r.at(r.tmin), kMaxRayCoordinate));
}

}  // namespace kdgrid
