#include "viewer/pick_view.h"

#include <imgui.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "util/enum_names.h"
#include "viewer/viewer.h"

namespace kdgrid::viewer {

const char* kind_name(StepKind k) {
  static constexpr EnumName<StepKind> kNames[] = {
      {StepKind::Inner, "inner"}, {StepKind::Leaf, "leaf"}, {StepKind::Cell, "cell"}};
  return enum_name(k, kNames);
}

RaySegment pick_segment(const Ray& ray, const Trace& t, const Box3& bounds) {
  RaySegment s;
  s.ray = ray;
  // Slab test against the scene's box.
  float te = std::max(ray.tmin, 0.0f), tx = ray.tmax;
  for (int a = 0; a < 3; ++a) {
    const float inv = 1.0f / ray.dir[a];
    float t0 = (bounds.lo[a] - ray.org[a]) * inv, t1 = (bounds.hi[a] - ray.org[a]) * inv;
    if (t0 > t1) std::swap(t0, t1);
    if (!std::isnan(t0)) te = std::max(te, t0);
    if (!std::isnan(t1)) tx = std::min(tx, t1);
  }
  const bool in_bounds = te <= tx && std::isfinite(tx);
  s.t0 = in_bounds ? te : std::max(ray.tmin, 0.0f);
  if (t.hit.valid()) {
    s.t1 = t.hit.t;
    s.t0 = std::min(s.t0, s.t1);  // a hit on the scene's boundary, rounded just outside it
  } else if (!t.steps.empty()) {
    float last = s.t0;
    for (const TraceStep& st : t.steps)
      if (std::isfinite(st.t_out)) last = std::max(last, st.t_out);
    s.t1 = in_bounds ? std::min(last, tx) : last;
  } else {
    s.t1 = in_bounds ? tx : s.t0 - 1.0f;
  }
  return s;
}

std::vector<Vec3> pick_frame_points(const Trace& t, const RaySegment& seg) {
  std::vector<Vec3> pts;
  const bool has_leaves = std::any_of(t.steps.begin(), t.steps.end(),
                                      [](const TraceStep& s) { return s.kind != StepKind::Inner; });
  // Where the ray tested triangles is what a person debugs; the empty leaves it crossed on
  // the way (a widened empty leaf can span half the scene) would shrink that to a few pixels.
  const bool has_tests = std::any_of(t.steps.begin(), t.steps.end(), [](const TraceStep& s) {
    return s.kind != StepKind::Inner && s.num_tested > 0;
  });
  float first = seg.t1;  // where the ray enters its first framed box
  for (const TraceStep& s : t.steps) {
    if ((has_leaves && s.kind == StepKind::Inner) || s.box.empty()) continue;
    if (has_tests && s.num_tested == 0) continue;
    for (int i = 0; i < 8; ++i)
      pts.push_back({(i & 1) ? s.box.hi.x : s.box.lo.x, (i & 2) ? s.box.hi.y : s.box.lo.y,
                     (i & 4) ? s.box.hi.z : s.box.lo.z});
    first = std::min(first, s.t_in);
  }
  // The ray from its first leaf or cell on: the stretch before it (from where it enters the
  // scene, through inner nodes only) runs along the view and would push the camera back.
  if (seg.t1 >= seg.t0) {
    pts.push_back(seg.ray.at(std::max(seg.t0, std::isfinite(first) ? first : seg.t0)));
    pts.push_back(seg.ray.at(seg.t1));
  }
  // A box or segment reaching infinity (a structure's unbounded step) cannot be framed.
  pts.erase(
      std::remove_if(pts.begin(), pts.end(),
                     [](const Vec3& p) {
                       return !(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z));
                     }),
      pts.end());
  return pts;
}

