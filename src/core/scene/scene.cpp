#include "scene/scene.h"

#include <cmath>
#include <cstdio>

#include "math/ray.h"
#include "util/error.h"

namespace kdgrid {

namespace {
float srgb_to_linear(float c) {
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}
}  // namespace

Vec3 Texture::sample(float u, float v) const {
  if (width <= 0 || height <= 0 || channels <= 0 || pixels.empty()) return Vec3(1.0f);
  // Wrap (glTF's default REPEAT), then bilinear between texel centres.
  u -= std::floor(u);
  v -= std::floor(v);
  const float x = u * width - 0.5f, y = v * height - 0.5f;
  const int x0 = int(std::floor(x)), y0 = int(std::floor(y));
  const float fx = x - x0, fy = y - y0;
  auto texel = [&](int xi, int yi) {
    xi = ((xi % width) + width) % width;
    yi = ((yi % height) + height) % height;
    const uint8_t* p = &pixels[(size_t(yi) * width + xi) * channels];
    Vec3 c(p[0] / 255.0f, p[channels > 1 ? 1 : 0] / 255.0f, p[channels > 2 ? 2 : 0] / 255.0f);
    if (srgb) c = {srgb_to_linear(c.x), srgb_to_linear(c.y), srgb_to_linear(c.z)};
    return c;
  };
  return lerp(lerp(texel(x0, y0), texel(x0 + 1, y0), fx),
              lerp(texel(x0, y0 + 1), texel(x0 + 1, y0 + 1), fx), fy);
}

Vec3 Material::reflectance() const {
  // Metals reflect their base colour (glTF); MTL mirrors give an explicit colour.
  Vec3 r = mirror;
  if (metallic > 0.0f) r = max(r, base_color * metallic);
  return r;
}

void check_scene_range(const Box3& b, const std::string& who) {
  if (b.empty() || (within(b.lo, kMaxSceneCoordinate) && within(b.hi, kMaxSceneCoordinate))) return;
  char buf[200];
  std::snprintf(buf, sizeof buf,
                "the scene's bounds (%g, %g, %g) to (%g, %g, %g) reach beyond the "
                "supported range +-%g of scene coordinates",
                double(b.lo.x), double(b.lo.y), double(b.lo.z), double(b.hi.x), double(b.hi.y),
                double(b.hi.z), double(kMaxSceneCoordinate));
  throw ParamError(who + ": " + buf + " (docs/LIMITS.md); scale the scene down or translate it");
}

Camera canonical_camera(const Box3& b, float fov_deg) {
  const Vec3 c = b.center();
  const float r = length(b.hi - b.lo) * 0.5f;
  const Vec3 d = normalize(Vec3(0.3f, 0.2f, 1.0f));
  const float half = fov_deg * 0.5f * 3.14159265358979f / 180.0f;
  Camera cam;
  cam.eye = c + d * (r / std::sin(half));
  cam.target = c;
  cam.up = {0, 1, 0};
  cam.fov_deg = fov_deg;
  cam.name = "canonical";
  return cam;
}

Vec3 canonical_light_position(const Box3& b) {
  const Vec3 c = b.center();
  const float r = length(b.hi - b.lo) * 0.5f;
  const Vec3 d = normalize(Vec3(0.3f, 0.2f, 1.0f));
  return c + Vec3(0, 2 * r, 0) + d * (0.5f * r);
}

void Scene::finalize() {
  mesh.validate(source);
  // Beyond this range the canonical camera and light, and the squared distances shading
  // takes, leave float range (a black image); refuse instead, naming the first such vertex.
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    const Vec3& p = mesh.positions[i];
    if (within(p, kMaxSceneCoordinate)) continue;
    char buf[160];
    std::snprintf(buf, sizeof buf,
                  "vertex %zu at (%g, %g, %g) is outside the supported range "
                  "+-%g of scene coordinates",
                  i, double(p.x), double(p.y), double(p.z), double(kMaxSceneCoordinate));
    throw LoadError(source + ": " + buf +
                    " (docs/LIMITS.md); scale the scene down or translate it near the origin");
  }
  const Box3 bounds = mesh.bounds();
  const float size = bounds.empty() ? 0.0f : max_component(bounds.hi - bounds.lo);
  // A scene of size 0 (a single point) is left to the camera, which names it.
  if (size > 0.0f && size < kMinSceneSize) {
    char buf[320];
    std::snprintf(buf, sizeof buf,
                  "the scene's size %g (the largest side of its bounds) is below the supported "
                  "minimum %g (docs/LIMITS.md): float products of its coordinates would "
                  "underflow; scale the scene up by a factor of %g or more (--scale multiplies "
                  "the coordinates of the file)",
                  double(size), double(kMinSceneSize),
                  std::pow(10.0, std::ceil(std::log10(double(kMinSceneSize) / double(size)))));
    throw LoadError(source + ": " + buf);
  }
  if (materials.empty()) {
    Material grey;
    grey.name = "default grey diffuse";
    materials.push_back(grey);
  }
  for (size_t i = 0; i < mesh.material_ids.size(); ++i)
    if (mesh.material_ids[i] >= materials.size())
      throw LoadError(source + ": triangle " + std::to_string(i) + " uses material " +
                      std::to_string(mesh.material_ids[i]) + " but the scene has " +
                      std::to_string(materials.size()) + " materials");
  const Box3 b = mesh.bounds();
  if (!camera) camera = canonical_camera(b);
  if (lights.empty()) {
    Light l;
    l.type = LightType::Point;
    l.position = canonical_light_position(b);
    const float r = length(b.hi - b.lo) * 0.5f;
    // Intensity chosen so the scene centre receives irradiance ~ 1 (inverse square).
    const float dist = length(l.position - b.center());
    l.intensity = dist * dist;
    l.name = r > 0 ? "default point light" : "default light";
    lights.push_back(l);
  }
}

void Scene::scale_by(double factor, const std::string& what) {
  const auto f = float(factor);
  if (!(factor > 0.0 && std::isnormal(f))) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%g", factor);
    throw ParamError(what + " " + buf +
                     ": a scale factor must be a positive number in float's range (1e-37 to "
                     "1e38), e.g. 1e-3");
  }
  if (factor == 1.0) return;
  for (Vec3& p : mesh.positions) p = p * f;
  if (camera) {
    camera->eye = camera->eye * f;
    camera->target = camera->target * f;
  }
  for (Light& l : lights) {
    l.position = l.position * f;
    if (l.type != LightType::Directional)
      l.intensity = float(double(l.intensity) * factor * factor);
  }
}

bool Scene::has_reflective_material() const {
  for (const auto& m : materials)
    if (m.reflects()) return true;
  return false;
}

bool Scene::has_refractive_material() const {
  for (const auto& m : materials)
    if (m.refracts()) return true;
  return false;
}

}  // namespace kdgrid
