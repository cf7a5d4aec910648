// kdgrid-viewer's application: window, input, panels, overlays, and the hand-over between
// the UI thread and the render worker / background builds. The core library does all the
// ray tracing; the viewer only shows it. The Viewer class is defined over several files, each
// named above the methods it holds: viewer.cpp, input.cpp, display.cpp, structure_overlay.cpp,
// background_tasks.cpp, panels.cpp, pick_view.cpp, ray_tree.cpp, diff_map.cpp,
// accuracy_map.cpp, stats_json.cpp.
#pragma once

#include <array>
#include <chrono>
#include <deque>
#include <future>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "bench/check.h"
#include "cli/common.h"
#include "util/cancel.h"
#include "viewer/background_job.h"
#include "viewer/camera_control.h"
#include "viewer/frame_phases.h"
#include "viewer/image_view.h"
#include "viewer/overlay.h"
#include "viewer/pick_view.h"
#include "viewer/render_worker.h"
#include "viewer/settings.h"

struct GLFWwindow;

namespace kdgrid::viewer {

/// What the heat map shows once a map is pinned (diff_map.cpp).
enum class DiffView { Current, Pinned, Difference, Split };
const char* to_string(DiffView v);

/// A pinned heat map against the current one.
struct DiffStats {
  double pinned_total = 0, current_total = 0;  ///< sums of the per-pixel values
  float max_abs = 0;                           ///< largest |current - pinned|
  float max_value = 0;                         ///< largest value of either map
  size_t more = 0, fewer = 0;                  ///< pixels with more / fewer than pinned
};

/// One batch of the accuracy map: the verdicts of some pixels' ray trees.
struct AccuracyBatch {
  std::vector<uint32_t> pixels;   ///< linear pixel indices
  std::vector<uint8_t> verdicts;  ///< per pixel: 1 + the worst AccuracyVerdict of its rays
  uint64_t counts[2][4] = {};     ///< rays by [primary, secondary][AccuracyVerdict]
  double seconds = 0;             ///< the batch's wall time
  double query_seconds = 0;       ///< the structure's fast queries on the batch's rays
  uint64_t query_rays = 0, answers = 0;
};

/// Judges the ray trees of `pixels` (of a w x h image of `camera`) against `ref`.
AccuracyBatch judge_accuracy_batch(std::shared_ptr<const World> world,
                                   std::shared_ptr<const AccuracyReference> ref, Camera camera,
                                   int w, int h, SecondaryOffset offset,
                                   std::vector<uint32_t> pixels);

/// The accuracy map so far.
struct AccuracySummary {
  size_t pixels = 0, judged = 0;
  uint64_t rays = 0;
  uint64_t counts[2][4] = {};       ///< rays by [primary, secondary][AccuracyVerdict]
  uint64_t pixel_verdicts[4] = {};  ///< judged pixels by their worst verdict
  double disagreement_rate = 0;     ///< (disagree + leak) / rays
  double mrays = 0;                 ///< the structure's fast queries on the judged rays
};

/// The structure and its build knobs as flags: "hybrid --cell-size 0.05".
std::string build_label(const World& w);

/// Command-line options (main.cpp parses them).
struct ViewerOptions {
  std::string scene;  ///< scene file (default assets/cornell.gltf)
  cli::AccelOptions accel;
  cli::CameraOptions camera;
  bool accel_given = false, cell_size_given = false;
  int width = 0, height = 0;      ///< window size; 0 = remembered / default
  float resolution_scale = 1.0f;  ///< render pixels per framebuffer pixel
  int max_samples = 256;          ///< stop refining at this many samples per pixel

