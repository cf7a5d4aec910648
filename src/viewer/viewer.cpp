// kdgrid-viewer's application: set-up, input, the hand-over to the render worker, the main
// loop. The panels are in panels.cpp, the background loads and builds in background_tasks.cpp,
// the --stats-json writer in stats_json.cpp and the pick's view in pick_view.cpp.
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

#include "accel/guards.h"
#include "util/error.h"
#include "viewer/gl_util.h"
#include "viewer/viewer_internal.h"
#include "viewer_shaders.h"

namespace kdgrid::viewer {

const char* mode_name(RenderMode m) {
  switch (m) {
    case RenderMode::Shaded:
      return "shaded";
    case RenderMode::HeatSteps:
      return "steps";
    case RenderMode::HeatTests:
      return "tests";
    case RenderMode::HeatTime:
      return "time";
  }
  return "shaded";
}

const char* heat_label(RenderMode m) {
  switch (m) {
    case RenderMode::HeatSteps:
      return "traversal steps";
    case RenderMode::HeatTests:
      return "triangle tests";
    case RenderMode::HeatTime:
      return "nanoseconds";
    case RenderMode::Shaded:
      break;
  }
  return "";
}

namespace {

Viewer* self(GLFWwindow* w) {
  return static_cast<Viewer*>(glfwGetWindowUserPointer(w));
}

/// Appends `v` to a plot's history, which keeps the last 120 values.
void push_history(std::deque<float>& h, float v) {
  h.push_back(v);
  while (h.size() > 120) h.pop_front();
}

}  // namespace

// ---- construction ---------------------------------------------------------------------------

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
  params_.cell_size =
      cell_choice_.kind == CellChoice::Kind::Units ? float(cell_choice_.value) : 0.0f;
  if (opts_.heatmap == "steps") mode_ = RenderMode::HeatSteps;
  if (opts_.heatmap == "tests") mode_ = RenderMode::HeatTests;
  if (opts_.heatmap == "time") mode_ = RenderMode::HeatTime;
  if (opts_.shading == "lights") shading_choice_ = ShadingChoice::Lights;
  if (opts_.shading == "eye") shading_choice_ = ShadingChoice::Eye;
  if (opts_.shading == "normals") shading_choice_ = ShadingChoice::Normals;
  for (const auto& o : opts_.overlays) {
    if (o == "splits") show_splits_ = true;
    if (o == "cells") show_cells_ = true;
    if (o == "boxes") show_boxes_ = true;
  }
  splits_of_pick_ = opts_.splits_of_pick;
  show_accuracy_ = opts_.accuracy;
  offset_ = parse_secondary_offset(opts_.offset, "--offset");
  for (DiffView v : {DiffView::Current, DiffView::Pinned, DiffView::Difference, DiffView::Split})
    if (opts_.diff_view == to_string(v)) diff_view_ = v;
}

