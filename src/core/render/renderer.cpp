// Progressive tiled Whitted renderer (renderer.h). Passes and tiles live in render_pass() and
// render_tile(); shading in shade_hit() (one ray) and shade_packet() (a packet's primary hits,
// their shadow rays traced together), both built from surface_at, light_term, shadow_ray,
// add_light and finish_hit so that the two add the same terms in the same order.
#include "render/renderer.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <chrono>
#include <cmath>

#include "math/rng.h"
#include "util/enum_names.h"
#include "util/error.h"

namespace kdgrid {

namespace {

constexpr float kPi = 3.14159265358979f;

// Uniform ambient radiance, reflected by the diffuse part of every surface. It stands in for
// the indirect light Whitted shading ignores, so that faces no light sees are dark grey
// rather than pure black (useful when inspecting geometry). Units: radiance, same as lights.
constexpr float kAmbient = 0.03f;

// Eye light (Shading::EyeLight): the share of a surface's albedo it shows when seen edge-on;
// face-on it shows all of it.
constexpr float kEyeLightFloor = 0.2f;

// Secondary rays whose path weight (the product of the reflection/transmission weights from
// the camera down to them) is below this are not traced: they could change a pixel by less
// than 1e-4 of the light they carry. Being a product, it also bounds the ray tree of glass.
constexpr float kMinWeight = 1e-4f;

// Highlight exponent bounds: below 1 the lobe is flat; above 1e4 it is smaller than a pixel.
constexpr float kMinExponent = 1.0f, kMaxExponent = 1e4f;

/// Per-pixel sample stream seeded from (seed, pixel, sample), so a pixel's samples do not
/// depend on which thread renders it or in what order.
SplitMix64 sample_stream(uint64_t seed, uint64_t pixel, uint64_t sample) {
  return SplitMix64(splitmix64_mix(splitmix64_mix(seed ^ SplitMix64::kIncrement) ^ pixel) +
                    splitmix64_mix(sample + 0x632be59bd9b4e019ull));
}

float saturate(float x) {
  return std::min(1.0f, std::max(0.0f, x));
}

float highlight_exponent(const Material& m) {
  if (m.shininess > 0.0f) return std::clamp(m.shininess, kMinExponent, kMaxExponent);
  // Blinn-Phong exponent matching a GGX-like lobe of width alpha = roughness^2.
  const float alpha = std::max(m.roughness * m.roughness, 1e-3f);
  return std::clamp(2.0f / (alpha * alpha) - 2.0f, kMinExponent, kMaxExponent);
}

Vec3 specular_color(const Material& m, const Vec3& albedo) {
  if (max_component(m.specular) > 0.0f) return m.specular;
  // glTF metallic-roughness: dielectrics reflect 4% achromatically, metals their base colour.
  return lerp(Vec3(0.04f), albedo, saturate(m.metallic));
}

}  // namespace

Renderer::Renderer(const Scene& scene, const Accelerator& accel, const RenderSettings& settings)
    : scene_(&scene), accel_(&accel) {
  camera_ = scene.camera ? *scene.camera : canonical_camera(scene.mesh.bounds());
  need_reflection_ = scene.has_reflective_material();
  need_refraction_ = scene.has_refractive_material();
  set_settings(settings);
}

void Renderer::set_camera(const Camera& cam) {
  camera_ = cam;
  reset();
}

void Renderer::set_accelerator(const Accelerator& accel) {
  accel_ = &accel;
  reset();
}

void Renderer::set_settings(const RenderSettings& s) {
  if (s.width < 1 || s.height < 1)
    throw ParamError("render size " + std::to_string(s.width) + "x" + std::to_string(s.height) +
                     " is invalid: width and height must be >= 1");
  if (s.tile_size < 1)
    throw ParamError("tile size " + std::to_string(s.tile_size) + " must be >= 1 pixel");
  if (s.max_depth < 0 || s.max_depth > kMaxRenderDepth)
    throw ParamError("max depth " + std::to_string(s.max_depth) + " must be between 0 and " +
                     std::to_string(kMaxRenderDepth) + " (docs/LIMITS.md)");
  settings_ = s;
  reset();
}

void Renderer::reset() {
  frame_ = CameraFrame::make(camera_, settings_.width, settings_.height);
  accum_.assign(size_t(settings_.width) * settings_.height * 3, 0.0f);
  samples_ = 0;
  counters_ = {};
  seconds_ = 0;
}

bool Renderer::render_pass(const std::atomic<bool>* cancel) {
  const auto t0 = std::chrono::steady_clock::now();
  const int w = settings_.width, h = settings_.height, ts = settings_.tile_size;
  const int tiles_x = (w + ts - 1) / ts, tiles_y = (h + ts - 1) / ts;
  const int num_tiles = tiles_x * tiles_y;
  // The pass renders into scratch and is committed only when every tile is done, so a
  // cancelled pass leaves the film exactly as it was.
  std::vector<float> scratch(accum_.size());
  std::vector<RenderCounters> tile_counters(num_tiles);
  std::atomic<bool> skipped{false};
  const uint64_t sample = uint64_t(samples_);

  tbb::parallel_for(tbb::blocked_range<int>(0, num_tiles, 1),
                    [&](const tbb::blocked_range<int>& r) {
                      for (int tile = r.begin(); tile != r.end(); ++tile) {
                        if (cancel && cancel->load(std::memory_order_relaxed)) {
                          skipped.store(true, std::memory_order_relaxed);
                          return;
                        }
                        const int x0 = (tile % tiles_x) * ts, y0 = (tile / tiles_x) * ts;
                        render_tile(x0, y0, std::min(x0 + ts, w), std::min(y0 + ts, h), sample,
                                    scratch.data(), tile_counters[tile]);
                      }
                    });
  if (skipped.load()) return false;

  for (size_t i = 0; i < accum_.size(); ++i) accum_[i] += scratch[i];
  for (const RenderCounters& c : tile_counters) {
    counters_.probed += c.probed;
    counters_.lit += c.lit;
    counters_.primary += c.primary;
    counters_.shadow += c.shadow;
    counters_.reflection += c.reflection;
    counters_.refraction += c.refraction;
  }
  ++samples_;
  seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

void Renderer::render_tile(int x0, int y0, int x1, int y1, uint64_t sample, float* film,
                           RenderCounters& c) const {
  const int w = settings_.width;
  auto camera_ray = [&](int x, int y) {
    SplitMix64 rng = sample_stream(settings_.seed, uint64_t(y) * w + x, sample);
    float jx = 0.5f, jy = 0.5f;
    if (settings_.jitter) {
      jx = rng.uniform();
      jy = rng.uniform();
    }
    return frame_.ray(float(x) + jx, float(y) + jy);
  };
  auto store = [&](int x, int y, const Vec3& value) {
    float* dst = &film[(uint64_t(y) * w + x) * 3];
    dst[0] = value.x;
    dst[1] = value.y;
    dst[2] = value.z;
  };
  if (settings_.mode == RenderMode::HeatTime) {
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        ++c.primary;
        const Ray ray = camera_ray(x, y);
        Hit hit;
        const auto t0 = std::chrono::steady_clock::now();
        accel_->intersect(ray, hit);
        const auto t1 = std::chrono::steady_clock::now();
        store(x, y, Vec3(float(std::chrono::duration<double, std::nano>(t1 - t0).count())));
      }
    return;
  }
  if (settings_.mode != RenderMode::Shaded) {
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        ++c.primary;
        RayCounters rc;
        Hit hit;
        accel_->intersect_counted(camera_ray(x, y), hit, rc);
        store(x, y, Vec3(float(settings_.mode == RenderMode::HeatSteps ? rc.steps : rc.tri_tests)));
      }
    return;
  }
  // Without scene lights (eye light, normals) a hit is coloured by itself; the probe pixels
  // also ask whether a scene light would reach it.
  const bool unlit_mode = settings_.shading != Shading::Lights;
  const auto probe = [](int x, int y) {
    return x % kLitProbeStride == 0 && y % kLitProbeStride == 0;
  };
  if (!settings_.packets) {
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        ++c.primary;
        const Ray ray = camera_ray(x, y);
        Hit hit;
        const bool found = accel_->intersect(ray, hit);
        uint32_t budget = kMaxSecondaryRaysPerSample;
        const Vec3 value = unlit_mode ? shade_unlit_mode(ray, found, hit, probe(x, y), c)
                                      : shade_hit(ray, found, hit, 0, Vec3(1.0f), budget, c);
        // Never let one bad sample poison the film.
        store(x, y, is_finite(value) ? value : Vec3(0.0f));
      }
    return;
  }
  // Whole rows of the tile per packet, as many as kRenderPacket rays hold (8 rows of a 16-pixel
  // tile's width would not fit: 4 rows of 16 do), so a packet is a coherent block of pixels.
  const int tw = x1 - x0;
  const int rows = std::max(1, kRenderPacket / std::max(1, tw));
  Ray rays[kRenderPacket];
  Hit hits[kRenderPacket];
  bool found[kRenderPacket];
  Vec3 values[kRenderPacket];
  for (int py = y0; py < y1; py += rows) {
    const int py1 = std::min(py + rows, y1);
    // A tile wider than a packet is cut along its rows as well.
    for (int px = x0; px < x1; px += kRenderPacket) {
      const int px1 = std::min(px + kRenderPacket, x1);
      int n = 0;
      for (int y = py; y < py1; ++y)
        for (int x = px; x < px1; ++x) rays[n++] = camera_ray(x, y);
      accel_->intersect_packet(rays, n, hits, found);
      if (!unlit_mode) shade_packet(rays, hits, found, n, values, c);
      c.primary += uint64_t(n);
      n = 0;
      for (int y = py; y < py1; ++y)
        for (int x = px; x < px1; ++x, ++n) {
          if (unlit_mode) values[n] = shade_unlit_mode(rays[n], found[n], hits[n], probe(x, y), c);
          store(x, y, is_finite(values[n]) ? values[n] : Vec3(0.0f));
        }
    }
  }
}

