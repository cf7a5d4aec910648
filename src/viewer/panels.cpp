// kdgrid-viewer's ImGui panels: the main panel (status, scene, structure and its cell size,
// render, statistics, overlays, pick), the heat map's legend and the key list (F1).
#include "viewer/viewer.h"

#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "accel/hybrid/hybrid.h"
#include "util/error.h"
#include "util/format.h"
#include "viewer/viewer_internal.h"

namespace kdgrid::viewer {

void Viewer::request_cell_choice(const CellChoice& c) {
  if (!world_) return;
  const BuildParams p = params_with_cell_size("hybrid", c.resolve(auto_cell_));
  try {
    const HybridEstimate e = GridKdHybrid::estimate(world_->scene->mesh, p);
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
  // cell_choice_ follows what is built (install_world): a build that is cancelled or fails
  // leaves the choice, the controls and what is remembered at exit on the built size.
  requested_choice_ = c;
  start_build("hybrid", p);
}

void Viewer::note_rect(const char* label) {
  const ImVec2 lo = ImGui::GetItemRectMin(), hi = ImGui::GetItemRectMax();
  item_rects_[label] = {lo.x, lo.y, hi.x - lo.x, hi.y - lo.y};
}

bool Viewer::committed_edit() const {
  // Esc leaves a text field with its value restored: not a request.
  return ImGui::IsItemDeactivatedAfterEdit() && !escape_this_frame_;
}

void Viewer::draw_cell_size_controls(BuildParams&, bool&) {
  // The hybrid's cell size, in scene units and as a multiple of the auto size; the slider and
  // the boxes show the built size until edited. Every request is estimated first (cells,
  // bytes, build time) and refused with a size that fits when it does not.
  const float r = scene_radius();
  bool auto_cs = cell_choice_.kind == CellChoice::Kind::Auto;
  const auto chk = [this](const char* label) { audit_.item(label); };
  if (ImGui::Checkbox("auto cell size", &auto_cs))
    request_cell_choice(auto_cs ? CellChoice{}
                                : CellChoice{CellChoice::Kind::Units, double(cell_size_slider_)});
  const float lo = std::min(r * 1e-3f, cell_size_slider_),
              hi = std::max(r * 2.0f, cell_size_slider_);
  ImGui::SliderFloat("cell", &cell_size_slider_, lo, hi, "%.4g", ImGuiSliderFlags_Logarithmic);
  if (committed_edit()) request_cell_choice({CellChoice::Kind::Units, double(cell_size_slider_)});
  chk("cell");
  ImGui::InputFloat("units", &cell_size_slider_, 0, 0, "%.6g");
  chk("units");
  note_rect("units");
  if (committed_edit() && cell_size_slider_ > 0)
    request_cell_choice({CellChoice::Kind::Units, double(cell_size_slider_)});
  if (auto_cell_ > 0) {
    float mult = float(cell_size_slider_ / auto_cell_);
    // The size follows the typed multiple as it is typed, so its estimate (below) is shown
    // before Enter builds it.
    if (ImGui::InputFloat("x auto", &mult, 0, 0, "%.4g") && mult > 0)
      cell_size_slider_ = float(mult * auto_cell_);
    chk("x auto");
    note_rect("x auto");
    if (committed_edit() && mult > 0)
      request_cell_choice({CellChoice::Kind::Multiple, double(mult)});
  }
  // The estimate of the size on the slider, updated while it moves. It walks every triangle,
  // so it runs off the UI thread; one at a time, the newest size next.
  if (estimate_job_.ready()) {
    cell_estimate_ = estimate_job_.get();
    cell_estimated_for_ = estimate_job_for_;
  }
  if (!estimate_job_.valid() && cell_estimated_for_ != cell_size_slider_ && cell_size_slider_ > 0 &&
      world_) {
    estimate_job_for_ = cell_size_slider_;
    estimate_job_ =
        run_in_background([w = world_, p = params_with_cell_size("hybrid", cell_size_slider_)] {
          try {
            return GridKdHybrid::estimate(w->scene->mesh, p).describe();
          } catch (const ParamError& e) {
            return std::string(e.what());
          }
        });
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

void Viewer::draw_panels() {
  // The panel starts kPanelWidth wide and, with the window's height, at most a quarter of its
  // area; it is resizable and collapsible (the title bar's triangle), and an interactive run
  // remembers its place and size in imgui.ini.
  const ImGuiIO& io = ImGui::GetIO();
  const ImGuiStyle& style = ImGui::GetStyle();
  const float margin = 8 * ui_scale_;
  const float pw = std::min(kPanelWidth * ui_scale_, io.DisplaySize.x * 0.5f);
  const float ph = std::max(
      std::min(io.DisplaySize.y - 2 * margin, io.DisplaySize.x * io.DisplaySize.y * 0.25f / pw),
      ImGui::GetFrameHeight() * 4);
  const ImGuiCond cond = reset_layout_ ? ImGuiCond_Always : ImGuiCond_FirstUseEver;
  ImGui::SetNextWindowPos(ImVec2(margin, margin), cond);
  ImGui::SetNextWindowSize(ImVec2(pw, ph), cond);
  if (reset_layout_) ImGui::SetNextWindowCollapsed(false, ImGuiCond_Always);
  ImGui::Begin("kdgrid");
  keep_in_window();
  const ImVec2 panel_pos = ImGui::GetWindowPos(), panel_size = ImGui::GetWindowSize();
  panel_rect_[0] = panel_pos.x;
  panel_rect_[1] = panel_pos.y;
  panel_rect_[2] = panel_size.x;
  panel_rect_[3] = panel_size.y;
  // Widgets leave room on their right for the widest label, so no label is cut.
  float label_w = 0;
  for (const char* l : {"structure", "max leaf size", "test/step cost", "cell", "units", "x auto",
                        "cell size", "max samples", "resolution", "Mrays/s", "frame work",
                        "split depths", "box depths", "opacity", "min", "max"})
    label_w = std::max(label_w, ImGui::CalcTextSize(l).x);
  ImGui::PushItemWidth(-(label_w + style.ItemInnerSpacing.x + 1));

  draw_status_area();
  if (!world_ && !task_) {
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextDisabled("no scene loaded: drop a .gltf/.glb/.ply/.obj file to load one");
    ImGui::PopTextWrapPos();
  }
  if (ImGui::CollapsingHeader("Scene", ImGuiTreeNodeFlags_DefaultOpen) && world_)
    draw_scene_section();
  if (ImGui::CollapsingHeader("Structure", ImGuiTreeNodeFlags_DefaultOpen) && world_) {
    draw_structure_knobs();
    draw_build_stats();
  }
  if (ImGui::CollapsingHeader("Render", ImGuiTreeNodeFlags_DefaultOpen)) draw_render_section();

  if (ImGui::CollapsingHeader("Accuracy")) draw_accuracy_panel();
  if (mode_ != RenderMode::Shaded &&
      ImGui::CollapsingHeader("Heat map", ImGuiTreeNodeFlags_DefaultOpen))
    draw_heat_map_section();
  if (ImGui::CollapsingHeader("Overlays", ImGuiTreeNodeFlags_DefaultOpen)) draw_overlay_section();

  if (ImGui::CollapsingHeader("Pick", ImGuiTreeNodeFlags_DefaultOpen)) draw_pick_panel();
  if (!message_.empty()) ImGui::TextWrapped("%s", message_.c_str());
  ImGui::PopItemWidth();
  ImGui::End();

  draw_pick_steps();
  if (have_image_ && image_.mode != RenderMode::Shaded) draw_heat_legend();
  reset_layout_ = false;
}

void Viewer::draw_status_area() {
  // The status area: a fixed height for the build's progress and the errors, scrolling when
  // they need more, so that nothing under it moves when a build starts or ends or an error
  // appears.
  audit_.status_top = ImGui::GetCursorPosY();
  ImGui::BeginChild("status", ImVec2(0, ImGui::GetFrameHeightWithSpacing() * kStatusLines), false);
  const std::string render_error = worker_ ? worker_->error() : std::string();
  if (task_) {
    const double secs = std::chrono::duration<double>(Clock::now() - task_->started).count();
    if (task_->expected_seconds > 0)
      ImGui::Text("%s ... %.1f s of about %.2g s", task_->what.c_str(), secs,
                  task_->expected_seconds);
    else
      ImGui::Text("%s ... %.1f s", task_->what.c_str(), secs);
    audit_.item(task_->what.c_str());
    same_line_if_fits(task_->cancel->cancelled() ? "cancelling" : "cancel (Esc)");
    if (task_->cancel->cancelled())
      ImGui::TextDisabled("cancelling");
    else if (ImGui::SmallButton("cancel (Esc)"))
      cancel_task();
    audit_.item("cancel (Esc)");
    // Builds report no progress: the bar runs towards the expected time, monotonically.
    const double f = task_progress(secs, task_->expected_seconds);
    if (progress_log_.empty() || progress_log_.back()[0] != secs)
      progress_log_.push_back({secs, f});
    ImGui::ProgressBar(float(f), ImVec2(-1, 0), "");
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
  if (!render_error.empty())
    ImGui::TextColored(ImVec4(1, 0.4f, 0.4f, 1), "render: %s", render_error.c_str());
  if (!brute_refusal_.empty())
    ImGui::TextColored(kRefusalColor, "not rendered: %s", brute_refusal_.c_str());
  ImGui::PopTextWrapPos();
  ImGui::EndChild();
  ImGui::Separator();
  audit_.below_status_y = ImGui::GetCursorPosY();
  auto& ys = below_status_y_by_state_[task_ ? "build" : (!task_error_.empty() ? "error" : "idle")];
  if (std::find(ys.begin(), ys.end(), audit_.below_status_y) == ys.end())
    ys.push_back(audit_.below_status_y);
}

void Viewer::draw_scene_section() {
  const Scene& s = *world_->scene;
  ImGui::TextWrapped("%s", s.source.c_str());
  ImGui::TextWrapped("%zu triangles, %zu vertices", s.mesh.num_triangles(), s.mesh.num_vertices());
  ImGui::TextWrapped("%zu materials, %zu lights, %zu textures", s.materials.size(), s.lights.size(),
                     s.textures.size());
  const Box3& b = scene_bounds_;
  ImGui::TextWrapped("bounds (%.3g %.3g %.3g) - (%.3g %.3g %.3g)", b.lo.x, b.lo.y, b.lo.z, b.hi.x,
                     b.hi.y, b.hi.z);
  ImGui::PushTextWrapPos(0.0f);
  ImGui::TextDisabled("drop a .gltf/.glb/.ply/.obj file to load it");
  ImGui::PopTextWrapPos();
}

void Viewer::draw_structure_knobs() {
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
  audit_.item("structure");
  // The main build knob of the selected structure; any change rebuilds off the UI thread.
  bool rebuild = false;
  BuildParams p = params_;
  const float r = scene_radius();
  if (accel_name_ == "bvh") {
    ImGui::SliderInt("max leaf size", &p.bvh_max_leaf, 1, 32);
    rebuild = committed_edit();
    audit_.item("max leaf size");
  } else if (accel_name_ == "kdtree") {
    ImGui::SliderFloat("test/step cost", &p.kd_intersection_cost, 0.1f, 20.0f, "%.2f",
                       ImGuiSliderFlags_Logarithmic);
    rebuild = committed_edit();
    audit_.item("test/step cost");
  } else if (accel_name_ == "hybrid") {
    draw_cell_size_controls(p, rebuild);
  } else if (accel_name_ == "irregular") {
    // The irregular grid has no cell size: its two densities (BuildParams) set its cells.
    ImGui::SliderFloat("top density", &p.irregular_top_density, 0.01f, 2.0f, "%.3g",
                       ImGuiSliderFlags_Logarithmic);
    rebuild = committed_edit();
    audit_.item("top density");
    ImGui::SliderFloat("sub density", &p.irregular_sub_density, 0.25f, 16.0f, "%.3g",
                       ImGuiSliderFlags_Logarithmic);
    rebuild = rebuild || committed_edit();
    audit_.item("sub density");
  } else if (accel_name_ == "grid") {
    if (cell_size_slider_ <= 0)
      cell_size_slider_ = params_.cell_size > 0 ? params_.cell_size : r * 0.05f;
    ImGui::SliderFloat("cell size", &cell_size_slider_, r * 1e-3f, r * 0.5f, "%.4g",
                       ImGuiSliderFlags_Logarithmic);
    audit_.item("cell size");
    if (committed_edit()) {
      p = params_with_cell_size(accel_name_, cell_size_slider_);
      rebuild = true;
    }
    ImGui::InputFloat("##cellvalue", &cell_size_slider_, 0, 0, "%.6g");
    if (committed_edit() && cell_size_slider_ > 0) {
      p = params_with_cell_size(accel_name_, cell_size_slider_);
      rebuild = true;
    }
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextDisabled("grid: cell size sets lambda = %.3g", params_.grid_lambda);
    ImGui::PopTextWrapPos();
  }
  if (rebuild) start_build(accel_name_, p);
}

void Viewer::draw_build_stats() {
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
    row("bytes", format_bytes_iec(double(st.bytes)));
    row("nodes", std::to_string(st.nodes));
    row("leaves", std::to_string(st.leaves) + " (" + std::to_string(st.empty_leaves) + " empty)");
    row("references", std::to_string(st.references));
    row("max depth", std::to_string(st.max_depth));
    for (const auto& [k, v] : st.extra) row(k.c_str(), v);
    ImGui::EndTable();
  }
}

void Viewer::draw_render_section() {
  int m = int(mode_);
  ImGui::RadioButton("shaded", &m, int(RenderMode::Shaded));
  ImGui::SameLine();
  ImGui::RadioButton("steps", &m, int(RenderMode::HeatSteps));
  ImGui::SameLine();
  ImGui::RadioButton("tri tests", &m, int(RenderMode::HeatTests));
  audit_.item("tri tests");
  ImGui::SameLine();
  ImGui::RadioButton("time", &m, int(RenderMode::HeatTime));
  mode_ = RenderMode(m);
  audit_.item("time");
  if (mode_ == RenderMode::Shaded) {
    // The shading (key L): auto shows the eye light where the scene's lights leave the view
    // dark (update_auto_shading).
    int sc = int(shading_choice_);
    ImGui::PushID("shading");
    ImGui::TextUnformatted("light (L):");
    for (const auto& [v, label] :
         {std::pair{ShadingChoice::Auto, "auto"}, std::pair{ShadingChoice::Lights, "lights"},
          std::pair{ShadingChoice::Eye, "eye"}, std::pair{ShadingChoice::Normals, "normals"}}) {
      same_line_if_fits(label);
      ImGui::RadioButton(label, &sc, int(v));
    }
    ImGui::PopID();
    shading_choice_ = ShadingChoice(sc);
    audit_.item("normals");
    if (shading_choice_ == ShadingChoice::Auto) {
      ImGui::PushTextWrapPos(0.0f);
      if (lit_fraction_ < 0)
        ImGui::TextDisabled("auto: the scene's lights");
      else
        ImGui::TextDisabled("auto: %s (the lights reach %.1f%% of the view)",
                            auto_eye_ ? "eye light" : "the scene's lights", 100.0 * lit_fraction_);
      ImGui::PopTextWrapPos();
    }
  }
  ImGui::TextWrapped("%d x %d, %d samples, %.3g Mrays/s, %d previews/s", posted_w_, posted_h_,
                     have_image_ ? image_.samples : 0, last_mrays_, previews_last_second());
  audit_.item("previews/s");
  ImGui::SliderInt("max samples", &opts_.max_samples, 1, 4096, "%d", ImGuiSliderFlags_Logarithmic);
  audit_.item("max samples");
  if (ImGui::SliderFloat("resolution", &opts_.resolution_scale, 0.1f, 1.0f, "%.2f")) {
    opts_.resolution_scale = std::clamp(opts_.resolution_scale, 0.1f, 1.0f);
  }
  audit_.item("resolution");
  // Both plots run from 0 to their history's maximum, which the overlay names (with the
  // latest value), so that their height reads as a fraction of a stated value.
  const auto plot = [this](const char* name, const std::deque<float>& hist, const char* unit) {
    std::vector<float> v(hist.begin(), hist.end());
    const float hi = v.empty() ? 0.0f : *std::max_element(v.begin(), v.end());
    char overlay[64];
    std::snprintf(overlay, sizeof overlay, "%.3g%s, axis 0-%.3g", v.empty() ? 0.0f : v.back(), unit,
                  hi);
    ImGui::PlotLines(name, v.data(), int(v.size()), 0, overlay, 0.0f, hi > 0 ? hi : 1.0f,
                     ImVec2(0, 40));
    audit_.item(name);
  };
  plot("Mrays/s", mrays_hist_, "");
  // Work per frame (events, hand-over, upload, drawing), not the idle sleep between frames.
  plot("frame work", frame_ms_hist_, " ms");
  ImGui::TextWrapped("camera: %s (Tab), speed x%.2f (+/-)",
                     cam_.mode() == CameraMode::Fly ? "fly" : "orbit", cam_.speed_scale());
  if (ImGui::Button("print camera (C)")) print_camera();
  audit_.item("print camera (C)");
  same_line_if_fits("frame scene (Home)");
  if (ImGui::Button("frame scene (Home)")) cam_.frame_scene();
  audit_.item("frame scene (Home)");
  same_line_if_fits("screenshot (P)");
  if (ImGui::Button("screenshot (P)"))
    save_screenshot(default_output_name("kdgrid-screenshot", "png"));
  audit_.item("screenshot (P)");
  same_line_if_fits("reset layout (R)");
  if (ImGui::Button("reset layout (R)")) reset_layout_ = true;
  audit_.item("reset layout (R)");
}

void Viewer::draw_heat_map_section() {
  int s = int(settings_.heat_scale);
  bool changed = ImGui::RadioButton("auto", &s, int(HeatScale::Auto));
  ImGui::SameLine();
  changed |= ImGui::RadioButton("fixed", &s, int(HeatScale::Fixed));
  ImGui::SameLine();
  changed |= ImGui::RadioButton("log", &s, int(HeatScale::Log));
  audit_.item("log");
  settings_.heat_scale = HeatScale(s);
  if (settings_.heat_scale == HeatScale::Fixed) {
    changed |= ImGui::InputFloat("min", &settings_.heat_fixed_min);
    changed |= ImGui::InputFloat("max", &settings_.heat_fixed_max);
  }
  if (changed) recolor_ = true;
  if (ImGui::Button("export EXR") && have_image_ && image_.mode != RenderMode::Shaded) {
    const std::string path =
        default_output_name((std::string("kdgrid-") + mode_name(image_.mode)).c_str(), "exr");
    const std::string err = write_counts_exr(
        path, image_,
        std::string("kdgrid ") + mode_name(image_.mode) + " per pixel, " + accel_name_);
    message_ = err.empty() ? "wrote " + path : err;
    std::printf("kdgrid-viewer: %s\n", message_.c_str());
  }
  draw_diff_panel();
}

void Viewer::draw_overlay_section() {
  bool dirty = false;
  // A depth-range slider with its colour ramp; the legend is recorded for --stats-json.
  const auto depth_range = [&](const char* label, const char* what, int range[2]) {
    ImGui::SliderInt2(label, range, 0, 64);
    dirty |= committed_edit();
    audit_.item(label);
    char l0[32], l2[32];
    std::snprintf(l0, sizeof l0, "depth %d", range[0]);
    std::snprintf(l2, sizeof l2, "%d", range[1]);
    draw_ramp_bar(ImGui::CalcItemWidth(), l0, "", l2);
    audit_.legends.push_back(std::string(what) + ": " + l0 + " .. " + l2);
  };
  dirty |= ImGui::Checkbox("kd split planes", &show_splits_);
  if (show_splits_) {
    dirty |= ImGui::Checkbox("splits of the picked ray", &splits_of_pick_);
    audit_.item("splits of the picked ray");
    if (splits_of_pick_ && !pick_) {
      ImGui::PushTextWrapPos(0.0f);
      ImGui::TextDisabled("pick a pixel to see the planes its ray crosses");
      ImGui::PopTextWrapPos();
    }
    depth_range("split depths", "split depth", split_depth_);
  }
  dirty |= ImGui::Checkbox("cells / leaves", &show_cells_);
  dirty |= ImGui::Checkbox("boxes by depth", &show_boxes_);
  if (show_boxes_) {
    depth_range("box depths", "box depth", box_depth_);
  }
  ImGui::SliderFloat("opacity", &overlay_alpha_, 0.05f, 1.0f);
  audit_.item("opacity");
  if (dirty) overlay_dirty_ = true;
  ImGui::TextWrapped("%zu items, %zu lines%s", overlay_items_, structure_lines_.vertex_count() / 2,
                     overlay_job_.valid() ? " (building the overlay ...)" : "");
  if (overlay_items_ < overlay_wanted_) {
    // The cap keeps the overlay drawable: say what it left out and how to see the rest.
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextColored(kRefusalColor,
                       "capped at %zu lines: %zu of %zu boxes drawn (the deepest levels left "
                       "out); narrow the depth range to see them",
                       kMaxOverlaySegments, overlay_items_, overlay_wanted_);
    ImGui::PopTextWrapPos();
    audit_.item("capped");
  }
}

int Viewer::previews_last_second() const {
  const double now = std::chrono::duration<double>(Clock::now() - run_started_).count();
  int n = 0;
  for (auto it = passes_.rbegin(); it != passes_.rend() && it->shown_at > now - 1.0; ++it)
    n += it->preview;
  return n;
}

void Viewer::keep_in_window() {
  // A window made smaller (down to a few pixels) leaves a panel where ImGui put it, partly
  // or wholly outside, and imgui.ini would remember that place: every frame the panel is put
  // back inside, at the top left when it is larger than the window.
  const ImVec2 d = ImGui::GetIO().DisplaySize, pos = ImGui::GetWindowPos(),
               size = ImGui::GetWindowSize();
  if (d.x <= 0 || d.y <= 0) return;  // minimised
  const ImVec2 in(std::clamp(pos.x, 0.0f, std::max(0.0f, d.x - size.x)),
                  std::clamp(pos.y, 0.0f, std::max(0.0f, d.y - size.y)));
  if (in.x != pos.x || in.y != pos.y) ImGui::SetWindowPos(in);
}

void Viewer::draw_heat_legend() {
  const ImGuiIO& io = ImGui::GetIO();
  const float s = ui_scale_;
  // Bottom right, or above the pick's step table where that reaches the right edge's corner.
  float bottom = io.DisplaySize.y - 8;
  const float legend_w = 260 * s;
  if (steps_rect_[2] > 0 && steps_rect_[0] + steps_rect_[2] > io.DisplaySize.x - legend_w &&
      steps_rect_[1] + steps_rect_[3] > bottom - 80 * s)
    bottom = std::max(80 * s, steps_rect_[1] - 8);
  ImGui::SetNextWindowPos(ImVec2(io.DisplaySize.x - 8, bottom), ImGuiCond_Always, ImVec2(1, 1));
  ImGui::SetNextWindowBgAlpha(0.7f);
  ImGui::Begin("legend", nullptr,
               ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_AlwaysAutoResize |
                   ImGuiWindowFlags_NoSavedSettings | ImGuiWindowFlags_NoFocusOnAppearing |
                   ImGuiWindowFlags_NoNav);
  const ImVec2 lp = ImGui::GetWindowPos(), ls = ImGui::GetWindowSize();
  item_rects_["legend"] = {lp.x, lp.y, ls.x, ls.y};
  if (world_ && !world_->accel->has_counters() && image_.mode != RenderMode::HeatTime) {
    // Embree counts nothing: a ramp with a 0..1 scale would read as "no work at all".
    ImGui::TextColored(ImVec4(1.0f, 0.8f, 0.3f, 1.0f),
                       "%s keeps no traversal counters: no %s heat map", world_->name.c_str(),
                       image_.mode == RenderMode::HeatSteps ? "step" : "test");
    ImGui::TextDisabled("choose a kdgrid structure to see its work per pixel");
    ImGui::End();
    return;
  }
  if (draw_diff_legend()) {
    ImGui::End();
    return;
  }
  ImGui::Text("%s per pixel (%s scale)", heat_label(image_.mode), to_string(settings_.heat_scale));
  // The value at the middle of the bar differs between linear and log scales.
  const float mid =
      settings_.heat_scale == HeatScale::Log
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
    const ImU32 ca = ImGui::GetColorU32(ImVec4(a.r, a.g, a.b, 1)),
                cb = ImGui::GetColorU32(ImVec4(b.r, b.g, b.b, 1));
    dl->AddRectFilledMultiColor(ImVec2(p.x + w * i / kSegs, p.y),
                                ImVec2(p.x + w * (i + 1) / kSegs, p.y + h), ca, cb, cb, ca);
  }
  ImGui::Dummy(ImVec2(w, h));
  const float x0 = ImGui::GetCursorPosX();
  ImGui::TextUnformatted(lo);
  ImGui::SameLine(x0 + 0.5f * (w - ImGui::CalcTextSize(mid).x));
  ImGui::TextUnformatted(mid);
  ImGui::SameLine(x0 + w - ImGui::CalcTextSize(hi).x);
  ImGui::TextUnformatted(hi);
}

void Viewer::draw_key_list() {
  if (!show_keys_) return;
  const ImGuiIO& io = ImGui::GetIO();
  ImGui::SetNextWindowPos(ImVec2(io.DisplaySize.x * 0.5f, io.DisplaySize.y * 0.5f),
                          ImGuiCond_Appearing, ImVec2(0.5f, 0.5f));
  if (!ImGui::Begin("keys (F1)", &show_keys_,
                    ImGuiWindowFlags_AlwaysAutoResize | ImGuiWindowFlags_NoSavedSettings)) {
    ImGui::End();
    return;
  }
  keep_in_window();
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
      {"L", "light: auto, the scene's lights, eye light, normals"},
      {"R", "reset the panels' layout (place, size, open)"},
      {"Esc", "cancel the running build (the built structure stays)"},
      {"F1", "this list"},
      {"Ctrl+Q", "quit (also from a text field)"},
  };
  if (ImGui::BeginTable("keys", 2, ImGuiTableFlags_SizingFixedFit | ImGuiTableFlags_RowBg)) {
    for (const auto& k : kKeys) {
      audit_.items.push_back(std::string("key ") + k[0]);
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

}  // namespace kdgrid::viewer
