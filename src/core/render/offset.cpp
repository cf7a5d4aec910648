// Robust secondary-ray origins (Wächter & Binder, "A Fast and Robust Method for Avoiding
// Self-Intersection", Ray Tracing Gems ch. 6).
#include <bit>
#include <cmath>
#include <cstdint>

#include "render/renderer.h"

namespace kdgrid {

namespace {
// Below this magnitude a coordinate's ULP is tiny, so an integer-ULP offset would be too
// small to escape the triangle's rounding error: use a fixed offset there instead.
constexpr float kOrigin = 1.0f / 32.0f;
// Fixed offset (per unit normal) used for coordinates near the origin.
constexpr float kFloatScale = 1.0f / 65536.0f;
// ULPs moved per unit normal component for coordinates away from the origin. 256 ULPs
// exceeds the error of a hit point interpolated from barycentrics in float.
constexpr float kIntScale = 256.0f;

float offset_component(float p, float n) {
  if (std::fabs(p) < kOrigin) return p + kFloatScale * n;
  // Moving the bit pattern by k moves the float by k ULPs away from zero when the sign
  // of p matches; so step towards the side n points to.
  const int32_t of = static_cast<int32_t>(kIntScale * n);
  const int32_t bits = std::bit_cast<int32_t>(p);
  return std::bit_cast<float>(bits + (p < 0 ? -of : of));
}
}  // namespace

Vec3 offset_ray_origin(const Vec3& p, const Vec3& geometric_normal) {
  // The integer offset assumes a unit normal (a huge one would overflow the ULP count).
  const Vec3 n = normalize(geometric_normal);
  return {offset_component(p.x, n.x), offset_component(p.y, n.y), offset_component(p.z, n.z)};
}

}  // namespace kdgrid
