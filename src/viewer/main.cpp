// `kdgrid-viewer`: interactive viewer and debugger for kdgrid's acceleration structures.
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>
#include <vector>

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <tbb/global_control.h>
#include <CLI/CLI.hpp>
#include <memory>

#include "accel/accelerator.h"
#include "image/image_io.h"
#include "render/renderer.h"
#include "util/atomic_file.h"
#include "util/error.h"
#include "util/paths.h"
#include "viewer/viewer.h"

using kdgrid::viewer::ViewerOptions;

namespace {

/// Exit code for "no display / no OpenGL": the caller should render headless instead.
constexpr int kExitNoDisplay = 3;

void glfw_error(int code, const char* description) {
  std::fprintf(stderr, "kdgrid-viewer: GLFW error 0x%x: %s\n", code, description);
}

void print_no_display(const char* why) {
  std::fprintf(stderr,
               "kdgrid-viewer: cannot open a window: %s.\n"
               "  The viewer needs a display (X11 or Wayland). Without one, render to a file:\n"
               "    kdgrid render SCENE -o out.png\n"
               "  or run the viewer under a virtual display:\n"
               "    xvfb-run -a kdgrid-viewer SCENE --frames 10 --screenshot out.png\n",
               why);
}

bool env_set(const char* name) {
  const char* v = std::getenv(name);
  return v && *v;
}

/// An option whose value is one of `choices`; --help shows its default.
CLI::Option* add_choice(CLI::App& app, const std::string& name, std::string& value,
                        const std::string& help, const std::vector<std::string>& choices,
                        const std::string& group) {
  return app.add_option(name, value, help)
      ->group(group)
      ->check(CLI::IsMember(choices))
      ->capture_default_str();
}

/// The Window group: size, resolution, samples, threads.
void add_window_options(CLI::App& app, ViewerOptions& o, int& threads) {
  const std::string gw = "Window";
  app.add_option("--width", o.width,
                 "Window width in screen units (default: remembered, else 1280)")
      ->group(gw)
      ->check(CLI::Range(64, 16384));
  app.add_option("--height", o.height,
                 "Window height in screen units (default: remembered, else 800)")
      ->group(gw)
      ->check(CLI::Range(64, 16384));
  app.add_option("--resolution-scale", o.resolution_scale,
                 "Render pixels per framebuffer pixel (0.1-1)")
      ->group(gw)
      ->check(CLI::Range(0.1f, 1.0f))
      ->capture_default_str();
  app.add_option("--max-samples", o.max_samples, "Stop refining at this many samples per pixel")
      ->group(gw)
      ->check(CLI::Range(1, kdgrid::kMaxSamplesPerPixel))
      ->capture_default_str();
  app.add_option("--threads", threads,
                 "Threads for rendering and builds; 0 = all. 1 runs everything on the calling "
                 "threads, which ThreadSanitizer can follow (libtbb itself is not instrumented)")
      ->group(gw)
      ->capture_default_str();
}

/// The scripted runs' group (tests, reports); --pick is parsed by check_options.
void add_scripted_options(CLI::App& app, ViewerOptions& o, std::string& pick) {
  const std::string gs = "Scripted runs (tests, reports)";
  app.add_option("--frames", o.frames, "Run at least N frames, then write --screenshot and exit 0")
      ->group(gs)
      ->check(CLI::Range(1, 1 << 30));
  app.add_option("--screenshot", o.screenshot,
                 "PNG of the window (image, overlays, panels) at the end")
      ->group(gs);
  app.add_option("--min-samples", o.min_samples, "Scripted: wait for this many samples per pixel")
      ->group(gs)
      ->check(CLI::Range(1, kdgrid::kMaxSamplesPerPixel))
      ->capture_default_str();
  app.add_option("--timeout", o.timeout,
                 "Scripted: give up with exit code 4 after this many seconds")
      ->group(gs)
      ->capture_default_str();
  app.add_option("--pick", pick, "Trace image pixel X,Y (0,0 = top left) and show its traversal")
      ->group(gs);
  app.add_option("--pick-ray", o.pick_ray,
                 "Scripted: after --pick, show ray N of the pixel's ray tree (0 = the primary; "
                 "--stats-json lists the tree as state.pick.tree)")
      ->group(gs)
      ->check(CLI::Range(0, 1 << 20));
  app.add_flag("--frame-pick", o.frame_pick,
               "Scripted: after --pick, frame its ray's traversal as the F key does")
      ->group(gs);
  app.add_flag("--splits-of-pick", o.splits_of_pick,
               "Split overlay: only the planes the picked ray crossed (with --overlay splits)")
      ->group(gs);
  add_choice(app, "--heatmap", o.heatmap,
             "Show per-pixel traversal steps, triangle tests or time (nanoseconds of the "
             "primary ray's query)",
             {"steps", "tests", "time"}, gs);
  add_choice(app, "--shading", o.shading,
             "How the shaded picture is lit: auto (the scene's lights, or the eye light when "
             "they leave the view dark), lights, eye (a light at the eye) or normals",
             {"auto", "lights", "eye", "normals"}, gs);
  add_choice(app, "--offset", o.offset,
             "Where secondary rays start on the surface they leave: robust (moved off it), "
             "epsilon (skip hits nearer than 1e-4) or none (at the hit point)",
             {"robust", "epsilon", "none"}, gs);
  app.add_option("--overlay", o.overlays, "Overlay: splits, cells or boxes (repeatable)")
      ->group(gs)
      ->check(CLI::IsMember({"splits", "cells", "boxes"}));
  app.add_option(
         "--rebuild-cell-size", o.rebuild_cell_size,
         "After start-up, rebuild live with this cell size ('auto' or a size) and wait for it")
      ->group(gs);
  app.add_option("--supersede-cell-size", o.supersede_cell_size,
                 "Scripted: while the --rebuild-cell-size build runs, request this cell size "
                 "('auto', '0.5x' or a size) the way the panel's cell-size box does, "
                 "--supersede-after seconds into it; the newer request cancels the running build")
      ->group(gs);
  app.add_option("--supersede-after", o.supersede_after,
                 "Scripted: seconds into the --rebuild-cell-size build at which "
                 "--supersede-cell-size is requested")
      ->group(gs)
      ->check(CLI::Range(0.0, 3600.0))
      ->capture_default_str();
  app.add_option(
         "--export-heatmap", o.export_heatmap,
         "Scripted: write the heat map's raw per-pixel counts to this EXR (needs --heatmap)")
      ->group(gs);
  app.add_flag("--pin-heatmap", o.pin_heatmap,
               "Scripted: pin the first complete heat map (needs --heatmap), before "
               "--rebuild-cell-size starts, so the end shows the difference")
      ->group(gs);
  app.add_option("--diff-exr", o.diff_exr,
                 "Scripted: at the end write the difference with the pinned heat map as EXR: "
                 "R = current - pinned, G = current, B = pinned (needs --pin-heatmap)")
      ->group(gs);
  add_choice(app, "--diff-view", o.diff_view,
             "With a pinned heat map, show the current map, the pinned one, their "
             "difference or both side by side",
             {"current", "pinned", "difference", "split"}, gs);
  app.add_flag("--accuracy", o.accuracy,
               "Show the accuracy map (every pixel's ray tree against a double-precision "
               "reference); a scripted run waits until every pixel is judged")
      ->group(gs);
  app.add_flag("--hide-ui", o.hide_ui, "Hide the ImGui panels (reproducible screenshots)")
      ->group(gs);
  app.add_option("--hold", o.hold,
                 "Keep the window open and interactive for up to this many seconds (for input "
                 "driven by xdotool); Ctrl+Q or closing the window ends it sooner. Then finish "
                 "the image and write --screenshot / --stats-json")
      ->group(gs)
      ->check(CLI::Range(0.001, 86400.0));
  app.add_option(
         "--stats-json", o.stats_json,
         "Write the run's statistics (every frame, pass and build; window, framebuffer, "
         "content scale) and its final state (scene, camera, mode, speed, pick) as JSON at exit")
      ->group(gs);
  app.add_option("--drop", o.drop,
                 "Once the first image is shown, load this file through the drag-and-drop handler")
      ->group(gs);
  app.add_option("--max-fps", o.max_fps,
                 "Scripted runs: frames per second cap (they swap without vsync); 0 = unlimited")
      ->group(gs)
      ->check(CLI::Range(0, 1000))
      ->capture_default_str();
}

/// Checks what can be checked before a window opens (a ParamError says what is wrong) and
/// fills in what the parse leaves: the default scene, the --pick pixel.
void check_options(ViewerOptions& o, const std::string& pick, int threads) {
  if (o.scene.empty()) o.scene = kdgrid::find_asset("cornell.gltf");
  if (o.scene.empty())
    throw kdgrid::ParamError(
        "no scene given and assets/cornell.gltf was found neither under "
        "the current directory nor beside the executable: give a scene file");
  o.scene = kdgrid::resolve_scene_path(o.scene);
  // Validate everything that can be validated before a window opens.
  (void)o.accel.resolve();
  if (o.accel_given) (void)kdgrid::make_accelerator(o.accel.accel);
  if (!o.rebuild_cell_size.empty()) (void)kdgrid::cli::parse_cell_size(o.rebuild_cell_size);
  if (!o.supersede_cell_size.empty()) {
    if (o.rebuild_cell_size.empty())
      throw kdgrid::ParamError(
          "--supersede-cell-size supersedes the --rebuild-cell-size build: give "
          "--rebuild-cell-size too");
    (void)kdgrid::viewer::CellChoice::parse(o.supersede_cell_size, "--supersede-cell-size");
  }
  if (!pick.empty()) {
    int x = 0, y = 0;
    char extra = 0;
    if (std::sscanf(pick.c_str(), "%d,%d%c", &x, &y, &extra) != 2 || x < 0 || y < 0)
      throw kdgrid::ParamError("--pick '" + pick +
                               "' must be X,Y image pixel coordinates, e.g. 320,240");
    o.pick = std::array<int, 2>{x, y};
  }
  kdgrid::check_threads(threads);
  if (o.pick_ray > 0 && !o.pick)
    throw kdgrid::ParamError("--pick-ray selects a ray of the --pick X,Y pixel: give --pick too");
  if (o.frame_pick && !o.pick)
    throw kdgrid::ParamError("--frame-pick frames the --pick X,Y ray: give --pick too");
  if (o.frames > 0 && o.hold > 0)
    throw kdgrid::ParamError("--frames and --hold both end a scripted run; give one of them");
  if (!o.screenshot.empty() && !o.scripted())
    throw kdgrid::ParamError(
        "--screenshot needs --frames N (the number of frames to run first) or --hold SECONDS");
  if (!o.export_heatmap.empty() && (o.heatmap.empty() || !o.scripted()))
    throw kdgrid::ParamError("--export-heatmap needs --heatmap steps|tests and --frames N");
  // The outputs are checked before the window opens, as the CLI checks its own: a missing
  // folder, a name the file system refuses or a device (written through the atomic writer,
  // /dev/null would be replaced) fails now, not after the frames.
  if (!o.export_heatmap.empty())
    kdgrid::check_output_path(o.export_heatmap, "--export-heatmap", {".png", ".exr"}, {o.scene});
  if (!o.screenshot.empty())
    kdgrid::check_output_path(o.screenshot, "--screenshot", {".png"}, {o.scene});
  if (!o.stats_json.empty())
    kdgrid::check_output_path(o.stats_json, "--stats-json", {".json"}, {o.scene});
  if (o.pin_heatmap && (o.heatmap.empty() || !o.scripted()))
    throw kdgrid::ParamError(
        "--pin-heatmap pins a heat map: give --heatmap steps|tests and "
        "--frames N");
  if (!o.diff_exr.empty() && !o.pin_heatmap)
    throw kdgrid::ParamError(
        "--diff-exr writes the difference with the pinned heat map: give "
        "--pin-heatmap (and --rebuild-cell-size or another change)");
  if (!o.diff_exr.empty()) kdgrid::check_image_extension(o.diff_exr);
  if (!o.screenshot.empty() || !o.export_heatmap.empty() || !o.diff_exr.empty())
    kdgrid::require_image_module();
  if (o.max_samples < o.min_samples) o.max_samples = o.min_samples;
}

}  // namespace