void Renderer::resolve(std::vector<float>& rgb) const {
  rgb.resize(accum_.size());
  const float inv = samples_ > 0 ? 1.0f / float(samples_) : 0.0f;
  for (size_t i = 0; i < accum_.size(); ++i) rgb[i] = accum_[i] * inv;
}

Vec3 Renderer::radiance(const Ray& ray, int depth, RenderCounters& counters) const {
  uint32_t budget = kMaxSecondaryRaysPerSample;
  return shade(ray, depth, Vec3(1.0f), budget, counters);
}

Vec3 Renderer::shade(const Ray& ray, int depth, const Vec3& path_weight, uint32_t& budget,
                     RenderCounters& counters, RayTree* tree, int parent, RayKind kind) const {
  Hit hit;
  if (!tree) {
    const bool found = accel_->intersect(ray, hit);
    return shade_hit(ray, found, hit, depth, path_weight, budget, counters);
  }
  const int node = record_ray(*tree, ray, kind, parent, depth);
  hit = tree->nodes[size_t(node)].trace.hit;
  return shade_hit(ray, hit.valid(), hit, depth, path_weight, budget, counters, tree, node);
}

RayTree Renderer::trace_tree(const Ray& primary, bool timed) const {
  RayTree tree;
  tree.timed = timed;
  RenderCounters counters;
  uint32_t budget = kMaxSecondaryRaysPerSample;
  tree.radiance = shade(primary, 0, Vec3(1.0f), budget, counters, &tree, -1, RayKind::Primary);
  return tree;
}

