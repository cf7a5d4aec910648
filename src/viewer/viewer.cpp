#include "viewer/viewer.h"

#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>
#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>
#include <tbb/global_control.h>

#include "accel/guards.h"
#include "accel/hybrid.h"
#include "scene/load.h"
#include "util/error.h"
#include "viewer/gl_util.h"
#include "viewer_shaders.h"

namespace kdgrid::viewer {

namespace {

using Clock = std::chrono::steady_clock;

/// Colour of the brute-force refusal: orange, apart from the errors' red.
const ImVec4 kRefusalColor(1.0f, 0.6f, 0.1f, 1.0f);

Viewer* self(GLFWwindow* w) { return static_cast<Viewer*>(glfwGetWindowUserPointer(w)); }

bool same_camera(const Camera& a, const Camera& b) {
  return a.eye == b.eye && a.target == b.target && a.up == b.up && a.fov_deg == b.fov_deg;
}

/// Quotes a path for a shell command line when it needs it.
std::string shell_quote(const std::string& s) {
  if (s.find_first_of(" \t'\"\\$`()&;|<>*?") == std::string::npos) return s;
  std::string q = "'";
  for (char c : s) q += (c == '\'') ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

std::string format_bytes(uint64_t b) {
  char buf[64];
  if (b >= (1ull << 20))
    std::snprintf(buf, sizeof buf, "%.2f MiB", double(b) / double(1 << 20));
  else if (b >= 1024)
    std::snprintf(buf, sizeof buf, "%.1f KiB", double(b) / 1024.0);
  else
    std::snprintf(buf, sizeof buf, "%llu B", (unsigned long long)b);
  return buf;
}

std::string fmt_float(float v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}

/// The build flags of `p` that differ from the defaults, as `kdgrid` options, so a printed
/// command line rebuilds the very same structure.
std::string accel_flags(const std::string& name, const BuildParams& p) {
  const BuildParams d;
  std::string s = " --accel " + name;
  if (p.cell_size > 0) s += " --cell-size " + fmt_float(p.cell_size);
  if (p.cell_percentile != d.cell_percentile) s += " --cell-percentile " + fmt_float(p.cell_percentile);
  if (p.hybrid_dense_matrix) s += " --dense-matrix";
  if (p.hybrid_subtree_min != d.hybrid_subtree_min) s += " --hybrid-subtree " + std::to_string(p.hybrid_subtree_min);
  if (!p.hybrid_expand_empty) s += " --hybrid-no-expand";
  if (!p.hybrid_guess) s += " --hybrid-no-guess";
  if (p.grid_lambda != d.grid_lambda) s += " --grid-lambda " + fmt_float(p.grid_lambda);
  if (p.kd_intersection_cost != d.kd_intersection_cost)
    s += " --kd-cost-ratio " + fmt_float(p.kd_intersection_cost);
  if (p.bvh_max_leaf != d.bvh_max_leaf) s += " --bvh-leaf " + std::to_string(p.bvh_max_leaf);
  if (p.triangle_test != d.triangle_test) s += std::string(" --triangle-test ") + to_string(p.triangle_test);
  return s;
}

const char* mode_name(RenderMode m) {
  switch (m) {
    case RenderMode::Shaded: return "shaded";
    case RenderMode::HeatSteps: return "steps";
    case RenderMode::HeatTests: return "tests";
  }
  return "shaded";
}

/// Wakes the UI thread (asleep in glfwWaitEventsTimeout) when a background task ends, however
/// it ends; it polls the task's future at once instead of at its next timeout.
struct WakeUiOnExit {
  WakeUiOnExit() = default;
  WakeUiOnExit(const WakeUiOnExit&) = delete;
  WakeUiOnExit& operator=(const WakeUiOnExit&) = delete;
  ~WakeUiOnExit() { glfwPostEmptyEvent(); }
};

/// Threads a background build may use: all but one of those the process may use, so that the
/// render worker keeps a core and the picture follows the camera while a structure builds (a
/// build on every core starves the passes, which then take seconds). At least 1.
int background_build_threads() {
  const int n = int(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
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

void push_history(std::deque<float>& h, float v) {
  h.push_back(v);
  while (h.size() > 120) h.pop_front();
}

}  // namespace

// ---- construction --------------------------------------------------------------------------

Viewer::Viewer(ViewerOptions opts) : opts_(std::move(opts)) {
  // Scripted runs are reproducible: they neither read nor write the remembered settings.
  if (!opts_.scripted()) {
    config_dir_ = config_dir();
    settings_ = load_settings(config_dir_);
  }
  // The cell size: the command line's for its scene, else the one remembered for this scene
  // (scene units) or for every scene (auto or a multiple of auto); resolved in start_load.
  std::string cs = opts_.accel.cell_size;
  if (!opts_.cell_size_given) cs = remembered_cell_choice(settings_, opts_.scene).text();
  const auto names = accelerator_names();
  const auto valid = [&](const std::string& n) {
    return std::find(names.begin(), names.end(), n) != names.end();
  };
  accel_name_ = opts_.accel.accel;
  if (!opts_.accel_given) {
    if (valid(settings_.accel))
      accel_name_ = settings_.accel;
    else if (!valid(accel_name_))
      accel_name_ = names.front();  // the default structure is not built into this binary
  }
  params_ = opts_.accel.resolve();
  try {
    cell_choice_ = CellChoice::parse(cs, "--cell-size");
    cell_size_text_ = cs;
  } catch (const ParamError&) {
    cell_choice_ = {};  // a bad remembered value falls back to auto
  }
  params_.cell_size = cell_choice_.kind == CellChoice::Kind::Units ? float(cell_choice_.value) : 0.0f;
  if (opts_.heatmap == "steps") mode_ = RenderMode::HeatSteps;
  if (opts_.heatmap == "tests") mode_ = RenderMode::HeatTests;
  for (const auto& o : opts_.overlays) {
    if (o == "splits") show_splits_ = true;
    if (o == "cells") show_cells_ = true;
    if (o == "boxes") show_boxes_ = true;
  }
  splits_of_pick_ = opts_.splits_of_pick;
}

Viewer::~Viewer() { shutdown(); }

bool Viewer::create_window() {
  glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
  glfwWindowHint(GLFW_SCALE_TO_MONITOR, GLFW_TRUE);
  int w = opts_.width > 0 ? opts_.width : settings_.window_width;
  int h = opts_.height > 0 ? opts_.height : settings_.window_height;
  w = std::clamp(w, 64, 16384);
  h = std::clamp(h, 64, 16384);
  window_ = glfwCreateWindow(w, h, "kdgrid-viewer", nullptr, nullptr);
  if (!window_) {
    std::fprintf(stderr,
                 "kdgrid-viewer: could not create a window with an OpenGL 3.3 core context "
                 "(see the GLFW error above). On a machine without a suitable GPU driver try "
                 "LIBGL_ALWAYS_SOFTWARE=1 (Mesa llvmpipe), or render without a window: "
                 "kdgrid render SCENE -o out.png\n");
    return false;
  }
  glfwSetWindowUserPointer(window_, this);
  glfwGetWindowContentScale(window_, &content_scale_[0], &content_scale_[1]);
  glfwMakeContextCurrent(window_);
  // Interactive: follow the display's refresh. Scripted: never block on vsync.
  glfwSwapInterval(opts_.scripted() ? 0 : 1);
  return true;
}

void Viewer::init_gl() {
  const auto gl_string = [](GLenum e) {
    const GLubyte* v = glGetString(e);
    return v ? std::string(reinterpret_cast<const char*>(v)) : std::string("?");
  };
  gl_renderer_ = gl_string(GL_RENDERER);
  gl_version_ = gl_string(GL_VERSION);
  image_program_ = make_program("image", shaders::k_image_vert, shaders::k_image_frag);
  GL_CHECK(glGenVertexArrays(1, &empty_vao_));
  GL_CHECK(glGenTextures(1, &tex_));
  GL_CHECK(glBindTexture(GL_TEXTURE_2D, tex_));
  // Nearest: one texel per image pixel when the render matches the framebuffer, and picked
  // pixels stay crisp when it does not.
  GL_CHECK(glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST));
  GL_CHECK(glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST));
  GL_CHECK(glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE));
  GL_CHECK(glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE));
  structure_lines_.init();

  // Our callbacks first; ImGui's backend then chains to them, so ImGui sees input first and
  // we gate on WantCaptureMouse / WantCaptureKeyboard (docs/DESIGN.md, "The viewer").
  glfwSetKeyCallback(window_, [](GLFWwindow* w, int k, int s, int a, int m) { self(w)->on_key(k, s, a, m); });
  glfwSetMouseButtonCallback(window_, [](GLFWwindow* w, int b, int a, int m) {
    self(w)->on_mouse_button(b, a, m);
  });
  glfwSetScrollCallback(window_, [](GLFWwindow* w, double dx, double dy) { self(w)->on_scroll(dx, dy); });
  // ImGui 1.86's GLFW backend polls the cursor and installs no position callback, so this one
  // stays ours; drags follow every reported position, not one sample per frame.
  glfwSetCursorPosCallback(window_, [](GLFWwindow* w, double x, double y) { self(w)->on_cursor_pos(x, y); });
  glfwGetCursorPos(window_, &cursor_x_, &cursor_y_);
  glfwSetDropCallback(window_, [](GLFWwindow* w, int n, const char** p) { self(w)->on_drop(n, p); });
  glfwSetFramebufferSizeCallback(window_, [](GLFWwindow* w, int, int) { self(w)->note_input(); });
  glfwSetWindowRefreshCallback(window_, [](GLFWwindow* w) { self(w)->note_input(); });

  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGuiIO& io = ImGui::GetIO();
  if (!opts_.scripted() && !config_dir_.empty()) {
    ini_path_ = (std::filesystem::path(config_dir_) / "imgui.ini").string();
    io.IniFilename = ini_path_.c_str();
  } else {
    io.IniFilename = nullptr;  // scripted runs use the default layout
  }
  apply_ui_scale(std::max(content_scale_[0], content_scale_[1]));
  ImGui_ImplGlfw_InitForOpenGL(window_, true);
  ImGui_ImplOpenGL3_Init("#version 330 core");
}