  // Scripted runs (tests, reports).
  int frames = 0;          ///< > 0: run at least this many frames, then exit
  std::string screenshot;  ///< PNG written at the end of a scripted run
  int min_samples = 1;     ///< scripted: wait for this many samples per pixel
  double timeout = 300;    ///< scripted: give up (exit 4) after this many seconds
  std::optional<std::array<int, 2>> pick;
  int pick_ray = 0;  ///< scripted: the ray of the pick's ray tree to select (0 = the primary)
  bool frame_pick = false;            ///< scripted: frame the --pick ray's traversal (key F)
  bool splits_of_pick = false;        ///< split overlay: only the planes the picked ray crossed
  std::string heatmap;                ///< "", "steps", "tests" or "time"
  std::string shading = "auto";       ///< "auto", "lights", "eye" or "normals"
  std::string offset = "robust";      ///< secondary rays' start: "robust", "epsilon" or "none"
  std::vector<std::string> overlays;  ///< "splits", "cells", "boxes"
  std::string rebuild_cell_size;      ///< scripted live rebuild after start-up
  /// Scripted: the cell size requested (as the panel's cell-size box requests it) while the
  /// --rebuild-cell-size build runs, supersede_after seconds into it; "" = none.
  std::string supersede_cell_size;
  double supersede_after = 2.0;  ///< seconds; 2 s lets the first build get well under way
  std::string export_heatmap;    ///< scripted: EXR of the heat map's raw counts at the end
  /// Scripted: pin the first complete heat map (before --rebuild-cell-size starts).
  bool pin_heatmap = false;
  std::string diff_exr;                  ///< scripted: the difference map's EXR at the end
  std::string diff_view = "difference";  ///< "current", "pinned", "difference" or "split"
  /// Scripted: show the accuracy map and wait until every pixel is judged.
  bool accuracy = false;
  bool hide_ui = false;  ///< no ImGui panels (reproducible screenshots)
  /// > 0: keep the window open and interactive for up to this many seconds (input tests drive
  /// it with xdotool); Ctrl+Q or closing the window ends it sooner.
  double hold = 0;
  std::string stats_json;  ///< run statistics and final state, written at exit
  std::string drop;        ///< scripted: load this file through the drop handler
  /// Scripted runs swap without vsync, so this caps their frame rate the way a 60 Hz display
  /// caps an interactive run; 0 = unlimited.
  int max_fps = 60;
  int threads = 0;  ///< --threads as given (0 = all), for the statistics
  bool scripted() const { return frames > 0 || hold > 0; }
};

class Viewer {
 public:
  explicit Viewer(ViewerOptions opts);
  ~Viewer();
  /// Opens the window and runs until closed (or the scripted run ends). Returns the exit code.
  int run();

  // GLFW callbacks (static trampolines in viewer.cpp forward here).
  void on_key(int key, int scancode, int action, int mods);
  void on_mouse_button(int button, int action, int mods);
  void on_scroll(double dx, double dy);
  void on_cursor_pos(double x, double y);
  void on_drop(int count, const char** paths);

 private:
  // ---- viewer.cpp: set-up, shutdown, the main loop
  bool create_window();
  void init_gl();
  void apply_ui_scale(float scale);
  /// A person's run loads the image module in the background at start (screenshots).
  void preload_image_module();
  void shutdown();
  float scene_radius() const;
  /// The scripted requests due this frame (--pick, --pin-heatmap, --rebuild-cell-size,
  /// --supersede-cell-size, --drop); `pick_done` turns true once --pick is made.
  void run_script_requests(bool& pick_done);
  /// One frame: the ImGui frame (pick overlay, panels, key list), the scene under it.
  void draw_frame();
  /// A scripted run's end: true (with `exit_code` and end_reason_ set, the outputs written)
  /// when it is done, failed or timed out.
  bool script_finished(bool closing, bool no_scene, bool pick_done,
                       std::chrono::steady_clock::time_point started, int& exit_code);
  /// Writes --export-heatmap, --diff-exr and --screenshot; 1 when one failed or a task erred.
  int write_script_outputs();

  // ---- input.cpp: the GLFW callbacks' handling, held keys
  void note_input();
  /// A key pressed and released within one frame is shown to ImGui as down in this frame
  /// (ImGui 1.86 samples key states once per frame) and released before the next.
  void hold_short_presses();
  void release_held_keys();
  bool wants_continuous_frames() const;
  void handle_continuous_input(float dt);
  void print_camera();

  // ---- display.cpp: the render hand-over, the picture, screenshots
  void sync_render_job();
  void receive_image();
  void draw_scene();
  void save_screenshot(const std::string& path);
  std::string default_output_name(const char* prefix, const char* ext) const;

  // ---- structure_overlay.cpp: the structure overlay, built off the UI thread
  void rebuild_structure_overlay();

  // ---- background_tasks.cpp: the scene and its structure, loaded and built off the UI thread
  void start_load(const std::string& path);
  void start_build(const std::string& name, const BuildParams& params);
  void cancel_task();
  /// Task::expected_seconds of a build of `name` with `params` over the current scene.
  double expected_build_seconds(const std::string& name, const BuildParams& params) const;
  void poll_tasks();
  void install_world(std::shared_ptr<const World> w, bool new_scene);
  BuildParams params_with_cell_size(const std::string& name, float cell_size) const;