Viewer::~Viewer() {
  shutdown();
}

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
  glfwSetKeyCallback(
      window_, [](GLFWwindow* w, int k, int s, int a, int m) { self(w)->on_key(k, s, a, m); });
  glfwSetMouseButtonCallback(
      window_, [](GLFWwindow* w, int b, int a, int m) { self(w)->on_mouse_button(b, a, m); });
  glfwSetScrollCallback(window_,
                        [](GLFWwindow* w, double dx, double dy) { self(w)->on_scroll(dx, dy); });
  // ImGui 1.86's GLFW backend polls the cursor and installs no position callback, so this one
  // stays ours; drags follow every reported position, not one sample per frame.
  glfwSetCursorPosCallback(window_,
                           [](GLFWwindow* w, double x, double y) { self(w)->on_cursor_pos(x, y); });
  glfwGetCursorPos(window_, &cursor_x_, &cursor_y_);
  glfwSetDropCallback(window_,
                      [](GLFWwindow* w, int n, const char** p) { self(w)->on_drop(n, p); });
  glfwSetFramebufferSizeCallback(window_, [](GLFWwindow* w, int, int) { self(w)->note_input(); });
  glfwSetWindowRefreshCallback(window_, [](GLFWwindow* w) { self(w)->note_input(); });

  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGuiIO& io = ImGui::GetIO();
  // The layout is read and written here, not by ImGui (io.IniFilename): read only from a
  // regular file, written through the atomic writer at exit. Scripted runs use the default.
  io.IniFilename = nullptr;
  if (!opts_.scripted() && !config_dir_.empty()) {
    save_layout_ = true;
    if (const auto ini = read_config_file(config_dir_, kLayoutFile))
      ImGui::LoadIniSettingsFromMemory(ini->data(), ini->size());
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
  if (overlay_job_.valid()) overlay_job_.wait();
  if (estimate_job_.valid()) estimate_job_.wait();
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
    if (save_layout_) {
      size_t n = 0;
      const char* ini = ImGui::SaveIniSettingsToMemory(&n);
      write_config_file(config_dir_, kLayoutFile, std::string(ini, n));
    }
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

float Viewer::scene_radius() const {
  if (!world_) return 1.0f;
  return std::max(length(scene_bounds_.extent()) * 0.5f, 1e-6f);
}

// ---- input ----------------------------------------------------------------------------------

void Viewer::print_camera() {
  message_ = cam_.cli_flags();
  std::printf("%s\n", message_.c_str());
  std::fflush(stdout);
}

void Viewer::on_key(int key, int /*scancode*/, int action, int mods) {
  note_input();
  // ImGui 1.86 reads a key's state once per frame, so a press and its release within one
  // frame would never reach it (a short Enter in a text field on a slow frame was lost): such
  // a key is held down through one frame (hold_short_presses).
  if (action == GLFW_PRESS && key >= 0) pressed_this_frame_.insert(key);
  if (action == GLFW_RELEASE && pressed_this_frame_.count(key)) short_presses_.insert(key);
  if (action != GLFW_PRESS) return;
  // Ctrl+Q and Esc work wherever the keyboard focus is, a panel's text field included.
  if (key == GLFW_KEY_Q && (mods & GLFW_MOD_CONTROL)) {
    // Ctrl+Q quits (plain Q is "down"); a --hold run then finishes like a closed window.
    glfwSetWindowShouldClose(window_, GLFW_TRUE);
    if (end_reason_.empty()) end_reason_ = "ctrl+q";
    cancel_task();  // a running build stops rather than delaying the exit
    return;
  }
  if (key == GLFW_KEY_ESCAPE) {
    // Cancels the running build; its old structure stays. The start-up scene's first build
    // has none, so it is not cancelled (Ctrl+Q quits). In a text field Esc also drops the
    // edit (ImGui restores the value), and the panel must not take that as a new request.
    escape_this_frame_ = true;
    if (world_) cancel_task();
    return;
  }
  if (ImGui::GetIO().WantCaptureKeyboard) return;
  switch (key) {
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
    case GLFW_KEY_R:
      reset_layout_ = true;
      break;
    case GLFW_KEY_L:
      // auto -> lights -> eye light -> normals -> auto
      shading_choice_ = ShadingChoice((int(shading_choice_) + 1) % 4);
      break;
    default:
      break;
  }
}

void Viewer::hold_short_presses() {
  ImGuiIO& io = ImGui::GetIO();
  for (int k : short_presses_)
    if (k < int(IM_ARRAYSIZE(io.KeysDown))) {
      io.KeysDown[k] = true;  // ImGui sees the key down in this frame...
      held_keys_.insert(k);
    }
  short_presses_.clear();
  pressed_this_frame_.clear();
}

void Viewer::release_held_keys() {
  ImGuiIO& io = ImGui::GetIO();
  for (int k : held_keys_)  // ...and released in the next, unless it is down again
    if (glfwGetKey(window_, k) != GLFW_PRESS) io.KeysDown[k] = false;
  held_keys_.clear();
  escape_this_frame_ = false;
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
        if (ww > 0 && wh > 0) do_pick(int(x / ww * posted_w_), int(y / wh * posted_h_));
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
  if (right_down_ && (dx != 0 || dy != 0))
    cam_.look(-float(dx) * kRadPerPixel, -float(dy) * kRadPerPixel);
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
  if (ImGui::GetCurrentContext() && (ImGui::GetIO().WantTextInput || ImGui::IsAnyItemActive()))
    return true;
  if (structure_lines_.uploading()) return true;  // an overlay goes up a part per frame
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

// ---- shading ----------------------------------------------------------------------------

Shading Viewer::shading_shown() const {
  switch (shading_choice_) {
    case ShadingChoice::Lights:
      return Shading::Lights;
    case ShadingChoice::Eye:
      return Shading::EyeLight;
    case ShadingChoice::Normals:
      return Shading::Normals;
    case ShadingChoice::Auto:
      break;
  }
  return auto_eye_ ? Shading::EyeLight : Shading::Lights;
}

void Viewer::update_auto_shading(const RenderedImage& img) {
  // The rule (docs/VIEWER.md, "Shading"): a shaded pass checks which of its primary hits a
  // scene light reaches (every hit with the lights, one pixel in 16 with the eye light or the
  // normals). Where the lights reach under 1% of them the picture is ambient light alone, a
  // uniform grey whatever the camera does; auto then shows the eye light, and goes back to
  // the lights once they reach 5% of the view. A view of background alone decides nothing.
  if (img.mode != RenderMode::Shaded) return;
  const RenderCounters& c = img.pass_counters;
  if (c.probed < kAutoMinProbed) return;
  lit_fraction_ = double(c.lit) / double(c.probed);
  if (!auto_eye_ && lit_fraction_ < kAutoLitFractionOn)
    auto_eye_ = true;
  else if (auto_eye_ && lit_fraction_ >= kAutoLitFractionOff)
    auto_eye_ = false;
}

// ---- render hand-over -----------------------------------------------------------------------

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
  if (refusal != brute_refusal_ && !refusal.empty())
    std::fprintf(stderr, "kdgrid-viewer: %s\n", refusal.c_str());
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
  const Shading shading = shading_shown();
  if (world_.get() == posted_world_ && same_size && mode_ == posted_mode_ &&
      shading == posted_shading_ && offset_ == posted_offset_ &&
      opts_.max_samples == posted_max_samples_ && same_camera(c, posted_camera_))
    return;
  RenderJob job;
  job.world = world_;
  job.camera = c;
  job.settings.width = w;
  job.settings.height = h;
  job.settings.mode = mode_;
  job.settings.shading = shading;
  job.settings.offset = offset_;
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
  posted_shading_ = shading;
  posted_offset_ = offset_;
  posted_max_samples_ = opts_.max_samples;
  posted_camera_ = c;
}

void Viewer::receive_image() {
  if (worker_ && worker_->take_image(image_)) {
    have_image_ = true;
    update_auto_shading(image_);
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
    pr.shading = image_.shading;
    const auto now = Clock::now();
    pr.shown_at = std::chrono::duration<double>(now - run_started_).count();
    // Motion to photon: the job was posted in the frame that handled the input that moved
    // the camera to what this image shows.
    for (const auto& [job, at] : post_times_)
      if (job == image_.job_id)
        pr.latency_ms = std::chrono::duration<double, std::milli>(now - at).count();
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
  heat_range_ =
      heat_range(image_, settings_.heat_scale, settings_.heat_fixed_min, settings_.heat_fixed_max);
  colorize(image_, settings_.heat_scale, heat_range_, rgba_);
  if (image_.mode != RenderMode::Shaded) colorize_diff(rgba_);
  colorize_accuracy(rgba_);
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
    const float dist = length(f.eye - scene_bounds_.center());
    const auto vp = view_projection(f, r * 1e-4f, (dist + r) * 10.0f);
    GL_CHECK(glEnable(GL_BLEND));
    GL_CHECK(glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA));
    structure_lines_.draw(vp, overlay_alpha_);
    GL_CHECK(glDisable(GL_BLEND));
  }
}

