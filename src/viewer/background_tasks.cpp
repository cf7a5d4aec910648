// kdgrid-viewer's background work: a scene load or a structure build runs on a thread of its
// own while the UI thread keeps drawing the old structure; one runs at a time, a newer build
// request cancels a running build, and the result is swapped in whole.
#include "viewer/viewer.h"

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <new>

#include <tbb/global_control.h>

#include "accel/hybrid/hybrid.h"
#include "scene/load.h"
#include "util/format.h"
#include "util/memory.h"
#include "viewer/viewer_internal.h"

namespace kdgrid::viewer {

void wake_ui() {
  glfwPostEmptyEvent();
}

namespace {

/// Threads a background build may use: all but one of those the process may use, so that the
/// render worker keeps a core and the picture follows the camera while a structure builds (a
/// build on every core starves the passes, which then take seconds). At least 1.
int background_build_threads() {
  const int n =
      int(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
  return std::max(1, n - 1);
}

/// The body of a background load or build: builds `name` over `scene` with `params`, polling
/// `cancel` (BuildCancelled when it is set).
std::shared_ptr<World> build_world(std::shared_ptr<const Scene> scene, const std::string& name,
                                   const BuildParams& params, const CancelToken& cancel) {
  auto w = std::make_shared<World>();
  w->scene = std::move(scene);
  w->name = name;
  w->params = params;  // as requested; the token and thread count below belong to this build only
  BuildParams p = params;
  p.cancel = &cancel;
  p.threads = background_build_threads();
  cancel.check();  // cancelled while the scene loaded
  const auto t0 = Clock::now();
  w->accel = build_accelerator(name, w->scene->mesh, p);
  w->build_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return w;
}

}  // namespace

BuildParams Viewer::params_with_cell_size(const std::string& name, float cs) const {
  BuildParams p = params_;
  if (name == "grid" && cs > 0 && world_) {
    // The uniform grid has no cell size knob; pick the density that gives cells of about
    // this edge: cells = volume / cs^3 = lambda * triangles.
    const Vec3 e = scene_bounds_.extent();
    const double v = double(std::max(e.x, cs)) * std::max(e.y, cs) * std::max(e.z, cs);
    const double cells = v / (double(cs) * cs * cs);
    p.grid_lambda =
        float(std::clamp(cells / double(world_->scene->mesh.num_triangles()), 1e-3, 1e3));
  } else {
    p.cell_size = cs;
  }
  return p;
}

void Viewer::start_load(const std::string& path) {
  if (task_) {
    task_error_ = "busy " + task_->what + "; drop the file again when it is done";
    return;
  }
  task_error_.clear();
  const std::string name = accel_name_;
  const BuildParams params = params_;
  // The new scene's own cell size: the command line's for its scene, else the remembered one;
  // a size in scene units never carries over from another scene.
  const bool own = path == opts_.scene && opts_.cell_size_given;
  CellChoice choice = remembered_cell_choice(settings_, path);
  if (own)
    choice = cell_choice_.kind == CellChoice::Kind::Multiple
                 ? cell_choice_
                 : CellChoice::parse(opts_.accel.cell_size, "--cell-size");
  loading_choice_ = choice;
  Task t;
  t.what = "loading " + std::filesystem::path(path).filename().string();
  t.path = path;
  t.kind = "load";
  t.new_scene = true;
  t.started = Clock::now();
  progress_log_.clear();
  t.cancel = std::make_shared<CancelToken>();
  // A size remembered in the settings file suited the scene it was chosen on; one that this
  // scene refuses (too fine a grid for the memory budget, too long a build) falls back to the
  // auto size with a warning naming the file, instead of failing every load.
  const std::string remembered_in = own || name != "hybrid" || choice.kind == CellChoice::Kind::Auto
                                        ? ""
                                        : settings_file(config_dir_);
  t.result = run_in_background([path, name, params, choice, remembered_in, cancel = t.cancel] {
    auto scene = std::make_shared<Scene>(load_scene(path));
    // The hybrid's auto size (the panel's "x auto") is found here, off the UI thread: it
    // sorts every triangle's extent.
    BuildParams a = params;
    a.cell_size = 0.0f;
    const double auto_cell = GridKdHybrid::estimate(scene->mesh, a).auto_cell;
    BuildParams p = params;
    p.cell_size = choice.resolve(choice.kind == CellChoice::Kind::Multiple ? auto_cell : 0.0);
    std::shared_ptr<World> w;
    try {
      w = build_world(scene, name, p, *cancel);
    } catch (const ParamError& e) {
      if (remembered_in.empty() || p.cell_size <= 0.0f) throw;
      std::fprintf(stderr,
                   "kdgrid-viewer: %s: the remembered cell size %s does not suit %s (%s); built "
                   "with the auto size instead\n",
                   remembered_in.c_str(), choice.text().c_str(),
                   std::filesystem::path(path).filename().c_str(), e.what());
      p.cell_size = 0.0f;
      w = build_world(std::move(scene), name, p, *cancel);
    }
    w->auto_cell = auto_cell;
    return w;
  });
  task_ = std::move(t);
}

void Viewer::start_build(const std::string& name, const BuildParams& params) {
  if (!world_) return;
  if (task_) {
    // The newest request wins: a running build stops (its old structure keeps rendering)
    // and this one starts when it has; a load of a new scene runs to its end first.
    if (!task_->new_scene) cancel_task();
    pending_build_ = {name, params};
    return;
  }
  task_error_.clear();
  std::shared_ptr<const Scene> scene = world_->scene;
  Task t;
  t.what = "building " + name;
  t.kind = name == accel_name_ ? "rebuild" : "build";
  t.expected_seconds = expected_build_seconds(name, params);
  t.started = Clock::now();
  progress_log_.clear();
  t.cancel = std::make_shared<CancelToken>();
  t.result = run_in_background([scene, name, params, cancel = t.cancel] {
    return build_world(scene, name, params, *cancel);
  });
  task_ = std::move(t);
}

double Viewer::expected_build_seconds(const std::string& name, const BuildParams& params) const {
  if (name == "hybrid") {
    // The estimate the panel showed, on the threads the background build gets.
    BuildParams p = params;
    p.threads = background_build_threads();
    try {
      return GridKdHybrid::estimate(world_->scene->mesh, p).seconds;
    } catch (const std::exception&) {
      return 0;
    }
  }
  // Another structure: as long as its last build on this scene took.
  for (auto it = builds_.rbegin(); it != builds_.rend(); ++it)
    if (it->accel == name && it->scene == world_->scene->source && it->error.empty())
      return it->build_seconds;
  return 0;
}

double Viewer::task_progress(double seconds, double expected) {
  // Linear up to 80% of the expected time, then easing towards 1 (same slope at 80%), so that
  // a build that takes longer than expected slows the bar down but never moves it back.
  if (expected <= 0) expected = 3.0;  // unknown: a few seconds
  const double p = seconds / expected;
  return p < 0.8 ? p : 0.8 + 0.2 * (1.0 - std::exp(-(p - 0.8) / 0.2));
}

void Viewer::cancel_task() {
  if (!task_ || task_->cancel->cancelled()) return;
  task_->cancel->cancel();
  task_->cancelled_at = Clock::now();
  pending_build_.reset();
}

void Viewer::poll_tasks() {
  if (!task_ || !task_->result.ready()) return;
  const bool new_scene = task_->new_scene;
  const bool was_scripted_rebuild =
      scripted_rebuild_started_ && !scripted_rebuild_done_ && !new_scene;
  BuildRecord rec;
  rec.kind = task_->kind;
  rec.wall_seconds = std::chrono::duration<double>(Clock::now() - task_->started).count();
  try {
    std::shared_ptr<World> w = task_->result.get();
    std::printf("kdgrid-viewer: %s %s in %.3f s (%s)\n", new_scene ? "loaded and built" : "rebuilt",
                w->name.c_str(), w->build_seconds,
                format_bytes_iec(double(w->accel->stats().bytes)).c_str());
    std::fflush(stdout);
    rec.accel = w->name;
    rec.scene = w->scene->source;
    rec.build_seconds = w->build_seconds;
    rec.stats = w->accel->stats();
    rec.cell_size = w->params.cell_size;
    install_world(std::move(w), new_scene);
  } catch (const BuildCancelled&) {
    // Not an error: the old structure stays and renders.
    rec.cancelled = true;
    rec.error = "cancelled";
    rec.cancel_seconds = std::chrono::duration<double>(Clock::now() - task_->cancelled_at).count();
    message_ = "cancelled " + task_->what + (world_ ? "; showing " + world_->name : "");
    if (!pending_build_) show_built_cell_size();
    std::printf("kdgrid-viewer: cancelled %s after %.3f s (it stopped %.3f s after the request)\n",
                task_->what.c_str(), rec.wall_seconds, rec.cancel_seconds);
    std::fflush(stdout);
  } catch (const std::exception& e) {
    // A failed allocation outside the loaders and builds, which name their own, says only
    // "std::bad_alloc": say what ran out.
    task_error_ = dynamic_cast<const std::bad_alloc*>(&e)
                      ? out_of_memory_message() + ": use a smaller scene or run with more memory"
                      : std::string(e.what());
    rec.error = task_error_;
    if (!new_scene) show_built_cell_size();
    std::fprintf(stderr, "kdgrid-viewer: %s failed: %s\n", task_->what.c_str(),
                 task_error_.c_str());
    if (new_scene && !world_) {
      // The window stays with the error in its panel; its title names the file, as a loaded
      // scene's does.
      const std::string title = "kdgrid-viewer - " +
                                std::filesystem::path(task_->path).filename().string() +
                                " (failed to load)";
      glfwSetWindowTitle(window_, title.c_str());
    }
  }
  builds_.push_back(std::move(rec));
  task_.reset();
  if (was_scripted_rebuild) scripted_rebuild_done_ = true;
  if (drop_started_ && new_scene) drop_done_ = true;
  if (pending_build_) {
    auto [name, params] = *pending_build_;
    pending_build_.reset();
    start_build(name, params);
  }
}

void Viewer::show_built_cell_size() {
  requested_choice_.reset();
  if (!world_) return;
  if (const auto* h = dynamic_cast<const GridKdHybrid*>(world_->accel.get()))
    cell_size_slider_ = float(h->cell_size());
  cell_estimated_for_ = -1;  // the estimate follows the built size again
}

void Viewer::install_world(std::shared_ptr<const World> w, bool new_scene) {
  if (new_scene) {
    const bool first = !world_;
    built_.clear();
    Camera c = *w->scene->camera;
    // Command-line camera flags apply to the scene given on the command line only.
    if (first) c = opts_.camera.apply(c);
    scene_bounds_ = w->scene->mesh.bounds();
    cam_.reset(c, scene_bounds_);
    start_camera_ = cam_.camera();
    pick_.reset();
    // The title names the scene; input tests wait for it (xdotool search --sync --name)
    // before they send events, as the camera is reset here.
    const std::string title =
        "kdgrid-viewer - " + std::filesystem::path(w->scene->source).filename().string();
    glfwSetWindowTitle(window_, title.c_str());
  }
  if (new_scene) {
    cell_choice_ = loading_choice_;
    auto_cell_ = w->auto_cell;
    cell_refusal_.clear();
  }
  // The choice follows what was built (a scripted rebuild, a build from the panel), and the
  // slider shows the built size, the auto rule's included.
  const float cs = w->params.cell_size;
  if (w->name == "hybrid") {
    if (requested_choice_ && !new_scene &&
        std::fabs(requested_choice_->resolve(auto_cell_) - cs) <= 1e-6f * std::max(cs, 1e-30f))
      cell_choice_ = *requested_choice_;  // what the panel asked for, as it asked (auto, 2x)
    requested_choice_.reset();
    if (cs <= 0.0f)
      cell_choice_ = {};
    else if (cell_choice_.kind != CellChoice::Kind::Multiple ||
             std::fabs(cell_choice_.resolve(auto_cell_) - cs) > 1e-6f * cs)
      cell_choice_ = {CellChoice::Kind::Units, double(cs)};
    if (const auto* h = dynamic_cast<const GridKdHybrid*>(w->accel.get()))
      cell_size_slider_ = float(h->cell_size());
    cell_estimated_for_ = -1;
  }
  accel_name_ = w->name;
  params_ = w->params;
  built_[w->name] = w;
  world_ = std::move(w);
  overlay_dirty_ = true;
  if (pick_) retrace_pick();  // the same ray through the new structure
}

}  // namespace kdgrid::viewer