  // ---- panels.cpp: the ImGui panels
  /// Estimates the hybrid at `c` (HybridEstimate) and rebuilds when it fits; otherwise keeps
  /// the structure and shows the refusal with the size that fits.
  void request_cell_choice(const CellChoice& c);
  void draw_cell_size_controls(BuildParams& p, bool& rebuild);
  /// The last item's edit ended and is a request: not left by Esc (which restores the value).
  bool committed_edit() const;
  /// Records the last item's rectangle under `label` (--stats-json ui.rects: where the input
  /// tests click).
  void note_rect(const char* label);
  /// The cell-size controls show the built size again (a requested build was cancelled or
  /// failed).
  void show_built_cell_size();
  /// The main panel: the status area, then one collapsing section each for the scene, the
  /// structure, the render, the accuracy map, the heat map, the overlays and the pick.
  void draw_panels();
  /// The build's progress and the errors, in a fixed height (nothing under it moves).
  void draw_status_area();
  void draw_scene_section();
  /// The structure's choice and its main build knob (a change rebuilds off the UI thread).
  void draw_structure_knobs();
  /// The built structure's statistics table.
  void draw_build_stats();
  /// Mode, shading, samples, resolution, the speed and frame plots, the camera's buttons.
  void draw_render_section();
  /// The heat map's scale, its EXR export and the pinned-map comparison.
  void draw_heat_map_section();
  /// The overlays' switches, depth ranges and opacity, with what the cap left out.
  void draw_overlay_section();
  /// Moves the current ImGui window back inside the display (after the OS window shrank).
  void keep_in_window();
  /// Preview pictures shown in the last second (the Render section's previews/s).
  int previews_last_second() const;
  void draw_heat_legend();
  /// The key list (F1): every key and mouse action of the viewer.
  void draw_key_list();
  /// A colour ramp bar (the heat map's and the overlays' ramp) with three labels under it.
  void draw_ramp_bar(float width, const char* lo, const char* mid, const char* hi);

  // ---- pick_view.cpp: the picked ray's view
  void do_pick(int px, int py);
  /// Traces the pick's ray again (a new structure) and refreshes what is derived from it.
  void retrace_pick();
  /// Moves the camera so that the picked ray's leaves/cells and its segment in the scene fill
  /// the view, keeping the view direction (key F, "frame pick").
  void frame_pick();
  /// The picked ray's traversal over the image (ImGui background list, thick lines).
  void draw_pick_overlay();
  /// The Pick section of the panel: summary, command, buttons, visit-order legend.
  void draw_pick_panel();
  /// The picked ray's steps, a table in a window of its own.
  void draw_pick_steps();
  /// Why a pick through a structure without counters (Embree) shows no steps.
  std::string no_traversal_note() const;

  // ---- ray_tree.cpp: the picked pixel's ray tree
  /// Traces the pick's whole Whitted ray tree (Renderer::trace_tree) and the replay command
  /// of each of its rays, then selects ray `selected` (the primary if out of range).
  void trace_pick_tree(int selected);
  /// Shows ray `i` of the pick's tree: it is drawn, its steps fill the step table and its
  /// replay command is the one shown.
  void select_tree_ray(int i);
  /// The ray tree in the Pick section: one row per ray (kind, hit, steps, tests, time), the
  /// selected ray's origin, direction and hit under it.
  void draw_ray_tree();

  // ---- diff_map.cpp: the pinned heat map and the difference map
  /// Pins the heat map on screen (its counts, camera, structure and knobs).
  void pin_heatmap();
  /// The pinned map and the current one compare: same mode, size and camera, not a preview.
  bool diff_ready() const;
  void diff_stats(DiffStats& s) const;
  /// Colours the pinned map, the difference or the split view into `rgba` per diff_view_;
  /// false (rgba untouched) when the current map is to be shown.
  bool colorize_diff(std::vector<uint8_t>& rgba);
  /// R = current - pinned, G = current, B = pinned; returns an error message or "".
  std::string write_diff_exr(const std::string& path) const;
  /// The Heat map section's pin / view / totals / histograms.
  void draw_diff_panel();
  /// The signed legend of the difference view (false when another view is shown).
  bool draw_diff_legend();
  /// The heat map's value under the cursor, as a tooltip (and hover_ for --stats-json).
  void update_hover();

