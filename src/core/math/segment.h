// Distances between a ray's segment and the world in double precision, for the extreme-ray
// suite's reference (bench/check.cpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <utility>

#include "math/ray.h"
#include "math/vec.h"

namespace kdgrid {

/// Where the ray r(t) = d t (origin at 0), t in [t0, t1], passes closest to the segment
/// [a, b]: the distance, the ray's t there and the sine of the angle between ray and segment
/// (0 for a point or a parallel segment).
struct Approach {
  double dist, t, sine;
};
inline Approach closest_approach(const Vec3d& d, double t0, double t1, const Vec3d& a,
                                 const Vec3d& b) {
  const Vec3d e = b - a;
  const double dd = dot(d, d), ee = dot(e, e), de = dot(d, e), da = dot(d, a), ea = dot(e, a);
  const double denom = dd * ee - de * de;
  const double sine = ee > 0 ? std::sqrt(std::max(0.0, denom / (dd * ee))) : 0.0;
  Approach best{kInf, t0, sine};
  auto consider = [&](double t, double s) {
    const Vec3d gap = d * t - (a + e * s);
    const double dist = std::sqrt(dot(gap, gap));
    if (dist < best.dist) best = {dist, t, sine};
  };
  auto t_for = [&](double s) { return std::clamp((da + de * s) / dd, t0, t1); };
  auto s_for = [&](double t) { return ee > 0 ? std::clamp((de * t - ea) / ee, 0.0, 1.0) : 0.0; };
  // The minimum of this convex quadratic lies inside the box (t0, t1) x (0, 1) where the
  // lines' closest points do, else on one of the box's sides.
  if (sine > 1e-12) {
    const double t = (da * ee - de * ea) / denom, s = (de * da - dd * ea) / denom;
    if (t >= t0 && t <= t1 && s >= 0 && s <= 1) consider(t, s);
  }
  consider(t_for(0.0), 0.0);
  consider(t_for(1.0), 1.0);
  consider(t0, s_for(t0));
  if (t1 < kInf) consider(t1, s_for(t1));
  return best;
}

/// The ray's segment t in [t0, t1] meets the box.
inline bool segment_overlaps_box(const Ray& r, const Box3& b, double t0, double t1) {
  for (int a = 0; a < 3; ++a) {
    const double o = r.org[a], d = r.dir[a];
    if (d == 0.0) {
      if (o < b.lo[a] || o > b.hi[a]) return false;
      continue;
    }
    double ta = (b.lo[a] - o) / d, tb = (b.hi[a] - o) / d;
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
    if (t0 > t1) return false;
  }
  return true;
}

}  // namespace kdgrid