int Renderer::record_ray(RayTree& tree, const Ray& ray, RayKind kind, int parent, int depth) const {
  RayTreeNode n;
  n.kind = kind;
  n.parent = parent;
  n.depth = depth;
  n.ray = ray;
  const bool any = kind == RayKind::Shadow;
  n.trace = any ? accel_->trace_occluded(ray) : accel_->trace(ray);
  // The fast query alone, repeated until the loop is long against the clock's resolution.
  uint64_t reps = 0, answers = 0;
  double nanos = 0;
  for (uint64_t batch = 8; tree.timed && nanos < kRayTreeTimingNanos && reps < (1u << 20);
       batch *= 2) {
    const auto t0 = std::chrono::steady_clock::now();
    for (uint64_t i = 0; i < batch; ++i) {
      Hit h;
      answers += any ? accel_->occluded(ray) : accel_->intersect(ray, h);
    }
    nanos +=
        std::chrono::duration<double, std::nano>(std::chrono::steady_clock::now() - t0).count();
    reps += batch;
  }
  // The answers are used, so the timed queries cannot be optimised away.
  static std::atomic<uint64_t> answers_sink{0};
  answers_sink.fetch_add(answers, std::memory_order_relaxed);
  n.seconds = reps ? nanos * 1e-9 / double(reps) : 0.0;
  tree.nodes.push_back(std::move(n));
  return int(tree.nodes.size()) - 1;
}