  // ---- accuracy_map.cpp: the accuracy map
  /// Collects a finished batch and starts the next; restarts the map when the view changed.
  void update_accuracy();
  /// Every pixel of the current view judged (true when the map is off).
  bool accuracy_complete() const;
  /// Paints the judged pixels' verdicts over `rgba` (the colourised image).
  void colorize_accuracy(std::vector<uint8_t>& rgba) const;
  AccuracySummary accuracy_summary() const;
  /// The Render panel's accuracy controls: the map, the triangle test, the rates.
  void draw_accuracy_panel();

  // ---- stats_json.cpp: --stats-json
  /// Writes the statistics through the atomic writer; false (after an error on stderr) when
  /// the file could not be written.
  bool write_stats(const std::string& path, int exit_code) const;
  /// The final state: scene, structure, shading, camera, pick, overlay, maps, messages.
  nlohmann::json state_json() const;
  /// The pick and its ray tree (null without a pick).
  nlohmann::json pick_json() const;

  ViewerOptions opts_;
  GLFWwindow* window_ = nullptr;
  std::string config_dir_;
  Settings settings_;
  bool save_layout_ = false;  ///< write the ImGui layout (kLayoutFile) at exit

  // What is shown and rendered (UI thread only).
  std::shared_ptr<const World> world_;
  /// The scene's bounds, computed once when it is installed (Mesh::bounds() walks every
  /// vertex: the UI thread does no scene-wide work per frame).
  Box3 scene_bounds_;
  std::string accel_name_;
  BuildParams params_;
  std::string cell_size_text_ = "auto";
  float cell_size_slider_ = 0;  ///< the built cell size, or the one being dragged
  CellChoice cell_choice_;      ///< the current scene's choice (remembered at exit)
  CellChoice loading_choice_;   ///< the choice the scene being loaded is built with
  /// The choice the panel's last hybrid build request asked for; it becomes cell_choice_ if
  /// that build is installed.
  std::optional<CellChoice> requested_choice_;
  double auto_cell_ = 0;           ///< the auto rule's size for the current scene (hybrid)
  std::string cell_estimate_;      ///< the estimate of the last requested or dragged size
  std::string cell_refusal_;       ///< why the last requested size was refused ("" if not)
  double cell_suggested_ = 0;      ///< the size the refusal suggests
  float cell_estimated_for_ = -1;  ///< the slider value cell_estimate_ describes
  /// The slider's estimate being made off the UI thread, and the size it is for.
  BackgroundJob<std::string> estimate_job_;
  float estimate_job_for_ = -1;
  std::map<std::string, std::shared_ptr<const World>> built_;  // per structure, same scene
  CameraControl cam_;
  RenderMode mode_ = RenderMode::Shaded;
  /// The shading chosen (key L, the Render section): the scene's lights, the eye light, the
  /// normals, or auto: the lights unless they leave the view dark (update_auto_shading).
  enum class ShadingChoice { Auto, Lights, Eye, Normals } shading_choice_ = ShadingChoice::Auto;
  /// Auto shading shows the eye light: the last passes found the lights reach almost none
  /// of the view.
  bool auto_eye_ = false;
  /// The share of the view's primary hits a scene light reaches, from the last shaded pass
  /// that checked (RenderCounters::lit / probed); -1 before any.
  double lit_fraction_ = -1;
  /// Below this lit fraction auto shading switches to the eye light; it switches back above
  /// kAutoLitFractionOff (hysteresis, so a view at the threshold does not flicker).
  static constexpr double kAutoLitFractionOn = 0.01, kAutoLitFractionOff = 0.05;
  /// Fewest checked hits that decide: a view that is mostly background keeps its shading.
  static constexpr uint64_t kAutoMinProbed = 16;
  /// The shading posted to the worker now.
  Shading shading_shown() const;
  /// Follows a finished shaded pass's lit fraction (auto shading).
  void update_auto_shading(const RenderedImage& img);
  std::unique_ptr<RenderWorker> worker_;

