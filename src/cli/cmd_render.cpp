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

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "accel/guards.h"
#include "bench/bench.h"
#include "cli/commands.h"
#include "cli/common.h"
#include "image/image_io.h"
#include "render/renderer.h"
#include "scene/load.h"
#include "util/atomic_file.h"
#include "util/enum_names.h"
#include "util/error.h"
#include "util/format.h"
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
  std::string shading = "lights";
  std::string stats_json;
  bool no_packets = false;
  double scale = 1.0;
};

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

/// The render's settings from the flags, every one validated before any expensive work.
RenderSettings render_settings(const RenderArgs& a) {
  if (a.spp < 1 || a.spp > kMaxSamplesPerPixel)
    throw ParamError("--spp " + std::to_string(a.spp) +
                     ": samples per pixel must be between 1 and " +
                     std::to_string(kMaxSamplesPerPixel));
  check_threads(a.threads);
  if (a.max_depth < 0 || a.max_depth > kMaxRenderDepth)
    throw ParamError("--max-depth " + std::to_string(a.max_depth) + " must be between 0 and " +
                     std::to_string(kMaxRenderDepth) +
                     " bounces (docs/LIMITS.md: deeper Whitted paths fade below 1e-4)");
  RenderSettings settings;
  parse_resolution(a.res, settings.width, settings.height);
  settings.max_depth = a.max_depth;
  settings.seed = a.seed;
  settings.packets = !a.no_packets;
  static constexpr EnumName<RenderMode> kHeatmaps[] = {{RenderMode::HeatSteps, "steps"},
                                                       {RenderMode::HeatTests, "tests"},
                                                       {RenderMode::HeatTime, "time"}};
  if (!a.heatmap.empty())
    settings.mode = parse_enum(a.heatmap, kHeatmaps, "--heatmap", "choose steps, tests or time");
  settings.shading = parse_shading(a.shading, "--shading");
  return settings;
}

/// Process memory by phase for --stats-json: the load's peak, then the build's own peak (the
/// high-water mark is reset first where the kernel allows).
struct MemoryPhases {
  uint64_t load_peak = 0, rss_before_build = 0, build_peak = 0, rss_after_build = 0;
  bool phase_peaks = false;  ///< the build's peak is its own (the reset worked)
};