Vec3 Renderer::shade_hit(const Ray& ray, bool found, const Hit& hit, int depth,
                         const Vec3& path_weight, uint32_t& budget, RenderCounters& counters,
                         RayTree* tree, int node) const {
  if (!found) return scene_->background;
  const Surface s = surface_at(ray, hit);
  Vec3 result = unlit(s);
  bool lit = max_component(s.m->emission) > 0.0f;
  for (uint32_t l = 0; l < scene_->lights.size(); ++l) {
    const Light& light = scene_->lights[l];
    LightTerm t;
    if (!light_term(s, light, t)) continue;
    if (settings_.shadows) {
      ++counters.shadow;
      const Ray shadow = shadow_ray(s, light, t);
      if (tree) {
        const int sn = record_ray(*tree, shadow, RayKind::Shadow, node, depth);
        tree->nodes[size_t(sn)].light = l;
        if (tree->nodes[size_t(sn)].trace.occluded) continue;
      } else if (accel_->occluded(shadow)) {
        continue;
      }
    }
    add_light(s, t, result);
    lit = true;
  }
  if (depth == 0) {
    ++counters.probed;
    counters.lit += lit;
  }
  return finish_hit(s, result, depth, path_weight, budget, counters, tree, node);
}

void Renderer::shade_packet(const Ray* rays, const Hit* hits, const bool* found, int n, Vec3* out,
                            RenderCounters& counters) const {
  // One entry per (hit, light) whose light can reach the hit, in the order shade_hit meets
  // them: hit by hit, each hit's lights in the scene's order. Per thread, reused.
  struct Lit {
    int hit;
    uint32_t light;
    LightTerm term;
    bool blocked;
  };
  thread_local std::vector<Surface> surfaces;
  thread_local std::vector<Lit> lit;
  surfaces.resize(size_t(n));
  lit.clear();
  const auto& lights = scene_->lights;
  for (int i = 0; i < n; ++i) {
    if (!found[i]) continue;
    surfaces[size_t(i)] = surface_at(rays[i], hits[i]);
    for (uint32_t l = 0; l < lights.size(); ++l) {
      LightTerm t;
      if (light_term(surfaces[size_t(i)], lights[l], t)) lit.push_back({i, l, t, false});
    }
  }
  if (settings_.shadows) {
    Ray shadow[kShadowPacket];
    bool blocked[kShadowPacket];
    for (size_t k0 = 0; k0 < lit.size(); k0 += kShadowPacket) {
      const int m = int(std::min<size_t>(kShadowPacket, lit.size() - k0));
      for (int k = 0; k < m; ++k) {
        const Lit& e = lit[k0 + size_t(k)];
        shadow[k] = shadow_ray(surfaces[size_t(e.hit)], lights[e.light], e.term);
      }
      accel_->occluded_packet(shadow, m, blocked);
      for (int k = 0; k < m; ++k) lit[k0 + size_t(k)].blocked = blocked[k];
    }
    counters.shadow += lit.size();
  }
  size_t next = 0;
  for (int i = 0; i < n; ++i) {
    if (!found[i]) {
      out[i] = scene_->background;
      continue;
    }
    const Surface& s = surfaces[size_t(i)];
    Vec3 result = unlit(s);
    bool reached = max_component(s.m->emission) > 0.0f;
    for (; next < lit.size() && lit[next].hit == i; ++next)
      if (!lit[next].blocked) {
        add_light(s, lit[next].term, result);
        reached = true;
      }
    ++counters.probed;
    counters.lit += reached;
    uint32_t budget = kMaxSecondaryRaysPerSample;
    out[i] = finish_hit(s, result, 0, Vec3(1.0f), budget, counters);
  }
}