// ---- overlays and pick ----------------------------------------------------------------------

void Viewer::rebuild_structure_overlay() {
  // Built off the UI thread (a BVH over the full dragon is 1.7M boxes): a newer request waits
  // for the running one and replaces its result; the old lines stay on screen meanwhile.
  if (overlay_job_.valid()) return;
  overlay_dirty_ = false;
  const std::shared_ptr<const World> w = world_;
  const bool splits = show_splits_ && (!splits_of_pick_ || pick_), cells = show_cells_,
             boxes = show_boxes_;
  const std::optional<RaySegment> seg =
      splits_of_pick_ && pick_ ? std::optional<RaySegment>(pick_->segment) : std::nullopt;
  const std::array<int, 4> depths = {split_depth_[0], split_depth_[1], box_depth_[0],
                                     box_depth_[1]};
  overlay_job_ = std::async(std::launch::async, [=] {
    OverlayResult r;
    if (w) {
      const Accelerator& a = *w->accel;
      if (splits)
        r.items += build_split_overlay(a, depths[0], depths[1], r.batch, seg ? &*seg : nullptr);
      if (cells) r.items += build_cell_overlay(a, r.batch, &r.wanted);
      if (boxes) r.items += build_box_overlay(a, depths[2], depths[3], r.batch, &r.wanted);
    }
    glfwPostEmptyEvent();  // the UI thread uploads it at once
    return r;
  });
}