/// Renders up to `spp` progressive passes with a progress bar on a terminal; Ctrl-C stops
/// between passes and keeps the finished ones. Returns true if interrupted.
bool render_passes(Renderer& renderer, int spp) {
  g_interrupted.store(false);
  auto old_handler = std::signal(SIGINT, on_sigint);
  const bool tty = ::isatty(STDERR_FILENO);
  const auto t0 = std::chrono::steady_clock::now();
  auto progress = [&](int done) {
    constexpr int kBar = 30;
    const int filled = done * kBar / spp;
    const double elapsed =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::fprintf(stderr, "\r[%.*s%*s] %d/%d spp  %.1f s", filled,
                 "==============================", kBar - filled, "", done, spp, elapsed);
    std::fflush(stderr);
  };
  bool interrupted = false;
  for (int pass = 0; pass < spp; ++pass) {
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
  return interrupted;
}

/// Writes the image (heat maps as a colour ramp, but raw counts in EXR) with its metadata.
void write_render_image(const RenderArgs& a, const std::string& scene_path,
                        const Renderer& renderer, const Accelerator& accel) {
  const RenderSettings& settings = renderer.settings();
  std::vector<float> rgb;
  renderer.resolve(rgb);
  std::string ext = std::filesystem::path(a.output).extension().string();
  for (char& ch : ext) ch = char(std::tolower(static_cast<unsigned char>(ch)));
  if (settings.mode != RenderMode::Shaded && ext != ".exr") heat_ramp(rgb);
  write_image(a.output, settings.width, settings.height, rgb,
              {{"samples", std::to_string(renderer.samples())},
               {"seconds", format_double("%.3f", renderer.seconds())},
               {"accelerator", accel.name()},
               {"build_seconds", format_double("%.3f", accel.stats().seconds)},
               {"scene", scene_path},
               {"seed", std::to_string(settings.seed)},
               {"max_depth", std::to_string(settings.max_depth)},
               {"mode", a.heatmap.empty() ? "shaded" : "heatmap-" + a.heatmap},
               {"shading", to_string(settings.shading)},
               {"rays", std::to_string(renderer.counters().total())}});
}

/// The --stats-json file: the scene, the build and its memory by phase, the render's figures.
void write_render_stats(const RenderArgs& a, const std::string& scene_path, const Scene& scene,
                        const Renderer& renderer, const Accelerator& accel,
                        const BuildParams& params, const MemoryPhases& mem, bool interrupted) {
  const BuildStats& st = accel.stats();
  const RenderCounters& c = renderer.counters();
  const RenderSettings& settings = renderer.settings();
  nlohmann::json j;
  j["scene"] = scene_path;
  j["triangles"] = scene.mesh.num_triangles();
  j["vertices"] = scene.mesh.num_vertices();
  j["mesh_bytes"] = scene.mesh.memory_bytes();
  j["accel"] = accel.name();
  j["build_seconds"] = st.seconds;
  j["bytes"] = st.bytes;
  j["peak_estimate_bytes"] = st.peak_estimate;
  nlohmann::json parts = nlohmann::json::object();
  for (const auto& [k, v] : st.bytes_by_part) parts[k] = v;
  j["bytes_by_part"] = parts;
  nlohmann::json extra = nlohmann::json::object();
  for (const auto& [k, v] : st.extra) extra[k] = v;
  j["extra"] = extra;
  j["memory_budget_bytes"] = effective_memory_budget(params);
  j["rss_load_peak_bytes"] = mem.load_peak;
  j["rss_before_build_bytes"] = mem.rss_before_build;
  j["rss_after_build_bytes"] = mem.rss_after_build;
  // Build peak over the RSS before the build: what the build itself needed at its worst.
  j["rss_build_peak_bytes"] = mem.build_peak;
  j["build_peak_is_phase"] = mem.phase_peaks;
  // After a reset the kernel's counters restart, so the process peak is the larger of the
  // load's peak and what came after.
  j["rss_peak_bytes"] = std::max({mem.load_peak, mem.build_peak, peak_rss_since_reset()});
  j["render_seconds"] = renderer.seconds();
  j["packets"] = settings.packets;
  j["width"] = settings.width;
  j["height"] = settings.height;
  j["spp"] = renderer.samples();
  j["rays"] = c.total();
  j["shading"] = to_string(settings.shading);
  // Primary hits checked for direct light and those a scene light reaches (RenderCounters).
  j["lit_probed"] = c.probed;
  j["lit"] = c.lit;
  j["interrupted"] = interrupted;
  write_file_atomically(a.stats_json, j.dump(2) + "\n");
}

void run_render(const RenderArgs& a) {
  // ---- validate everything before any expensive work ----
  const RenderSettings settings = render_settings(a);
  const std::string scene_path = resolve_scene_path(a.scene);
  check_output_path(a.output, "-o", {".png", ".exr"}, {scene_path});
  const BuildParams params = a.accel.resolve();
  make_accelerator(a.accel.accel);  // an unknown --accel fails here, before the scene loads
  std::optional<tbb::global_control> threads;
  if (a.threads > 0)
    threads.emplace(tbb::global_control::max_allowed_parallelism, size_t(a.threads));
  if (!a.stats_json.empty())
    check_output_path(a.stats_json, "--stats-json", {".json"}, {scene_path, a.output});
  require_image_module();

  const Scene scene = load_scene(scene_path, a.scale);
  // One pass: passes are progressive and Ctrl-C keeps the finished ones, but a single pass
  // of brute force over millions of triangles would look like a hang.
  check_brute_force_work(a.accel.accel, uint64_t(settings.width) * uint64_t(settings.height),
                         scene.mesh.num_triangles(), params);
  MemoryPhases mem;
  mem.load_peak = process_peak_rss_bytes();
  mem.phase_peaks = reset_peak_rss();
  mem.rss_before_build = current_rss_bytes();
  const auto accel = build_interruptible(a.accel.accel, scene.mesh, params);
  mem.build_peak = peak_rss_since_reset();
  mem.rss_after_build = current_rss_bytes();

  Renderer renderer(scene, *accel, settings);
  renderer.set_camera(a.camera.apply(*scene.camera));
  const bool interrupted = render_passes(renderer, a.spp);
  if (renderer.samples() == 0) {
    std::fprintf(stderr, "kdgrid: interrupted before the first pass finished; no image written\n");
    throw CLI::RuntimeError(130);
  }
  write_render_image(a, scene_path, renderer, *accel);

  const RenderCounters& c = renderer.counters();
  const double mrays = renderer.seconds() > 0 ? double(c.total()) / renderer.seconds() / 1e6 : 0.0;
  std::printf(
      "%s: %dx%d, %d spp, %.3f s, rays %s (primary %s, shadow %s, reflection %s, "
      "refraction %s), %.3g Mrays/s, %s build %.3f s\n",
      a.output.c_str(), settings.width, settings.height, renderer.samples(), renderer.seconds(),
      mega(c.total()).c_str(), mega(c.primary).c_str(), mega(c.shadow).c_str(),
      mega(c.reflection).c_str(), mega(c.refraction).c_str(), mrays, accel->name().c_str(),
      accel->stats().seconds);
  std::fflush(stdout);
  if (!a.stats_json.empty())
    write_render_stats(a, scene_path, scene, renderer, *accel, params, mem, interrupted);
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
  add_scene_argument(cmd, a->scene);
  cmd->add_option("-o,--output", a->output,
                  "Output image: .png (sRGB 8-bit) or .exr (linear float)")
      ->required();
  cmd->add_option("--spp", a->spp, "Samples (progressive passes) per pixel, >= 1")
      ->capture_default_str();
  cmd->add_option("--res", a->res, "Resolution W or WxH")->capture_default_str();
  add_threads_option(cmd, a->threads);
  cmd->add_option("--max-depth", a->max_depth,
                  "Reflection/refraction bounces after the primary hit, 0 to " +
                      std::to_string(kMaxRenderDepth))
      ->capture_default_str();
  cmd->add_option("--seed", a->seed, "Sample pattern seed")->capture_default_str();
  add_scale_option(cmd, a->scale);
  cmd->add_option("--heatmap", a->heatmap,
                  "Render traversal cost of primary rays instead: steps, tests or time (ns per "
                  "ray) (PNG: colour "
                  "ramp scaled to the maximum; EXR: raw counts)");
  cmd->add_option("--shading", a->shading,
                  "How surfaces are lit: lights (the scene's lights and shadows), eye (a light "
                  "at the eye, no scene light needed) or normals (the normal as a colour)")
      ->capture_default_str();
  cmd->add_flag("--no-packets", a->no_packets,
                "Trace primary rays and their shadow rays one at a time instead of in "
                "packets of a tile's rays (the same image; for timing the packet queries)");
  cmd->add_option("--stats-json", a->stats_json,
                  "Also write build/render figures and process memory by phase (peak RSS of "
                  "the load and of the build) as JSON here");
  a->accel.add_to(cmd, "bvh");
  a->camera.add_to(cmd);
  cmd->callback([a] { run_render(*a); });
}

}  // namespace kdgrid::cli
