// Robust secondary-ray origins (Wächter & Binder, "A Fast and Robust Method for Avoiding
// Self-Intersection", Ray Tracing Gems ch. 6), with the paper's two absolute constants (the
// 1/32 threshold and the 1/65536 offset near the origin) made relative to the magnitude of the
// hit triangle's coordinates, so that a scene scaled by any factor is offset by the same
// factor and renders the same picture.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>

#include "render/renderer.h"

namespace kdgrid {

namespace {
// A component below this fraction of its reference magnitude has ULPs too small to escape
// the rounding error of the hit point (which is that of the corners' coordinates): a fixed
// offset proportional to the magnitude is used there instead.
constexpr float kOrigin = 1.0f / 32.0f;
// That fixed offset per unit normal, relative to the magnitude: about 128 ULPs of it.
constexpr float kFloatScale = 1.0f / 65536.0f;
// ULPs moved per unit normal component for coordinates away from the origin. 256 ULPs
// exceeds the error of a hit point interpolated from barycentrics in float.
constexpr float kIntScale = 256.0f;
// A component in which all three corners are 0 is exact (the plane is axis-aligned there),
// so any step leaves the plane; the reference magnitude is then this fraction of the largest
// coordinate of the triangle, which keeps the step scale invariant and far from denormals.
constexpr float kFloorFraction = 1.0f / 256.0f;

float offset_component(float p, float n, float magnitude) {
  if (std::fabs(p) < kOrigin * magnitude) return p + kFloatScale * magnitude * n;
  // Moving the bit pattern by k moves the float by k ULPs away from zero when the sign
  // of p matches; so step towards the side n points to.
  const int32_t of = static_cast<int32_t>(kIntScale * n);
  const int32_t bits = std::bit_cast<int32_t>(p);
  return std::bit_cast<float>(bits + (p < 0 ? -of : of));
}
}  // namespace

Vec3 offset_ray_origin(const Vec3& p, const Vec3& geometric_normal,
                       const std::array<Vec3, 3>& corners) {
  // The integer offset assumes a unit normal (a huge one would overflow the ULP count).
  const Vec3 n = normalize(geometric_normal);
  const Vec3 m = max(abs(corners[0]), max(abs(corners[1]), abs(corners[2])));
  const Vec3 ref = max(m, Vec3(kFloorFraction * max_component(m)));
  return {offset_component(p.x, n.x, ref.x), offset_component(p.y, n.y, ref.y),
          offset_component(p.z, n.z, ref.z)};
}

}  // namespace kdgrid