Camera fit_points(const Camera& cam, const std::vector<Vec3>& pts, int w, int h, float margin) {
  if (pts.empty() || w <= 0 || h <= 0) return cam;
  const CameraFrame f = CameraFrame::make(cam, w, h);
  Box3 b;
  for (const Vec3& p : pts) b.grow(p);
  const Vec3 c = b.center();
  // The eye sits at c - fwd * d. A point at (x, y, z) in the camera's basis around c is in
  // view when |x| <= tan_x * (d + z) and |y| <= tan_y * (d + z): the smallest such d over all
  // points, with the margin taken off the half-angles.
  const float keep = std::clamp(1.0f - margin, 0.1f, 1.0f);
  const float tan_y = f.tan_half_fov * keep, tan_x = f.tan_half_fov * float(w) / float(h) * keep;
  float d = 0.0f;
  for (const Vec3& p : pts) {
    const Vec3 r = p - c;
    const float x = std::fabs(dot(r, f.right)), y = std::fabs(dot(r, f.up)), z = dot(r, f.fwd);
    d = std::max({d, x / tan_x - z, y / tan_y - z});
  }
  // Every point in front of the eye, and the eye apart from the target (float resolution at
  // the target's coordinates).
  const float extent = length(b.extent());
  float zmin = 0.0f;
  for (const Vec3& p : pts) zmin = std::min(zmin, dot(p - c, f.fwd));
  d = std::max({d, -zmin + 1e-3f * extent, 1e-5f * std::max(1.0f, length(c))});
  Camera out = cam;
  out.target = c;
  out.eye = c - f.fwd * d;
  return out;
}

namespace {

/// A point in the camera's basis: x right, y up, z along the view direction.
struct CamPoint {
  float x, y, z;
};

struct Projector {
  const CameraFrame& f;
  float dw, dh, near_z;

  CamPoint to_cam(const Vec3& p) const {
    const Vec3 r = p - f.eye;
    return {dot(r, f.right), dot(r, f.up), dot(r, f.fwd)};
  }
  ImVec2 to_window(const CamPoint& p) const {
    const float aspect = float(f.width) / float(f.height);
    const float u = p.x / p.z / (f.tan_half_fov * aspect), v = p.y / p.z / f.tan_half_fov;
    return {(u + 1.0f) * 0.5f * dw, (1.0f - v) * 0.5f * dh};
  }
  static CamPoint lerp(const CamPoint& a, const CamPoint& b, float t) {
    return {a.x + (b.x - a.x) * t, a.y + (b.y - a.y) * t, a.z + (b.z - a.z) * t};
  }
  void line(ImDrawList* dl, const Vec3& pa, const Vec3& pb, ImU32 col, float width) const {
    CamPoint a = to_cam(pa), b = to_cam(pb);
    if (a.z < near_z && b.z < near_z) return;
    // Clip to the near plane, so a box around the eye still draws its visible edges.
    if (a.z < near_z) a = lerp(a, b, (near_z - a.z) / (b.z - a.z));
    if (b.z < near_z) b = lerp(b, a, (near_z - b.z) / (a.z - b.z));
    dl->AddLine(to_window(a), to_window(b), col, width);
  }
  void polygon(ImDrawList* dl, const Vec3* pts, int n, ImU32 col) const {
    // Sutherland-Hodgman against the near plane, then a convex fill in clockwise order (ImGui
    // draws its anti-aliased fringe outwards only for that winding).
    CamPoint in[8], out[8];
    int m = 0;
    for (int i = 0; i < n; ++i) in[i] = to_cam(pts[i]);
    for (int i = 0; i < n; ++i) {
      const CamPoint &a = in[i], &b = in[(i + 1) % n];
      const bool ia = a.z >= near_z, ib = b.z >= near_z;
      if (ia) out[m++] = a;
      if (ia != ib) out[m++] = lerp(a, b, (near_z - a.z) / (b.z - a.z));
    }
    if (m < 3) return;
    ImVec2 w[8];
    float area = 0.0f;
    for (int i = 0; i < m; ++i) w[i] = to_window(out[i]);
    for (int i = 0; i < m; ++i) area += w[i].x * w[(i + 1) % m].y - w[(i + 1) % m].x * w[i].y;
    if (area < 0.0f) std::reverse(w, w + m);
    dl->AddConvexPolyFilled(w, m, col);
  }
};

ImU32 to_u32(const Color& c) {
  return ImGui::ColorConvertFloat4ToU32(ImVec4(c.r, c.g, c.b, c.a));
}

}  // namespace