void Viewer::apply_ui_scale(float scale) {
  // Below 1 the default font becomes unreadable; fractional scales above 1 are kept.
  ui_scale_ = std::clamp(scale, 1.0f, 8.0f);
  ImGui::GetStyle() = ImGuiStyle();
  ImGui::StyleColorsDark();
  ImGui::GetStyle().ScaleAllSizes(ui_scale_);
  // Rasterise the font at the scaled size instead of magnifying a 13 px atlas
  // (FontGlobalScale), so text stays sharp on a HiDPI screen.
  ImGuiIO& io = ImGui::GetIO();
  io.Fonts->Clear();
  ImFontConfig font;
  font.SizePixels = std::round(13.0f * ui_scale_);
  io.Fonts->AddFontDefault(&font);
  io.FontGlobalScale = 1.0f;
}

void Viewer::shutdown() {
  // The worker goes first: it may hold the last reference to a world.
  worker_.reset();
  if (task_) {
    cancel_task();  // a build stops within about 100 ms (a scene still loading finishes first)
    task_->result.wait();
    task_.reset();
  }
  if (!window_) return;
  if (!opts_.scripted()) {
    int ww, wh, fw, fh;
    glfwGetWindowSize(window_, &ww, &wh);
    glfwGetFramebufferSize(window_, &fw, &fh);
    // Where window coordinates are pixels (X11, Windows), GLFW_SCALE_TO_MONITOR multiplied the
    // requested size by the content scale; store the unscaled size, or the window would grow
    // by that factor at every start. Where they are not (macOS, Wayland) the framebuffer is
    // larger than the window and the size is already in screen units.
    const float cs = std::max(content_scale_[0], content_scale_[1]);
    if (fw == ww && fh == wh && cs > 1.0f) {
      ww = int(std::lround(ww / cs));
      wh = int(std::lround(wh / cs));
    }
    settings_.window_width = ww;
    settings_.window_height = wh;
    settings_.accel = accel_name_;
    if (world_) remember_cell_choice(settings_, world_->scene->source, cell_choice_);
    save_settings(config_dir_, settings_);
  }
  ImGui_ImplOpenGL3_Shutdown();
  ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
  structure_lines_.destroy();
  if (tex_) glDeleteTextures(1, &tex_);
  if (empty_vao_) glDeleteVertexArrays(1, &empty_vao_);
  if (image_program_) glDeleteProgram(image_program_);
  glfwDestroyWindow(window_);
  window_ = nullptr;
}

// ---- worlds ----------------------------------------------------------------------------------

float Viewer::scene_radius() const {
  if (!world_) return 1.0f;
  return std::max(length(world_->scene->mesh.bounds().extent()) * 0.5f, 1e-6f);
}