bool Renderer::any_light_reaches(const Surface& s, RenderCounters& counters) const {
  if (max_component(s.m->emission) > 0.0f) return true;
  for (const Light& light : scene_->lights) {
    LightTerm t;
    if (!light_term(s, light, t)) continue;
    if (!settings_.shadows) return true;
    ++counters.shadow;
    if (!accel_->occluded(shadow_ray(s, light, t))) return true;
  }
  return false;
}

Vec3 Renderer::shade_unlit_mode(const Ray& ray, bool found, const Hit& hit, bool probe,
                                RenderCounters& counters) const {
  if (!found) return scene_->background;
  const Surface s = surface_at(ray, hit);
  if (probe) {
    ++counters.probed;
    counters.lit += any_light_reaches(s, counters);
  }
  if (settings_.shading == Shading::Normals) {
    // The normal as the mesh orients it (surface_at turned it towards the viewer).
    const Vec3 n = s.front ? s.n : -s.n;
    return (n + Vec3(1.0f)) * 0.5f;
  }
  // Eye light: a light at the eye, so every visible surface is lit and its brightness follows
  // the angle it is seen at; a floor of kEyeLightFloor keeps grazing faces readable. Emission
  // is shown as in Lights mode; metals and glass show their base colour.
  const float cos_v = std::fabs(dot(s.n, s.d));
  return s.m->emission + s.albedo * (kEyeLightFloor + (1.0f - kEyeLightFloor) * cos_v);
}

constexpr EnumName<Shading> kShadingNames[] = {
    {Shading::Lights, "lights"}, {Shading::EyeLight, "eye"}, {Shading::Normals, "normals"}};
constexpr EnumName<SecondaryOffset> kSecondaryOffsetNames[] = {
    {SecondaryOffset::Robust, "robust"},
    {SecondaryOffset::Epsilon, "epsilon"},
    {SecondaryOffset::None, "none"}};

Shading parse_shading(const std::string& s, const std::string& what) {
  return parse_enum(s, kShadingNames, what,
                    "choose lights (the scene's lights), eye (a light at the eye) or normals (the "
                    "surface normal as a colour)");
}

SecondaryOffset parse_secondary_offset(const std::string& s, const std::string& what) {
  return parse_enum(s, kSecondaryOffsetNames, what,
                    "choose robust (the hit point moved off the surface), epsilon (skip hits "
                    "nearer than 1e-4) or none (start at the hit point)");
}

const char* to_string(Shading s) {
  return enum_name(s, kShadingNames, "lights");
}

const char* to_string(SecondaryOffset o) {
  return enum_name(o, kSecondaryOffsetNames, "robust");
}