void draw_trace(ImDrawList* dl, const CameraFrame& f, float dw, float dh, const Trace& t,
                const RaySegment& seg, const Mesh& mesh, float s, float miss_length) {
  const float ray_t0 = std::max(seg.ray.tmin, 0.0f);
  const float ray_t1 =
      seg.t1 >= seg.t0 ? seg.t1 : ray_t0 + miss_length / std::max(length(seg.ray.dir), 1e-30f);
  // The near plane: a small fraction of the distance to the segment's far end, so that a
  // camera close to the boxes (a framed pick) clips only what lies behind it.
  const float far_z = std::fabs(dot(seg.ray.at(ray_t1) - f.eye, f.fwd));
  const Projector pr{f, dw, dh, std::max(far_z * 1e-4f, 1e-7f)};
  const size_t n = t.steps.size();
  // Faint fills first, then the edges over them: the leaves and cells read as solid blocks in
  // visit order, the inner nodes as thin frames.
  for (size_t i = 0; i < n; ++i) {
    const TraceStep& st = t.steps[i];
    if (st.kind == StepKind::Inner || st.box.empty()) continue;
    const Color c = ramp(n > 1 ? float(i) / float(n - 1) : 1.0f, 0.2f);
    const Vec3 l = st.box.lo, h = st.box.hi;
    const Vec3 faces[6][4] = {{{l.x, l.y, l.z}, {l.x, h.y, l.z}, {l.x, h.y, h.z}, {l.x, l.y, h.z}},
                              {{h.x, l.y, l.z}, {h.x, h.y, l.z}, {h.x, h.y, h.z}, {h.x, l.y, h.z}},
                              {{l.x, l.y, l.z}, {h.x, l.y, l.z}, {h.x, l.y, h.z}, {l.x, l.y, h.z}},
                              {{l.x, h.y, l.z}, {h.x, h.y, l.z}, {h.x, h.y, h.z}, {l.x, h.y, h.z}},
                              {{l.x, l.y, l.z}, {h.x, l.y, l.z}, {h.x, h.y, l.z}, {l.x, h.y, l.z}},
                              {{l.x, l.y, h.z}, {h.x, l.y, h.z}, {h.x, h.y, h.z}, {l.x, h.y, h.z}}};
    for (const auto& face : faces) pr.polygon(dl, face, 4, to_u32(c));
  }
  for (size_t i = 0; i < n; ++i) {
    const TraceStep& st = t.steps[i];
    if (st.box.empty()) continue;
    const bool inner = st.kind == StepKind::Inner;
    const ImU32 col = to_u32(ramp(n > 1 ? float(i) / float(n - 1) : 1.0f, inner ? 0.6f : 1.0f));
    const float width = (inner ? 1.0f : 2.0f) * s;
    const Vec3 l = st.box.lo, h = st.box.hi;
    const Vec3 p[8] = {{l.x, l.y, l.z}, {h.x, l.y, l.z}, {h.x, h.y, l.z}, {l.x, h.y, l.z},
                       {l.x, l.y, h.z}, {h.x, l.y, h.z}, {h.x, h.y, h.z}, {l.x, h.y, h.z}};
    for (int k = 0; k < 4; ++k) {
      pr.line(dl, p[k], p[(k + 1) % 4], col, width);
      pr.line(dl, p[k + 4], p[(k + 1) % 4 + 4], col, width);
      pr.line(dl, p[k], p[k + 4], col, width);
    }
  }
  // Tested triangles; a brute-force trace tests every triangle, so cap what is drawn.
  constexpr size_t kMaxTris = 20000;
  const ImU32 yellow = to_u32({1.0f, 0.95f, 0.1f, 0.9f}), white = to_u32({1, 1, 1, 1});
  const ImU32 cyan = to_u32({0.0f, 1.0f, 1.0f, 1.0f});
  const size_t nt = std::min(t.tested.size(), kMaxTris);
  for (size_t i = 0; i < nt; ++i) {
    const uint32_t prim = t.tested[i];
    if (prim >= mesh.num_triangles() || prim == t.hit.prim) continue;
    const auto c = mesh.corners(prim);
    for (int k = 0; k < 3; ++k) pr.line(dl, c[size_t(k)], c[size_t((k + 1) % 3)], yellow, 1.5f * s);
  }
  if (t.hit.valid() && t.hit.prim < mesh.num_triangles()) {
    const auto c = mesh.corners(t.hit.prim);
    for (int k = 0; k < 3; ++k) pr.line(dl, c[size_t(k)], c[size_t((k + 1) % 3)], white, 2.5f * s);
  }
  const Vec3 end = seg.ray.at(ray_t1);
  pr.line(dl, seg.ray.at(ray_t0), end, cyan, 2.5f * s);
  // The end marker keeps its size on screen at any distance.
  const CamPoint e = pr.to_cam(end);
  if (e.z >= pr.near_z) dl->AddCircle(pr.to_window(e), 6.0f * s, cyan, 16, 2.0f * s);
}

