#include "bench/raysets.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "math/rng.h"
#include "render/camera.h"
#include "render/renderer.h"
#include "util/enum_names.h"
#include "util/error.h"

namespace kdgrid {

namespace {

constexpr float kPi = 3.14159265358979f;

/// Counter-based streams: ray i of a set draws from its own stream (seed, i), so a set is the
/// same whatever the thread count or generation order.
SplitMix64 ray_stream(uint64_t seed, uint64_t index) {
  return SplitMix64(splitmix64_mix(seed * SplitMix64::kIncrement + splitmix64_mix(index)));
}

Vec3 hit_point(const Mesh& mesh, const Hit& h) {
  // Barycentric interpolation is more accurate than org + t*dir far from the origin.
  const auto c = mesh.corners(h.prim);
  return c[0] * (1.0f - h.u - h.v) + c[1] * h.u + c[2] * h.v;
}

/// Geometric normal of the hit triangle turned towards the side the ray came from.
Vec3 facing_normal(const Mesh& mesh, const Hit& h, const Vec3& ray_dir) {
  Vec3 n = normalize(mesh.geometric_normal(h.prim));
  if (dot(n, ray_dir) > 0.0f) n = -n;
  return n;
}

Vec3 uniform_direction(SplitMix64& rng) {
  const float z = 1.0f - 2.0f * rng.uniform();
  const float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
  const float phi = 2.0f * kPi * rng.uniform();
  return {r * std::cos(phi), r * std::sin(phi), z};
}

/// Moves the origin of each ray (leaving triangle from[i]) past the coincident surfaces it
/// would start on, in parallel.
void step_origins(const Accelerator* accel, const Mesh& mesh, const std::vector<uint32_t>& from,
                  std::vector<Ray>& rays, bool keep_end) {
  if (!accel) return;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, rays.size(), 1024),
                    [&](const tbb::blocked_range<size_t>& r) {
                      for (size_t i = r.begin(); i < r.end(); ++i)
                        step_past_coincident(*accel, mesh, from[i], rays[i], keep_end);
                    });
}

}  // namespace

constexpr EnumName<RaySetKind> kRaySetNames[] = {{RaySetKind::Primary, "primary"},
                                                 {RaySetKind::Shadow, "shadow"},
                                                 {RaySetKind::Diffuse, "diffuse"},
                                                 {RaySetKind::Random, "random"}};

RaySetKind parse_ray_set(const std::string& s) {
  return parse_enum(s, kRaySetNames, "unknown ray set", "use primary, shadow, diffuse or random");
}

const char* to_string(RaySetKind k) {
  return enum_name(k, kRaySetNames);
}

std::vector<Ray> primary_rays(const Camera& cam, int width, int height) {
  if (width < 1 || height < 1)
    throw ParamError("ray set resolution " + std::to_string(width) + "x" + std::to_string(height) +
                     " must be at least 1x1");
  const CameraFrame f = CameraFrame::make(cam, width, height);
  std::vector<Ray> rays(size_t(width) * size_t(height));
  tbb::parallel_for(0, height, [&](int j) {
    for (int i = 0; i < width; ++i)
      rays[size_t(j) * width + i] = f.ray(float(i) + 0.5f, float(j) + 0.5f);
  });
  return rays;
}

std::vector<uint32_t> tile_order(int width, int height, int tile) {
  if (width < 1 || height < 1 || tile < 1)
    throw ParamError("tile order of a " + std::to_string(width) + "x" + std::to_string(height) +
                     " image in " + std::to_string(tile) + "-pixel tiles: all must be >= 1");
  std::vector<uint32_t> order;
  order.reserve(size_t(width) * size_t(height));
  for (int y0 = 0; y0 < height; y0 += tile)
    for (int x0 = 0; x0 < width; x0 += tile)
      for (int y = y0; y < std::min(y0 + tile, height); ++y)
        for (int x = x0; x < std::min(x0 + tile, width); ++x)
          order.push_back(uint32_t(size_t(y) * size_t(width) + size_t(x)));
  return order;
}

std::vector<Hit> trace_hits(const Accelerator& accel, const std::vector<Ray>& rays, size_t grain) {
  std::vector<Hit> hits(rays.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, rays.size(), grain),
                    [&](const tbb::blocked_range<size_t>& r) {
                      for (size_t i = r.begin(); i < r.end(); ++i) {
                        Hit h;
                        if (accel.intersect(rays[i], h)) hits[i] = h;
                      }
                    });
  return hits;
}

std::vector<Ray> shadow_rays(const Mesh& mesh, const std::vector<Ray>& primary,
                             const std::vector<Hit>& hits, const Vec3& light,
                             const Accelerator* accel) {
  std::vector<Ray> out;
  std::vector<uint32_t> from;
  for (size_t i = 0; i < primary.size() && i < hits.size(); ++i) {
    if (!hits[i].valid()) continue;
    const Vec3 o =
        offset_ray_origin(hit_point(mesh, hits[i]), facing_normal(mesh, hits[i], primary[i].dir),
                          mesh.corners(hits[i].prim));
    out.push_back({o, 0.0f, light - o, 1.0f});
    from.push_back(hits[i].prim);
  }
  step_origins(accel, mesh, from, out, /*keep_end=*/true);
  return out;
}

