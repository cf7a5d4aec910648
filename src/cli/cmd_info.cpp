// `kdgrid info SCENE [--json]`: what a scene holds.
#include <cstdio>

#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/common.h"
#include "scene/load.h"

namespace kdgrid::cli {

void add_info_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("info", "Print what a scene holds: triangles, bounds, materials");
  auto path = std::make_shared<std::string>();
  auto json = std::make_shared<bool>(false);
  auto scale = std::make_shared<double>(1.0);
  add_scene_argument(cmd, *path);
  cmd->add_flag("--json", *json, "Print JSON instead of text");
  add_scale_option(cmd, *scale);
  cmd->callback([path, json, scale] {
    LoadOptions options;
    options.decode_textures = false;  // info reports textures' count, not their pixels
    options.scale = *scale;
    const Scene s = load_scene(*path, options);
    const Box3 b = s.mesh.bounds();
    nlohmann::json j;
    j["file"] = *path;
    j["triangles"] = s.mesh.num_triangles();
    j["vertices"] = s.mesh.num_vertices();
    j["bounds"] = {{"lo", {b.lo.x, b.lo.y, b.lo.z}}, {"hi", {b.hi.x, b.hi.y, b.hi.z}}};
    j["has_normals"] = !s.mesh.normals.empty();
    j["has_uvs"] = !s.mesh.uvs.empty();
    for (const auto& m : s.materials)
      j["materials"].push_back({{"name", m.name},
                                {"base_color", {m.base_color.x, m.base_color.y, m.base_color.z}},
                                {"metallic", m.metallic},
                                {"roughness", m.roughness},
                                {"transmission", m.transmission},
                                {"ior", m.ior},
                                {"emission", {m.emission.x, m.emission.y, m.emission.z}},
                                {"texture", m.base_color_texture}});
    for (const auto& l : s.lights)
      j["lights"].push_back({{"type", enum_name(l.type, kLightTypeNames)},
                             {"name", l.name},
                             {"position", {l.position.x, l.position.y, l.position.z}},
                             {"intensity", l.intensity}});
    const Camera& c = *s.camera;
    j["camera"] = {{"name", c.name},
                   {"eye", {c.eye.x, c.eye.y, c.eye.z}},
                   {"target", {c.target.x, c.target.y, c.target.z}},
                   {"fov", c.fov_deg}};
    j["textures"] = s.textures.size();
    if (*json) {
      std::printf("%s\n", j.dump(2).c_str());
      return;
    }
    std::printf("file        %s\n", path->c_str());
    std::printf("triangles   %zu\nvertices    %zu\n", s.mesh.num_triangles(),
                s.mesh.num_vertices());
    std::printf("bounds      (%g, %g, %g) - (%g, %g, %g)\n", b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y,
                b.hi.z);
    std::printf("materials   %zu\n", s.materials.size());
    for (const auto& m : s.materials)
      std::printf("  %-24s base (%.3g %.3g %.3g) metallic %.2g rough %.2g transmission %.2g%s\n",
                  m.name.c_str(), m.base_color.x, m.base_color.y, m.base_color.z, m.metallic,
                  m.roughness, m.transmission, m.base_color_texture >= 0 ? " textured" : "");
    std::printf("textures    %zu\nlights      %zu\n", s.textures.size(), s.lights.size());
    for (const auto& l : s.lights)
      std::printf("  %-11s %s at (%g, %g, %g) intensity %g\n", enum_name(l.type, kLightTypeNames),
                  l.name.c_str(), l.position.x, l.position.y, l.position.z, l.intensity);
    std::printf("camera      %s: --eye %g,%g,%g --target %g,%g,%g --fov %g\n", c.name.c_str(),
                c.eye.x, c.eye.y, c.eye.z, c.target.x, c.target.y, c.target.z, c.fov_deg);
  });
}

}  // namespace kdgrid::cli