void same_line_if_fits(const char* next_label) {
  const ImGuiStyle& style = ImGui::GetStyle();
  const float w = ImGui::CalcTextSize(next_label, nullptr, true).x + style.FramePadding.x * 2;
  const float right = ImGui::GetWindowPos().x + ImGui::GetWindowContentRegionMax().x;
  if (ImGui::GetItemRectMax().x + style.ItemSpacing.x + w <= right) ImGui::SameLine();
}

void UiAudit::item(const char* label) {
  items.push_back(label);
  const float right = ImGui::GetWindowPos().x + ImGui::GetWindowContentRegionMax().x;
  const float have = right - ImGui::GetItemRectMin().x, need = ImGui::GetItemRectSize().x;
  if (need > have + 0.5f) {
    char buf[256];
    std::snprintf(buf, sizeof buf, "%s (needs %.0f, has %.0f)", label, need, have);
    clipped.push_back(buf);
  }
}

void UiAudit::cell(const char* text) {
  ++table_cells;
  const float have = ImGui::GetContentRegionAvail().x, need = ImGui::CalcTextSize(text).x;
  if (need > have + 0.5f) {
    char buf[256];
    std::snprintf(buf, sizeof buf, "%s (needs %.0f, has %.0f)", text, need, have);
    clipped.push_back(buf);
  }
}

// ---- the Viewer's pick members ----------------------------------------------------------------

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

void Viewer::frame_pick() {
  if (!pick_ || !world_) return;
  int fw = 0, fh = 0;
  glfwGetFramebufferSize(window_, &fw, &fh);
  const auto pts = pick_frame_points(pick_->trace, pick_->segment);
  if (pts.empty() || fw <= 0 || fh <= 0) {
    message_ = "frame pick: the ray visited nothing to frame";
    return;
  }
  const Camera c = fit_points(cam_.camera(), pts, fw, fh, kPickFrameMargin);
  try {
    check_camera(c, "frame pick");
  } catch (const std::exception& e) {
    message_ = e.what();
    return;
  }
  cam_.set_camera(c);
  pick_->framed = true;
  message_ = "framed the pick: orbit turns about its traversal, Home frames the scene";
}

void Viewer::draw_pick_overlay() {
  if (!pick_ || !world_ || posted_w_ <= 0) return;
  const ImGuiIO& io = ImGui::GetIO();
  // The live camera (not the displayed image's) so the overlay follows the mouse at once.
  const CameraFrame f = CameraFrame::make(cam_.camera(), posted_w_, posted_h_);
  draw_trace(ImGui::GetBackgroundDrawList(), f, io.DisplaySize.x, io.DisplaySize.y, pick_->trace,
             pick_->segment, world_->scene->mesh, ui_scale_, scene_radius() * 4.0f);
}

std::string Viewer::no_traversal_note() const {
  return world_->name + " exposes no traversal (its steps and tests are not counted): only " +
         "the hit is shown; choose a kdgrid structure to see the ray's steps";
}