void Viewer::poll_structure_overlay() {
  if (structure_lines_.uploading()) structure_lines_.upload_step(kUploadVerticesPerFrame);
  if (!overlay_job_.valid() ||
      overlay_job_.wait_for(std::chrono::seconds(0)) != std::future_status::ready)
    return;
  OverlayResult r = overlay_job_.get();
  if (overlay_dirty_) return;  // settings changed meanwhile: the next build replaces it
  overlay_items_ = r.items;
  overlay_wanted_ = r.wanted;
  structure_lines_.upload(std::move(r.batch));
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
  trace_pick_tree(0);
  const Trace& t = pick_->trace;
  std::printf(
      "kdgrid-viewer: pick %d,%d: %zu steps, %llu triangle tests, %s; %zu rays in its ray "
      "tree\n  %s\n",
      pick_->x, pick_->y, t.steps.size(), (unsigned long long)t.counters.tri_tests,
      t.hit.valid() ? ("hit triangle " + std::to_string(t.hit.prim)).c_str() : "miss",
      pick_->tree.nodes.size(), pick_->command.c_str());
  std::fflush(stdout);
}

void Viewer::retrace_pick() {
  if (!pick_ || !world_) return;
  trace_pick_tree(pick_->selected);
}

// ---- output ---------------------------------------------------------------------------------

std::string Viewer::default_output_name(const char* prefix, const char* ext) const {
  const std::time_t now = std::time(nullptr);
  char stamp[32];
  std::strftime(stamp, sizeof stamp, "%Y%m%d-%H%M%S", std::localtime(&now));
  // Two files within one second get -2, -3, ...: none overwrites another.
  const std::string base = std::string(prefix) + "-" + stamp;
  std::string name = base + "." + ext;
  for (int n = 2; std::filesystem::exists(name); ++n)
    name = base + "-" + std::to_string(n) + "." + ext;
  return name;
}

int Viewer::previews_last_second() const {
  const double now = std::chrono::duration<double>(Clock::now() - run_started_).count();
  int n = 0;
  for (auto it = passes_.rbegin(); it != passes_.rend() && it->shown_at > now - 1.0; ++it)
    n += it->preview;
  return n;
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
  if (err.empty())
    std::printf("kdgrid-viewer: %s\n", message_.c_str());
  else
    std::fprintf(stderr, "kdgrid-viewer: error: %s\n", err.c_str());
  std::fflush(stdout);
}