BuildParams Viewer::params_with_cell_size(const std::string& name, float cs) const {
  BuildParams p = params_;
  if (name == "grid" && cs > 0 && world_) {
    // The uniform grid has no cell size knob; pick the density that gives cells of about
    // this edge: cells = volume / cs^3 = lambda * triangles.
    const Vec3 e = world_->scene->mesh.bounds().extent();
    const double v = double(std::max(e.x, cs)) * std::max(e.y, cs) * std::max(e.z, cs);
    const double cells = v / (double(cs) * cs * cs);
    p.grid_lambda = float(std::clamp(cells / double(world_->scene->mesh.num_triangles()), 1e-3, 1e3));
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
  if (own) choice = cell_choice_.kind == CellChoice::Kind::Multiple ? cell_choice_ : CellChoice::parse(opts_.accel.cell_size, "--cell-size");
  loading_choice_ = choice;
  Task t;
  t.what = "loading " + std::filesystem::path(path).filename().string();
  t.path = path;
  t.kind = "load";
  t.new_scene = true;
  t.started = Clock::now();
  t.cancel = std::make_shared<CancelToken>();
  t.result = std::async(std::launch::async, [path, name, params, choice, cancel = t.cancel] {
    const WakeUiOnExit wake;
    auto scene = std::make_shared<Scene>(load_scene(path));
    BuildParams p = params;
    p.cell_size = choice.resolve(choice.kind == CellChoice::Kind::Multiple
                                     ? Hybrid::estimate(scene->mesh, params).auto_cell
                                     : 0.0);
    return build_world(std::move(scene), name, p, *cancel);
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
  t.started = Clock::now();
  t.cancel = std::make_shared<CancelToken>();
  t.result = std::async(std::launch::async, [scene, name, params, cancel = t.cancel] {
    const WakeUiOnExit wake;
    return build_world(scene, name, params, *cancel);
  });
  task_ = std::move(t);
}

void Viewer::cancel_task() {
  if (!task_ || task_->cancel->cancelled()) return;
  task_->cancel->cancel();
  task_->cancelled_at = Clock::now();
  pending_build_.reset();
}

void Viewer::poll_tasks() {
  if (!task_ || task_->result.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return;
  const bool new_scene = task_->new_scene;
  const bool was_scripted_rebuild = scripted_rebuild_started_ && !scripted_rebuild_done_ && !new_scene;
  BuildRecord rec;
  rec.kind = task_->kind;
  rec.wall_seconds = std::chrono::duration<double>(Clock::now() - task_->started).count();
  try {
    std::shared_ptr<World> w = task_->result.get();
    std::printf("kdgrid-viewer: %s %s in %.3f s (%s)\n", new_scene ? "loaded and built" : "rebuilt",
                w->name.c_str(), w->build_seconds, format_bytes(w->accel->stats().bytes).c_str());
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
    std::printf("kdgrid-viewer: cancelled %s after %.3f s (it stopped %.3f s after the request)\n",
                task_->what.c_str(), rec.wall_seconds, rec.cancel_seconds);
    std::fflush(stdout);
  } catch (const std::exception& e) {
    task_error_ = e.what();
    rec.error = e.what();
    std::fprintf(stderr, "kdgrid-viewer: %s failed: %s\n", task_->what.c_str(), e.what());
    if (new_scene && !world_) {
      // The window stays with the error in its panel; its title names the file, as a loaded
      // scene's does.
      const std::string title =
          "kdgrid-viewer - " + std::filesystem::path(task_->path).filename().string() + " (failed to load)";
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

void Viewer::install_world(std::shared_ptr<const World> w, bool new_scene) {
  if (new_scene) {
    const bool first = !world_;
    built_.clear();
    Camera c = *w->scene->camera;
    // Command-line camera flags apply to the scene given on the command line only.
    if (first) c = opts_.camera.apply(c);
    cam_.reset(c, w->scene->mesh.bounds());
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
    BuildParams a = w->params;
    a.cell_size = 0.0f;
    auto_cell_ = Hybrid::estimate(w->scene->mesh, a).auto_cell;
    cell_refusal_.clear();
  }
  // The choice follows what was built (a scripted rebuild, a build from the panel), and the
  // slider shows the built size, the auto rule's included.
  const float cs = w->params.cell_size;
  if (w->name == "hybrid") {
    if (cs <= 0.0f)
      cell_choice_ = {};
    else if (cell_choice_.kind != CellChoice::Kind::Multiple || std::fabs(cell_choice_.resolve(auto_cell_) - cs) > 1e-6f * cs)
      cell_choice_ = {CellChoice::Kind::Units, double(cs)};
    if (const auto* h = dynamic_cast<const Hybrid*>(w->accel.get())) cell_size_slider_ = float(h->cell_size());
    cell_estimated_for_ = -1;
  }
  accel_name_ = w->name;
  params_ = w->params;
  built_[w->name] = w;
  world_ = std::move(w);
  overlay_dirty_ = true;
  if (pick_) retrace_pick();  // the same ray through the new structure
}

// ---- input -----------------------------------------------------------------------------------

void Viewer::print_camera() {
  message_ = cam_.cli_flags();
  std::printf("%s\n", message_.c_str());
  std::fflush(stdout);
}

void Viewer::on_key(int key, int /*scancode*/, int action, int mods) {
  note_input();
  if (action != GLFW_PRESS || ImGui::GetIO().WantCaptureKeyboard) return;
  if (key == GLFW_KEY_Q && (mods & GLFW_MOD_CONTROL)) {
    // Ctrl+Q quits (plain Q is "down"); a --hold run then finishes like a closed window.
    glfwSetWindowShouldClose(window_, GLFW_TRUE);
    if (end_reason_.empty()) end_reason_ = "ctrl+q";
    cancel_task();  // a running build stops rather than delaying the exit
    return;
  }
  switch (key) {
    case GLFW_KEY_ESCAPE:
      // Cancels the running build; its old structure stays. The start-up scene's first build
      // has none, so it is not cancelled (Ctrl+Q quits).
      if (world_) cancel_task();
      break;
    case GLFW_KEY_TAB:
      cam_.toggle_mode();
      break;
    case GLFW_KEY_HOME:
      cam_.frame_scene();
      break;
    case GLFW_KEY_C:
      print_camera();
      break;
    case GLFW_KEY_EQUAL:
    case GLFW_KEY_KP_ADD:
      cam_.scale_speed(1.25f);
      break;
    case GLFW_KEY_MINUS:
    case GLFW_KEY_KP_SUBTRACT:
      cam_.scale_speed(1.0f / 1.25f);
      break;
    case GLFW_KEY_F12:
    case GLFW_KEY_P:
      save_screenshot(default_output_name("kdgrid-screenshot", "png"));
      break;
    case GLFW_KEY_H:
      opts_.hide_ui = !opts_.hide_ui;  // the picture alone, as a screenshot with --hide-ui
      break;
    case GLFW_KEY_F1:
      show_keys_ = !show_keys_;
      break;
    case GLFW_KEY_F:
      frame_pick();
      break;
    default:
      break;
  }
}

void Viewer::on_mouse_button(int button, int action, int mods) {
  note_input();
  const double x = cursor_x_, y = cursor_y_;
  if (action == GLFW_PRESS) {
    if (ImGui::GetIO().WantCaptureMouse) return;
    if (button == GLFW_MOUSE_BUTTON_LEFT) {
      if (mods & GLFW_MOD_CONTROL) {
        left_down_ = false;
        int ww, wh;
        glfwGetWindowSize(window_, &ww, &wh);
        if (ww > 0 && wh > 0)
          do_pick(int(x / ww * posted_w_), int(y / wh * posted_h_));
        return;
      }
      left_down_ = true;
      dragged_ = false;
      press_x_ = x;
      press_y_ = y;
    } else if (button == GLFW_MOUSE_BUTTON_RIGHT) {
      right_down_ = true;
    }
  } else if (action == GLFW_RELEASE) {
    if (button == GLFW_MOUSE_BUTTON_LEFT && left_down_) {
      left_down_ = false;
      if (!dragged_) {
        // Window coordinates to image pixels (the image fills the window).
        int ww, wh;
        glfwGetWindowSize(window_, &ww, &wh);
        if (ww > 0 && wh > 0) do_pick(int(x / ww * posted_w_), int(y / wh * posted_h_));
      }
    } else if (button == GLFW_MOUSE_BUTTON_RIGHT) {
      right_down_ = false;
    }
  }
}

void Viewer::on_scroll(double /*dx*/, double dy) {
  note_input();
  if (ImGui::GetIO().WantCaptureMouse) return;
  cam_.dolly(float(dy));
}

void Viewer::on_cursor_pos(double x, double y) {
  note_input();
  const double dx = x - cursor_x_, dy = y - cursor_y_;
  cursor_x_ = x;
  cursor_y_ = y;
  if (left_down_) {
    if (dragged_) {
      cam_.orbit(-float(dx) * kRadPerPixel, float(dy) * kRadPerPixel);
    } else if (std::hypot(x - press_x_, y - press_y_) > 3.0) {
      // A press that moves less than 3 units is a click (pick). Past that it is a drag, and
      // the motion since the press counts, so the orbit follows the cursor exactly.
      dragged_ = true;
      cam_.orbit(-float(x - press_x_) * kRadPerPixel, float(y - press_y_) * kRadPerPixel);
    }
  }
  if (right_down_ && (dx != 0 || dy != 0)) cam_.look(-float(dx) * kRadPerPixel, -float(dy) * kRadPerPixel);
}

void Viewer::on_drop(int count, const char** paths) {
  note_input();
  if (count > 0) start_load(paths[0]);
}

void Viewer::note_input() {
  // ImGui updates hover and active state in the frame after an event, and shows the result of
  // a click in the one after that.
  settle_frames_ = 3;
}

bool Viewer::wants_continuous_frames() const {
  // A coarse preview is showing: keep drawing until the full resolution has been posted.
  if (settle_frames_ > 0 || glfwWindowShouldClose(window_) || posted_preview_) return true;
  if (ImGui::GetCurrentContext() && (ImGui::GetIO().WantTextInput || ImGui::IsAnyItemActive())) return true;
  // Held keys move the camera every frame without sending events.
  for (int k : {GLFW_KEY_W, GLFW_KEY_A, GLFW_KEY_S, GLFW_KEY_D, GLFW_KEY_Q, GLFW_KEY_E})
    if (glfwGetKey(window_, k) == GLFW_PRESS) return true;
  // A scripted --frames run counts frames: give it them at the capped rate.
  return opts_.frames > 0 && frame_count_ < opts_.frames;
}

void Viewer::handle_continuous_input(float dt) {
  if (ImGui::GetIO().WantCaptureKeyboard || glfwWindowShouldClose(window_)) return;
  const auto down = [&](int k) { return glfwGetKey(window_, k) == GLFW_PRESS ? 1.0f : 0.0f; };
  // Ctrl+letter is a shortcut (Ctrl+Q quits), not a move.
  if (down(GLFW_KEY_LEFT_CONTROL) + down(GLFW_KEY_RIGHT_CONTROL) > 0) return;
  const float right = down(GLFW_KEY_D) - down(GLFW_KEY_A);
  const float up = down(GLFW_KEY_E) - down(GLFW_KEY_Q);
  const float fwd = down(GLFW_KEY_W) - down(GLFW_KEY_S);
  if (right != 0 || up != 0 || fwd != 0) {
    const float boost = (down(GLFW_KEY_LEFT_SHIFT) + down(GLFW_KEY_RIGHT_SHIFT)) > 0 ? 4.0f : 1.0f;
    cam_.move(right, up, fwd, dt * boost);
  }
}

// ---- render hand-over ----------------------------------------------------------------------

void Viewer::sync_render_job() {
  if (!world_ || !worker_) return;
  int fw, fh;
  glfwGetFramebufferSize(window_, &fw, &fh);
  if (fw <= 0 || fh <= 0) return;  // minimised
  // Brute force stops at its work limit (--brute-work-limit), as `kdgrid render` does for one
  // pass: here a full-resolution pass. Nothing is rendered then, and the picture says so
  // instead of showing the last image of another structure or size.
  std::string refusal;
  try {
    check_brute_force_work(world_->name,
                           uint64_t(std::max(1L, std::lround(fw * opts_.resolution_scale))) *
                               uint64_t(std::max(1L, std::lround(fh * opts_.resolution_scale))),
                           world_->scene->mesh.num_triangles(), world_->params);
  } catch (const ParamError& e) {
    refusal = e.what();
  }
  if (refusal != brute_refusal_ && !refusal.empty()) std::fprintf(stderr, "kdgrid-viewer: %s\n", refusal.c_str());
  brute_refusal_ = refusal;
  if (!brute_refusal_.empty()) return;
  const Camera& c = cam_.camera();
  // While the camera moves, render a coarse preview so that passes finish between moves; the
  // full resolution follows once it has been still for a moment.
  const auto now = Clock::now();
  if (!same_camera(c, last_seen_camera_)) {
    last_seen_camera_ = c;
    last_move_ = now;
  }
  // --frames runs render every frame at full resolution (reproducible screenshots); --hold
  // runs are driven like a person's session and preview as one.
  const bool preview = opts_.frames <= 0 && now - last_move_ < std::chrono::milliseconds(150);
  float scale = opts_.resolution_scale;
  if (preview) {
    // The resolution at which a pass takes kPreviewPassSeconds at the measured speed.
    float f = kPreviewScale;
    if (pixels_per_second_ > 0)
      f = float(std::sqrt(pixels_per_second_ * kPreviewPassSeconds / (double(fw) * double(fh))));
    scale = std::clamp(f, kMinPreviewScale * opts_.resolution_scale, opts_.resolution_scale);
  }
  const int w = std::max(1, int(std::lround(fw * scale)));
  const int h = std::max(1, int(std::lround(fh * scale)));
  posted_preview_ = preview;
  // A moving camera is posted however little it moved; a preview whose size alone changed
  // (the speed estimate moved) is not reposted for that.
  const bool same_size = (w == posted_w_ && h == posted_h_) || (preview && posted_preview_job_);
  if (world_.get() == posted_world_ && same_size && mode_ == posted_mode_ &&
      opts_.max_samples == posted_max_samples_ && same_camera(c, posted_camera_))
    return;
  RenderJob job;
  job.world = world_;
  job.camera = c;
  job.settings.width = w;
  job.settings.height = h;
  job.settings.mode = mode_;
  job.max_samples = opts_.max_samples;
  job.preview = preview;
  posted_job_ = worker_->post(std::move(job));
  post_times_.emplace_back(posted_job_, now);
  while (post_times_.size() > 256) post_times_.pop_front();
  posted_preview_job_ = preview;
  posted_world_ = world_.get();
  posted_w_ = w;
  posted_h_ = h;
  posted_mode_ = mode_;
  posted_max_samples_ = opts_.max_samples;
  posted_camera_ = c;
}

void Viewer::receive_image() {
  if (worker_ && worker_->take_image(image_)) {
    have_image_ = true;
    recolor_ = true;
    if (image_.pass_seconds > 0) {
      last_mrays_ = float(double(image_.pass_rays) / image_.pass_seconds * 1e-6);
      push_history(mrays_hist_, last_mrays_);
      // The speed the next preview is sized by, in pixels per second: a slower pass lowers it
      // at once (a build or another process took the cores: the next preview must shrink to
      // stay on time), a faster one raises it gradually (one lucky pass does not double it).
      const double pps = double(image_.width) * double(image_.height) / image_.pass_seconds;
      pixels_per_second_ = pixels_per_second_ > 0 && pps > pixels_per_second_
                               ? 0.7 * pixels_per_second_ + 0.3 * pps
                               : pps;
    }
    PassRecord pr;
    pr.job = image_.job_id;
    pr.preview = image_.preview;
    const auto now = Clock::now();
    pr.shown_at = std::chrono::duration<double>(now - run_started_).count();
    // Motion to photon: the job was posted in the frame that handled the input that moved
    // the camera to what this image shows.
    for (const auto& [job, at] : post_times_)
      if (job == image_.job_id) pr.latency_ms = std::chrono::duration<double, std::milli>(now - at).count();
    pr.width = image_.width;
    pr.height = image_.height;
    pr.samples = image_.samples;
    pr.seconds = image_.pass_seconds;
    pr.rays = image_.pass_counters;
    passes_.push_back(pr);
  }
  if (!recolor_ || !have_image_) return;
  recolor_ = false;
  const auto t0 = Clock::now();
  heat_range_ = heat_range(image_, settings_.heat_scale, settings_.heat_fixed_min, settings_.heat_fixed_max);
  colorize(image_, settings_.heat_scale, heat_range_, rgba_);
  const auto t1 = Clock::now();
  colorize_ms_.push_back(std::chrono::duration<float, std::milli>(t1 - t0).count());
  GL_CHECK(glBindTexture(GL_TEXTURE_2D, tex_));
  GL_CHECK(glPixelStorei(GL_UNPACK_ALIGNMENT, 1));
  if (image_.width != tex_w_ || image_.height != tex_h_) {
    GL_CHECK(glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, image_.width, image_.height, 0, GL_RGBA,
                          GL_UNSIGNED_BYTE, rgba_.data()));
    tex_w_ = image_.width;
    tex_h_ = image_.height;
  } else {
    GL_CHECK(glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, image_.width, image_.height, GL_RGBA,
                             GL_UNSIGNED_BYTE, rgba_.data()));
  }
  // CPU time of the upload calls; with Mesa's llvmpipe that includes the copy itself.
  upload_ms_.push_back(std::chrono::duration<float, std::milli>(Clock::now() - t1).count());
}

// ---- overlays and pick ----------------------------------------------------------------------

void Viewer::rebuild_structure_overlay() {
  overlay_dirty_ = false;
  LineBatch b;
  overlay_items_ = 0;
  if (world_) {
    const Accelerator& a = *world_->accel;
    if (show_splits_ && (!splits_of_pick_ || pick_))
      overlay_items_ += build_split_overlay(a, split_depth_[0], split_depth_[1], b,
                                            splits_of_pick_ ? &pick_->segment : nullptr);
    if (show_cells_) overlay_items_ += build_cell_overlay(a, b);
    if (show_boxes_) overlay_items_ += build_box_overlay(a, box_depth_[0], box_depth_[1], b);
  }
  structure_lines_.upload(b);
}

void Viewer::do_pick(int px, int py) {
  if (!world_ || posted_w_ <= 0 || posted_h_ <= 0) return;
  Pick p;
  p.x = std::clamp(px, 0, posted_w_ - 1);
  p.y = std::clamp(py, 0, posted_h_ - 1);
  p.w = posted_w_;
  p.h = posted_h_;
  p.camera = cam_.camera();
  const CameraFrame f = CameraFrame::make(p.camera, p.w, p.h);
  p.ray = f.ray(float(p.x) + 0.5f, float(p.y) + 0.5f);  // the pixel centre, as `trace --pixel`
  pick_ = std::move(p);
  retrace_pick();
  const Trace& t = pick_->trace;
  std::printf("kdgrid-viewer: pick %d,%d: %zu steps, %llu triangle tests, %s\n  %s\n", pick_->x, pick_->y,
              t.steps.size(), (unsigned long long)t.counters.tri_tests,
              t.hit.valid() ? ("hit triangle " + std::to_string(t.hit.prim)).c_str() : "miss",
              pick_->command.c_str());
  std::fflush(stdout);
}

void Viewer::retrace_pick() {
  if (!pick_ || !world_) return;
  Pick& p = *pick_;
  p.trace = world_->accel->trace(p.ray);
  p.segment = pick_segment(p.ray, p.trace, world_->scene->mesh.bounds());
  p.widths_for_font = 0;  // the step table's text and widths follow the new trace
  p.serial = ++pick_serial_;
  CameraControl at_pick;
  at_pick.set_camera(p.camera);
  p.command = "kdgrid trace " + shell_quote(world_->scene->source) + accel_flags(world_->name, world_->params) +
              " --pixel " + std::to_string(p.x) + "," + std::to_string(p.y) + " --res " + std::to_string(p.w) +
              "x" + std::to_string(p.h) + " " + at_pick.cli_flags();
  if (splits_of_pick_) overlay_dirty_ = true;
}

// ---- output ----------------------------------------------------------------------------------

std::string Viewer::default_output_name(const char* prefix, const char* ext) const {
  const std::time_t now = std::time(nullptr);
  char stamp[32];
  std::strftime(stamp, sizeof stamp, "%Y%m%d-%H%M%S", std::localtime(&now));
  return std::string(prefix) + "-" + stamp + "." + ext;
}

void Viewer::save_screenshot(const std::string& path) {
  int fw, fh;
  glfwGetFramebufferSize(window_, &fw, &fh);
  std::vector<uint8_t> pixels(size_t(fw) * size_t(fh) * 3), flipped(pixels.size());
  GL_CHECK(glPixelStorei(GL_PACK_ALIGNMENT, 1));
  GL_CHECK(glReadBuffer(GL_BACK));
  GL_CHECK(glReadPixels(0, 0, fw, fh, GL_RGB, GL_UNSIGNED_BYTE, pixels.data()));
  // GL's row 0 is the bottom; image files start at the top.
  const size_t row = size_t(fw) * 3;
  for (int y = 0; y < fh; ++y)
    std::copy_n(pixels.data() + size_t(fh - 1 - y) * row, row, flipped.data() + size_t(y) * row);
  const std::string err = write_png(path, fw, fh, flipped);
  message_ = err.empty() ? "wrote " + path : err;
  std::printf("kdgrid-viewer: %s\n", message_.c_str());
  std::fflush(stdout);
}

namespace {

nlohmann::json vec_json(const Vec3& v) { return {v.x, v.y, v.z}; }

nlohmann::json camera_json(const Camera& c) {
  return {{"eye", vec_json(c.eye)}, {"target", vec_json(c.target)}, {"up", vec_json(c.up)}, {"fov", c.fov_deg}};
}

}  // namespace

void Viewer::write_stats(const std::string& path, int exit_code) const {
  using nlohmann::json;
  int ww = 0, wh = 0, fw = 0, fh = 0;
  glfwGetWindowSize(window_, &ww, &wh);
  glfwGetFramebufferSize(window_, &fw, &fh);
  json j;
  j["exit_code"] = exit_code;
  j["end"] = end_reason_;
  j["display"] = {{"window", {ww, wh}},
                  {"framebuffer", {fw, fh}},
                  {"content_scale", {content_scale_[0], content_scale_[1]}},
                  {"ui_scale", ui_scale_},
                  {"font_size", ImGui::GetIO().Fonts->Fonts.empty() ? 0.0f : ImGui::GetIO().Fonts->Fonts[0]->FontSize},
                  {"image", {posted_w_, posted_h_}},
                  {"panel", opts_.hide_ui ? json(nullptr)
                                          : json{{"x", panel_rect_[0]}, {"y", panel_rect_[1]},
                                                 {"w", panel_rect_[2]}, {"h", panel_rect_[3]}}},
                  {"gl_renderer", gl_renderer_},
                  {"gl_version", gl_version_}};
  const RenderSettings rs;  // what sync_render_job leaves at its defaults
  j["settings"] = {{"threads", tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism)},
                   {"threads_option", opts_.threads},
                   {"max_samples", opts_.max_samples},
                   {"samples_per_pass", 1},
                   {"shadows", rs.shadows},
                   {"max_depth", rs.max_depth},
                   {"resolution_scale", opts_.resolution_scale},
                   {"max_fps", opts_.max_fps},
                   {"mode", mode_name(mode_)}};
  json st;
  if (world_) {
    st["scene"] = world_->scene->source;
    st["triangles"] = world_->scene->mesh.num_triangles();
    st["accel"] = world_->name;
    st["cell_size"] = world_->params.cell_size;
    if (const auto* h = dynamic_cast<const Hybrid*>(world_->accel.get())) {
      st["built_cell_size"] = h->cell_size();
      st["auto_cell_size"] = auto_cell_;
      st["cell_size_shown"] = cell_size_slider_;
      st["cell_choice"] = cell_choice_.text();
    }
    st["cell_estimate"] = cell_estimate_;
    st["cell_refusal"] = cell_refusal_;
  } else {
    st["scene"] = nullptr;
  }
  st["camera"] = camera_json(cam_.camera());
  st["ui_hidden"] = opts_.hide_ui;
  st["keys_shown"] = show_keys_;
  st["start_camera"] = camera_json(start_camera_);
  st["camera_mode"] = cam_.mode() == CameraMode::Fly ? "fly" : "orbit";
  st["speed_scale"] = cam_.speed_scale();
  st["speed"] = cam_.speed();
  st["camera_flags"] = cam_.cli_flags();
  if (pick_)
    st["pick"] = {{"x", pick_->x}, {"y", pick_->y}, {"steps", pick_->trace.steps.size()},
                  {"hit", pick_->trace.hit.valid()}, {"command", pick_->command}, {"framed", pick_->framed},
                  {"segment", {pick_->segment.t0, pick_->segment.t1}}};
  else
    st["pick"] = nullptr;
  st["overlay"] = {{"splits", show_splits_}, {"cells", show_cells_}, {"boxes", show_boxes_},
                   {"splits_of_pick", splits_of_pick_}, {"split_depths", {split_depth_[0], split_depth_[1]}},
                   {"items", overlay_items_}, {"lines", structure_lines_.vertex_count() / 2}};
  st["message"] = message_;
  st["error"] = task_error_;
  st["render_error"] = worker_ ? worker_->error() : std::string();
  st["render_refusal"] = brute_refusal_;
  st["samples"] = have_image_ ? image_.samples : 0;
  j["state"] = st;
  // What the last frame's panels showed (empty with the panels hidden).
  j["ui"] = {{"clipped", audit_.clipped},
             {"legends", audit_.legends},
             {"status_top", audit_.status_top},
             {"below_status_y", audit_.below_status_y},
             {"table_cells", audit_.table_cells},
             {"below_status_y_by_state", below_status_y_by_state_}};

  j["frames"] = {{"count", frame_count_}, {"interval_ms", frame_interval_ms_}, {"work_ms", frame_work_ms_},
                 {"swap_ms", frame_swap_ms_}};
  json passes = json::array();
  for (const PassRecord& p : passes_) {
    const uint64_t rays = p.rays.total();
    passes.push_back({{"job", p.job},
                      {"preview", p.preview},
                      {"latency_ms", p.latency_ms},
                      {"shown_at", p.shown_at},
                      {"width", p.width},
                      {"height", p.height},
                      {"samples", p.samples},
                      {"seconds", p.seconds},
                      {"rays", rays},
                      {"primary", p.rays.primary},
                      {"shadow", p.rays.shadow},
                      {"reflection", p.rays.reflection},
                      {"refraction", p.rays.refraction},
                      {"mrays", p.seconds > 0 ? double(rays) / p.seconds * 1e-6 : 0.0}});
  }
  j["passes"] = passes;
  j["colorize_ms"] = colorize_ms_;
  j["upload_ms"] = upload_ms_;
  json builds = json::array();
  for (const BuildRecord& b : builds_) {
    json e = {{"kind", b.kind}, {"accel", b.accel}, {"scene", b.scene}, {"build_seconds", b.build_seconds},
              {"wall_seconds", b.wall_seconds}, {"requested_cell_size", b.cell_size}};
    if (b.cancelled) e["cancel_seconds"] = b.cancel_seconds;
    if (!b.error.empty()) {
      e["error"] = b.error;
    } else {
      json extra = json::object();
      for (const auto& [k, v] : b.stats.extra) extra[k] = v;
      e["stats"] = {{"seconds", b.stats.seconds}, {"bytes", b.stats.bytes}, {"nodes", b.stats.nodes},
                    {"leaves", b.stats.leaves}, {"max_depth", b.stats.max_depth}, {"extra", extra}};
    }
    builds.push_back(e);
  }
  j["builds"] = builds;

  std::ofstream out(path);
  // Error texts can quote a file's bytes (a PLY with garbage after its header): invalid UTF-8
  // is replaced (U+FFFD) instead of throwing out of dump() and leaving the file empty.
  out << j.dump(1, ' ', false, json::error_handler_t::replace) << "\n";
  if (!out)
    std::fprintf(stderr, "kdgrid-viewer: could not write --stats-json %s\n", path.c_str());
  else
    std::printf("kdgrid-viewer: wrote %s\n", path.c_str());
  std::fflush(stdout);
}

// ---- panels ----------------------------------------------------------------------------------

void Viewer::request_cell_choice(const CellChoice& c) {
  if (!world_) return;
  const BuildParams p = params_with_cell_size("hybrid", c.resolve(auto_cell_));
  try {
    const HybridEstimate e = Hybrid::estimate(world_->scene->mesh, p);
    cell_estimate_ = e.describe();
    cell_estimated_for_ = float(e.cell);
    if (!e.fits) {
      cell_refusal_ = e.refusal();
      cell_suggested_ = e.suggested_cell;
      return;
    }
  } catch (const ParamError& err) {
    cell_refusal_ = err.what();
    cell_suggested_ = 0;
    return;
  }
  cell_refusal_.clear();
  cell_choice_ = c;
  start_build("hybrid", p);
}

void Viewer::draw_cell_size_controls(BuildParams&, bool&) {
  // The hybrid's cell size, in scene units and as a multiple of the auto size; the slider and
  // the boxes show the built size until edited. Every request is estimated first (cells,
  // bytes, build time) and refused with a size that fits when it does not.
  const float r = scene_radius();
  bool auto_cs = cell_choice_.kind == CellChoice::Kind::Auto;
  const auto chk = [this](const char* label) { audit_.item(label); };
  if (ImGui::Checkbox("auto cell size", &auto_cs))
    request_cell_choice(auto_cs ? CellChoice{} : CellChoice{CellChoice::Kind::Units, double(cell_size_slider_)});
  const float lo = std::min(r * 1e-3f, cell_size_slider_), hi = std::max(r * 2.0f, cell_size_slider_);
  ImGui::SliderFloat("cell", &cell_size_slider_, lo, hi, "%.4g", ImGuiSliderFlags_Logarithmic);
  if (ImGui::IsItemDeactivatedAfterEdit()) request_cell_choice({CellChoice::Kind::Units, double(cell_size_slider_)});
  chk("cell");
  ImGui::InputFloat("units", &cell_size_slider_, 0, 0, "%.6g");
  chk("units");
  if (ImGui::IsItemDeactivatedAfterEdit() && cell_size_slider_ > 0)
    request_cell_choice({CellChoice::Kind::Units, double(cell_size_slider_)});
  if (auto_cell_ > 0) {
    float mult = float(cell_size_slider_ / auto_cell_);
    ImGui::InputFloat("x auto", &mult, 0, 0, "%.4g");
    chk("x auto");
    if (ImGui::IsItemDeactivatedAfterEdit() && mult > 0) {
      cell_size_slider_ = float(mult * auto_cell_);
      request_cell_choice({CellChoice::Kind::Multiple, double(mult)});
    }
  }
  // The estimate of the size on the slider, updated while it moves (O(triangles)).
  if (cell_estimated_for_ != cell_size_slider_ && cell_size_slider_ > 0 && world_) {
    try {
      cell_estimate_ =
          Hybrid::estimate(world_->scene->mesh, params_with_cell_size("hybrid", cell_size_slider_)).describe();
    } catch (const ParamError& e) {
      cell_estimate_ = e.what();
    }
    cell_estimated_for_ = cell_size_slider_;
  }
  ImGui::PushTextWrapPos(0.0f);
  ImGui::TextDisabled("estimate: %s", cell_estimate_.c_str());
  if (!cell_refusal_.empty()) {
    ImGui::TextColored(ImVec4(1.0f, 0.45f, 0.35f, 1.0f), "refused: %s", cell_refusal_.c_str());
    if (cell_suggested_ > 0) {
      char label[64];
      std::snprintf(label, sizeof label, "use %.2g", cell_suggested_);
      if (ImGui::Button(label)) {
        cell_size_slider_ = float(cell_suggested_);
        request_cell_choice({CellChoice::Kind::Units, cell_suggested_});
      }
    }
  }
  ImGui::PopTextWrapPos();
}

void Viewer::draw_key_list() {
  if (!show_keys_) return;
  const ImGuiIO& io = ImGui::GetIO();
  ImGui::SetNextWindowPos(ImVec2(io.DisplaySize.x * 0.5f, io.DisplaySize.y * 0.5f), ImGuiCond_Appearing,
                          ImVec2(0.5f, 0.5f));
  if (!ImGui::Begin("keys (F1)", &show_keys_, ImGuiWindowFlags_AlwaysAutoResize | ImGuiWindowFlags_NoSavedSettings)) {
    ImGui::End();
    return;
  }
  static const char* const kKeys[][2] = {
      {"left drag", "orbit about the target"},
      {"right drag", "look around from the eye"},
      {"wheel", "dolly towards / away from the target"},
      {"W A S D Q E", "fly forward, left, back, right, down, up (Shift: 4x)"},
      {"Tab", "switch orbit / fly camera"},
      {"+ / -", "faster / slower camera"},
      {"Home", "frame the scene"},
      {"click", "pick the pixel: its ray's traversal, step by step"},
      {"F", "frame the pick: its leaves/cells and ray fill the view"},
      {"C", "print the camera as command-line flags"},
      {"P or F12", "save a screenshot"},
      {"H", "hide / show the panels"},
      {"F1", "this list"},
      {"Ctrl+Q", "quit"},
  };
  if (ImGui::BeginTable("keys", 2, ImGuiTableFlags_SizingFixedFit | ImGuiTableFlags_RowBg)) {
    for (const auto& k : kKeys) {
      ImGui::TableNextRow();
      ImGui::TableNextColumn();
      ImGui::TextUnformatted(k[0]);
      ImGui::TableNextColumn();
      ImGui::TextUnformatted(k[1]);
    }
    ImGui::EndTable();
  }
  ImGui::End();
}

void Viewer::draw_panels() {
  // The panel starts kPanelWidth wide and, with the window's height, at most a quarter of its
  // area; it is resizable and collapsible (the title bar's triangle), and an interactive run
  // remembers its place and size in imgui.ini.
  const ImGuiIO& io = ImGui::GetIO();
  const ImGuiStyle& style = ImGui::GetStyle();
  const float margin = 8 * ui_scale_;
  const float pw = std::min(kPanelWidth * ui_scale_, io.DisplaySize.x * 0.5f);
  const float ph = std::max(std::min(io.DisplaySize.y - 2 * margin, io.DisplaySize.x * io.DisplaySize.y * 0.25f / pw),
                            ImGui::GetFrameHeight() * 4);
  ImGui::SetNextWindowPos(ImVec2(margin, margin), ImGuiCond_FirstUseEver);
  ImGui::SetNextWindowSize(ImVec2(pw, ph), ImGuiCond_FirstUseEver);
  ImGui::Begin("kdgrid");
  const ImVec2 panel_pos = ImGui::GetWindowPos(), panel_size = ImGui::GetWindowSize();
  panel_rect_[0] = panel_pos.x;
  panel_rect_[1] = panel_pos.y;
  panel_rect_[2] = panel_size.x;
  panel_rect_[3] = panel_size.y;
  // Widgets leave room on their right for the widest label, so no label is cut.
  float label_w = 0;
  for (const char* l : {"structure", "max leaf size", "test/step cost", "cell", "units", "x auto", "cell size",
                        "max samples", "resolution", "Mrays/s", "frame work", "split depths", "box depths",
                        "opacity", "min", "max"})
    label_w = std::max(label_w, ImGui::CalcTextSize(l).x);
  ImGui::PushItemWidth(-(label_w + style.ItemInnerSpacing.x + 1));
  const auto chk = [this](const char* label) { audit_.item(label); };

  // The status area: a fixed height for the build's progress and the errors, scrolling when
  // they need more, so that nothing under it moves when a build starts or ends or an error
  // appears.
  audit_.status_top = ImGui::GetCursorPosY();
  ImGui::BeginChild("status", ImVec2(0, ImGui::GetFrameHeightWithSpacing() * kStatusLines), false);
  const std::string render_error = worker_ ? worker_->error() : std::string();
  if (task_) {
    const double secs = std::chrono::duration<double>(Clock::now() - task_->started).count();
    ImGui::Text("%s ... %.1f s", task_->what.c_str(), secs);
    chk(task_->what.c_str());
    same_line_if_fits(task_->cancel->cancelled() ? "cancelling" : "cancel (Esc)");
    if (task_->cancel->cancelled())
      ImGui::TextDisabled("cancelling");
    else if (ImGui::SmallButton("cancel (Esc)"))
      cancel_task();
    chk("cancel (Esc)");
    // Builds report no progress, so show motion rather than a fraction.
    ImGui::ProgressBar(float(std::fmod(secs, 1.0)), ImVec2(-1, 0), "");
  } else if (task_error_.empty() && render_error.empty() && brute_refusal_.empty()) {
    ImGui::TextDisabled("%s", world_ ? ("showing " + world_->name).c_str() : "no scene");
  }
  ImGui::PushTextWrapPos(0.0f);
  if (!task_error_.empty()) {
    ImGui::PushStyleColor(ImGuiCol_Text, ImVec4(1, 0.4f, 0.4f, 1));
    ImGui::TextUnformatted(task_error_.c_str());
    ImGui::PopStyleColor();
    if (ImGui::SmallButton("dismiss")) task_error_.clear();
  }
  if (!render_error.empty()) ImGui::TextColored(ImVec4(1, 0.4f, 0.4f, 1), "render: %s", render_error.c_str());
  if (!brute_refusal_.empty()) ImGui::TextColored(kRefusalColor, "not rendered: %s", brute_refusal_.c_str());
  ImGui::PopTextWrapPos();
  ImGui::EndChild();
  ImGui::Separator();
  audit_.below_status_y = ImGui::GetCursorPosY();
  auto& ys = below_status_y_by_state_[task_ ? "build" : (!task_error_.empty() ? "error" : "idle")];
  if (std::find(ys.begin(), ys.end(), audit_.below_status_y) == ys.end()) ys.push_back(audit_.below_status_y);

  if (!world_ && !task_) {
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextDisabled("no scene loaded: drop a .gltf/.glb/.ply/.obj file to load one");
    ImGui::PopTextWrapPos();
  }
  if (ImGui::CollapsingHeader("Scene", ImGuiTreeNodeFlags_DefaultOpen) && world_) {
    const Scene& s = *world_->scene;
    ImGui::TextWrapped("%s", s.source.c_str());
    ImGui::TextWrapped("%zu triangles, %zu vertices", s.mesh.num_triangles(), s.mesh.num_vertices());
    ImGui::TextWrapped("%zu materials, %zu lights, %zu textures", s.materials.size(), s.lights.size(),
                       s.textures.size());
    const Box3 b = s.mesh.bounds();
    ImGui::TextWrapped("bounds (%.3g %.3g %.3g) - (%.3g %.3g %.3g)", b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z);
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextDisabled("drop a .gltf/.glb/.ply/.obj file to load it");
    ImGui::PopTextWrapPos();
  }

  if (ImGui::CollapsingHeader("Structure", ImGuiTreeNodeFlags_DefaultOpen) && world_) {
    const auto names = accelerator_names();
    if (ImGui::BeginCombo("structure", accel_name_.c_str())) {
      for (const auto& n : names) {
        const bool built = built_.count(n) > 0;
        const std::string label = n + (built ? "" : "  (build)");
        if (ImGui::Selectable(label.c_str(), n == accel_name_) && n != accel_name_) {
          if (built)
            install_world(built_[n], false);  // switch on the same view, no rebuild
          else
            start_build(n, params_);
        }
      }
      ImGui::EndCombo();
    }
    chk("structure");
    // The main build knob of the selected structure; any change rebuilds off the UI thread.
    bool rebuild = false;
    BuildParams p = params_;
    const float r = scene_radius();
    if (accel_name_ == "bvh") {
      ImGui::SliderInt("max leaf size", &p.bvh_max_leaf, 1, 32);
      rebuild = ImGui::IsItemDeactivatedAfterEdit();
      chk("max leaf size");
    } else if (accel_name_ == "kdtree") {
      ImGui::SliderFloat("test/step cost", &p.kd_intersection_cost, 0.1f, 20.0f, "%.2f",
                         ImGuiSliderFlags_Logarithmic);
      rebuild = ImGui::IsItemDeactivatedAfterEdit();
      chk("test/step cost");
    } else if (accel_name_ == "hybrid") {
      draw_cell_size_controls(p, rebuild);
    } else if (accel_name_ != "brute" && accel_name_ != "embree") {
      if (cell_size_slider_ <= 0) cell_size_slider_ = params_.cell_size > 0 ? params_.cell_size : r * 0.05f;
      bool auto_cs = params_.cell_size <= 0 && accel_name_ != "grid";
      if (accel_name_ != "grid" && ImGui::Checkbox("auto cell size", &auto_cs)) {
        p = params_with_cell_size(accel_name_, auto_cs ? 0.0f : cell_size_slider_);
        rebuild = true;
      }
      ImGui::SliderFloat("cell size", &cell_size_slider_, r * 1e-3f, r * 0.5f, "%.4g",
                         ImGuiSliderFlags_Logarithmic);
      audit_.item("cell size");
      if (ImGui::IsItemDeactivatedAfterEdit()) {
        p = params_with_cell_size(accel_name_, cell_size_slider_);
        rebuild = true;
      }
      ImGui::InputFloat("##cellvalue", &cell_size_slider_, 0, 0, "%.6g");
      if (ImGui::IsItemDeactivatedAfterEdit() && cell_size_slider_ > 0) {
        p = params_with_cell_size(accel_name_, cell_size_slider_);
        rebuild = true;
      }
      if (accel_name_ == "grid") {
        ImGui::PushTextWrapPos(0.0f);
        ImGui::TextDisabled("grid: cell size sets lambda = %.3g", params_.grid_lambda);
        ImGui::PopTextWrapPos();
      }
    }
    if (rebuild) start_build(accel_name_, p);

    const BuildStats& st = world_->accel->stats();
    if (ImGui::BeginTable("stats", 2)) {
      // Labels keep their whole width; long values (the hybrid's build notes) wrap instead.
      ImGui::TableSetupColumn("name", ImGuiTableColumnFlags_WidthFixed);
      ImGui::TableSetupColumn("value", ImGuiTableColumnFlags_WidthStretch);
      const auto row = [](const char* k, const std::string& v) {
        ImGui::TableNextRow();
        ImGui::TableNextColumn();
        ImGui::TextUnformatted(k);
        ImGui::TableNextColumn();
        ImGui::TextWrapped("%s", v.c_str());
      };
      char buf[64];
      std::snprintf(buf, sizeof buf, "%.3f s", st.seconds > 0 ? st.seconds : world_->build_seconds);
      row("build time", buf);
      row("bytes", format_bytes(st.bytes));
      row("nodes", std::to_string(st.nodes));
      row("leaves", std::to_string(st.leaves) + " (" + std::to_string(st.empty_leaves) + " empty)");
      row("references", std::to_string(st.references));
      row("max depth", std::to_string(st.max_depth));
      for (const auto& [k, v] : st.extra) row(k.c_str(), v);
      ImGui::EndTable();
    }
  }

  if (ImGui::CollapsingHeader("Render", ImGuiTreeNodeFlags_DefaultOpen)) {
    int m = int(mode_);
    ImGui::RadioButton("shaded", &m, int(RenderMode::Shaded));
    ImGui::SameLine();
    ImGui::RadioButton("steps", &m, int(RenderMode::HeatSteps));
    ImGui::SameLine();
    ImGui::RadioButton("tri tests", &m, int(RenderMode::HeatTests));
    mode_ = RenderMode(m);
    chk("tri tests");
    ImGui::TextWrapped("%d x %d, %d samples, %.3g Mrays/s", posted_w_, posted_h_, have_image_ ? image_.samples : 0,
                       last_mrays_);
    ImGui::SliderInt("max samples", &opts_.max_samples, 1, 4096, "%d", ImGuiSliderFlags_Logarithmic);
    chk("max samples");
    if (ImGui::SliderFloat("resolution", &opts_.resolution_scale, 0.1f, 1.0f, "%.2f")) {
      opts_.resolution_scale = std::clamp(opts_.resolution_scale, 0.1f, 1.0f);
    }
    chk("resolution");
    // Both plots run from 0 to their history's maximum, which the overlay names (with the
    // latest value), so that their height reads as a fraction of a stated value.
    const auto plot = [&chk](const char* name, const std::deque<float>& hist, const char* unit) {
      std::vector<float> v(hist.begin(), hist.end());
      const float hi = v.empty() ? 0.0f : *std::max_element(v.begin(), v.end());
      char overlay[64];
      std::snprintf(overlay, sizeof overlay, "%.3g%s, axis 0-%.3g", v.empty() ? 0.0f : v.back(), unit, hi);
      ImGui::PlotLines(name, v.data(), int(v.size()), 0, overlay, 0.0f, hi > 0 ? hi : 1.0f, ImVec2(0, 40));
      chk(name);
    };
    plot("Mrays/s", mrays_hist_, "");
    // Work per frame (events, hand-over, upload, drawing), not the idle sleep between frames.
    plot("frame work", frame_ms_hist_, " ms");
    ImGui::TextWrapped("camera: %s (Tab), speed x%.2f (+/-)", cam_.mode() == CameraMode::Fly ? "fly" : "orbit",
                       cam_.speed_scale());
    if (ImGui::Button("print camera (C)")) print_camera();
    chk("print camera (C)");
    same_line_if_fits("frame scene (Home)");
    if (ImGui::Button("frame scene (Home)")) cam_.frame_scene();
    chk("frame scene (Home)");
    same_line_if_fits("screenshot (P)");
    if (ImGui::Button("screenshot (P)")) save_screenshot(default_output_name("kdgrid-screenshot", "png"));
    chk("screenshot (P)");
  }

  if (mode_ != RenderMode::Shaded && ImGui::CollapsingHeader("Heat map", ImGuiTreeNodeFlags_DefaultOpen)) {
    int s = int(settings_.heat_scale);
    bool changed = ImGui::RadioButton("auto", &s, int(HeatScale::Auto));
    ImGui::SameLine();
    changed |= ImGui::RadioButton("fixed", &s, int(HeatScale::Fixed));
    ImGui::SameLine();
    changed |= ImGui::RadioButton("log", &s, int(HeatScale::Log));
    chk("log");
    settings_.heat_scale = HeatScale(s);
    if (settings_.heat_scale == HeatScale::Fixed) {
      changed |= ImGui::InputFloat("min", &settings_.heat_fixed_min);
      changed |= ImGui::InputFloat("max", &settings_.heat_fixed_max);
    }
    if (changed) recolor_ = true;
    if (ImGui::Button("export EXR") && have_image_ && image_.mode != RenderMode::Shaded) {
      const std::string path = default_output_name(image_.mode == RenderMode::HeatSteps ? "kdgrid-steps" : "kdgrid-tests", "exr");
      const std::string err = write_counts_exr(path, image_, std::string("kdgrid ") + mode_name(image_.mode) +
                                                                  " per pixel, " + accel_name_);
      message_ = err.empty() ? "wrote " + path : err;
      std::printf("kdgrid-viewer: %s\n", message_.c_str());
    }
  }

  if (ImGui::CollapsingHeader("Overlays", ImGuiTreeNodeFlags_DefaultOpen)) {
    bool dirty = ImGui::Checkbox("kd split planes", &show_splits_);
    if (show_splits_) {
      dirty |= ImGui::Checkbox("splits of the picked ray", &splits_of_pick_);
      chk("splits of the picked ray");
      if (splits_of_pick_ && !pick_) {
        ImGui::PushTextWrapPos(0.0f);
        ImGui::TextDisabled("pick a pixel to see the planes its ray crosses");
        ImGui::PopTextWrapPos();
      }
      ImGui::SliderInt2("split depths", split_depth_, 0, 64);
      dirty |= ImGui::IsItemDeactivatedAfterEdit();
      chk("split depths");
      char l0[32], l2[32];
      std::snprintf(l0, sizeof l0, "depth %d", split_depth_[0]);
      std::snprintf(l2, sizeof l2, "%d", split_depth_[1]);
      draw_ramp_bar(ImGui::CalcItemWidth(), l0, "", l2);
      audit_.legends.push_back(std::string("split depth: ") + l0 + " .. " + l2);
    }
    dirty |= ImGui::Checkbox("cells / leaves", &show_cells_);
    dirty |= ImGui::Checkbox("boxes by depth", &show_boxes_);
    if (show_boxes_) {
      ImGui::SliderInt2("box depths", box_depth_, 0, 64);
      dirty |= ImGui::IsItemDeactivatedAfterEdit();
      chk("box depths");
      char l0[32], l2[32];
      std::snprintf(l0, sizeof l0, "depth %d", box_depth_[0]);
      std::snprintf(l2, sizeof l2, "%d", box_depth_[1]);
      draw_ramp_bar(ImGui::CalcItemWidth(), l0, "", l2);
    }
    ImGui::SliderFloat("opacity", &overlay_alpha_, 0.05f, 1.0f);
    chk("opacity");
    if (dirty) overlay_dirty_ = true;
    ImGui::TextWrapped("%zu items, %zu lines%s", overlay_items_, structure_lines_.vertex_count() / 2,
                       structure_lines_.vertex_count() / 2 >= kMaxOverlaySegments ? " (capped)" : "");
  }

  if (ImGui::CollapsingHeader("Pick", ImGuiTreeNodeFlags_DefaultOpen)) draw_pick_panel();
  if (!message_.empty()) ImGui::TextWrapped("%s", message_.c_str());
  ImGui::PopItemWidth();
  ImGui::End();

  draw_pick_steps();
  if (have_image_ && image_.mode != RenderMode::Shaded) draw_heat_legend();
}

void Viewer::draw_heat_legend() {
  const ImGuiIO& io = ImGui::GetIO();
  const float s = ui_scale_;
  ImGui::SetNextWindowPos(ImVec2(io.DisplaySize.x - 8, io.DisplaySize.y - 8), ImGuiCond_Always, ImVec2(1, 1));
  ImGui::SetNextWindowBgAlpha(0.7f);
  ImGui::Begin("legend", nullptr,
               ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_AlwaysAutoResize | ImGuiWindowFlags_NoSavedSettings |
                   ImGuiWindowFlags_NoFocusOnAppearing | ImGuiWindowFlags_NoNav);
  if (world_ && !world_->accel->has_counters()) {
    // Embree counts nothing: a ramp with a 0..1 scale would read as "no work at all".
    ImGui::TextColored(ImVec4(1.0f, 0.8f, 0.3f, 1.0f), "%s keeps no traversal counters: no %s heat map",
                       world_->name.c_str(), image_.mode == RenderMode::HeatSteps ? "step" : "test");
    ImGui::TextDisabled("choose a kdgrid structure to see its work per pixel");
    ImGui::End();
    return;
  }
  ImGui::Text("%s per pixel (%s scale)", image_.mode == RenderMode::HeatSteps ? "traversal steps" : "triangle tests",
              to_string(settings_.heat_scale));
  // The value at the middle of the bar differs between linear and log scales.
  const float mid = settings_.heat_scale == HeatScale::Log
                        ? heat_range_.lo + std::expm1(0.5f * std::log1p(heat_range_.hi - heat_range_.lo))
                        : 0.5f * (heat_range_.lo + heat_range_.hi);
  char l0[32], l1[32], l2[32];
  std::snprintf(l0, sizeof l0, "%.4g", heat_range_.lo);
  std::snprintf(l1, sizeof l1, "%.4g", mid);
  std::snprintf(l2, sizeof l2, "%.4g", heat_range_.hi);
  draw_ramp_bar(240 * s, l0, l1, l2);
  ImGui::End();
}

void Viewer::draw_ramp_bar(float w, const char* lo, const char* mid, const char* hi) {
  const float s = ui_scale_;
  const ImVec2 p = ImGui::GetCursorScreenPos();
  const float h = 14 * s;
  ImDrawList* dl = ImGui::GetWindowDrawList();
  constexpr int kSegs = 32;
  for (int i = 0; i < kSegs; ++i) {
    const Color a = ramp(float(i) / kSegs), b = ramp(float(i + 1) / kSegs);
    const ImU32 ca = ImGui::GetColorU32(ImVec4(a.r, a.g, a.b, 1)), cb = ImGui::GetColorU32(ImVec4(b.r, b.g, b.b, 1));
    dl->AddRectFilledMultiColor(ImVec2(p.x + w * i / kSegs, p.y), ImVec2(p.x + w * (i + 1) / kSegs, p.y + h), ca, cb,
                                cb, ca);
  }
  ImGui::Dummy(ImVec2(w, h));
  const float x0 = ImGui::GetCursorPosX();
  ImGui::TextUnformatted(lo);
  ImGui::SameLine(x0 + 0.5f * (w - ImGui::CalcTextSize(mid).x));
  ImGui::TextUnformatted(mid);
  ImGui::SameLine(x0 + w - ImGui::CalcTextSize(hi).x);
  ImGui::TextUnformatted(hi);
}

void Viewer::draw_scene() {
  int fw, fh;
  glfwGetFramebufferSize(window_, &fw, &fh);
  GL_CHECK(glViewport(0, 0, fw, fh));
  GL_CHECK(glClearColor(0.08f, 0.08f, 0.1f, 1.0f));
  GL_CHECK(glClear(GL_COLOR_BUFFER_BIT));
  GL_CHECK(glDisable(GL_DEPTH_TEST));
  if (have_image_ && brute_refusal_.empty()) {
    GL_CHECK(glUseProgram(image_program_));
    GL_CHECK(glActiveTexture(GL_TEXTURE0));
    GL_CHECK(glBindTexture(GL_TEXTURE_2D, tex_));
    GL_CHECK(glUniform1i(glGetUniformLocation(image_program_, "u_image"), 0));
    GL_CHECK(glBindVertexArray(empty_vao_));
    GL_CHECK(glDrawArrays(GL_TRIANGLES, 0, 6));
    GL_CHECK(glBindVertexArray(0));
  }
  if (world_ && posted_w_ > 0) {
    // The live camera (not the displayed image's) so overlays follow the mouse at once.
    const CameraFrame f = CameraFrame::make(cam_.camera(), posted_w_, posted_h_);
    const float r = scene_radius();
    const float dist = length(f.eye - world_->scene->mesh.bounds().center());
    const auto vp = view_projection(f, r * 1e-4f, (dist + r) * 10.0f);
    GL_CHECK(glEnable(GL_BLEND));
    GL_CHECK(glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA));
    structure_lines_.draw(vp, overlay_alpha_);
    GL_CHECK(glDisable(GL_BLEND));
  }
}

// ---- main loop -------------------------------------------------------------------------------

int Viewer::run() {
  if (!create_window()) return 3;
  try {
    init_gl();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "kdgrid-viewer: %s\n", e.what());
    return 3;
  }
  // A finished pass wakes the UI thread if it is asleep waiting for events.
  worker_ = std::make_unique<RenderWorker>([] { glfwPostEmptyEvent(); });
  start_load(opts_.scene);
  drop_done_ = opts_.drop.empty();

  const auto started = Clock::now();
  run_started_ = started;
  auto last = started;
  bool pick_done = !opts_.pick.has_value();
  int exit_code = 0;
  const double min_frame_s = opts_.scripted() && opts_.max_fps > 0 ? 1.0 / opts_.max_fps : 0.0;
  for (;;) {
    // Draw only when something can change what is shown. Idle, sleep on the event queue:
    // input, a finished pass (the worker posts an empty event) or a finished build wakes it;
    // the timeout keeps a build's progress bar moving and catches anything else. Busy, scripted
    // runs (which swap without vsync) wait out the rest of a 60 Hz frame instead of spinning.
    const double since = std::chrono::duration<double>(Clock::now() - last).count();
    if (!wants_continuous_frames()) {
      const double idle_s = task_ ? kBusyIdleSeconds : kIdleSeconds;
      if (idle_s > since) glfwWaitEventsTimeout(idle_s - since);
    } else if (min_frame_s > since) {
      glfwWaitEventsTimeout(min_frame_s - since);
    }
    if (settle_frames_ > 0) --settle_frames_;
    glfwPollEvents();
    const auto now = Clock::now();
    const float dt = std::chrono::duration<float>(now - last).count();
    last = now;
    if (frame_count_ > 0) frame_interval_ms_.push_back(dt * 1000.0f);

    // A --hold run treats a close request (Ctrl+Q, the window manager) as the end of the
    // script: it still finishes the image and writes its outputs. Other runs stop at once.
    const double elapsed = std::chrono::duration<double>(now - started).count();
    if (opts_.hold > 0 && elapsed > opts_.hold && !glfwWindowShouldClose(window_)) {
      end_reason_ = "hold expired";
      glfwSetWindowShouldClose(window_, GLFW_TRUE);
    }
    const bool closing = glfwWindowShouldClose(window_);
    if (closing && opts_.hold <= 0) {
      if (end_reason_.empty()) end_reason_ = "window closed";
      break;
    }
    if (closing && end_reason_.empty()) end_reason_ = "window closed";
    if (closing) cancel_task();  // whatever closed the window: a running build stops

    poll_tasks();
    // No scene loaded (the start-up scene failed, poll_tasks said why on stderr): the window
    // stays, its panel shows the error and another file can be dropped. The run's exit code
    // says the load failed.
    const bool no_scene = !world_ && !task_;
    if (no_scene && closing && opts_.hold <= 0) {  // closed during the first build, or after it failed
      if (!task_error_.empty()) exit_code = 1;
      break;
    }
    handle_continuous_input(dt);
    sync_render_job();
    receive_image();
    if (overlay_dirty_) rebuild_structure_overlay();

    if (opts_.scripted()) {
      if (!pick_done && world_ && posted_w_ > 0) {
        do_pick((*opts_.pick)[0], (*opts_.pick)[1]);
        if (opts_.frame_pick) frame_pick();
        pick_done = true;
      }
      if (!opts_.rebuild_cell_size.empty() && !scripted_rebuild_started_ && have_image_ && !task_) {
        scripted_rebuild_started_ = true;
        scripted_rebuild_at_ = Clock::now();
        const float cs = cli::parse_cell_size(opts_.rebuild_cell_size);
        start_build(accel_name_, params_with_cell_size(accel_name_, cs));
      }
      // The second request goes in while the first build runs (or once it has ended, if it
      // ended sooner), through the panel's own path.
      if (!opts_.supersede_cell_size.empty() && scripted_rebuild_started_ && !supersede_started_ &&
          (scripted_rebuild_done_ ||
           std::chrono::duration<double>(Clock::now() - scripted_rebuild_at_).count() >= opts_.supersede_after)) {
        supersede_started_ = true;
        const CellChoice c = CellChoice::parse(opts_.supersede_cell_size, "--supersede-cell-size");
        if (accel_name_ == "hybrid")
          request_cell_choice(c);
        else
          start_build(accel_name_, params_with_cell_size(accel_name_, c.resolve(auto_cell_)));
      }
    }
    if (!opts_.drop.empty() && !drop_started_ && have_image_ && !task_) {
      // The same handler GLFW's drop callback calls, for tests (xdotool cannot drop files).
      drop_started_ = true;
      const char* paths[] = {opts_.drop.c_str()};
      on_drop(1, paths);
      if (!task_) drop_done_ = true;  // refused (e.g. busy): nothing to wait for
    }

    ImGui_ImplOpenGL3_NewFrame();
    ImGui_ImplGlfw_NewFrame();
    ImGui::NewFrame();
    draw_pick_overlay();
    if (!brute_refusal_.empty()) {
      // Over the empty picture, panels or not: why there is no image.
      const ImGuiIO& io = ImGui::GetIO();
      const std::string text = "brute force stopped at its work limit: " + brute_refusal_;
      const float wrap = std::min(io.DisplaySize.x * 0.6f, 640 * ui_scale_);
      const ImVec2 size = ImGui::CalcTextSize(text.c_str(), nullptr, false, wrap);
      ImGui::GetBackgroundDrawList()->AddText(
          nullptr, 0.0f, ImVec2(std::max(0.0f, (io.DisplaySize.x - size.x) * 0.5f), std::max(0.0f, (io.DisplaySize.y - size.y) * 0.5f)),
          ImGui::GetColorU32(kRefusalColor), text.c_str(), nullptr, wrap);
    }
    audit_.clear();
    if (!opts_.hide_ui) {
      draw_panels();
      draw_key_list();
    } else
      std::fill(std::begin(panel_rect_), std::end(panel_rect_), 0.0f);
    ImGui::Render();
    draw_scene();
    ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
    ++frame_count_;

    if (opts_.scripted()) {
      if (worker_ && !worker_->error().empty()) {
        std::fprintf(stderr, "kdgrid-viewer: render failed: %s\n", worker_->error().c_str());
        exit_code = 1;
        end_reason_ = "render failed";
        break;
      }
      const bool rebuild_ok = (opts_.rebuild_cell_size.empty() || scripted_rebuild_done_) &&
                              (opts_.supersede_cell_size.empty() || supersede_started_);
      const bool image_ok = have_image_ && image_.job_id == posted_job_ &&
                            image_.samples >= std::min(opts_.min_samples, opts_.max_samples);
      const bool script_done = opts_.hold > 0 ? closing : frame_count_ >= opts_.frames;
      if (script_done && world_ && !task_ && !brute_refusal_.empty()) {
        // Brute force stopped at its work limit: the message is on screen (and was printed).
        end_reason_ = "brute-force work limit";
        exit_code = 1;
        if (!opts_.screenshot.empty()) save_screenshot(opts_.screenshot);
        break;
      }
      if (script_done && no_scene) {
        // The error is on screen (and was printed once when the load failed).
        end_reason_ = "start-up scene failed";
        exit_code = 1;
        if (!opts_.screenshot.empty()) save_screenshot(opts_.screenshot);
        break;
      }
      if (script_done && world_ && !task_ && rebuild_ok && pick_done && drop_done_ && image_ok &&
          !recolor_) {
        if (end_reason_.empty()) end_reason_ = "frames done";
        if (!task_error_.empty()) {
          std::fprintf(stderr, "kdgrid-viewer: %s\n", task_error_.c_str());
          exit_code = 1;
        }
        if (!opts_.export_heatmap.empty()) {
          const std::string err = write_counts_exr(opts_.export_heatmap, image_,
                                                   std::string("kdgrid ") + mode_name(image_.mode) +
                                                       " per pixel, " + accel_name_);
          std::printf("kdgrid-viewer: %s\n", err.empty() ? ("wrote " + opts_.export_heatmap).c_str() : err.c_str());
          if (!err.empty()) exit_code = 1;
        }
        if (!opts_.screenshot.empty()) {
          save_screenshot(opts_.screenshot);
          if (message_.rfind("wrote ", 0) != 0) exit_code = 1;
        }
        break;
      }
      const double limit = opts_.timeout + std::max(0.0, opts_.hold);
      if (std::chrono::duration<double>(Clock::now() - started).count() > limit) {
        std::fprintf(stderr,
                     "kdgrid-viewer: scripted run timed out after %.0f s (frames %d/%d, image %s, "
                     "samples %d/%d, task %s); raise --timeout or lower --min-samples\n",
                     limit, frame_count_, opts_.frames, have_image_ ? "yes" : "no",
                     have_image_ ? image_.samples : 0, opts_.min_samples, task_ ? task_->what.c_str() : "none");
        exit_code = 4;
        end_reason_ = "timeout";
        break;
      }
    }
    const auto swap_start = Clock::now();
    glfwSwapBuffers(window_);
    // With a software GL (llvmpipe) the drawing happens here, when the frame is flushed.
    frame_swap_ms_.push_back(std::chrono::duration<float, std::milli>(Clock::now() - swap_start).count());
    // What the UI thread did this frame: events, hand-over, upload, panels, drawing, swap.
    // The frame plot shows this, not the interval: an idle loop sleeps between frames.
    const float work_ms = std::chrono::duration<float, std::milli>(Clock::now() - now).count();
    frame_work_ms_.push_back(work_ms);
    push_history(frame_ms_hist_, work_ms);
  }
  if (!opts_.stats_json.empty()) write_stats(opts_.stats_json, exit_code);
  shutdown();
  return exit_code;
}

}  // namespace kdgrid::viewer