void Viewer::draw_pick_panel() {
  if (!pick_) {
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextDisabled("click (or Ctrl+click) a pixel to trace its ray");
    ImGui::PopTextWrapPos();
    audit_.item("click (or Ctrl+click) a pixel to trace its ray");
    return;
  }
  Pick& p = *pick_;
  const Trace& t = p.trace;
  ImGui::TextWrapped("pixel %d,%d: %zu steps, %llu tests, %s", p.x, p.y, t.steps.size(),
                     (unsigned long long)t.counters.tri_tests, t.hit.valid() ? "hit" : "miss");
  if (world_ && !world_->accel->has_counters()) {
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextColored(ImVec4(1.0f, 0.8f, 0.3f, 1.0f), "%s", no_traversal_note().c_str());
    ImGui::PopTextWrapPos();
    audit_.item(no_traversal_note().c_str());
  }
  if (t.hit.valid()) ImGui::TextWrapped("hit triangle %u at t = %.6g", t.hit.prim, t.hit.t);
  ImGui::TextWrapped("%s", p.command.c_str());
  if (ImGui::SmallButton("copy command")) ImGui::SetClipboardText(p.command.c_str());
  audit_.item("copy command");
  same_line_if_fits("frame pick (F)");
  if (ImGui::SmallButton("frame pick (F)")) frame_pick();
  audit_.item("frame pick (F)");
  same_line_if_fits("clear pick");
  if (ImGui::SmallButton("clear pick")) {
    pick_.reset();
    if (splits_of_pick_) overlay_dirty_ = true;
    return;
  }
  audit_.item("clear pick");

  // The visit order's colours: the boxes drawn over the image and the table's step numbers.
  const size_t n = t.steps.size();
  char l0[32], l1[32], l2[32];
  std::snprintf(l0, sizeof l0, "step 0");
  std::snprintf(l1, sizeof l1, n > 2 ? "%zu" : "", (n - 1) / 2);
  std::snprintf(l2, sizeof l2, "%zu", n > 0 ? n - 1 : 0);
  ImGui::TextUnformatted("visit order (first .. last step)");
  audit_.item("visit order (first .. last step)");
  draw_ramp_bar(std::min(ImGui::GetContentRegionAvail().x, 240 * ui_scale_), l0, l1, l2);
  audit_.legends.push_back(std::string("visit order: ") + l0 + " .. " + l2);
  draw_ray_tree();
}

