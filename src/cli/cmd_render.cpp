// `kdgrid render SCENE -o OUT.png|OUT.exr`: headless progressive rendering.
#include <tbb/global_control.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <optional>

#include "accel/accelerator.h"
#include "cli/commands.h"
#include "cli/common.h"
#include "render/image_io.h"
#include "render/renderer.h"
#include "scene/load.h"
#include "util/error.h"
#include "util/paths.h"

namespace kdgrid::cli {

namespace {

// Set by SIGINT while passes run; the renderer polls it between tiles. A lock-free atomic
// is async-signal-safe to store to.
std::atomic<bool> g_interrupted{false};
static_assert(std::atomic<bool>::is_always_lock_free);

extern "C" void on_sigint(int) {
  g_interrupted.store(true);
}

struct RenderArgs {
  std::string scene, output;
  AccelOptions accel;
  CameraOptions camera;
  int spp = 16;
  std::string res = "640x480";
  int threads = 0;
  int max_depth = 5;
  uint64_t seed = 1;
  std::string heatmap;
};

/// Throws ParamError unless the directory `path` will be written into exists and is writable.
void check_output_directory(const std::string& path) {
  namespace fs = std::filesystem;
  fs::path dir = fs::path(path).parent_path();
  if (dir.empty()) dir = ".";
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw ParamError(path + ": output directory '" + dir.string() +
                     "' does not exist; create it first (mkdir -p " + dir.string() + ")");
  if (::access(dir.c_str(), W_OK) != 0)
    throw ParamError(path + ": output directory '" + dir.string() + "' is not writable");
}

/// Heat maps as PNG: counts / max through a blue-cyan-green-yellow-red ramp (EXR keeps raw
/// counts, which is what comparisons want).
void heat_ramp(std::vector<float>& rgb) {
  float peak = 0.0f;
  for (size_t i = 0; i < rgb.size(); i += 3) peak = std::max(peak, rgb[i]);
  if (peak <= 0.0f) return;
  static const float stops[5][3] = {
      {0, 0, 0.5f}, {0, 0.7f, 1}, {0.1f, 0.9f, 0.1f}, {1, 0.9f, 0}, {1, 0, 0}};
  for (size_t i = 0; i < rgb.size(); i += 3) {
    const float x = std::min(1.0f, rgb[i] / peak) * 4.0f;
    const int k = std::min(3, int(x));
    const float f = x - float(k);
    for (int c = 0; c < 3; ++c) rgb[i + c] = stops[k][c] * (1 - f) + stops[k + 1][c] * f;
  }
}

std::string mega(uint64_t n) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2fM", double(n) / 1e6);
  return buf;
}

void run_render(const RenderArgs& a) {
  // ---- validate everything before any expensive work ----
  if (a.spp < 1)
    throw ParamError("--spp " + std::to_string(a.spp) + ": samples per pixel must be >= 1");
  if (a.threads < 0) throw ParamError("--threads must be >= 0 (0 = all cores)");
  if (a.max_depth < 0) throw ParamError("--max-depth must be >= 0");
  RenderSettings settings;
  parse_resolution(a.res, settings.width, settings.height);
  check_image_extension(a.output);
  check_output_directory(a.output);
  const BuildParams params = a.accel.resolve();
  make_accelerator(a.accel.accel);  // an unknown --accel fails here, before the scene loads
  settings.max_depth = a.max_depth;
  settings.seed = a.seed;
  if (a.heatmap == "steps")
    settings.mode = RenderMode::HeatSteps;
  else if (a.heatmap == "tests")
    settings.mode = RenderMode::HeatTests;
  else if (!a.heatmap.empty())
    throw ParamError("--heatmap '" + a.heatmap + "': choose steps or tests");

  std::optional<tbb::global_control> threads;
  if (a.threads > 0)
    threads.emplace(tbb::global_control::max_allowed_parallelism, size_t(a.threads));

  const std::string scene_path = resolve_scene_path(a.scene);
  const Scene scene = load_scene(scene_path);
  const auto accel = build_accelerator(a.accel.accel, scene.mesh, params);
  const double build_seconds = accel->stats().seconds;

  Renderer renderer(scene, *accel, settings);
  renderer.set_camera(a.camera.apply(*scene.camera));

  // ---- progressive passes, interruptible by Ctrl-C ----
  g_interrupted.store(false);
  auto old_handler = std::signal(SIGINT, on_sigint);
  const bool tty = ::isatty(STDERR_FILENO);
  const auto t0 = std::chrono::steady_clock::now();
  auto elapsed = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  };
  auto progress = [&](int done) {
    constexpr int kBar = 30;
    const int filled = done * kBar / a.spp;
    std::fprintf(stderr, "\r[%.*s%*s] %d/%d spp  %.1f s", filled,
                 "==============================", kBar - filled, "", done, a.spp, elapsed());
    std::fflush(stderr);
  };
  bool interrupted = false;
  for (int pass = 0; pass < a.spp; ++pass) {
    if (tty) progress(pass);
    if (!renderer.render_pass(&g_interrupted)) {
      interrupted = true;
      break;
    }
  }
  std::signal(SIGINT, old_handler == SIG_ERR ? SIG_DFL : old_handler);
  interrupted = interrupted || g_interrupted.load();
  progress(renderer.samples());
  std::fprintf(stderr, "\n");

