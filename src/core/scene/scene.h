// Scene description: one world-space mesh plus materials, textures, lights and a camera.
// Loaders (scene/load.h) fill it; procedural generators (scene/procedural.h) build it.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "math/vec.h"
#include "scene/mesh.h"
#include "util/enum_names.h"

namespace kdgrid {

/// RGB8/RGBA8 texture in linear or sRGB space (glTF base colour textures are sRGB).
struct Texture {
  int width = 0, height = 0, channels = 0;
  std::vector<uint8_t> pixels;  // row-major, top row first
  bool srgb = true;
  std::string name;
  /// Bilinear lookup with wrap-around addressing; returns linear RGB.
  Vec3 sample(float u, float v) const;
};

/// A material covering glTF metallic-roughness, OBJ/MTL and Whitted needs. All colours
/// are linear RGB.
struct Material {
  std::string name;
  Vec3 base_color{0.8f, 0.8f, 0.8f};  ///< diffuse albedo (glTF baseColorFactor, MTL Kd)
  int base_color_texture = -1;        ///< index into Scene::textures, or -1
  float metallic = 0.0f;              ///< 0..1; > 0 makes the surface a (tinted) mirror
  float roughness = 1.0f;             ///< 0..1; sets the highlight exponent
  Vec3 specular{0.0f};                ///< Phong specular colour (MTL Ks)
  float shininess = 0.0f;             ///< Phong exponent (MTL Ns); 0 = derive from roughness
  Vec3 mirror{0.0f};                  ///< explicit mirror reflectance (MTL illum 3/5/7)
  Vec3 emission{0.0f};                ///< emitted radiance (glTF emissive*strength, MTL Ke)
  float transmission = 0.0f;          ///< 0..1 (KHR_materials_transmission, MTL 1-d/illum 7)
  float ior = 1.5f;                   ///< index of refraction (KHR_materials_ior, MTL Ni)

  /// Reflectance of perfect mirror reflection spawned by the Whitted shader.
  Vec3 reflectance() const;
  bool reflects() const { return max_component(reflectance()) > 0.0f; }
  bool refracts() const { return transmission > 0.0f; }
};

enum class LightType { Point, Directional, Spot };
/// The light types by name, as glTF's KHR_lights_punctual and `kdgrid info` name them.
inline constexpr EnumName<LightType> kLightTypeNames[] = {{LightType::Point, "point"},
                                                          {LightType::Directional, "directional"},
                                                          {LightType::Spot, "spot"}};

struct Light {
  LightType type = LightType::Point;
  Vec3 position{0.0f};
  Vec3 direction{0, -1, 0};  ///< direction the light travels (directional, spot)
  Vec3 color{1.0f};
  float intensity = 1.0f;   ///< point/spot: candela-like (W/sr); directional: irradiance
  float inner_cone = 0.0f;  ///< spot: radians
  float outer_cone = 0.7853982f;
  std::string name;
};

/// Pinhole camera. fov is vertical, in degrees. up is the world up used to build the basis.
struct Camera {
  Vec3 eye{0, 0, 1};
  Vec3 target{0, 0, 0};
  Vec3 up{0, 1, 0};
  float fov_deg = 45.0f;
  std::string name;
};

struct Scene {
  Mesh mesh;
  std::vector<Material> materials;  ///< never empty after finalize()
  std::vector<Texture> textures;
  std::vector<Light> lights;     ///< never empty after finalize()
  std::optional<Camera> camera;  ///< set after finalize() (canonical if the file had none)
  std::string source;            ///< file it came from, or generator name
  Vec3 background{0.0f};         ///< radiance of rays that escape

  /// Fills what the file did not give: a grey diffuse material, the canonical camera
  /// (docs/RAYSETS.md), a default light; then validates the mesh. Throws LoadError.
  void finalize();
  /// Multiplies every coordinate of the scene (vertices, camera, light positions) by
  /// `factor` and point and spot light intensities by factor squared, so the scene renders
  /// the same picture at its new size; call before finalize(). Throws ParamError naming
  /// `what` unless factor is finite and positive.
  void scale_by(double factor, const std::string& what);
  bool has_reflective_material() const;
  bool has_refractive_material() const;
};

/// Throws ParamError naming `who` (a structure) if `bounds` reaches beyond
/// kMaxSceneCoordinate (math/ray.h): past it, extents and cell counts computed in float
/// overflow. Scene::finalize refuses such scenes first; this guards direct builds.
void check_scene_range(const Box3& bounds, const std::string& who);

/// The canonical primary camera of docs/RAYSETS.md for a box [lo, hi].
Camera canonical_camera(const Box3& bounds, float fov_deg = 45.0f);
/// The benchmark point light position c + (0, 2r, 0) + 0.5 r d (docs/RAYSETS.md, shadow set).
Vec3 canonical_light_position(const Box3& bounds);

}  // namespace kdgrid