void Viewer::draw_pick_steps() {
  steps_rect_ = {0, 0, 0, 0};
  if (!pick_) return;
  Pick& p = *pick_;
  const Trace& t = p.trace;
  const size_t n = t.steps.size();
  // The step table: every column as wide as its widest value (computed once per pick over
  // all rows, not only those on screen), scrolling both ways, columns resizable, in a window
  // of its own (resizable, collapsible) beside the panel: the box column alone is wider than
  // the panel.
  static const char* const kHeads[7] = {"#", "kind", "id", "box", "t in", "t out", "tested"};
  // The tested triangles' ids, up to this many per step (a brute-force step tests them all).
  constexpr uint32_t kMaxIds = 16;
  const float font = ImGui::GetFontSize();
  if (p.widths_for_font == 0) {
    p.rows.assign(n, {});
    for (size_t i = 0; i < n; ++i) {
      const TraceStep& s = t.steps[i];
      char buf[160];
      auto& r = p.rows[i];
      r[0] = std::to_string(i);
      std::snprintf(buf, sizeof buf, "%s d%d", kind_name(s.kind), s.depth);
      r[1] = buf;
      // The node's index (inner nodes, leaves) or the linear cell index (cells).
      r[2] = std::to_string(s.id);
      std::snprintf(buf, sizeof buf, "(%.5g %.5g %.5g)-(%.5g %.5g %.5g)", s.box.lo.x, s.box.lo.y,
                    s.box.lo.z, s.box.hi.x, s.box.hi.y, s.box.hi.z);
      r[3] = buf;
      std::snprintf(buf, sizeof buf, "%.6g", s.t_in);
      r[4] = buf;
      std::snprintf(buf, sizeof buf, "%.6g", s.t_out);
      r[5] = buf;
      std::string ids = std::to_string(s.num_tested);
      for (uint32_t k = 0; k < std::min(s.num_tested, kMaxIds); ++k)
        ids += (k == 0 ? ": " : " ") + std::to_string(t.tested[s.first_tested + k]);
      if (s.num_tested > kMaxIds)
        ids += " ... (" + std::to_string(s.num_tested - kMaxIds) + " more)";
      r[6] = std::move(ids);
    }
  }
  if (p.widths_for_font != font) {
    for (int c = 0; c < 7; ++c) {
      float w = ImGui::CalcTextSize(kHeads[c]).x;
      for (const auto& r : p.rows) w = std::max(w, ImGui::CalcTextSize(r[size_t(c)].c_str()).x);
      p.widths[c] = std::ceil(w) + 1.0f;
    }
    p.widths_for_font = font;
  }
  const ImGuiIO& io = ImGui::GetIO();
  const ImGuiStyle& style = ImGui::GetStyle();
  const float m = 8 * ui_scale_, left = panel_rect_[0] + panel_rect_[2] + m;
  const ImGuiCond cond = reset_layout_ ? ImGuiCond_Always : ImGuiCond_FirstUseEver;
  // Beside the panel, at the bottom, or at the top when the picked pixel is in the lower
  // half of the window (the table would hide it).
  const bool pick_low = posted_h_ > 0 && float(p.y) > 0.5f * float(posted_h_);
  ImGui::SetNextWindowPos(ImVec2(left, pick_low ? m : io.DisplaySize.y - m), cond,
                          ImVec2(0, pick_low ? 0.0f : 1.0f));
  // As wide as every column needs (no column cut), within the room right of the panel.
  float table_w = style.WindowPadding.x * 2 + style.ScrollbarSize;
  for (float w : p.widths) table_w += w + style.CellPadding.x * 2 + 1;
  const float room = io.DisplaySize.x - left - m;
  steps_table_w_ = table_w;
  ImGui::SetNextWindowSize(ImVec2(std::max(160 * ui_scale_, std::min(table_w, room)),
                                  std::min(220 * ui_scale_, io.DisplaySize.y * 0.4f)),
                           cond);
  char title[64];
  std::snprintf(title, sizeof title, "pick steps: %zu###pick steps", n);
  if (!ImGui::Begin(title)) {
    ImGui::End();
    return;
  }
  keep_in_window();
  const ImVec2 sp = ImGui::GetWindowPos(), ss = ImGui::GetWindowSize();
  steps_rect_ = {sp.x, sp.y, ss.x, ss.y};
  item_rects_["pick steps"] = steps_rect_;
  if (n == 0 && world_ && !world_->accel->has_counters()) {
    ImGui::TextWrapped("%s", no_traversal_note().c_str());
    ImGui::End();
    return;
  }
  const ImGuiTableFlags flags = ImGuiTableFlags_Resizable | ImGuiTableFlags_ScrollX |
                                ImGuiTableFlags_ScrollY | ImGuiTableFlags_SizingFixedFit |
                                ImGuiTableFlags_RowBg | ImGuiTableFlags_Borders;
  // A table per pick: its columns take their initial widths from this pick's values.
  ImGui::PushID(int(p.serial));
  if (ImGui::BeginTable("steps", 7, flags, ImVec2(0, ImGui::GetContentRegionAvail().y))) {
    ImGui::TableSetupScrollFreeze(1, 1);
    for (int c = 0; c < 7; ++c)
      ImGui::TableSetupColumn(kHeads[c], ImGuiTableColumnFlags_WidthFixed, p.widths[c]);
    ImGui::TableHeadersRow();
    ImGuiListClipper clip;
    clip.Begin(int(n));
    while (clip.Step()) {
      for (int i = clip.DisplayStart; i < clip.DisplayEnd; ++i) {
        const auto& r = p.rows[size_t(i)];
        const Color c = ramp(n > 1 ? float(i) / float(n - 1) : 1.0f);
        ImGui::TableNextRow();
        for (int k = 0; k < 7; ++k) {
          ImGui::TableNextColumn();
          audit_.cell(r[size_t(k)].c_str());
          if (k == 0)
            ImGui::TextColored(ImVec4(c.r, c.g, c.b, 1), "%s", r[0].c_str());
          else
            ImGui::TextUnformatted(r[size_t(k)].c_str());
        }
      }
    }
    ImGui::EndTable();
  }
  ImGui::PopID();
  ImGui::End();
}

}  // namespace kdgrid::viewer
