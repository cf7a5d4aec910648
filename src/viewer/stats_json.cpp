// kdgrid-viewer's --stats-json: the run's statistics (every frame, pass and build) and its
// final state (scene, structure, camera, overlays, pick, what the panels showed), written at
// exit for the tests and the reports.
#include "viewer/viewer.h"

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <tbb/global_control.h>
#include <nlohmann/json.hpp>

#include "accel/hybrid/hybrid.h"
#include "util/atomic_file.h"
#include "viewer/viewer_internal.h"

namespace kdgrid::viewer {

namespace {

nlohmann::json vec_json(const Vec3& v) {
  return {v.x, v.y, v.z};
}

nlohmann::json camera_json(const Camera& c) {
  return {{"eye", vec_json(c.eye)},
          {"target", vec_json(c.target)},
          {"up", vec_json(c.up)},
          {"fov", c.fov_deg}};
}

/// The largest, median and 95th-percentile value of `ms` (nulls when it is empty).
nlohmann::json summarize_ms(std::vector<float> ms) {
  if (ms.empty()) return {{"max", nullptr}, {"p50", nullptr}, {"p95", nullptr}, {"frames", 0}};
  std::sort(ms.begin(), ms.end());
  const auto at = [&](double q) { return ms[size_t(q * double(ms.size() - 1) + 0.5)]; };
  return {{"max", ms.back()}, {"p50", at(0.5)}, {"p95", at(0.95)}, {"frames", ms.size()}};
}

}  // namespace

nlohmann::json Viewer::pick_json() const {
  using nlohmann::json;
  json p;
  if (pick_) {
    p = {{"x", pick_->x},
         {"y", pick_->y},
         {"steps", pick_->trace.steps.size()},
         {"hit", pick_->trace.hit.valid()},
         {"command", pick_->command},
         {"framed", pick_->framed},
         {"segment", {pick_->segment.t0, pick_->segment.t1}},
         {"selected", pick_->selected}};
    // The pixel's ray tree, in the order the renderer traced it.
    json tree = json::array();
    for (size_t k = 0; k < pick_->tree.nodes.size(); ++k) {
      const RayTreeNode& n = pick_->tree.nodes[k];
      const Trace& t = n.trace;
      json e = {{"kind", to_string(n.kind)},
                {"parent", n.parent},
                {"depth", n.depth},
                {"origin", vec_json(n.ray.org)},
                {"dir", vec_json(n.ray.dir)},
                {"tmin", n.ray.tmin},
                {"tmax", std::isfinite(n.ray.tmax) ? json(n.ray.tmax) : json("inf")},
                {"steps", t.steps.size()},
                {"leaves", t.counters.leaves},
                {"tests", t.counters.tri_tests},
                {"seconds", n.seconds},
                {"command", pick_->commands[k]}};
      if (n.kind == RayKind::Shadow) {
        e["light"] = n.light;
        e["occluded"] = t.occluded;
      } else {
        e["hit"] = t.hit.valid() ? json{{"prim", t.hit.prim}, {"t", t.hit.t}} : json(nullptr);
      }
      tree.push_back(e);
    }
    p["tree"] = tree;
  } else {
    p = nullptr;
  }
  return p;
}

nlohmann::json Viewer::state_json() const {
  using nlohmann::json;
  json st;
  if (world_) {
    st["scene"] = world_->scene->source;
    st["triangles"] = world_->scene->mesh.num_triangles();
    st["accel"] = world_->name;
    st["cell_size"] = world_->params.cell_size;
    if (const auto* h = dynamic_cast<const GridKdHybrid*>(world_->accel.get())) {
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
  static const char* const kShadingChoices[] = {"auto", "lights", "eye", "normals"};
  st["shading"] = kShadingChoices[int(shading_choice_)];
  st["shading_shown"] = to_string(shading_shown());
  st["lit_fraction"] = lit_fraction_;
  st["camera"] = camera_json(cam_.camera());
  st["ui_hidden"] = opts_.hide_ui;
  st["keys_shown"] = show_keys_;
  st["start_camera"] = camera_json(start_camera_);
  st["camera_mode"] = cam_.mode() == CameraMode::Fly ? "fly" : "orbit";
  st["speed_scale"] = cam_.speed_scale();
  st["speed"] = cam_.speed();
  st["camera_flags"] = cam_.cli_flags();
  st["pick"] = pick_json();
  st["overlay"] = {{"splits", show_splits_},
                   {"cells", show_cells_},
                   {"boxes", show_boxes_},
                   {"splits_of_pick", splits_of_pick_},
                   {"split_depths", {split_depth_[0], split_depth_[1]}},
                   {"items", overlay_items_},
                   {"wanted", overlay_wanted_},
                   {"lines", structure_lines_.vertex_count() / 2},
                   {"upload_limit", kUploadVerticesPerFrame},
                   {"draw_limit", kDrawLinesPerFrame},
                   {"max_vertices_uploaded_per_frame", overlay_frames_.max_uploaded},
                   {"max_lines_drawn_per_frame", overlay_frames_.max_drawn},
                   {"vertices_uploaded", overlay_frames_.uploaded},
                   {"upload_frames", overlay_frames_.upload_frames},
                   {"draw_frames", overlay_frames_.draw_frames},
                   {"complete", !structure_lines_.uploading() && !structure_lines_.drawing()}};
  if (pinned_) {
    DiffStats ds;
    diff_stats(ds);
    st["diff"] = {{"pinned", pinned_->label},
                  {"mode", mode_name(pinned_->image.mode)},
                  {"view", to_string(diff_view_)},
                  {"ready", diff_ready()},
                  {"pinned_total", ds.pinned_total},
                  {"current_total", ds.current_total},
                  {"more", ds.more},
                  {"fewer", ds.fewer},
                  {"max_abs", ds.max_abs}};
  } else {
    st["diff"] = nullptr;
  }
  st["hover"] = hover_.valid
                    ? json{{"x", hover_.x},
                           {"y", hover_.y},
                           {"current", hover_.current},
                           {"pinned", hover_.has_pinned ? json(hover_.pinned) : json(nullptr)}}
                    : json(nullptr);
  if (show_accuracy_) {
    const AccuracySummary a = accuracy_summary();
    json by_kind = json::object();
    const char* kinds[2] = {"primary", "secondary"};
    for (int i = 0; i < 2; ++i)
      for (int v = 0; v < 4; ++v) by_kind[kinds[i]][to_string(AccuracyVerdict(v))] = a.counts[i][v];
    json pixels = json::object();
    for (int v = 0; v < 4; ++v) pixels[to_string(AccuracyVerdict(v))] = a.pixel_verdicts[v];
    st["accuracy"] = {{"triangle_test", world_ ? to_string(world_->params.triangle_test) : ""},
                      {"offset", to_string(offset_)},
                      {"pixels", a.pixels},
                      {"judged", a.judged},
                      {"complete", accuracy_complete()},
                      {"rays", a.rays},
                      {"rays_by_kind", by_kind},
                      {"pixels_by_verdict", pixels},
                      {"disagreement_rate", a.disagreement_rate},
                      {"mrays", a.mrays}};
  } else {
    st["accuracy"] = nullptr;
  }
  st["message"] = message_;
  st["error"] = task_error_;
  st["render_error"] = worker_ ? worker_->error() : std::string();
  st["render_refusal"] = brute_refusal_;
  st["samples"] = have_image_ ? image_.samples : 0;
  return st;
}

bool Viewer::write_stats(const std::string& path, int exit_code) const {
  using nlohmann::json;
  int ww = 0, wh = 0, fw = 0, fh = 0;
  glfwGetWindowSize(window_, &ww, &wh);
  glfwGetFramebufferSize(window_, &fw, &fh);
  json j;
  j["exit_code"] = exit_code;
  j["end"] = end_reason_;
  j["display"] = {
      {"window", {ww, wh}},
      {"framebuffer", {fw, fh}},
      {"content_scale", {content_scale_[0], content_scale_[1]}},
      {"ui_scale", ui_scale_},
      {"font_size",
       ImGui::GetIO().Fonts->Fonts.empty() ? 0.0f : ImGui::GetIO().Fonts->Fonts[0]->FontSize},
      {"image", {posted_w_, posted_h_}},
      {"panel", opts_.hide_ui ? json(nullptr)
                              : json{{"x", panel_rect_[0]},
                                     {"y", panel_rect_[1]},
                                     {"w", panel_rect_[2]},
                                     {"h", panel_rect_[3]}}},
      {"gl_renderer", gl_renderer_},
      {"gl_version", gl_version_}};
  const RenderSettings rs;  // what sync_render_job leaves at its defaults
  j["settings"] = {
      {"threads", tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism)},
      {"threads_option", opts_.threads},
      {"max_samples", opts_.max_samples},
      {"samples_per_pass", 1},
      {"shadows", rs.shadows},
      {"max_depth", rs.max_depth},
      {"offset", to_string(offset_)},
      {"resolution_scale", opts_.resolution_scale},
      {"max_fps", opts_.max_fps},
      {"mode", mode_name(mode_)}};
  j["state"] = state_json();
  // What the last frame's panels showed (empty with the panels hidden).
  j["ui"] = {{"clipped", audit_.clipped},
             {"legends", audit_.legends},
             {"items", audit_.items},
             {"status_top", audit_.status_top},
             {"below_status_y", audit_.below_status_y},
             {"table_cells", audit_.table_cells},
             {"below_status_y_by_state", below_status_y_by_state_},
             {"rects", item_rects_},
             {"steps_table_width", steps_table_w_}};

  // The UI thread's cost per frame, whole (work_ms) and without the buffer swap, where a
  // software GL draws (ui_ms): the largest, the median and the 95th percentile.
  std::vector<float> ui_ms(frame_work_ms_.size());
  for (size_t i = 0; i < ui_ms.size(); ++i)
    ui_ms[i] = frame_work_ms_[i] - (i < frame_swap_ms_.size() ? frame_swap_ms_[i] : 0.0f);
  j["frames"] = {{"count", frame_count_},
                 {"interval_ms", frame_interval_ms_},
                 {"work_ms", frame_work_ms_},
                 {"swap_ms", frame_swap_ms_},
                 {"ui_ms", ui_ms},
                 {"work_ms_summary", summarize_ms(frame_work_ms_)},
                 {"ui_ms_summary", summarize_ms(ui_ms)}};
  // The largest time of each phase of the loop, and the frame it was taken in.
  json phases = json::object();
  for (size_t p = 0; p < FramePhases::kCount; ++p)
    phases[FramePhases::kNames[p]] = {{"max_ms", phases_.max_ms(p)},
                                      {"frame", phases_.max_frame(p)}};
  j["frames"]["phases"] = phases;
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
                      {"shading", to_string(p.shading)},
                      {"lit_probed", p.rays.probed},
                      {"lit", p.rays.lit},
                      {"mrays", p.seconds > 0 ? double(rays) / p.seconds * 1e-6 : 0.0}});
  }
  j["passes"] = passes;
  j["colorize_ms"] = colorize_ms_;
  j["upload_ms"] = upload_ms_;
  json builds = json::array();
  for (const BuildRecord& b : builds_) {
    json e = {{"kind", b.kind},
              {"accel", b.accel},
              {"scene", b.scene},
              {"build_seconds", b.build_seconds},
              {"wall_seconds", b.wall_seconds},
              {"requested_cell_size", b.cell_size}};
    if (b.cancelled) e["cancel_seconds"] = b.cancel_seconds;
    if (!b.error.empty()) {
      e["error"] = b.error;
    } else {
      json extra = json::object();
      for (const auto& [k, v] : b.stats.extra) extra[k] = v;
      e["stats"] = {{"seconds", b.stats.seconds},     {"bytes", b.stats.bytes},
                    {"nodes", b.stats.nodes},         {"leaves", b.stats.leaves},
                    {"max_depth", b.stats.max_depth}, {"extra", extra}};
    }
    builds.push_back(e);
  }
  j["builds"] = builds;
  j["build_progress"] = progress_log_;  // the last task's bar: (seconds, fraction) per frame

  // Error texts can quote a file's bytes (a PLY with garbage after its header): invalid UTF-8
  // is replaced (U+FFFD) instead of throwing out of dump() and leaving the file empty.
  try {
    write_file_atomically(path, j.dump(1, ' ', false, json::error_handler_t::replace) + "\n");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "kdgrid-viewer: error: --stats-json %s\n", e.what());
    return false;
  }
  std::printf("kdgrid-viewer: wrote %s\n", path.c_str());
  std::fflush(stdout);
  return true;
}

}  // namespace kdgrid::viewer