  // Background tasks: one build/load at a time; a newer build request cancels a running build
  // and waits in pending_* until it has stopped (a load runs to its end first).
  struct Task {
    BackgroundJob<std::shared_ptr<World>> result;
    std::string what;  // shown next to the spinner
    std::string path;  // the scene file a load reads
    std::string kind;  // "load", "rebuild" or "build", for the statistics
    bool new_scene = false;
    std::chrono::steady_clock::time_point started;
    /// The expected build time (the hybrid's estimate, else the last build of the same
    /// structure on this scene); 0 = unknown. The progress bar runs towards it.
    double expected_seconds = 0;
    std::shared_ptr<CancelToken> cancel;                 // the build's BuildParams::cancel
    std::chrono::steady_clock::time_point cancelled_at;  // when cancel_task() set it
  };
  std::optional<Task> task_;
  /// The progress bar of the running task: a fraction of its expected time, rising
  /// monotonically and never reaching 1 before the task ends (Task::expected_seconds).
  static double task_progress(double seconds, double expected);
  /// The fractions the progress bar showed for the last task, (seconds, fraction) per frame.
  std::vector<std::array<double, 2>> progress_log_;
  std::optional<std::pair<std::string, BuildParams>> pending_build_;
  std::string task_error_;
  /// Why brute force renders nothing (its work limit, --brute-work-limit); "" when it renders.
  std::string brute_refusal_;
  bool scripted_rebuild_started_ = false, scripted_rebuild_done_ = false;
  std::chrono::steady_clock::time_point scripted_rebuild_at_{};  ///< when it was requested
  bool supersede_started_ = false;  ///< --supersede-cell-size requested

  // Render job tracking.
  /// Resolution factor of the first preview of a moving camera, before any pass has been
  /// timed; later previews size themselves to kPreviewPassSeconds.
  static constexpr float kPreviewScale = 0.35f;
  /// Frame-time target of a preview pass while the camera moves, in seconds: the preview's
  /// pixel count is chosen from the measured pixels per second of recent passes so that one
  /// pass takes about this long, as a viewport lowers its pixel size to hold a frame rate.
  /// 0.045 s gives about 15 pictures per second (a pass plus the frame and hand-over around it,
  /// docs/VIEWER.md) with the motion-to-photon time about two passes (the pass in flight
  /// finishes, then the newest camera's).
  static constexpr double kPreviewPassSeconds = 0.045;
  /// Bounds of the preview's resolution factor (per axis, times --resolution-scale): below
  /// 0.05 a 1280-wide window gets under 64 pixels across, too coarse to steer by.
  static constexpr float kMinPreviewScale = 0.05f;
  static constexpr float kRadPerPixel = 0.005f;  ///< orbit / look turn per window unit of drag
  /// Longest sleep of an idle UI loop (nothing moving, no build), in seconds: input and new
  /// passes wake it at once, so this only bounds how stale anything else can get.
  static constexpr double kIdleSeconds = 0.25;
  /// The same while a build or load runs: its progress bar moves at 10 frames per second.
  static constexpr double kBusyIdleSeconds = 0.1;
  int settle_frames_ = 3;  ///< frames still to draw without sleeping after the last input
  Camera last_seen_camera_;
  std::chrono::steady_clock::time_point last_move_{};
  Camera posted_camera_;
  int posted_w_ = 0, posted_h_ = 0;
  RenderMode posted_mode_ = RenderMode::Shaded;
  Shading posted_shading_ = Shading::Lights;
  SecondaryOffset posted_offset_ = SecondaryOffset::Robust;
  const World* posted_world_ = nullptr;
  int posted_max_samples_ = 0;
  uint64_t posted_job_ = 0;
  bool posted_preview_ = false;      ///< the camera moved within the last moment
  bool posted_preview_job_ = false;  ///< posted_job_ is a preview
  double pixels_per_second_ = 0;     ///< smoothed render speed of recent passes (0 = none yet)
  /// When each recent job was posted (motion-to-photon figures in --stats-json).
  std::deque<std::pair<uint64_t, std::chrono::steady_clock::time_point>> post_times_;
  std::chrono::steady_clock::time_point run_started_{};  ///< run()'s start, for the statistics

  // The displayed image.
  RenderedImage image_;
  bool have_image_ = false;
  std::vector<uint8_t> rgba_;
  bool recolor_ = false;
  HeatRange heat_range_;
  unsigned tex_ = 0, image_program_ = 0, empty_vao_ = 0;
  std::string gl_renderer_, gl_version_;  // glGetString, for the statistics
  int tex_w_ = 0, tex_h_ = 0;

