// Robust secondary-ray origins (Wächter & Binder, "A Fast and Robust Method for Avoiding
// Self-Intersection", Ray Tracing Gems ch. 6), with the paper's two absolute constants (the
// 1/32 threshold and the 1/65536 offset near the origin) made relative to the magnitude of the
// hit triangle's coordinates, so that a scene scaled by any factor is offset by the same
// factor and renders the same picture.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>

#include "render/offset.h"

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
// Triangles whose unit normals differ by less than this cosine (about 0.8 degrees) are
// parallel layers for step_past_coincident; anything steeper is a surface the ray must hit.
constexpr float kParallelCos = 0.9999f;

float offset_component(float p, float n, float magnitude) {
  if (std::fabs(p) < kOrigin * magnitude) return p + kFloatScale * magnitude * n;
  // Moving the bit pattern by k moves the float by k ULPs away from zero when the sign
  // of p matches; so step towards the side n points to.
  const int32_t of = static_cast<int32_t>(kIntScale * n);
  const int32_t bits = std::bit_cast<int32_t>(p);
  return std::bit_cast<float>(bits + (p < 0 ? -of : of));
}
/// The plane of a triangle in double precision: its unit normal and the signed distance of
/// `p` from it. False for a triangle of zero area.
bool plane_distance(const Vec3& p, const std::array<Vec3, 3>& c, Vec3& unit_normal,
                    double& distance) {
  double e1[3], e2[3], d[3];
  for (int a = 0; a < 3; ++a) {
    e1[a] = double(c[1][a]) - double(c[0][a]);
    e2[a] = double(c[2][a]) - double(c[0][a]);
    d[a] = double(p[a]) - double(c[0][a]);
  }
  const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                       e1[0] * e2[1] - e1[1] * e2[0]};
  const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  if (!(len > 0.0) || !std::isfinite(len)) return false;
  unit_normal = Vec3(float(n[0] / len), float(n[1] / len), float(n[2] / len));
  distance = (d[0] * n[0] + d[1] * n[1] + d[2] * n[2]) / len;
  return std::isfinite(distance);
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

namespace {
/// How far offset_ray_origin moves the point q of a triangle's plane off it (along its unit
/// normal n).
double offset_distance(const Vec3& q, const Vec3& n, const std::array<Vec3, 3>& corners) {
  const Vec3 moved = offset_ray_origin(q, n, corners);
  return std::fabs(double(moved.x - q.x) * n.x + double(moved.y - q.y) * n.y +
                   double(moved.z - q.z) * n.z);
}
}  // namespace

bool starts_on_triangle(const Vec3& org, const std::array<Vec3, 3>& corners) {
  Vec3 n;
  double distance;
  if (!plane_distance(org, corners, n, distance)) return false;
  const Vec3 q = org - n * float(distance);
  return std::fabs(distance) < 0.5 * offset_distance(q, n, corners);
}

int step_past_coincident(const Accelerator& accel, const Mesh& mesh, uint32_t from, Ray& ray,
                         bool keep_end) {
  Vec3 n;
  double distance;
  if (!plane_distance(ray.org, mesh.corners(from), n, distance)) return 0;
  if (dot(n, ray.dir) < 0.0f) n = -n;  // the side the ray travels to
  const Vec3 end = ray.org + ray.dir * ray.tmax;
  double window = offset_distance(ray.org - n * float(distance), n, mesh.corners(from));
  int steps = 0;
  while (steps < kMaxCoincidentSteps) {
    // The layers the origin lies on, found by a probe along the normal through it (a steep ray,
    // so rounding cannot hide them whatever the ray's own direction): three quarters of an
    // offset each way, which leaves out the surface the origin was offset from.
    const float h = float(0.75 * window);
    if (!(h > 0.0f)) break;
    Hit hit;
    const Ray probe{ray.org - n * h, 0.0f, n, 2.0f};
    if (!accel.intersect(probe, hit) || hit.prim >= mesh.num_triangles()) break;
    const auto c = mesh.corners(hit.prim);
    Vec3 m;
    if (!plane_distance(ray.org, c, m, distance) || !(std::fabs(dot(m, n)) >= kParallelCos) ||
        !starts_on_triangle(ray.org, c))
      break;
    const Vec3 q = ray.org - m * float(distance);
    if (dot(m, n) < 0.0f) m = -m;
    window = offset_distance(q, m, c);
    ray.org = offset_ray_origin(q, m, c);
    if (keep_end) ray.dir = end - ray.org;
    ++steps;
  }
  return steps;
}

}  // namespace kdgrid
