// The picked ray in the viewer: the camera that frames its traversal ("frame pick", F), its
// traversal drawn over the image with thick screen-space lines, and the panel audit that the
// tests read from --stats-json. The Pick panel itself is Viewer::draw_pick_panel
// (pick_view.cpp).
#pragma once

#include <string>
#include <vector>

#include "accel/accelerator.h"
#include "render/camera.h"
#include "scene/mesh.h"
#include "scene/scene.h"
#include "viewer/overlay.h"

struct ImDrawList;

namespace kdgrid::viewer {

const char* kind_name(StepKind k);

/// The part of a picked ray that its traversal covered: from where it enters `scene_bounds`
/// (or its origin, inside them) to its hit, else to where it leaves the last visited box or
/// the bounds. `seg.t1 < seg.t0` when the ray misses the bounds and visited nothing.
RaySegment pick_segment(const Ray& ray, const Trace& t, const Box3& scene_bounds);

/// What "frame pick" fits into the view: the corners of the leaves and cells the ray visited
/// (of every visited box when it visited none of those: a structure without leaves) and the
/// ray from where it enters the first of them to the end of `seg`. Not the hit triangle: a
/// wall's would frame the whole wall.
std::vector<Vec3> pick_frame_points(const Trace& t, const RaySegment& seg);

/// The camera with `cam`'s view direction, up and fov whose w x h image holds every point of
/// `pts` with `margin` (a fraction of each half-extent, e.g. 0.1) to spare; its target is the
/// centre of the points' box, which orbiting then turns about. `cam` itself if pts is empty.
Camera fit_points(const Camera& cam, const std::vector<Vec3>& pts, int w, int h, float margin);

/// Draws a picked ray's traversal into `dl` (ImGui's background list: over the ray-traced
/// image and the structure overlays, under the panels) with lines a few pixels wide, so that
/// it reads at any zoom: the visited boxes in visit order (blue first, red last; the leaves and
/// cells filled faintly, inner nodes thinner), the tested triangles (yellow), the hit triangle
/// (white), the ray (cyan) and a ring around the hit point. `f` is the live camera's frame
/// over the image, which covers `display_w` x `display_h` window units; `ui_scale` scales the
/// line widths like the panels. A ray that misses the scene is drawn `miss_length` long.
void draw_trace(ImDrawList* dl, const CameraFrame& f, float display_w, float display_h,
                const Trace& t, const RaySegment& seg, const Mesh& mesh, float ui_scale,
                float miss_length);

/// Puts the next button on the current line when it fits there, else leaves it for the next
/// line, so that a row of buttons wraps instead of being cut at the window's edge.
void same_line_if_fits(const char* next_label);

/// A record of what the last frame's panels showed, written to --stats-json for the tests:
/// labels and values cut by their window or column, legends drawn, and the layout's anchors.
struct UiAudit {
  std::vector<std::string> clipped;  ///< "text (needs W, has A)" for each cut label or value
  std::vector<std::string> items;    ///< the label of every audited item, in drawing order
  std::vector<std::string> legends;  ///< each legend drawn: "<name>: <lo> .. <hi>"
  float status_top = -1;             ///< the panel's y (window units) of the status area
  float below_status_y = -1;         ///< the panel's y of the first widget under the status area
  int table_cells = 0;               ///< step-table cells checked

  void clear() { *this = UiAudit{}; }
  /// After an item: records `label` when the item reaches past the window's visible content
  /// region (its label or text is cut at the right edge).
  void item(const char* label);
  /// Before `text` is drawn in a table cell: records it when it is wider than the cell.
  void cell(const char* text);
};

}  // namespace kdgrid::viewer