// ---- main loop ------------------------------------------------------------------------------

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
    release_held_keys();
    const double since = std::chrono::duration<double>(Clock::now() - last).count();
    if (!wants_continuous_frames()) {
      const double idle_s = task_ ? kBusyIdleSeconds : kIdleSeconds;
      if (idle_s > since) glfwWaitEventsTimeout(idle_s - since);
    } else if (min_frame_s > since) {
      glfwWaitEventsTimeout(min_frame_s - since);
    }
    if (settle_frames_ > 0) --settle_frames_;
    glfwPollEvents();
    hold_short_presses();
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
    if (no_scene && closing &&
        opts_.hold <= 0) {  // closed during the first build, or after it failed
      if (!task_error_.empty()) exit_code = 1;
      break;
    }
    handle_continuous_input(dt);
    sync_render_job();
    receive_image();
    poll_structure_overlay();
    if (overlay_dirty_) rebuild_structure_overlay();
    update_accuracy();

    if (opts_.scripted()) {
      if (!pick_done && world_ && posted_w_ > 0) {
        do_pick((*opts_.pick)[0], (*opts_.pick)[1]);
        if (pick_ && opts_.pick_ray > 0) select_tree_ray(opts_.pick_ray);
        if (opts_.frame_pick) frame_pick();
        pick_done = true;
      }
      if (opts_.pin_heatmap && !pinned_ && have_image_ && image_.job_id == posted_job_ &&
          image_.samples >= std::min(opts_.min_samples, opts_.max_samples))
        pin_heatmap();
      if (!opts_.rebuild_cell_size.empty() && !scripted_rebuild_started_ && have_image_ && !task_ &&
          (!opts_.pin_heatmap || pinned_)) {
        scripted_rebuild_started_ = true;
        scripted_rebuild_at_ = Clock::now();
        const float cs = cli::parse_cell_size(opts_.rebuild_cell_size);
        start_build(accel_name_, params_with_cell_size(accel_name_, cs));
      }
      // The second request goes in while the first build runs (or once it has ended, if it
      // ended sooner), through the panel's own path.
      if (!opts_.supersede_cell_size.empty() && scripted_rebuild_started_ && !supersede_started_ &&
          (scripted_rebuild_done_ ||
           std::chrono::duration<double>(Clock::now() - scripted_rebuild_at_).count() >=
               opts_.supersede_after)) {
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
    update_hover();
    if (!brute_refusal_.empty()) {
      // Over the empty picture, panels or not: why there is no image.
      const ImGuiIO& io = ImGui::GetIO();
      const std::string text = "brute force stopped at its work limit: " + brute_refusal_;
      const float wrap = std::min(io.DisplaySize.x * 0.6f, 640 * ui_scale_);
      const ImVec2 size = ImGui::CalcTextSize(text.c_str(), nullptr, false, wrap);
      ImGui::GetBackgroundDrawList()->AddText(
          nullptr, 0.0f,
          ImVec2(std::max(0.0f, (io.DisplaySize.x - size.x) * 0.5f),
                 std::max(0.0f, (io.DisplaySize.y - size.y) * 0.5f)),
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
      // Auto shading may have just chosen another light: its picture is still to come.
      const bool image_ok = have_image_ && image_.job_id == posted_job_ &&
                            (mode_ != RenderMode::Shaded || shading_shown() == posted_shading_) &&
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
      const bool overlay_ok =
          !overlay_dirty_ && !overlay_job_.valid() && !structure_lines_.uploading();
      if (script_done && world_ && !task_ && rebuild_ok && pick_done && drop_done_ && image_ok &&
          overlay_ok && !recolor_ && accuracy_complete() && !estimate_job_.valid()) {
        if (end_reason_.empty()) end_reason_ = "frames done";
        if (!task_error_.empty()) {
          std::fprintf(stderr, "kdgrid-viewer: %s\n", task_error_.c_str());
          exit_code = 1;
        }
        if (!opts_.export_heatmap.empty()) {
          const std::string err = write_counts_exr(
              opts_.export_heatmap, image_,
              std::string("kdgrid ") + mode_name(image_.mode) + " per pixel, " + accel_name_);
          std::printf("kdgrid-viewer: %s\n",
                      err.empty() ? ("wrote " + opts_.export_heatmap).c_str() : err.c_str());
          if (!err.empty()) exit_code = 1;
        }
        if (!opts_.diff_exr.empty()) {
          const std::string err = write_diff_exr(opts_.diff_exr);
          std::printf("kdgrid-viewer: %s\n",
                      err.empty() ? ("wrote " + opts_.diff_exr).c_str() : err.c_str());
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
                     have_image_ ? image_.samples : 0, opts_.min_samples,
                     task_ ? task_->what.c_str() : "none");
        exit_code = 4;
        end_reason_ = "timeout";
        break;
      }
    }
    const auto swap_start = Clock::now();
    glfwSwapBuffers(window_);
    // With a software GL (llvmpipe) the drawing happens here, when the frame is flushed.
    frame_swap_ms_.push_back(
        std::chrono::duration<float, std::milli>(Clock::now() - swap_start).count());
    // What the UI thread did this frame: events, hand-over, upload, panels, drawing, swap.
    // The frame plot shows this, not the interval: an idle loop sleeps between frames.
    const float work_ms = std::chrono::duration<float, std::milli>(Clock::now() - now).count();
    frame_work_ms_.push_back(work_ms);
    push_history(frame_ms_hist_, work_ms);
  }
  if (!opts_.stats_json.empty() && !write_stats(opts_.stats_json, exit_code) && exit_code == 0)
    exit_code = 1;
  shutdown();
  return exit_code;
}

}  // namespace kdgrid::viewer