Renderer::Surface Renderer::surface_at(const Ray& ray, const Hit& hit) const {
  Surface s;
  const Mesh& mesh = scene_->mesh;
  const auto& tri = mesh.triangles[hit.prim];
  const auto c = mesh.corners(hit.prim);
  s.corners = c;
  const float b0 = 1.0f - hit.u - hit.v, b1 = hit.u, b2 = hit.v;
  // The hit point from barycentrics is accurate relative to the triangle's coordinates
  // (what offset_ray_origin assumes), unlike org + t*dir.
  s.p = c[0] * b0 + c[1] * b1 + c[2] * b2;
  s.d = normalize(ray.dir);

  s.ng = normalize(mesh.geometric_normal(hit.prim));
  s.front = dot(s.ng, s.d) < 0.0f;  // entering a closed object through its outside
  if (!s.front) s.ng = -s.ng;       // ng now faces the incoming ray
  s.n = s.ng;
  if (!mesh.normals.empty()) {
    const Vec3 ns =
        mesh.normals[tri[0]] * b0 + mesh.normals[tri[1]] * b1 + mesh.normals[tri[2]] * b2;
    if (dot(ns, ns) > 0.0f && is_finite(ns)) {
      s.n = normalize(ns);
      if (dot(s.n, s.ng) < 0.0f) s.n = -s.n;
    }
  }

  const uint32_t mat_id = mesh.material_of(hit.prim);
  s.m = &scene_->materials[mat_id < scene_->materials.size() ? mat_id : 0];
  const Material& m = *s.m;
  s.albedo = m.base_color;
  if (m.base_color_texture >= 0 && size_t(m.base_color_texture) < scene_->textures.size() &&
      !mesh.uvs.empty()) {
    const auto& uv0 = mesh.uvs[tri[0]];
    const auto& uv1 = mesh.uvs[tri[1]];
    const auto& uv2 = mesh.uvs[tri[2]];
    const float tu = uv0[0] * b0 + uv1[0] * b1 + uv2[0] * b2;
    const float tv = uv0[1] * b0 + uv1[1] * b1 + uv2[1] * b2;
    s.albedo = s.albedo * scene_->textures[size_t(m.base_color_texture)].sample(tu, tv);
  }

  s.transmission = need_refraction_ ? saturate(m.transmission) : 0.0f;
  s.diffuse = s.albedo * ((1.0f - saturate(m.metallic)) * (1.0f - s.transmission));
  s.spec = specular_color(m, s.albedo);
  s.exponent = highlight_exponent(m);
  s.shadow_org =
      settings_.offset == SecondaryOffset::Robust ? offset_ray_origin(s.p, s.ng, c) : s.p;
  s.shadow_skip = settings_.offset == SecondaryOffset::Epsilon ? kSecondaryEpsilon : 0.0f;
  return s;
}

Vec3 Renderer::unlit(const Surface& s) {
  return s.m->emission + s.diffuse * kAmbient;
}

bool Renderer::light_term(const Surface& s, const Light& light, LightTerm& t) const {
  t.irradiance = light.color * light.intensity;  // at normal incidence
  if (light.type == LightType::Directional) {
    t.wi = -normalize(light.direction);
  } else {
    const Vec3 to_light = light.position - s.p;
    const float d2 = dot(to_light, to_light);
    if (!(d2 > 0.0f)) return false;
    const float dist = std::sqrt(d2);
    t.wi = to_light / dist;
    t.irradiance = t.irradiance / d2;
    if (light.type == LightType::Spot) {
      // glTF KHR_lights_punctual: smooth falloff between the inner and outer cone.
      const float cos_outer = std::cos(light.outer_cone), cos_inner = std::cos(light.inner_cone);
      const float scale = 1.0f / std::max(1e-3f, cos_inner - cos_outer);
      const float cd = dot(normalize(light.direction), -t.wi);
      const float a = saturate((cd - cos_outer) * scale);
      if (a <= 0.0f) return false;
      t.irradiance = t.irradiance * (a * a);
    }
  }
  // Lights behind the geometric surface cannot reach it, whatever the shading normal says.
  if (dot(t.wi, s.ng) <= 0.0f) return false;
  t.cos_l = dot(s.n, t.wi);
  return t.cos_l > 0.0f;
}

Ray Renderer::shadow_ray(const Surface& s, const Light& light, const LightTerm& t) {
  Ray shadow{s.shadow_org, s.shadow_skip, t.wi, kInf};
  if (light.type != LightType::Directional) {
    // Aim at the light itself and stop just short of it.
    shadow.dir = light.position - s.shadow_org;
    shadow.tmax = 1.0f - 1e-4f;
    if (s.shadow_skip > 0.0f) shadow.tmin = s.shadow_skip / length(shadow.dir);
  }
  return shadow;
}

Ray Renderer::leaving_ray(const Surface& s, const Vec3& side, const Vec3& dir) const {
  switch (settings_.offset) {
    case SecondaryOffset::Robust:
      break;
    case SecondaryOffset::Epsilon:
      return Ray{s.p, kSecondaryEpsilon, dir, kInf};
    case SecondaryOffset::None:
      return Ray{s.p, 0.0f, dir, kInf};
  }
  return Ray{offset_ray_origin(s.p, side, s.corners), 0.0f, dir, kInf};
}

