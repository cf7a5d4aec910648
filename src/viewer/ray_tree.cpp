// The picked pixel's ray tree: every ray the render traces for that pixel's sample (primary,
// shadow, reflection, refraction), traced by the renderer's own shading code
// (Renderer::trace_tree), shown as a tree in the Pick section; the selected ray is the one
// drawn over the image, listed in the step table and given as a `kdgrid trace` command.
#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "util/format.h"
#include "viewer/viewer.h"

namespace kdgrid::viewer {

namespace {

/// Quotes a path for a shell command line when it needs it.
std::string shell_quote(const std::string& s) {
  if (s.find_first_of(" \t'\"\\$`()&;|<>*?") == std::string::npos) return s;
  std::string q = "'";
  for (char c : s) q += (c == '\'') ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

/// A float as `kdgrid trace` reads it back unchanged ("inf" for infinity).
std::string exact(float v) {
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  return format_double("%.9g", double(v));
}

std::string exact3(const Vec3& v) {
  return exact(v.x) + "," + exact(v.y) + "," + exact(v.z);
}

/// One line per ray: its kind, answer, steps, tests and time.
std::string node_label(const RayTreeNode& n, bool counters) {
  char buf[200];
  std::string answer;
  if (n.kind == RayKind::Shadow)
    answer = std::string("light ") + std::to_string(n.light) +
             (n.trace.occluded ? ", occluded" : ", reaches it");
  else if (n.trace.hit.valid())
    answer = "hit " + std::to_string(n.trace.hit.prim);
  else
    answer = "miss";
  if (counters)
    std::snprintf(buf, sizeof buf, "%s: %s, %zu steps, %llu tests, %.3g us", to_string(n.kind),
                  answer.c_str(), n.trace.steps.size(),
                  (unsigned long long)n.trace.counters.tri_tests, n.seconds * 1e6);
  else
    std::snprintf(buf, sizeof buf, "%s: %s, %.3g us", to_string(n.kind), answer.c_str(),
                  n.seconds * 1e6);
  return buf;
}

}  // namespace

void Viewer::trace_pick_tree(int selected) {
  if (!pick_ || !world_) return;
  Pick& p = *pick_;
  // The settings the render worker renders with (RenderJob's defaults): the same depth and
  // shadows, so the tree holds exactly the rays of the pixel's sample.
  RenderSettings rs;
  rs.width = rs.height = 1;
  rs.offset = offset_;
  const Renderer renderer(*world_->scene, *world_->accel, rs);
  p.tree = renderer.trace_tree(p.ray);
  const std::string base = "kdgrid trace " + shell_quote(world_->scene->source) +
                           cli::accel_flags(world_->name, world_->params);
  p.commands.clear();
  for (const RayTreeNode& n : p.tree.nodes) {
    if (n.kind == RayKind::Primary) {
      CameraControl at_pick;
      at_pick.set_camera(p.camera);
      p.commands.push_back(base + " --pixel " + std::to_string(p.x) + "," + std::to_string(p.y) +
                           " --res " + std::to_string(p.w) + "x" + std::to_string(p.h) + " " +
                           at_pick.cli_flags());
    } else {
      p.commands.push_back(base + " --origin " + exact3(n.ray.org) + " --dir " + exact3(n.ray.dir) +
                           " --tmin " + exact(n.ray.tmin) + " --tmax " + exact(n.ray.tmax) +
                           (n.kind == RayKind::Shadow ? " --any" : ""));
    }
  }
  select_tree_ray(selected);
}

void Viewer::select_tree_ray(int i) {
  if (!pick_ || !world_ || pick_->tree.nodes.empty()) return;
  Pick& p = *pick_;
  if (i < 0 || size_t(i) >= p.tree.nodes.size()) i = 0;
  p.selected = i;
  const RayTreeNode& n = p.tree.nodes[size_t(i)];
  p.trace = n.trace;
  p.segment = pick_segment(n.ray, n.trace, scene_bounds_);
  p.command = p.commands[size_t(i)];
  p.widths_for_font = 0;  // the step table's text and widths follow the selected ray
  p.serial = ++pick_serial_;
  if (splits_of_pick_) overlay_dirty_ = true;
}

void Viewer::draw_ray_tree() {
  if (!pick_) return;
  Pick& p = *pick_;
  const auto& nodes = p.tree.nodes;
  const bool counters = world_ && world_->accel->has_counters();
  ImGui::Text("ray tree: %zu rays (click one to show it)", nodes.size());
  audit_.item("ray tree");
  if (!counters) {
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextDisabled("%s exposes no traversal: answers and times only",
                        world_ ? world_->name.c_str() : "");
    ImGui::PopTextWrapPos();
  }
  std::vector<std::vector<int>> children(nodes.size());
  for (size_t k = 1; k < nodes.size(); ++k)
    if (nodes[k].parent >= 0) children[size_t(nodes[k].parent)].push_back(int(k));
  int clicked = -1;
  // Depth first from the primary, as the renderer traced them.
  const auto draw_node = [&](const auto& self, int k) -> void {
    const RayTreeNode& n = nodes[size_t(k)];
    ImGuiTreeNodeFlags f = ImGuiTreeNodeFlags_OpenOnArrow | ImGuiTreeNodeFlags_DefaultOpen |
                           ImGuiTreeNodeFlags_SpanAvailWidth;
    if (children[size_t(k)].empty())
      f |= ImGuiTreeNodeFlags_Leaf | ImGuiTreeNodeFlags_NoTreePushOnOpen;
    if (k == p.selected) f |= ImGuiTreeNodeFlags_Selected;
    const std::string label = node_label(n, counters);
    const bool open = ImGui::TreeNodeEx((void*)(intptr_t)k, f, "%s", label.c_str());
    if (ImGui::IsItemClicked() && !ImGui::IsItemToggledOpen()) clicked = k;
    if (ImGui::IsItemHovered())
      ImGui::SetTooltip("origin (%.6g %.6g %.6g)\ndirection (%.6g %.6g %.6g)\nt [%.6g, %.6g]",
                        n.ray.org.x, n.ray.org.y, n.ray.org.z, n.ray.dir.x, n.ray.dir.y,
                        n.ray.dir.z, n.ray.tmin, n.ray.tmax);
    audit_.items.push_back(label);
    if (open && !children[size_t(k)].empty()) {
      for (int c : children[size_t(k)]) self(self, c);
      ImGui::TreePop();
    }
  };
  if (!nodes.empty()) draw_node(draw_node, 0);
  if (clicked >= 0 && clicked != p.selected) select_tree_ray(clicked);

  const RayTreeNode& s = nodes[size_t(p.selected)];
  ImGui::PushTextWrapPos(0.0f);
  ImGui::Text("shown: %s ray %d", to_string(s.kind), p.selected);
  ImGui::TextWrapped("origin (%.6g %.6g %.6g) direction (%.6g %.6g %.6g)", s.ray.org.x, s.ray.org.y,
                     s.ray.org.z, s.ray.dir.x, s.ray.dir.y, s.ray.dir.z);
  if (s.trace.hit.valid()) {
    const Vec3 h = s.ray.at(s.trace.hit.t);
    ImGui::TextWrapped("hit triangle %u at t = %.6g, (%.6g %.6g %.6g)", s.trace.hit.prim,
                       s.trace.hit.t, h.x, h.y, h.z);
  } else if (s.kind == RayKind::Shadow) {
    ImGui::TextWrapped("%s", s.trace.occluded ? "occluded (any hit)" : "not occluded");
  } else {
    ImGui::TextWrapped("miss");
  }
  ImGui::PopTextWrapPos();
}

}  // namespace kdgrid::viewer
