// `kdgrid profile SCENE --accel kdtree,hybrid,embree`: single-thread cost per ray of each
// structure, split into rays that hit, rays that miss but cross the scene box, and rays that
// miss the box; cold (image order) and warm (the same ray again) times, and counters. See
// bench/profile.h for what each figure means.
#include <cstdio>
#include <memory>
#include <string>

#include "bench/profile.h"
#include "bench/raysets.h"
#include "cli/commands.h"
#include "cli/common.h"
#include "scene/load.h"
#include "util/error.h"
#include "util/paths.h"

namespace kdgrid::cli {

namespace {
struct ProfileArgs {
  std::string scene, res = "512", reference = "embree";
  int reps = 5;
  bool cache_sim = false;
  AccelOptions accel;
  CameraOptions camera;
};
}  // namespace

void add_profile_command(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "profile",
      "Where the time goes: single-thread ns per primary ray of each structure for the rays "
      "that hit, that miss but cross the scene box, and that miss the box; cold (image "
      "order) and warm (each ray traced again at once, its data cached: cold - warm is the "
      "cost of cache misses); steps, leaves, tests and lookups per ray. The camera is the "
      "canonical one unless --eye/--target/--fov are given (the suite's Sponza camera: "
      "--eye -14,3,0 --target 10,5,0 --fov 60).");
  auto a = std::make_shared<ProfileArgs>();
  add_scene_argument(cmd, a->scene);
  cmd->add_option("--res", a->res, "Primary rays: W or WxH pixels")->capture_default_str();
  cmd->add_option("--reps", a->reps, "Timed repetitions (the minimum is reported)")
      ->capture_default_str();
  cmd->add_option("--reference", a->reference, "Structure whose answers classify the rays")
      ->capture_default_str();
  cmd->add_flag(
      "--cache-sim", a->cache_sim,
      "Untimed: trace each class once through kdgrid::cache_sim_pass, for a cache "
      "simulator to collect (scripts/cache-profile.sh runs it under valgrind's callgrind); "
      "prints the passes in order with their counters");
  a->accel.add_to(cmd, "kdtree,hybrid,embree");
  a->camera.add_to(cmd);
  cmd->callback([a] {
    if (a->reps < 1)
      throw ParamError("profile: --reps must be at least 1 (got " + std::to_string(a->reps) + ")");
    const std::vector<std::string> names = split_list(a->accel.accel);
    if (names.empty())
      throw ParamError("profile: --accel names no structure (e.g. --accel kdtree,hybrid)");
    require_accelerator_names(names);
    require_accelerator_names({a->reference});
    int w = 0, h = 0;
    parse_resolution(a->res, w, h);
    const BuildParams params = a->accel.resolve();
    const Scene scene = load_scene(resolve_scene_path(a->scene));
    const Camera cam = a->camera.apply(canonical_camera(scene.mesh.bounds()));
    const std::vector<Ray> rays = primary_rays(cam, w, h);
    const auto ref = build_interruptible(a->reference, scene.mesh, params);
    const RayClasses cls = classify_rays(*ref, scene.mesh.bounds(), rays);
    const std::string passes =
        a->cache_sim
            ? std::string("one untimed pass per class in image order")
            : std::to_string(a->reps) + " repetitions (cold: the fastest; warm: the median)";
    std::printf(
        "%s: %zu triangles, %dx%d primary rays (camera --eye %g,%g,%g --target %g,%g,%g --fov %g), "
        "one thread, %s; classes by %s\n\n",
        a->scene.c_str(), scene.mesh.num_triangles(), w, h, cam.eye.x, cam.eye.y, cam.eye.z,
        cam.target.x, cam.target.y, cam.target.z, cam.fov_deg, passes.c_str(),
        a->reference.c_str());
    // --cache-sim: one line per cache_sim_pass call, numbered in call order, so that pass k is
    // the k-th profile part callgrind writes; "all" is left out and empty classes are skipped.
    if (a->cache_sim) {
      std::printf(
          "| pass | structure | rays | count | hits | steps | leaves | tests | lookups |\n");
      std::printf("|---:|---|---|---:|---:|---:|---:|---:|---:|\n");
    } else {
      std::printf(
          "| structure | rays | count | cold ns/ray | warm ns/ray | steps | leaves | tests | "
          "lookups |\n");
      std::printf("|---|---|---:|---:|---:|---:|---:|---:|---:|\n");
    }
    auto counters = [](const ProfileFigures& f) {
      char buf[96] = "n/a | n/a | n/a | n/a";
      if (f.counted)
        std::snprintf(buf, sizeof buf, "%.2f | %.2f | %.2f | %.2f", f.steps, f.leaves, f.tests,
                      f.lookups);
      return std::string(buf);
    };
    int pass = 0;
    for (const std::string& name : names) {
      const auto acc = build_interruptible(name, scene.mesh, params);
      const std::pair<const char*, const std::vector<Ray>*> sets[] = {{"all", &rays},
                                                                      {"hit", &cls.hit},
                                                                      {"miss-box", &cls.miss_box},
                                                                      {"miss-out", &cls.miss_out}};
      for (const auto& [label, set] : sets) {
        if (a->cache_sim) {
          if (set == &rays || set->empty()) continue;
          const uint64_t hits = cache_sim_pass(*acc, *set);
          ProfileFigures f;
          count_rays(*acc, *set, f);
          std::printf("| %d | %s | %s | %llu | %llu | %s |\n", ++pass, name.c_str(), label,
                      (unsigned long long)f.rays, (unsigned long long)hits, counters(f).c_str());
        } else {
          const ProfileFigures f = profile_rays(*acc, *set, a->reps);
          if (f.rays == 0)
            std::printf("| %s | %s | 0 | - | - | - | - | - | - |\n", name.c_str(), label);
          else
            std::printf("| %s | %s | %llu | %.1f | %.1f | %s |\n", name.c_str(), label,
                        (unsigned long long)f.rays, f.cold_ns, f.warm_ns, counters(f).c_str());
        }
        std::fflush(stdout);
      }
    }
  });
}

}  // namespace kdgrid::cli