std::vector<Ray> diffuse_rays(const Mesh& mesh, const std::vector<Ray>& primary,
                              const std::vector<Hit>& hits, uint64_t seed,
                              const Accelerator* accel) {
  std::vector<Ray> out;
  std::vector<uint32_t> from;
  for (size_t i = 0; i < primary.size() && i < hits.size(); ++i) {
    if (!hits[i].valid()) continue;
    const Vec3 n = facing_normal(mesh, hits[i], primary[i].dir);
    const Vec3 o = offset_ray_origin(hit_point(mesh, hits[i]), n, mesh.corners(hits[i].prim));
    // Orthonormal basis about n (Duff et al. 2017), then a cosine-weighted hemisphere sample.
    const float sign = std::copysign(1.0f, n.z);
    const float a = -1.0f / (sign + n.z), b = n.x * n.y * a;
    const Vec3 t1(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    const Vec3 t2(b, sign + n.y * n.y * a, -n.y);
    SplitMix64 rng = ray_stream(seed, i);
    const float u1 = rng.uniform(), u2 = rng.uniform();
    const float r = std::sqrt(u1), phi = 2.0f * kPi * u2;
    const Vec3 d = t1 * (r * std::cos(phi)) + t2 * (r * std::sin(phi)) +
                   n * std::sqrt(std::max(0.0f, 1.0f - u1));
    out.push_back({o, 0.0f, normalize(d), kInf});
    from.push_back(hits[i].prim);
  }
  step_origins(accel, mesh, from, out, /*keep_end=*/false);
  return out;
}

std::vector<Ray> random_rays(const Box3& bounds, size_t count, uint64_t seed) {
  std::vector<Ray> rays(count);
  Vec3 ext = bounds.empty() ? Vec3(1.0f) : bounds.extent();
  // A flat axis gets the largest extent (relative, so a tiny scene keeps its proportions).
  const float big = max_component(ext) > 0.0f ? max_component(ext) : 1.0f;
  for (int a = 0; a < 3; ++a)
    if (!(ext[a] > 0.0f)) ext[a] = big;
  const Vec3 lo = bounds.empty() ? Vec3(-0.5f) : bounds.lo;
  tbb::parallel_for(size_t(0), count, [&](size_t i) {
    SplitMix64 rng = ray_stream(seed, i);
    auto in_box = [&](float margin) {
      return Vec3(lo.x - margin * ext.x + (1 + 2 * margin) * ext.x * rng.uniform(),
                  lo.y - margin * ext.y + (1 + 2 * margin) * ext.y * rng.uniform(),
                  lo.z - margin * ext.z + (1 + 2 * margin) * ext.z * rng.uniform());
    };
    Ray r;
    r.org = in_box(0.5f);
    switch (i % 8) {
      case 0:
      case 1:  // uniform direction from anywhere around the box
        r.dir = uniform_direction(rng);
        break;
      case 2:
      case 3:
      case 4: {  // aimed at a point inside the box (mostly hits on closed meshes)
        r.dir = in_box(0.0f) - r.org;
        break;
      }
      case 5: {  // aimed, with tmax somewhere before or after the target
        r.dir = in_box(0.0f) - r.org;
        r.tmax = 1.5f * rng.uniform();
        break;
      }
      case 6: {  // aimed, starting part-way (tmin > 0)
        r.dir = in_box(0.0f) - r.org;
        r.tmin = 0.8f * rng.uniform();
        break;
      }
      default: {  // axis-parallel from inside the box: zero direction components
        r.org = in_box(0.0f);
        const int axis = int(rng.next() % 3);
        r.dir = Vec3(0.0f);
        r.dir[axis] = rng.uniform() < 0.5f ? -1.0f : 1.0f;
        break;
      }
    }
    if (!(length(r.dir) > 0.0f)) r.dir = {0.0f, 1.0f, 0.0f};
    rays[i] = r;
  });
  return rays;
}

std::vector<Ray> make_ray_set(const RaySetSpec& spec, const Mesh& mesh, const Accelerator* accel) {
  const Box3 b = mesh.bounds();
  if (spec.kind == RaySetKind::Random) return random_rays(b, spec.count, spec.seed);
  const Camera cam = spec.camera ? *spec.camera : canonical_camera(b);
  std::vector<Ray> primary = primary_rays(cam, spec.width, spec.height);
  if (spec.kind == RaySetKind::Primary) return primary;
  if (!accel)
    throw ParamError(std::string("the ") + to_string(spec.kind) +
                     " ray set needs an accelerator to find the primary hits");
  const std::vector<Hit> hits = trace_hits(*accel, primary);
  if (spec.kind == RaySetKind::Shadow)
    return shadow_rays(mesh, primary, hits, canonical_light_position(b), accel);
  return diffuse_rays(mesh, primary, hits, spec.seed, accel);
}

}  // namespace kdgrid
