#include "scene/procedural.h"

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <map>
#include <utility>

#include "math/rng.h"
#include "util/error.h"

namespace kdgrid {

namespace {

constexpr float kPi = 3.14159265358979f;

Material make_material(const std::string& name, const Vec3& color) {
  Material m;
  m.name = name;
  m.base_color = color;
  return m;
}

/// Appends a quad (a, b, c, d counter-clockwise seen from the side its normal points to) with
/// flat normals.
void add_quad(Mesh& mesh, const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  const uint32_t base = uint32_t(mesh.positions.size());
  const Vec3 n = normalize(cross(b - a, c - a));
  for (const Vec3& p : {a, b, c, d}) {
    mesh.positions.push_back(p);
    mesh.normals.push_back(n);
  }
  mesh.triangles.push_back({base, base + 1, base + 2});
  mesh.triangles.push_back({base, base + 2, base + 3});
}

void check_count(const std::string& name, int count, int max_count) {
  if (count < 0 || count > max_count)
    throw ParamError("gen " + name + ": --count " + std::to_string(count) +
                     " is out of range; give 1.." + std::to_string(max_count) +
                     " (0 = the default)");
}

int pick_count(const std::string& name, const ProceduralParams& p, int def,
               int max_count = 50'000'000) {
  check_count(name, p.count, max_count);
  return p.count > 0 ? p.count : def;
}

int pick_level(const std::string& name, const ProceduralParams& p, int def) {
  if (p.level < -1 || p.level > 8)
    throw ParamError("gen " + name + ": --level " + std::to_string(p.level) +
                     " is out of range; give 0..8 (each level multiplies triangles by 4)");
  return p.level >= 0 ? p.level : def;
}

/// Torus segment counts giving about `triangles` triangles with roughly square facets
/// (the major circle is ~3x the minor one for radii 1 and 0.35).
std::pair<int, int> torus_segments(int triangles) {
  const int major = std::max(3, int(std::lround(std::sqrt(triangles / 2.0 * 2.86))));
  const int minor = std::max(3, int(std::lround(triangles / 2.0 / major)));
  return {major, minor};
}

// ---- generators ----------------------------------------------------------------------

Scene cornell(const ProceduralParams& p) {
  const int level = pick_level("cornell", p, 3);
  Scene s;
  enum : uint32_t { kWhite, kRed, kGreen, kLight, kMirror, kGlass };
  s.materials.push_back(make_material("white", {0.73f, 0.73f, 0.73f}));
  s.materials.push_back(make_material("red", {0.65f, 0.05f, 0.05f}));
  s.materials.push_back(make_material("green", {0.12f, 0.45f, 0.15f}));
  Material light = make_material("light", {0.78f, 0.78f, 0.78f});
  light.emission = Vec3(6.0f, 5.6f, 4.8f);
  s.materials.push_back(light);
  Material mirror = make_material("mirror", {0.95f, 0.95f, 0.95f});
  mirror.metallic = 1.0f;
  mirror.roughness = 0.0f;
  s.materials.push_back(mirror);
  Material glass = make_material("glass", {1.0f, 1.0f, 1.0f});
  glass.transmission = 1.0f;
  glass.ior = 1.5f;
  glass.roughness = 0.0f;
  s.materials.push_back(glass);

  // Walls face into the box. Each part is appended with its material id.
  auto add_part = [&](const Mesh& part, uint32_t mat) { s.mesh.append(part, mat); };
  Mesh floor, ceiling, back, left, right, panel;
  add_quad(floor, {-1, 0, 1}, {1, 0, 1}, {1, 0, -1}, {-1, 0, -1});
  add_quad(ceiling, {-1, 2, -1}, {1, 2, -1}, {1, 2, 1}, {-1, 2, 1});
  add_quad(back, {-1, 0, -1}, {1, 0, -1}, {1, 2, -1}, {-1, 2, -1});
  add_quad(left, {-1, 0, 1}, {-1, 0, -1}, {-1, 2, -1}, {-1, 2, 1});
  add_quad(right, {1, 0, -1}, {1, 0, 1}, {1, 2, 1}, {1, 2, -1});
  // The panel hangs just below the ceiling, facing down.
  const float h = 0.28f, y = 1.995f;
  add_quad(panel, {-h, y, -h}, {h, y, -h}, {h, y, h}, {-h, y, h});
  add_part(floor, kWhite);
  add_part(ceiling, kWhite);
  add_part(back, kWhite);
  add_part(left, kRed);
  add_part(right, kGreen);
  add_part(panel, kLight);
  add_part(make_icosphere(level, {-0.42f, 0.45f, -0.4f}, 0.45f), kMirror);
  add_part(make_icosphere(level, {0.45f, 0.36f, 0.3f}, 0.36f), kGlass);

  s.lights.push_back({.type = LightType::Point,
                      .position = {0.0f, 1.9f, 0.0f},
                      .color = Vec3(1.0f, 0.93f, 0.8f),
                      .intensity = 6.0f,
                      .name = "ceiling light"});
  s.camera = Camera{
      .eye = {0.0f, 1.0f, 3.9f}, .target = {0.0f, 1.0f, 0.0f}, .fov_deg = 40.0f, .name = "cornell"};
  return s;
}

Scene teapot_in_stadium(const ProceduralParams& p) {
  const int count = pick_count("teapot-in-stadium", p, 20000);
  const auto [major, minor] = torus_segments(count);
  Scene s;
  s.materials.push_back(make_material("stadium", {0.6f, 0.6f, 0.6f}));
  s.materials.push_back(make_material("teapot", {0.8f, 0.55f, 0.2f}));
  Mesh stadium = make_box(Vec3(0.0f, 1490.0f, 0.0f), Vec3(1500.0f), 0.0f, /*inward=*/true);
  s.mesh.append(stadium, 0);
  s.mesh.append(make_torus(major, minor, 1.0f, 0.35f, {0.0f, 0.0f, 0.0f}), 1);
  s.lights.push_back({.position = {2.0f, 5.0f, 4.0f}, .intensity = 40.0f, .name = "key light"});
  s.camera = Camera{
      .eye = {0.0f, 2.2f, 4.0f}, .target = {0.0f, 0.0f, 0.0f}, .fov_deg = 45.0f, .name = "teapot"};
  return s;
}

Scene thin_triangles(const ProceduralParams& p) {
  const int count = pick_count("thin-triangles", p, 10000);
  SplitMix64 rng(p.seed);
  Scene s;
  for (int i = 0; i < count; ++i) {
    const Vec3 c = rng.in_box(-1.0f, 1.0f);
    const Vec3 u = rng.unit_vector();
    Vec3 v = normalize(cross(u, rng.unit_vector()));
    if (!(length(v) > 0.5f)) v = normalize(cross(u, Vec3(0.577f, 0.577f, 0.577f)));
    const float len = rng.uniform(0.5f, 2.0f), width = rng.uniform(1e-4f, 1e-3f);
    const uint32_t b = uint32_t(s.mesh.positions.size());
    s.mesh.positions.push_back(c - u * (len * 0.5f));
    s.mesh.positions.push_back(c + u * (len * 0.5f));
    s.mesh.positions.push_back(c + v * width);
    s.mesh.triangles.push_back({b, b + 1, b + 2});
  }
  return s;
}

Scene coplanar_quads(const ProceduralParams& p) {
  const int count = pick_count("coplanar-quads", p, 2000);
  SplitMix64 rng(p.seed);
  Scene s;
  // (axis of the plane normal, exact plane coordinate): all representable exactly.
  const std::pair<int, float> planes[] = {{2, 0.0f}, {2, 3.0f}, {0, 0.0f}, {1, 1.5f}};
  for (int i = 0; i < count; ++i) {
    // Plain variables, not a structured binding: clang 14 cannot capture those in a lambda.
    const int axis = planes[i % 4].first;
    const float k = planes[i % 4].second;
    float a0, a1, b0, b1;
    if ((i / 4) % 2 == 0) {  // unit lattice quad: every corner on integer coordinates
      a0 = float(rng.integer(-8, 8));
      b0 = float(rng.integer(-8, 8));
      a1 = a0 + 1.0f;
      b1 = b0 + 1.0f;
    } else {  // random rectangle, overlapping others in the same plane
      a0 = rng.uniform(-8.0f, 7.0f);
      b0 = rng.uniform(-8.0f, 7.0f);
      a1 = a0 + rng.uniform(0.05f, 3.0f);
      b1 = b0 + rng.uniform(0.05f, 3.0f);
    }
    const int ua = (axis + 1) % 3, ub = (axis + 2) % 3;
    auto corner = [&](float a, float b) {
      Vec3 q;
      q[axis] = k;
      q[ua] = a;
      q[ub] = b;
      return q;
    };
    const uint32_t base = uint32_t(s.mesh.positions.size());
    for (const Vec3& q : {corner(a0, b0), corner(a1, b0), corner(a1, b1), corner(a0, b1)})
      s.mesh.positions.push_back(q);
    s.mesh.triangles.push_back({base, base + 1, base + 2});
    s.mesh.triangles.push_back({base, base + 2, base + 3});
  }
  return s;
}

Scene duplicates(const ProceduralParams& p) {
  const int count = pick_count("duplicates", p, 2000);
  SplitMix64 rng(p.seed);
  Scene s;
  Mesh& m = s.mesh;
  for (int i = 0; i < count; ++i) {
    const Vec3 c = rng.in_box(-1.0f, 1.0f);
    const uint32_t b = uint32_t(m.positions.size());
    for (int k = 0; k < 3; ++k) m.positions.push_back(c + rng.unit_vector() * 0.15f);
    m.triangles.push_back({b, b + 1, b + 2});
    m.triangles.push_back({b, b + 1, b + 2});  // exact duplicate, same indices
    if (i % 4 == 0) {
      // A nearly identical copy: 1 ULP away per coordinate, or 1e-6 along the normal.
      const Vec3 n = normalize(m.geometric_normal(m.triangles.size() - 1));
      const uint32_t d = uint32_t(m.positions.size());
      for (int k = 0; k < 3; ++k) {
        Vec3 q = m.positions[b + k];
        if ((i / 4) % 2 == 0)
          q = {next_float_up(q.x), next_float_up(q.y), next_float_up(q.z)};
        else
          q = q + n * 1e-6f;
        m.positions.push_back(q);
      }
      m.triangles.push_back({d, d + 1, d + 2});
    }
  }
  return s;
}

Scene soup(const ProceduralParams& p) {
  const int count = pick_count("soup", p, 10000);
  SplitMix64 rng(p.seed);
  Scene s;
  for (int i = 0; i < count; ++i) {
    const Vec3 c = rng.in_box(-1.0f, 1.0f);
    const uint32_t b = uint32_t(s.mesh.positions.size());
    for (int k = 0; k < 3; ++k) s.mesh.positions.push_back(c + rng.in_box(-0.1f, 0.1f));
    s.mesh.triangles.push_back({b, b + 1, b + 2});
  }
  return s;
}

Scene sphere(const ProceduralParams& p) {
  Scene s;
  s.mesh = make_icosphere(pick_level("sphere", p, 4));
  return s;
}

Scene torus(const ProceduralParams& p) {
  const auto [major, minor] = torus_segments(pick_count("torus", p, 5000));
  Scene s;
  s.mesh = make_torus(major, minor);
  return s;
}

/// Value noise on an integer lattice hashed with the seed, smoothly interpolated: the
/// building block of the landscape's fBm heights. Deterministic on every platform.
class ValueNoise {
 public:
  explicit ValueNoise(uint64_t seed) : seed_(seed) {}
  /// In [-1, 1].
  float operator()(float x, float z) const {
    const float fx = std::floor(x), fz = std::floor(z);
    const int64_t ix = int64_t(fx), iz = int64_t(fz);
    const float tx = smooth(x - fx), tz = smooth(z - fz);
    const float a = lattice(ix, iz), b = lattice(ix + 1, iz);
    const float c = lattice(ix, iz + 1), d = lattice(ix + 1, iz + 1);
    return (a + (b - a) * tx) + ((c + (d - c) * tx) - (a + (b - a) * tx)) * tz;
  }