  // Statistics: short histories for the plots, and every frame, pass, upload and build of
  // the run for --stats-json.
  std::deque<float> mrays_hist_, frame_ms_hist_;
  float last_mrays_ = 0;
  struct PassRecord {
    uint64_t job = 0;
    bool preview = false;
    Shading shading = Shading::Lights;
    double latency_ms = 0;  // the job's post (its camera's input) to its image's upload
    double shown_at = 0;    // seconds since start-up, for the intervals between pictures
    int width = 0, height = 0, samples = 0;
    double seconds = 0;
    RenderCounters rays;
  };
  struct BuildRecord {
    std::string kind;  // "load", "rebuild" or "build"
    std::string accel, scene;
    double build_seconds = 0;  // build() alone
    double wall_seconds = 0;   // request to result, loading included
    BuildStats stats;
    float cell_size = 0;  // requested; 0 = auto
    std::string error;
    bool cancelled = false;
    double cancel_seconds = 0;  // cancel request to the build's end
  };
  std::vector<float> frame_interval_ms_, frame_work_ms_, frame_swap_ms_, colorize_ms_, upload_ms_;
  FramePhases phases_;                // the UI thread's largest time per phase of its loop
  std::thread image_module_preload_;  // see preload_image_module()
  std::vector<PassRecord> passes_;
  std::vector<BuildRecord> builds_;

  // Overlays.
  bool show_splits_ = false, show_cells_ = false, show_boxes_ = false;
  /// Depth ranges drawn. Splits default to the shallow levels (0-6): all 64 levels of the
  /// bunny's hybrid are 37k boxes over the model.
  int split_depth_[2] = {0, 6}, box_depth_[2] = {0, 64};
  bool overlay_dirty_ = true;
  size_t overlay_items_ = 0;
  /// Boxes or cells the overlays would draw without the kMaxOverlaySegments cap.
  size_t overlay_wanted_ = 0;
  struct OverlayResult {
    LineBatch batch;
    size_t items = 0, wanted = 0;
  };
  BackgroundJob<OverlayResult> overlay_job_;  ///< the overlay being built off the UI thread
  /// Uploads the overlay built off the UI thread once it is ready.
  void poll_structure_overlay();
  LineRenderer structure_lines_;
  /// The overlay's work per frame over the run (--stats-json): the most vertices uploaded and
  /// lines drawn in one frame, the vertices uploaded, the frames that uploaded or drew.
  struct OverlayFrames {
    size_t max_uploaded = 0, max_drawn = 0, uploaded = 0;
    int upload_frames = 0, draw_frames = 0;
  } overlay_frames_;
  float overlay_alpha_ = 1.0f;
  /// The split overlay shows only the planes the picked ray crossed ("splits of the picked
  /// ray"), within the depth range.
  bool splits_of_pick_ = false;

  // The pinned heat map (diff_map.cpp).
  struct PinnedMap {
    RenderedImage image;
    Camera camera;      ///< the camera it was rendered with
    std::string label;  ///< build_label() of its structure
  };
  std::optional<PinnedMap> pinned_;
  DiffView diff_view_ = DiffView::Difference;
  float split_at_ = 0.5f;  ///< split view: the fraction of the width showing the pinned map
  float diff_scale_ = 0;   ///< the difference view's |current - pinned| at the scale's ends
  struct Hover {
    bool valid = false, has_pinned = false;
    int x = 0, y = 0;
    float current = 0, pinned = 0;
  };
  Hover hover_;  ///< the heat map's values under the cursor in the last frame

  // The accuracy map (accuracy_map.cpp).
  struct AccuracyMap {
    std::shared_ptr<const World> world;
    SecondaryOffset offset = SecondaryOffset::Robust;
    Camera camera;
    int w = 0, h = 0;
    std::vector<uint8_t> verdict;  ///< per pixel: 0 not judged, else 1 + the worst verdict
    std::vector<uint32_t> order;   ///< the pixels in the order they are judged (shuffled)
    size_t next = 0, judged = 0;
    size_t batch = 16;  ///< pixels in the next batch
    uint64_t counts[2][4] = {};
    double query_seconds = 0;
    uint64_t query_rays = 0;
    BackgroundJob<AccuracyBatch> running;
  };
  bool show_accuracy_ = false;
  /// Where secondary rays start (the accuracy panel, --offset): the render, the pick's ray
  /// tree and the accuracy map all use it.
  SecondaryOffset offset_ = SecondaryOffset::Robust;
  AccuracyMap accuracy_;
  /// The double-precision reference of the current scene, made off the UI thread (its build
  /// walks every triangle) by reference_job_; the batches start once it is made.
  std::shared_ptr<const AccuracyReference> reference_;
  BackgroundJob<std::shared_ptr<const AccuracyReference>> reference_job_;
  /// The scene reference_ (or the running reference_job_) is made for: held with it, as the
  /// reference reads its mesh.
  std::shared_ptr<const Scene> reference_scene_;

