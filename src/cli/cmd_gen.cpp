// `kdgrid gen NAME -o FILE`: writes a procedural scene (scene/procedural.h).
#include <cstdio>
#include <filesystem>
#include <memory>

#include "cli/commands.h"
#include "scene/procedural.h"
#include "scene/write.h"
#include "util/atomic_file.h"
#include "util/error.h"

namespace kdgrid::cli {

void add_gen_command(CLI::App& app) {
  std::string names;
  for (const auto& g : procedural_generators()) names += "\n  " + g.name + ": " + g.description;
  auto* cmd = app.add_subcommand("gen", "Write a procedural scene: " + names);
  struct Args {
    std::string name, output;
    ProceduralParams params;
  };
  auto a = std::make_shared<Args>();
  cmd->add_option("name", a->name, "Generator name (see above)")->required();
  cmd->add_option("-o,--output", a->output,
                  "Output file: .gltf or .glb (materials, camera, lights), .ply or .obj")
      ->required();
  cmd->add_option("--count,--triangles", a->params.count,
                  "Triangle/quad count (0 = the generator's default; landscape: exact triangles)")
      ->capture_default_str();
  cmd->add_option("--seed", a->params.seed, "Seed of random generators")->capture_default_str();
  cmd->add_option("--level", a->params.level, "Subdivision level (cornell, sphere; -1 = default)")
      ->capture_default_str();
  cmd->callback([a] {
    namespace fs = std::filesystem;
    check_output_path(a->output, "-o", {".gltf", ".glb", ".ply", ".obj"});
    const Scene scene = generate_scene(a->name, a->params);
    write_scene(scene, a->output);
    std::error_code ec;
    std::printf("%s: %s, %zu triangles, %zu vertices, %zu bytes\n", a->output.c_str(),
                a->name.c_str(), scene.mesh.num_triangles(), scene.mesh.num_vertices(),
                size_t(fs::file_size(a->output, ec)));
  });
}

}  // namespace kdgrid::cli