  const RenderCounters& c = renderer.counters();
  if (renderer.samples() == 0) {
    std::fprintf(stderr, "kdgrid: interrupted before the first pass finished; no image written\n");
    throw CLI::RuntimeError(130);
  }
  std::vector<float> rgb;
  renderer.resolve(rgb);
  std::string ext = std::filesystem::path(a.output).extension().string();
  for (char& ch : ext) ch = char(std::tolower(static_cast<unsigned char>(ch)));
  if (settings.mode != RenderMode::Shaded && ext != ".exr") heat_ramp(rgb);
  char secs[32];
  std::snprintf(secs, sizeof secs, "%.3f", renderer.seconds());
  char bsecs[32];
  std::snprintf(bsecs, sizeof bsecs, "%.3f", build_seconds);
  write_image(a.output, settings.width, settings.height, rgb,
              {{"samples", std::to_string(renderer.samples())},
               {"seconds", secs},
               {"accelerator", accel->name()},
               {"build_seconds", bsecs},
               {"scene", scene_path},
               {"seed", std::to_string(settings.seed)},
               {"max_depth", std::to_string(settings.max_depth)},
               {"mode", a.heatmap.empty() ? "shaded" : "heatmap-" + a.heatmap},
               {"rays", std::to_string(c.total())}});

  const double mrays = renderer.seconds() > 0 ? double(c.total()) / renderer.seconds() / 1e6 : 0.0;
  std::printf(
      "%s: %dx%d, %d spp, %.3f s, rays %s (primary %s, shadow %s, reflection %s, "
      "refraction %s), %.3g Mrays/s, %s build %.3f s\n",
      a.output.c_str(), settings.width, settings.height, renderer.samples(), renderer.seconds(),
      mega(c.total()).c_str(), mega(c.primary).c_str(), mega(c.shadow).c_str(),
      mega(c.reflection).c_str(), mega(c.refraction).c_str(), mrays, accel->name().c_str(),
      build_seconds);
  std::fflush(stdout);
  if (interrupted) {
    std::fprintf(stderr, "kdgrid: interrupted: wrote the %d of %d samples finished to %s\n",
                 renderer.samples(), a.spp, a.output.c_str());
    throw CLI::RuntimeError(130);
  }
}

}  // namespace

void add_render_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("render", "Render a scene to an image (.png or .exr)");
  auto a = std::make_shared<RenderArgs>();
  cmd->add_option("scene", a->scene, "Scene file (.gltf .glb .ply .obj)")->required();
  cmd->add_option("-o,--output", a->output,
                  "Output image: .png (sRGB 8-bit) or .exr (linear float)")
      ->required();
  cmd->add_option("--spp", a->spp, "Samples (progressive passes) per pixel, >= 1")
      ->capture_default_str();
  cmd->add_option("--res", a->res, "Resolution W or WxH")->capture_default_str();
  cmd->add_option("--threads", a->threads, "Worker threads (0 = all cores)")->capture_default_str();
  cmd->add_option("--max-depth", a->max_depth,
                  "Reflection/refraction bounces after the primary hit")
      ->capture_default_str();
  cmd->add_option("--seed", a->seed, "Sample pattern seed")->capture_default_str();
  cmd->add_option("--heatmap", a->heatmap,
                  "Render traversal cost of primary rays instead: steps or tests (PNG: colour "
                  "ramp scaled to the maximum; EXR: raw counts)");
  a->accel.add_to(cmd, "bvh");
  a->camera.add_to(cmd);
  cmd->callback([a] { run_render(*a); });
}

}  // namespace kdgrid::cli
