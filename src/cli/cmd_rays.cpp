// `kdgrid rays SCENE --set primary|shadow|diffuse|random -o FILE.rays`: writes a benchmark
// ray set (docs/RAYSETS.md) so that any tool can trace exactly the same rays. With --pixel X,Y
// it writes --count copies of the primary ray through that pixel instead: traced by
// `kdgrid trace`, they time one path through a structure with its data in the caches and its
// branches learnt, i.e. the latency of its dependency chain alone.
#include <cstdio>
#include <memory>

#include "bench/rayfile.h"
#include "bench/raysets.h"
#include "cli/commands.h"
#include "cli/common.h"
#include "scene/load.h"
#include "util/atomic_file.h"
#include "util/error.h"
#include "util/paths.h"

namespace kdgrid::cli {

namespace {
/// --count bound: 2^27 rays are 4 GiB in memory and on disk (32 bytes each).
constexpr size_t kMaxCount = size_t(1) << 27;

struct RaysArgs {
  std::string scene, set = "primary", res = "1024", out, pixel;
  uint64_t seed = 1;
  size_t count = 100000;
  AccelOptions accel;
  CameraOptions camera;
  double scale = 1.0;
};
}  // namespace

void add_rays_command(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "rays",
      "Write a benchmark ray set (.rays, docs/RAYSETS.md). The camera is the canonical camera of "
      "docs/RAYSETS.md unless --eye/--target/--fov are given, even if the scene file has its own "
      "camera, so that ray sets are comparable across scenes and tools.");
  auto a = std::make_shared<RaysArgs>();
  add_scene_argument(cmd, a->scene);
  cmd->add_option("--set", a->set,
                  "primary (one ray per pixel centre), shadow (from primary hits to the "
                  "benchmark light), diffuse (cosine bounce from primary hits) or random")
      ->capture_default_str();
  cmd->add_option("--res", a->res, "Image size W or WxH of the primary rays")
      ->capture_default_str();
  cmd->add_option("--seed", a->seed, "Seed of the diffuse and random sets")->capture_default_str();
  cmd->add_option("--count", a->count,
                  "Number of rays of the random set, or of copies of the --pixel ray")
      ->capture_default_str();
  cmd->add_option("--pixel", a->pixel,
                  "Write --count copies of the primary ray through pixel X,Y (integers: the pixel "
                  "centre) of the --res image instead of a set: one path timed alone");
  cmd->add_option("-o,--output", a->out, "Output .rays file")->required();
  a->accel.add_to(cmd, "bvh");
  a->camera.add_to(cmd);
  add_scale_option(cmd, a->scale);
  cmd->callback([a] {
    RaySetSpec spec;
    spec.kind = parse_ray_set(a->set);
    parse_resolution(a->res, spec.width, spec.height);
    spec.seed = a->seed;
    spec.count = a->count;
    if (a->count > kMaxCount)
      throw ParamError("--count " + std::to_string(a->count) + " would take " +
                       std::to_string(a->count * sizeof(Ray) >> 30) + " GiB of rays: use at most " +
                       std::to_string(kMaxCount));
    const BuildParams params = a->accel.resolve();
    const std::string scene_path = resolve_scene_path(a->scene);
    check_output_path(a->out, "-o", {".rays"}, {scene_path});
    const Scene scene = load_scene(scene_path, a->scale);
    const Camera cam = a->camera.apply(canonical_camera(scene.mesh.bounds()));
    spec.camera = cam;
    if (!a->pixel.empty()) {
      if (spec.kind != RaySetKind::Primary)
        throw ParamError(
            "--pixel repeats one primary ray: use it without --set, or with --set primary");
      if (a->count == 0) throw ParamError("--count must be at least 1");
      const Ray ray = pixel_ray(cam, a->res, a->pixel);
      write_rays(a->out, std::vector<Ray>(a->count, ray));
      std::printf(
          "wrote %zu copies of the primary ray through pixel %s of %dx%d (camera --eye %g,%g,%g "
          "--target %g,%g,%g --fov %g) to %s\n",
          a->count, a->pixel.c_str(), spec.width, spec.height, cam.eye.x, cam.eye.y, cam.eye.z,
          cam.target.x, cam.target.y, cam.target.z, cam.fov_deg, a->out.c_str());
      return;
    }
    std::unique_ptr<Accelerator> accel;
    if (spec.kind == RaySetKind::Shadow || spec.kind == RaySetKind::Diffuse)
      accel = build_interruptible(a->accel.accel, scene.mesh, params);
    const std::vector<Ray> rays = make_ray_set(spec, scene.mesh, accel.get());
    write_rays(a->out, rays);
    if (spec.kind == RaySetKind::Random)
      std::printf("wrote %zu random rays (seed %llu) to %s\n", rays.size(),
                  (unsigned long long)spec.seed, a->out.c_str());
    else
      std::printf(
          "wrote %zu %s rays (%dx%d, camera --eye %g,%g,%g --target %g,%g,%g --fov %g%s) "
          "to %s\n",
          rays.size(), to_string(spec.kind), spec.width, spec.height, cam.eye.x, cam.eye.y,
          cam.eye.z, cam.target.x, cam.target.y, cam.target.z, cam.fov_deg,
          accel ? (", primary hits by " + accel->name()).c_str() : "", a->out.c_str());
  });
}

}  // namespace kdgrid::cli