  // Pick.
  struct Pick {
    int x = 0, y = 0;
    int w = 0, h = 0;  ///< the image the pixel belongs to
    Camera camera;     ///< the camera the pixel was picked with
    Ray ray;           ///< the pixel's primary ray
    /// The pixel's whole Whitted ray tree, as the render traces it (nodes[0]: `ray`).
    RayTree tree;
    int selected = 0;                   ///< the ray of `tree` shown
    std::vector<std::string> commands;  ///< each tree ray's `kdgrid trace` replay command
    Trace trace;                        ///< the selected ray's traversal
    RaySegment segment;                 ///< the part of the selected ray its traversal covered
    std::string command;                ///< the selected ray's replay command
    bool framed = false;                ///< frame_pick() moved the camera onto it
    uint64_t serial = 0;                ///< distinguishes picks (the step table's ID)
    std::vector<std::array<std::string, 7>> rows;  ///< the step table's text, per step
    float widths[7] = {};                          ///< its columns' content widths
    float widths_for_font = 0;                     ///< the font size the widths were measured with
  };
  std::optional<Pick> pick_;
  uint64_t pick_serial_ = 0;
  /// Space left around the framed pick, as a fraction of the view's half-extent.
  static constexpr float kPickFrameMargin = 0.1f;
  UiAudit audit_;  ///< what the last frame's panels showed (--stats-json)
  /// Window-unit rectangles (x, y, w, h) of the panel's text fields, as last drawn.
  std::map<std::string, std::array<float, 4>> item_rects_;
  /// The panel's y of the first widget under the status area in every frame, by what the
  /// status area showed ("idle", "build", "error"): one value each when nothing jumps.
  std::map<std::string, std::vector<float>> below_status_y_by_state_;
  /// The panel's default width in screen units (times the UI scale): at the full height of a
  /// 1280x720 window it covers under a quarter of it.
  static constexpr float kPanelWidth = 320.0f;
  /// Height of the status area in widget rows: the build line, its progress bar and a line of
  /// error; longer errors scroll inside it.
  static constexpr float kStatusLines = 3.0f;

  // Keys pressed during this frame's events, those also released in them, and those
  // hold_short_presses() holds down for ImGui until the next frame (GLFW key codes).
  std::set<int> pressed_this_frame_, short_presses_, held_keys_;
  /// Esc was pressed in this frame's events: a text field it left is not a request.
  bool escape_this_frame_ = false;

  // Mouse state. The cursor position is the last one GLFW reported through its callback (not a
  // live query), so a press, motion and release queued within one frame replay in order.
  bool left_down_ = false, right_down_ = false, dragged_ = false;
  double press_x_ = 0, press_y_ = 0, cursor_x_ = 0, cursor_y_ = 0;

  // HiDPI: the window's content scale and the UI scale derived from it.
  float content_scale_[2] = {1, 1};
  float ui_scale_ = 1.0f;
  float panel_rect_[4] = {0, 0, 0, 0};  // x, y, w, h of the main panel; w = 0 when hidden
  /// x, y, w, h of the pick's step table as last drawn; w = 0 when not shown. The heat map's
  /// legend keeps clear of it.
  std::array<float, 4> steps_rect_ = {0, 0, 0, 0};
  float steps_table_w_ = 0;  ///< the window width the step table needs for every column

  // Scripted run progress.
  int frame_count_ = 0;
  bool drop_done_ = true;  // --drop issued and its load finished
  bool drop_started_ = false;
  std::string end_reason_;  // why the run ended, for --stats-json
  Camera start_camera_;     // the camera when the current scene was installed
  bool show_keys_ = false;  ///< the key list (F1) is open
  /// The panels go back to their default place and size this frame (key R, "reset layout").
  bool reset_layout_ = false;
  std::string message_;  // last status line (screenshot written, camera printed, ...)
};

}  // namespace kdgrid::viewer