void Renderer::add_light(const Surface& s, const LightTerm& t, Vec3& result) {
  const Vec3 half = normalize(t.wi - s.d);  // -d: towards the eye
  const float cos_h = std::max(0.0f, dot(s.n, half));
  // Energy-normalised Blinn-Phong lobe so that the exponent changes shape, not brightness.
  const float lobe = (s.exponent + 8.0f) / (8.0f * kPi) * std::pow(cos_h, s.exponent);
  result += (s.diffuse * (1.0f / kPi) + s.spec * lobe) * t.irradiance * t.cos_l;
}

Vec3 Renderer::finish_hit(const Surface& s, Vec3 result, int depth, const Vec3& path_weight,
                          uint32_t& budget, RenderCounters& counters, RayTree* tree,
                          int node) const {
  const Material& m = *s.m;
  const Vec3 &d = s.d, &n = s.n, &ng = s.ng, &albedo = s.albedo;
  const bool front = s.front;
  const float transmission = s.transmission;
  if (depth >= settings_.max_depth) return result;
  // Traces one secondary ray of weight `w` if its path still matters and the budget allows.
  auto secondary = [&](const Vec3& w, const Ray& next, uint64_t& count, RayKind kind) {
    const Vec3 pw = path_weight * w;
    if (!(max_component(pw) > kMinWeight) || budget == 0) return;
    --budget;
    ++count;
    result += w * shade(next, depth + 1, pw, budget, counters, tree, node, kind);
  };

  // Mirror reflection, only for materials that reflect (and only when the scene has one).
  if (need_reflection_ && m.reflects()) {
    Vec3 r = reflect(d, n);
    if (dot(r, ng) <= 0.0f) r = reflect(d, ng);  // shading normal bent it below the surface
    secondary(m.reflectance(), leaving_ray(s, ng, r), counters.reflection, RayKind::Reflection);
  }

  // Refraction with Fresnel (Schlick) and total internal reflection.
  if (transmission > 0.0f) {
    const float eta = front ? 1.0f / m.ior : m.ior;  // n_incident / n_transmitted
    const float cos_i = std::min(1.0f, std::max(0.0f, -dot(d, n)));
    const float k = 1.0f - eta * eta * (1.0f - cos_i * cos_i);
    Vec3 reflect_weight(transmission);
    if (k > 0.0f) {
      const float cos_t = std::sqrt(k);
      const float f0 = ((m.ior - 1.0f) / (m.ior + 1.0f)) * ((m.ior - 1.0f) / (m.ior + 1.0f));
      // Schlick's approximation uses the angle on the optically thinner side.
      const float cos_thin = front ? cos_i : cos_t;
      const float fresnel = f0 + (1.0f - f0) * std::pow(1.0f - cos_thin, 5.0f);
      reflect_weight = Vec3(transmission * fresnel);
      const Vec3 t = normalize(d * eta + n * (eta * cos_i - cos_t));
      const Vec3 tweight = albedo * (transmission * (1.0f - fresnel));
      if (dot(t, ng) < 0.0f)
        secondary(tweight, leaving_ray(s, -ng, t), counters.refraction, RayKind::Refraction);
    }
    // Fresnel reflection of transparent surfaces (all of it under total internal reflection).
    Vec3 r = reflect(d, n);
    if (dot(r, ng) <= 0.0f) r = reflect(d, ng);
    secondary(reflect_weight, leaving_ray(s, ng, r), counters.reflection, RayKind::Reflection);
  }
  return result;
}

const char* to_string(RayKind k) {
  static constexpr EnumName<RayKind> kNames[] = {{RayKind::Primary, "primary"},
                                                 {RayKind::Shadow, "shadow"},
                                                 {RayKind::Reflection, "reflection"},
                                                 {RayKind::Refraction, "refraction"}};
  return enum_name(k, kNames);
}

}  // namespace kdgrid
