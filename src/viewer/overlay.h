// Overlays drawn over the ray-traced image: structure split planes, cells/leaves, BVH boxes,
// and a picked ray's traversal. Lines are built on the CPU in world space and projected with
// a matrix made from the ray tracer's own CameraFrame, so they line up with the render.
#pragma once

#include <epoxy/gl.h>

#include <array>
#include <cstddef>
#include <vector>

#include "accel/accelerator.h"
#include "render/camera.h"
#include "scene/mesh.h"

namespace kdgrid::viewer {

struct Color {
  float r = 1, g = 1, b = 1, a = 1;
};

/// Blue (t = 0) to red (t = 1) through cyan, green and yellow; used for depth, visit order
/// and heat maps.
Color ramp(float t, float alpha = 1.0f);

struct LineVertex {
  float x, y, z;
  float r, g, b, a;
};

/// World-space line segments with per-vertex colour (GL_LINES).
class LineBatch {
 public:
  void clear() { verts_.clear(); }
  void line(const Vec3& a, const Vec3& b, const Color& c);
  void box(const Box3& b, const Color& c);
  /// Rectangle where the plane axis = pos cuts `node_box`.
  void split(int axis, float pos, const Box3& node_box, const Color& c);
  /// Three axis-aligned strokes of half-length `size` through p.
  void cross3(const Vec3& p, float size, const Color& c);
  const std::vector<LineVertex>& vertices() const { return verts_; }
  std::vector<LineVertex> take() { return std::move(verts_); }
  size_t segments() const { return verts_.size() / 2; }

 private:
  std::vector<LineVertex> verts_;
};

/// Column-major view-projection matrix that maps a world point to the same image position
/// CameraFrame::ray uses for it: x_ndc = dot(p-eye, right) / dot(p-eye, fwd) / (tan*aspect),
/// y_ndc likewise with up and tan. near/far only bound the clip volume (no depth test).
std::array<float, 16> view_projection(const CameraFrame& f, float near_dist, float far_dist);

/// Projects p to image pixel coordinates (x right, y down) of frame f; false if behind.
bool project_to_pixel(const CameraFrame& f, const Vec3& p, float& px, float& py);

/// Limits that keep overlays of huge structures drawable; reported in the panel when hit.
inline constexpr size_t kMaxOverlaySegments = 250'000;
/// Vertices sent to the GPU per frame when an overlay is uploaded, into a buffer allocated once
/// for kMaxOverlaySegments, so that no frame stalls on one large upload or allocation.
inline constexpr size_t kUploadVerticesPerFrame = 100'000;
/// Lines drawn per frame. A software GL (Mesa llvmpipe) transforms and bins every line on the
/// thread that draws it, so drawing a whole capped overlay in every frame would cost that
/// thread time in proportion to the lines; instead the lines are drawn into an offscreen
/// picture this many per frame (the shallow levels first) and the picture is shown whole.
inline constexpr size_t kDrawLinesPerFrame = 10'000;

/// A stretch [t0, t1] of a ray: the part of a picked ray its traversal covered.
struct RaySegment {
  Ray ray;
  float t0 = 0, t1 = -1;  ///< empty when t1 < t0
};

/// Whether `seg` passes through the split plane s inside its node's box (the ray goes from
/// one child to the other there).
bool crosses_split(const RaySegment& seg, const SplitPlane& s);

/// Split planes with depth in [depth_lo, depth_hi], coloured by depth; with `crossed_by`, only
/// those that segment crosses. Returns planes drawn.
size_t build_split_overlay(const Accelerator& a, int depth_lo, int depth_hi, LineBatch& out,
                           const RaySegment* crossed_by = nullptr);
/// Leaf boxes / non-empty cells (StructureBox::leaf), coloured by triangle count. Returns
/// those drawn; `wanted` (if given) grows by how many there are, drawn or cut by the cap.
size_t build_cell_overlay(const Accelerator& a, LineBatch& out, size_t* wanted = nullptr);
/// All boxes (BVH nodes) with depth in [depth_lo, depth_hi], coloured by depth; returns and
/// counts as build_cell_overlay.
size_t build_box_overlay(const Accelerator& a, int depth_lo, int depth_hi, LineBatch& out,
                         size_t* wanted = nullptr);
/// GL side: the lines' vertex buffer, the lines shader, and the offscreen picture the lines are
/// drawn into, a bounded number per frame (kUploadVerticesPerFrame, kDrawLinesPerFrame).
class LineRenderer {
 public:
  void init();
  void destroy();
  /// Starts replacing the lines with `batch`'s (at most kMaxOverlaySegments; more are dropped):
  /// upload_step() sends them; until then only what has been sent is drawn.
  void upload(LineBatch&& batch);
  /// Sends up to `max_vertices` more; returns how many it sent.
  size_t upload_step(size_t max_vertices);
  bool uploading() const { return uploaded_ < pending_.size(); }
  /// Draws up to kDrawLinesPerFrame more of the uploaded lines into the offscreen picture of
  /// this view (a new view, size, opacity or overlay starts it again) and shows the picture
  /// over the framebuffer (fb_w x fb_h). Returns the lines drawn in this call.
  size_t draw(const std::array<float, 16>& view_proj, float alpha, int fb_w, int fb_h);
  /// Lines uploaded but not yet in the picture of the last drawn view.
  bool drawing() const { return drawn_ < count_; }
  size_t vertex_count() const { return count_; }

 private:
  /// Resizes the offscreen picture to w x h (when it differs).
  void size_picture(int w, int h);
  GLuint program_ = 0, vao_ = 0, vbo_ = 0;
  GLint u_view_proj_ = -1, u_alpha_ = -1;
  GLuint picture_fbo_ = 0, picture_tex_ = 0, show_program_ = 0, show_vao_ = 0;
  int picture_w_ = 0, picture_h_ = 0;
  size_t count_ = 0;                 ///< vertices on the GPU
  std::vector<LineVertex> pending_;  ///< the lines being uploaded
  size_t uploaded_ = 0;              ///< how many of pending_ are on the GPU
  uint64_t generation_ = 0;          ///< counts upload() calls: a new overlay
  /// What the offscreen picture shows: the view, the opacity and the overlay (generation_).
  struct PictureKey {
    std::array<float, 16> view_proj{};
    float alpha = -1;
    uint64_t generation = ~uint64_t(0);
    bool operator==(const PictureKey&) const = default;
  } picture_key_;
  size_t drawn_ = 0;  ///< vertices in the offscreen picture
};

}  // namespace kdgrid::viewer