int main(int argc, char** argv) {
  ViewerOptions o;
  CLI::App app{
      "kdgrid-viewer: interactive viewer and debugger for kdgrid's acceleration structures"};
  app.add_option("scene", o.scene,
                 "Scene file (.gltf .glb .ply .obj); default assets/cornell.gltf");
  o.accel.add_to(&app);
  o.camera.add_to(&app);
  int threads = 0;
  std::string pick;
  add_window_options(app, o, threads);
  add_scripted_options(app, o, pick);

  try {
    app.parse(argc, argv);
    o.accel_given = app.get_option("--accel")->count() > 0;
    o.cell_size_given = app.get_option("--cell-size")->count() > 0;
    check_options(o, pick, threads);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const kdgrid::Error& e) {
    std::fprintf(stderr, "kdgrid-viewer: error: %s\n", e.what());
    return 2;
  }

  o.threads = threads;
  std::unique_ptr<tbb::global_control> thread_limit;
  if (threads > 0)
    thread_limit = std::make_unique<tbb::global_control>(
        tbb::global_control::max_allowed_parallelism, size_t(threads));
  glfwSetErrorCallback(glfw_error);
  if (!env_set("DISPLAY") && !env_set("WAYLAND_DISPLAY")) {
    print_no_display("neither DISPLAY nor WAYLAND_DISPLAY is set");
    return kExitNoDisplay;
  }
  if (!glfwInit()) {
    print_no_display("GLFW could not initialise (see the GLFW error above)");
    return kExitNoDisplay;
  }
  int code = 0;
  try {
    kdgrid::viewer::Viewer v(std::move(o));
    code = v.run();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "kdgrid-viewer: error: %s\n", e.what());
    code = 1;
  }
  glfwTerminate();
  return code;
}
