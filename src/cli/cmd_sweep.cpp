// `kdgrid sweep KIND [SCENE]`: vary one knob and measure speed against accuracy or memory
// (bench/sweep.h). Writes the table as CSV and JSON (--out FILE.csv or FILE.json writes both,
// same stem); without --out the CSV goes to stdout. Progress goes to stderr.
#include <cstdio>
#include <filesystem>
#include <sstream>

#include "bench/sweep.h"
#include "cli/commands.h"
#include "cli/common.h"
#include "util/atomic_file.h"
#include "util/error.h"

namespace kdgrid::cli {

namespace {

struct SweepArgs {
  std::string kind, scene, out, values, accel;
  int threads = 0, reps = 3;
  std::string res;
  int spp_max = 64, spp_reference = 256;
  bool quiet = false;
  AccelOptions knobs;
  CameraOptions camera;
};

void write_text(const std::filesystem::path& p, const std::string& text) {
  std::error_code ec;
  if (p.has_parent_path()) std::filesystem::create_directories(p.parent_path(), ec);
  write_file_atomically(p.string(), text);
}

}  // namespace

void add_sweep_command(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "sweep",
      "Vary one knob and measure: cellsize (hybrid), lambda (grid), kdcost (kd-tree), triangle "
      "(watertight vs Moller: speed and leaks), scale (the scene scaled by 10^-20 .. 10^16: "
      "image difference from scale 1 and speed per structure), spp (render samples vs RMSE vs "
      "time)");
  auto a = std::make_shared<SweepArgs>();
  cmd->add_option("kind", a->kind, "cellsize, lambda, kdcost, triangle, scale or spp")->required();
  cmd->add_option("scene", a->scene,
                  "Scene file (spp: default assets/cornell.gltf; triangle: optional, for speed)");
  cmd->add_option("--out,-o", a->out, "Write FILE.csv and FILE.json (either extension given)");
  cmd->add_option("--values", a->values,
                  "Comma-separated values of the knob (cellsize: multiples of the auto size; "
                  "scale: factors, e.g. 1e-6,1,1e6; spp: sample counts)");
  cmd->add_option(
      "--structures", a->accel,
      "triangle: comma-separated structures (default all but brute and Embree's configurations); "
      "scale: the structures (default bvh,hybrid); spp: the renderer's structure (default bvh)");
  add_threads_option(cmd, a->threads);
  cmd->add_option("--reps", a->reps, "Timed repetitions per row (median reported)")
      ->capture_default_str();
  cmd->add_option("--res", a->res,
                  "Primary rays / spp image size: W or WxH (default 512; spp 200; scale 128)");
  cmd->add_option("--spp-max", a->spp_max, "spp: largest sample count (powers of two from 1)")
      ->capture_default_str();
  cmd->add_option("--spp-reference", a->spp_reference, "spp: samples of the reference image")
      ->capture_default_str();
  cmd->add_flag("--quiet,-q", a->quiet, "No progress on stderr");
  a->knobs.add_to(cmd, "");
  cmd->get_option("--accel")->description("Unused by sweeps (see --structures)");
  a->camera.add_to(cmd);
  cmd->callback([a] {
    SweepOptions o;
    o.kind = a->kind;
    o.scene = a->scene;
    o.threads = a->threads;
    o.reps = a->reps;
    o.spp_max = a->spp_max;
    o.spp_reference = a->spp_reference;
    if (!a->res.empty()) parse_resolution(a->res, o.width, o.height);
    o.params = a->knobs.resolve();
    if (a->camera.any()) {
      if (a->camera.eye.empty() || a->camera.target.empty())
        throw ParamError("sweep camera: give both --eye and --target (and optionally --fov)");
      o.camera = a->camera.apply(Camera{});
    }
    std::stringstream ss(a->values);
    std::string item;
    while (std::getline(ss, item, ',')) {
      if (item.empty()) continue;
      char* end = nullptr;
      const double v = std::strtod(item.c_str(), &end);
      if (end == item.c_str() || *end != '\0')
        throw ParamError("--values: '" + item + "' is not a number");
      o.values.push_back(v);
    }
    std::stringstream as(a->accel);
    while (std::getline(as, item, ','))
      if (!item.empty()) o.accels.push_back(item);
    if (!a->quiet)
      o.progress = [](const std::string& s) { std::fprintf(stderr, "%s\n", s.c_str()); };

    // The outputs are checked before the sweep runs, not after it.
    std::filesystem::path base(a->out);
    if (base.extension() == ".csv" || base.extension() == ".json") base.replace_extension();
    if (!a->out.empty()) {
      std::error_code ec;
      if (base.has_parent_path()) std::filesystem::create_directories(base.parent_path(), ec);
      check_output_path(base.string() + ".csv", "--out", {".csv"}, {a->scene});
      check_output_path(base.string() + ".json", "--out", {".json"}, {a->scene});
    }
    const SweepTable t = run_sweep(o);
    if (a->out.empty()) {
      std::printf("%s", sweep_to_csv(t).c_str());
      return;
    }
    write_text(base.string() + ".csv", sweep_to_csv(t));
    write_text(base.string() + ".json", sweep_to_json(t));
    if (!a->quiet) std::fprintf(stderr, "wrote %s.csv and %s.json\n", base.c_str(), base.c_str());
  });
}

}  // namespace kdgrid::cli