 private:
  static float smooth(float t) { return t * t * (3.0f - 2.0f * t); }
  float lattice(int64_t x, int64_t z) const {
    SplitMix64 r(seed_ ^ (uint64_t(x) * 0x9E3779B185EBCA87ull) ^
                 (uint64_t(z) * 0xC2B2AE3D27D4EB4Full));
    return r.uniform() * 2.0f - 1.0f;
  }
  uint64_t seed_;
};

/// Landscape height at (x, z): rolling fBm plus ridged mountains towards one side, so the
/// terrain has flat valleys, steep slopes and a high range (heights about -40..260).
float landscape_height(const ValueNoise& noise, float x, float z) {
  float h = 0.0f, amp = 60.0f, freq = 1.0f / 400.0f;
  for (int o = 0; o < 6; ++o) {
    h += amp * noise(x * freq, z * freq);
    amp *= 0.5f;
    freq *= 2.03f;
  }
  // Ridged octaves (1 - |n|), weighted up towards +z: a mountain range behind the plains.
  float ridge = 0.0f;
  amp = 1.0f;
  freq = 1.0f / 300.0f;
  for (int o = 0; o < 4; ++o) {
    const float r = 1.0f - std::fabs(noise(x * freq + 31.7f, z * freq - 12.9f));
    ridge += amp * r * r;
    amp *= 0.5f;
    freq *= 2.1f;
  }
  const float w = std::clamp((z + 200.0f) / 1000.0f, 0.0f, 1.0f);
  return h + 160.0f * w * w * ridge;
}

Scene landscape(const ProceduralParams& p) {
  const int count = pick_count("landscape", p, 1'000'000);
  const uint64_t total = uint64_t(count);
  SplitMix64 rng(p.seed);
  const ValueNoise noise(p.seed * 0x2545F4914F6CDD1Dull + 17);
  constexpr float kHalf = 1000.0f;  // terrain spans [-1000, 1000] in x and z
  Scene s;
  enum : uint32_t { kGround, kStone, kFoliage, kMetal, kFence };
  s.materials.push_back(make_material("ground", {0.45f, 0.42f, 0.33f}));
  s.materials.push_back(make_material("stone", {0.55f, 0.55f, 0.58f}));
  s.materials.push_back(make_material("foliage", {0.18f, 0.42f, 0.16f}));
  Material metal = make_material("metal", {0.9f, 0.85f, 0.7f});
  metal.metallic = 1.0f;
  metal.roughness = 0.1f;
  s.materials.push_back(metal);
  s.materials.push_back(make_material("fence", {0.5f, 0.3f, 0.2f}));

  // ---- objects: about 35% of the triangles in clusters, sqrt(budget) objects of sqrt(budget)
  // triangles each, so both the object count and their detail grow with the scene ----
  std::vector<std::pair<Mesh, uint32_t>> objects;
  uint64_t object_tris = 0;
  if (total >= 2000) {
    const double budget = 0.35 * double(total);
    const int per_object = std::max(80, int(std::sqrt(budget)));
    const int num_objects = std::max(1, int(budget / per_object));
    const int num_clusters = std::max(1, num_objects / 40);
    std::vector<std::array<float, 3>> clusters;  // x, z, radius
    for (int c = 0; c < num_clusters; ++c)
      clusters.push_back({rng.uniform(-0.9f, 0.9f) * kHalf, rng.uniform(-0.9f, 0.9f) * kHalf,
                          rng.uniform(15.0f, 60.0f)});
    int level = 0;
    while (20 * (4 << (2 * level)) <= per_object && level < 6) ++level;
    for (int i = 0; i < num_objects && object_tris + uint64_t(per_object) <= uint64_t(budget);
         ++i) {
      const auto& cl = clusters[size_t(rng.integer(0, num_clusters))];
      const float ang = rng.uniform(0.0f, 2.0f * kPi), rad = cl[2] * std::sqrt(rng.uniform());
      const float x = cl[0] + rad * std::cos(ang), z = cl[1] + rad * std::sin(ang);
      const float size = rng.uniform(1.5f, 8.0f);
      // One object in ten floats well above the ground: small dense islands in empty air.
      const float lift = rng.uniform() < 0.1f ? rng.uniform(30.0f, 150.0f) : 0.0f;
      const Vec3 base(x, landscape_height(noise, x, z) + lift, z);
      if (i % 2 == 0) {
        objects.push_back({make_icosphere(level, base + Vec3(0.0f, size * 0.8f, 0.0f), size),
                           rng.uniform() < 0.5f ? kFoliage : kStone});
      } else {
        const auto [major, minor] = torus_segments(per_object);
        objects.push_back(
            {make_torus(major, minor, size, size * 0.35f, base + Vec3(0.0f, size * 0.5f, 0.0f)),
             kMetal});
      }
      object_tris += objects.back().first.num_triangles();
    }
  }

  // ---- terrain: a gx x gz grid of quads, two triangles each, over most of the rest ----
  const uint64_t rest = total - object_tris;
  const uint64_t gx = uint64_t(std::sqrt(double(rest / 2)));
  const uint64_t gz = gx > 0 ? rest / 2 / gx : 0;
  const uint64_t strip = rest - 2 * gx * gz;  // < 2 gx + 2: a fence makes up the exact count

  Mesh& m = s.mesh;
  m.positions.reserve(size_t((gx + 1) * (gz + 1) + strip + 2 + object_tris));
  m.normals.reserve(m.positions.capacity());
  m.triangles.reserve(size_t(total));
  m.material_ids.reserve(size_t(total));
  if (gx > 0 && gz > 0) {
    const float dx = 2.0f * kHalf / float(gx), dz = 2.0f * kHalf / float(gz);
    std::vector<float> h((gx + 1) * (gz + 1));
    for (uint64_t j = 0; j <= gz; ++j)
      for (uint64_t i = 0; i <= gx; ++i)
        h[j * (gx + 1) + i] =
            landscape_height(noise, -kHalf + float(i) * dx, -kHalf + float(j) * dz);
    auto H = [&](int64_t i, int64_t j) {
      i = std::clamp<int64_t>(i, 0, int64_t(gx));
      j = std::clamp<int64_t>(j, 0, int64_t(gz));
      return h[size_t(j) * (gx + 1) + size_t(i)];
    };
    for (uint64_t j = 0; j <= gz; ++j)
      for (uint64_t i = 0; i <= gx; ++i) {
        const int64_t ii = int64_t(i), jj = int64_t(j);
        m.positions.push_back({-kHalf + float(i) * dx, H(ii, jj), -kHalf + float(j) * dz});
        // Central differences of the height field: smooth shading normals.
        const float sx = (H(ii + 1, jj) - H(ii - 1, jj)) / (2.0f * dx);
        const float sz = (H(ii, jj + 1) - H(ii, jj - 1)) / (2.0f * dz);
        m.normals.push_back(normalize(Vec3(-sx, 1.0f, -sz)));
      }
    for (uint64_t j = 0; j < gz; ++j)
      for (uint64_t i = 0; i < gx; ++i) {
        const uint32_t a = uint32_t(j * (gx + 1) + i), b = a + 1;
        const uint32_t c = uint32_t(a + gx + 1), d = c + 1;
        // Counter-clockwise seen from above (+y).
        m.triangles.push_back({a, c, d});
        m.triangles.push_back({a, d, b});
      }
    m.material_ids.assign(m.triangles.size(), kGround);
  }
  if (strip > 0) {
    // A fence along the southern edge: a triangle strip of exactly `strip` triangles.
    const uint32_t base = uint32_t(m.positions.size());
    const float w = 2.0f * kHalf / float(strip / 2 + 1);
    for (uint64_t v = 0; v < strip + 2; ++v) {
      const float x = -kHalf + float(v / 2) * w + (v % 2 ? 0.5f * w : 0.0f);
      const float ground = landscape_height(noise, x, -kHalf - 2.0f);
      m.positions.push_back({x, ground + (v % 2 ? 3.0f : -1.0f), -kHalf - 2.0f});
      m.normals.push_back({0.0f, 0.0f, -1.0f});
    }
    for (uint64_t t = 0; t < strip; ++t) {
      const uint32_t v = base + uint32_t(t);
      if (t % 2 == 0)
        m.triangles.push_back({v, v + 1, v + 2});
      else
        m.triangles.push_back({v + 1, v, v + 2});
      m.material_ids.push_back(kFence);
    }
  }
  for (const auto& [obj, mat] : objects) m.append(obj, mat);

  s.lights.push_back({.type = LightType::Directional,
                      .direction = normalize(Vec3(0.45f, -1.0f, 0.6f)),
                      .intensity = 2.5f,
                      .name = "sun"});
  s.background = Vec3(0.45f, 0.6f, 0.85f);
  s.camera = Camera{.eye = {-300.0f, 420.0f, -1250.0f},
                    .target = {0.0f, 40.0f, 0.0f},
                    .fov_deg = 55.0f,
                    .name = "overview"};
  return s;
}

Scene interior(const ProceduralParams& p) {
  const int count = pick_count("interior", p, 560, 4'000'000);
  Scene s;
  enum : uint32_t { kTiles, kSlab, kRug, kWall, kPlaster, kCeiling, kColumn, kWood };
  for (const auto& [name, c] :
       std::initializer_list<std::pair<const char*, Vec3>>{{"tiles", {0.7f, 0.68f, 0.62f}},
                                                           {"slab", {0.5f, 0.5f, 0.5f}},
                                                           {"rug", {0.55f, 0.12f, 0.1f}},
                                                           {"wall", {0.8f, 0.78f, 0.72f}},
                                                           {"plaster", {0.85f, 0.85f, 0.85f}},
                                                           {"ceiling", {0.9f, 0.9f, 0.9f}},
                                                           {"column", {0.6f, 0.6f, 0.65f}},
                                                           {"wood", {0.45f, 0.3f, 0.15f}}})
    s.materials.push_back(make_material(name, c));

  // Local room coordinates: x in [0, W], z in [0, D], the floor at y = kFloor, the ceiling at
  // y = H. The room is placed off the origin and turned about +y, as CAD exports often are:
  // the floor stays exactly level, the walls lie in planes no float represents exactly.
  constexpr float W = 20.0f, D = 14.0f, H = 5.0f, kFloor = 0.15f, kTurn = 0.3f;
  const Vec3 origin(240.5f, 0.0f, -130.25f);
  const float cs = std::cos(kTurn), sn = std::sin(kTurn);
  auto place = [&](float x, float y, float z) {
    return origin + Vec3(cs * x + sn * z, y, -sn * x + cs * z);
  };
  // A quad from local corners (counter-clockwise seen from the side it faces).
  auto quad = [&](uint32_t mat, const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
    Mesh m;
    add_quad(m, place(a.x, a.y, a.z), place(b.x, b.y, b.z), place(c.x, c.y, c.z),
             place(d.x, d.y, d.z));
    s.mesh.append(m, mat);
  };
  // An axis-aligned local box with all six faces outward, its bottom exactly at y0.
  auto box = [&](uint32_t mat, float x0, float y0, float z0, float x1, float y1, float z1) {
    quad(mat, {x0, y1, z0}, {x0, y1, z1}, {x1, y1, z1}, {x1, y1, z0});  // top
    quad(mat, {x0, y0, z0}, {x1, y0, z0}, {x1, y0, z1}, {x0, y0, z1});  // bottom, on what holds it
    quad(mat, {x0, y0, z0}, {x0, y1, z0}, {x1, y1, z0}, {x1, y0, z0});  // -z
    quad(mat, {x1, y0, z1}, {x1, y1, z1}, {x0, y1, z1}, {x0, y0, z1});  // +z
    quad(mat, {x0, y0, z1}, {x0, y1, z1}, {x0, y1, z0}, {x0, y0, z0});  // -x
    quad(mat, {x1, y0, z0}, {x1, y1, z0}, {x1, y1, z1}, {x1, y0, z1});  // +x
  };

  // Floor tiles (count of them, as square as the room allows), facing up.
  const int nx = std::max(1, int(std::lround(std::sqrt(count * W / D))));
  const int nz = std::max(1, (count + nx - 1) / nx);
  for (int i = 0; i < nx; ++i)
    for (int k = 0; k < nz; ++k) {
      const float x0 = W * i / nx, x1 = W * (i + 1) / nx;
      const float z0 = D * k / nz, z1 = D * (k + 1) / nz;
      quad(kTiles, {x0, kFloor, z0}, {x0, kFloor, z1}, {x1, kFloor, z1}, {x1, kFloor, z0});
    }
  // The slab's top, exactly coincident with the tiles, split along the other diagonal.
  quad(kSlab, {0, kFloor, D}, {W, kFloor, D}, {W, kFloor, 0}, {0, kFloor, 0});
  // A rug a rounding error above the floor, where the offset origin of a ray leaving the
  // floor lies.
  const float rug = kFloor + 4e-6f;
  quad(kRug, {6, rug, 4}, {6, rug, 10}, {13, rug, 10}, {13, rug, 4});
  // Walls facing in; the z = 0 wall has two windows. Each wall has a plaster layer in its
  // own plane, split differently, as duplicated CAD layers are.
  auto wall = [&](const Vec3& a, const Vec3& b, float y0, float y1, uint32_t mat) {
    quad(mat, {a.x, y0, a.z}, {b.x, y0, b.z}, {b.x, y1, b.z}, {a.x, y1, a.z});
  };
  const Vec3 c00(0, 0, 0), cW0(W, 0, 0), cWD(W, 0, D), c0D(0, 0, D);
  wall(cW0, cWD, kFloor, H, kWall);
  wall(cWD, c0D, kFloor, H, kWall);
  wall(c0D, c00, kFloor, H, kWall);
  wall(Vec3(W, 0, 0), Vec3(W / 2, 0, 0), kFloor, H, kPlaster);
  wall(Vec3(W / 2, 0, 0), Vec3(0, 0, 0), kFloor, H, kPlaster);
  wall(cW0, cWD, kFloor, H / 2, kPlaster);
  // The window wall: below, above and between two windows spanning x in [3, 8] and [12, 17].
  wall(c00, cW0, kFloor, 1.0f, kWall);
  wall(c00, cW0, 3.5f, H, kWall);
  for (const auto& [x0, x1] :
       std::initializer_list<std::pair<float, float>>{{0.0f, 3.0f}, {8.0f, 12.0f}, {17.0f, W}})
    wall(Vec3(x0, 0, 0), Vec3(x1, 0, 0), 1.0f, 3.5f, kWall);
  quad(kCeiling, {0, H, 0}, {W, H, 0}, {W, H, D}, {0, H, D});
  // Columns standing on the floor and a table with its top resting on its body.
  for (const float x : {5.0f, 15.0f})
    for (const float z : {5.0f, 9.0f})
      box(kColumn, x - 0.3f, kFloor, z - 0.3f, x + 0.3f, H, z + 0.3f);
  box(kWood, 8.0f, kFloor, 6.0f, 11.0f, 0.9f, 8.0f);
  box(kWood, 7.8f, 0.9f, 5.8f, 11.2f, 0.95f, 8.2f);

  s.lights.push_back({.position = place(W * 0.5f, 12.0f, -15.0f),
                      .intensity = 400.0f,
                      .name = "sun through the windows"});
  s.camera = Camera{.eye = place(2.0f, 1.7f, 12.5f),
                    .target = place(14.0f, 1.0f, 3.0f),
                    .fov_deg = 60.0f,
                    .name = "inside"};
  return s;
}

struct Generator {
  const char* name;
  const char* description;
  /// Builds the scene; generate_scene names its source and validates its mesh.
  Scene (*fn)(const ProceduralParams&);
};

const Generator kGenerators[] = {
    {"cornell", "Cornell box with mirror box, glass sphere and ceiling light (--level: sphere)",
     cornell},
    {"teapot-in-stadium", "dense torus (--count triangles) inside a ~1100x larger box",
     teapot_in_stadium},
    {"thin-triangles", "--count long thin random triangles (--seed)", thin_triangles},
    {"coplanar-quads", "--count axis-aligned quads in 4 shared planes, many on integer coords",
     coplanar_quads},
    {"interior",
     "a room turned off the axes: --count floor tiles on a coincident slab, a rug a rounding "
     "error above, walls with coincident plaster layers, windows, columns, a table",
     interior},
    {"duplicates", "--count random triangles, each twice, some shifted by 1 ULP or 1e-6",
     duplicates},
    {"soup", "--count random small triangles in [-1,1]^3 (--seed)", soup},
    {"sphere", "closed icosphere, 20*4^level triangles (--level, default 4)", sphere},
    {"torus", "closed torus of about --count triangles (default 5000)", torus},
    {"landscape",
     "exactly --count triangles (default 1M): fBm terrain with clusters of spheres and tori, "
     "some floating, and empty sky (--seed)",
     landscape},
};

}  // namespace

std::vector<ProceduralInfo> procedural_generators() {
  std::vector<ProceduralInfo> out;
  for (const Generator& g : kGenerators) out.push_back({g.name, g.description});
  return out;
}

Scene generate_scene(const std::string& name, const ProceduralParams& params) {
  for (const Generator& g : kGenerators)
    if (name == g.name) {
      Scene s = g.fn(params);
      s.source = "procedural:" + name;
      s.mesh.validate(s.source);
      return s;
    }
  std::string valid;
  for (const Generator& g : kGenerators) valid += (valid.empty() ? "" : ", ") + std::string(g.name);
  throw ParamError("unknown procedural scene '" + name + "': choose one of " + valid);
}

Mesh make_icosphere(int level, const Vec3& center, float radius) {
  // Regular icosahedron, then each level splits every triangle into four, pushing the new
  // midpoints onto the sphere. Midpoints are shared through an edge map so the mesh stays
  // closed (every edge used by exactly two triangles).
  const float t = (1.0f + std::sqrt(5.0f)) * 0.5f;
  std::vector<Vec3> unit = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                            {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                            {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  for (Vec3& v : unit) v = normalize(v);
  std::vector<std::array<uint32_t, 3>> tris = {
      {0, 11, 5},  {0, 5, 1},  {0, 1, 7},  {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
      {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
      {3, 8, 9},   {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (int l = 0; l < level; ++l) {
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> midpoints;
    auto midpoint = [&](uint32_t a, uint32_t b) {
      const auto key = std::minmax(a, b);
      auto it = midpoints.find(key);
      if (it != midpoints.end()) return it->second;
      unit.push_back(normalize(unit[a] + unit[b]));
      const uint32_t id = uint32_t(unit.size() - 1);
      midpoints.emplace(key, id);
      return id;
    };
    std::vector<std::array<uint32_t, 3>> next;
    next.reserve(tris.size() * 4);
    for (const auto& f : tris) {
      const uint32_t a = midpoint(f[0], f[1]), b = midpoint(f[1], f[2]), c = midpoint(f[2], f[0]);
      next.push_back({f[0], a, c});
      next.push_back({f[1], b, a});
      next.push_back({f[2], c, b});
      next.push_back({a, b, c});
    }
    tris = std::move(next);
  }
  Mesh m;
  m.triangles = std::move(tris);
  m.positions.reserve(unit.size());
  for (const Vec3& u : unit) m.positions.push_back(center + u * radius);
  m.normals = std::move(unit);
  return m;
}

Mesh make_torus(int major_segments, int minor_segments, float major_radius, float minor_radius,
                const Vec3& center) {
  const int n = std::max(3, major_segments), k = std::max(3, minor_segments);
  Mesh m;
  m.positions.reserve(size_t(n) * k);
  m.normals.reserve(size_t(n) * k);
  for (int i = 0; i < n; ++i) {
    const float phi = 2.0f * kPi * float(i) / float(n);
    const Vec3 radial(std::cos(phi), 0.0f, std::sin(phi));
    for (int j = 0; j < k; ++j) {
      const float theta = 2.0f * kPi * float(j) / float(k);
      const Vec3 normal = radial * std::cos(theta) + Vec3(0.0f, std::sin(theta), 0.0f);
      m.positions.push_back(center + radial * major_radius + normal * minor_radius);
      m.normals.push_back(normal);
    }
  }
  // Indices wrap around both circles, so the surface is closed without seam vertices.
  auto id = [&](int i, int j) { return uint32_t((i % n) * k + (j % k)); };
  m.triangles.reserve(size_t(2) * n * k);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < k; ++j) {
      const uint32_t a = id(i, j), b = id(i + 1, j), c = id(i + 1, j + 1), d = id(i, j + 1);
      m.triangles.push_back({a, d, c});
      m.triangles.push_back({a, c, b});
    }
  return m;
}

Mesh make_box(const Vec3& center, const Vec3& he, float rotation_y, bool inward) {
  const float cs = std::cos(rotation_y), sn = std::sin(rotation_y);
  auto place = [&](float x, float y, float z) {
    const Vec3 local(x * he.x, y * he.y, z * he.z);
    return center + Vec3(cs * local.x + sn * local.z, local.y, -sn * local.x + cs * local.z);
  };
  Mesh m;
  // Six faces, corners counter-clockwise seen from outside.
  const float faces[6][4][3] = {
      {{1, -1, -1}, {1, 1, -1}, {1, 1, 1}, {1, -1, 1}},      // +x
      {{-1, -1, 1}, {-1, 1, 1}, {-1, 1, -1}, {-1, -1, -1}},  // -x
      {{-1, 1, -1}, {-1, 1, 1}, {1, 1, 1}, {1, 1, -1}},      // +y
      {{-1, -1, 1}, {-1, -1, -1}, {1, -1, -1}, {1, -1, 1}},  // -y
      {{-1, -1, 1}, {1, -1, 1}, {1, 1, 1}, {-1, 1, 1}},      // +z
      {{1, -1, -1}, {-1, -1, -1}, {-1, 1, -1}, {1, 1, -1}},  // -z
  };
  for (const auto& f : faces) {
    Vec3 q[4];
    for (int c = 0; c < 4; ++c) q[c] = place(f[c][0], f[c][1], f[c][2]);
    if (inward)
      add_quad(m, q[3], q[2], q[1], q[0]);
    else
      add_quad(m, q[0], q[1], q[2], q[3]);
  }
  return m;
}

}  // namespace kdgrid
