// kdgrid-viewer's application: construction from the options, the window and GL set-up,
// shutdown (settings and layout saved), and the main loop. Input is in input.cpp, the picture
// and the render hand-over in display.cpp, the structure overlay in structure_overlay.cpp, the
// panels in panels.cpp, the background loads and builds in background_tasks.cpp, the
// --stats-json writer in stats_json.cpp and the pick's view in pick_view.cpp.
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

#include "image/image_io.h"
#include "util/error.h"
#include "viewer/gl_util.h"
#include "viewer/viewer_internal.h"
#include "viewer_shaders.h"

namespace kdgrid::viewer {

namespace {

Viewer* self(GLFWwindow* w) {
  return static_cast<Viewer*>(glfwGetWindowUserPointer(w));
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
  preload_image_module();
}

void Viewer::preload_image_module() {
  // Runs that write an image loaded the module before they started (main.cpp). A person can
  // press the screenshot key at any time: their runs load it now, beside the window's set-up,
  // not at the first screenshot, when a build may have left the process short of memory (the
  // module's libraries do not survive a failed allocation in their static set-up). Scripted
  // runs that write no image never load it.
  const bool writes_image =
      !opts_.screenshot.empty() || !opts_.export_heatmap.empty() || !opts_.diff_exr.empty();
  if (writes_image || (opts_.scripted() && opts_.hold <= 0)) return;
  image_module_preload_ = std::thread([] {
    try {
      require_image_module();
    } catch (const Error& e) {
      std::fprintf(stderr, "kdgrid-viewer: screenshots are unavailable: %s\n", e.what());
    }
  });
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
  // ImGui's shaders and font texture now, at start-up, rather than inside the first frame.
  ImGui_ImplOpenGL3_CreateDeviceObjects();
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
  if (image_module_preload_.joinable()) image_module_preload_.join();
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

// ---- main loop ------------------------------------------------------------------------------

void Viewer::run_script_requests(bool& pick_done) {
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
}

void Viewer::draw_frame() {
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
}

bool Viewer::script_finished(bool closing, bool no_scene, bool pick_done, Clock::time_point started,
                             int& exit_code) {
  if (worker_ && !worker_->error().empty()) {
    std::fprintf(stderr, "kdgrid-viewer: render failed: %s\n", worker_->error().c_str());
    exit_code = 1;
    end_reason_ = "render failed";
    return true;
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
    return true;
  }
  if (script_done && no_scene) {
    // The error is on screen (and was printed once when the load failed).
    end_reason_ = "start-up scene failed";
    exit_code = 1;
    if (!opts_.screenshot.empty()) save_screenshot(opts_.screenshot);
    return true;
  }
  const bool overlay_ok = !overlay_dirty_ && !overlay_job_.valid() &&
                          !structure_lines_.uploading() && !structure_lines_.drawing();
  if (script_done && world_ && !task_ && rebuild_ok && pick_done && drop_done_ && image_ok &&
      overlay_ok && !recolor_ && accuracy_complete() && !estimate_job_.valid()) {
    if (end_reason_.empty()) end_reason_ = "frames done";
    if (write_script_outputs() != 0) exit_code = 1;
    return true;
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
    return true;
  }
  return false;
}

int Viewer::write_script_outputs() {
  int code = 0;
  if (!task_error_.empty()) {
    std::fprintf(stderr, "kdgrid-viewer: %s\n", task_error_.c_str());
    code = 1;
  }
  // What a scripted run was asked to write: "wrote PATH", or the error, on stdout.
  const auto report = [&code](const std::string& path, const std::string& err) {
    std::printf("kdgrid-viewer: %s\n", err.empty() ? ("wrote " + path).c_str() : err.c_str());
    if (!err.empty()) code = 1;
  };
  if (!opts_.export_heatmap.empty())
    report(opts_.export_heatmap, write_counts_exr(opts_.export_heatmap, image_,
                                                  std::string("kdgrid ") + mode_name(image_.mode) +
                                                      " per pixel, " + accel_name_));
  if (!opts_.diff_exr.empty()) report(opts_.diff_exr, write_diff_exr(opts_.diff_exr));
  if (!opts_.screenshot.empty()) {
    save_screenshot(opts_.screenshot);
    if (message_.rfind("wrote ", 0) != 0) code = 1;
  }
  return code;
}

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
    phases_.start(Clock::now(), frame_count_);  // the wait above is idle time, not work
    if (settle_frames_ > 0) --settle_frames_;
    glfwPollEvents();
    hold_short_presses();
    phases_.end(FramePhases::kEvents);
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
    phases_.end(FramePhases::kTasks);
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
    phases_.end(FramePhases::kInput);
    sync_render_job();
    phases_.end(FramePhases::kRenderJob);
    receive_image();
    phases_.end(FramePhases::kImage);
    poll_structure_overlay();
    if (overlay_dirty_) rebuild_structure_overlay();
    phases_.end(FramePhases::kOverlay);
    update_accuracy();
    phases_.end(FramePhases::kAccuracy);

    run_script_requests(pick_done);
    phases_.end(FramePhases::kScript);
    draw_frame();
    phases_.end(FramePhases::kDraw);
    if (opts_.scripted() && script_finished(closing, no_scene, pick_done, started, exit_code))
      break;
    const auto swap_start = Clock::now();
    glfwSwapBuffers(window_);
    phases_.end(FramePhases::kSwap);
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
