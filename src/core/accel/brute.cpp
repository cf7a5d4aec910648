#include "accel/brute.h"

#include <chrono>

namespace kdgrid {

BuildStats BruteForce::build(const Mesh& mesh, const BuildParams& params) {
  const auto t0 = std::chrono::steady_clock::now();
  mesh_ = &mesh;
  triangle_test_ = params.triangle_test;
  bounds_ = mesh.bounds();
  stats_ = {};
  stats_.nodes = 1;
  stats_.leaves = 1;
  stats_.references = mesh.num_triangles();
  stats_.bytes = sizeof(*this);
  stats_.bytes_by_part = {{"object", sizeof(*this)}};
  stats_.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return stats_;
}

bool intersect_triangle_double(const Ray& ray, const Vec3& a, const Vec3& b, const Vec3& c,
                               double tmin, double tmax, double& t, double& u, double& v) {
  // Möller-Trumbore in double about the ray origin; with 53-bit mantissas the float inputs'
  // products are exact, so this is a faithful reference away from exact edge hits.
  const Vec3d o(ray.org), d(ray.dir);
  const Vec3d v0 = Vec3d(a) - o, v1 = Vec3d(b) - o, v2 = Vec3d(c) - o;
  const Vec3d e1 = v1 - v0, e2 = v2 - v0;
  const Vec3d p = cross(d, e2);
  const double det = dot(e1, p);
  if (det == 0.0) return false;
  const double inv = 1.0 / det;
  const Vec3d s = v0 * -1.0;
  const double uu = dot(s, p) * inv;
  if (uu < 0.0 || uu > 1.0) return false;
  const Vec3d q = cross(s, e1);
  const double vv = dot(d, q) * inv;
  if (vv < 0.0 || uu + vv > 1.0) return false;
  const double tt = dot(e2, q) * inv;
  if (!(tt >= tmin && tt < tmax)) return false;
  t = tt;
  u = uu;
  v = vv;
  return true;
}

bool brute_force_double(const Mesh& mesh, const Ray& ray, Hit& hit, double* t_exact) {
  if (!ray_is_valid(ray)) return false;
  double best = ray.tmax;
  bool found = false;
  for (uint32_t i = 0; i < static_cast<uint32_t>(mesh.triangles.size()); ++i) {
    const auto c = mesh.corners(i);
    double t, u, v;
    if (intersect_triangle_double(ray, c[0], c[1], c[2], ray.tmin, best, t, u, v)) {
      best = t;
      hit = {float(t), i, float(u), float(v)};
      found = true;
    }
  }
  if (found && t_exact) *t_exact = best;
  return found;
}

}  // namespace kdgrid
