#include "viewer/overlay.h"

#include <algorithm>
#include <cmath>

#include "viewer/gl_util.h"
#include "viewer_shaders.h"

namespace kdgrid::viewer {

Color ramp(float t, float alpha) {
  // Five stops, evenly spaced; chosen to stay distinguishable over grey renders.
  static constexpr float kStops[5][3] = {{0.10f, 0.20f, 1.00f},
                                         {0.00f, 0.85f, 1.00f},
                                         {0.10f, 0.95f, 0.20f},
                                         {1.00f, 0.90f, 0.00f},
                                         {1.00f, 0.10f, 0.05f}};
  if (!(t >= 0.0f)) t = 0.0f;  // also catches NaN
  t = std::min(t, 1.0f) * 4.0f;
  const int i = std::min(int(t), 3);
  const float f = t - float(i);
  return {kStops[i][0] + (kStops[i + 1][0] - kStops[i][0]) * f,
          kStops[i][1] + (kStops[i + 1][1] - kStops[i][1]) * f,
          kStops[i][2] + (kStops[i + 1][2] - kStops[i][2]) * f, alpha};
}

void LineBatch::line(const Vec3& a, const Vec3& b, const Color& c) {
  verts_.push_back({a.x, a.y, a.z, c.r, c.g, c.b, c.a});
  verts_.push_back({b.x, b.y, b.z, c.r, c.g, c.b, c.a});
}

void LineBatch::box(const Box3& b, const Color& c) {
  if (b.empty()) return;
  const Vec3 l = b.lo, h = b.hi;
  const Vec3 p[8] = {{l.x, l.y, l.z}, {h.x, l.y, l.z}, {h.x, h.y, l.z}, {l.x, h.y, l.z},
                     {l.x, l.y, h.z}, {h.x, l.y, h.z}, {h.x, h.y, h.z}, {l.x, h.y, h.z}};
  for (int i = 0; i < 4; ++i) {
    line(p[i], p[(i + 1) % 4], c);          // bottom face (z = lo)
    line(p[i + 4], p[(i + 1) % 4 + 4], c);  // top face (z = hi)
    line(p[i], p[i + 4], c);                // verticals
  }
}

void LineBatch::split(int axis, float pos, const Box3& nb, const Color& c) {
  const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
  Vec3 q[4];
  for (int i = 0; i < 4; ++i) {
    q[i][axis] = pos;
    q[i][a1] = (i == 1 || i == 2) ? nb.hi[a1] : nb.lo[a1];
    q[i][a2] = (i >= 2) ? nb.hi[a2] : nb.lo[a2];
  }
  for (int i = 0; i < 4; ++i) line(q[i], q[(i + 1) % 4], c);
}

void LineBatch::cross3(const Vec3& p, float s, const Color& c) {
  line(p - Vec3(s, 0, 0), p + Vec3(s, 0, 0), c);
  line(p - Vec3(0, s, 0), p + Vec3(0, s, 0), c);
  line(p - Vec3(0, 0, s), p + Vec3(0, 0, s), c);
}

std::array<float, 16> view_projection(const CameraFrame& f, float n, float fa) {
  const float aspect = float(f.width) / float(f.height);
  const float sx = 1.0f / (f.tan_half_fov * aspect), sy = 1.0f / f.tan_half_fov;
  // Rows of the view matrix: camera x = right, y = up, z = -fwd (GL looks down -z).
  const Vec3 r = f.right, u = f.up, b = -f.fwd;
  const float tr = -dot(r, f.eye), tu = -dot(u, f.eye), tb = -dot(b, f.eye);
  const float A = -(fa + n) / (fa - n), B = -2.0f * fa * n / (fa - n);
  // P * V written out; m[col * 4 + row].
  std::array<float, 16> m{};
  const float rows[4][4] = {{sx * r.x, sx * r.y, sx * r.z, sx * tr},
                            {sy * u.x, sy * u.y, sy * u.z, sy * tu},
                            {A * b.x, A * b.y, A * b.z, A * tb + B},
                            {-b.x, -b.y, -b.z, -tb}};
  for (int row = 0; row < 4; ++row)
    for (int col = 0; col < 4; ++col) m[col * 4 + row] = rows[row][col];
  return m;
}

bool project_to_pixel(const CameraFrame& f, const Vec3& p, float& px, float& py) {
  const Vec3 d = p - f.eye;
  const float z = dot(d, f.fwd);
  if (!(z > 0.0f)) return false;
  const float aspect = float(f.width) / float(f.height);
  const float u = dot(d, f.right) / z / (f.tan_half_fov * aspect);
  const float v = dot(d, f.up) / z / f.tan_half_fov;
  px = (u + 1.0f) * 0.5f * f.width;
  py = (1.0f - v) * 0.5f * f.height;
  return true;
}

bool crosses_split(const RaySegment& seg, const SplitPlane& s) {
  const int ax = s.axis;
  const float d = seg.ray.dir[ax];
  if (d == 0.0f || !(seg.t1 >= seg.t0)) return false;  // parallel to the plane, or no segment
  const float t = (s.position - seg.ray.org[ax]) / d;
  if (!(t >= seg.t0 && t <= seg.t1)) return false;
  const Vec3 p = seg.ray.at(t);
  // The crossing lies on the node's face when the ray hits the plane at its edge; a relative
  // tolerance keeps those.
  for (int k = 1; k <= 2; ++k) {
    const int a = (ax + k) % 3;
    const float tol =
        1e-5f * std::max(1.0f, std::fabs(s.node_box.hi[a] - s.node_box.lo[a]) + std::fabs(p[a]));
    if (p[a] < s.node_box.lo[a] - tol || p[a] > s.node_box.hi[a] + tol) return false;
  }
  return true;
}

size_t build_split_overlay(const Accelerator& a, int lo, int hi, LineBatch& out,
                           const RaySegment* crossed_by) {
  int max_depth = 1;
  a.for_each_split([&](const SplitPlane& s) { max_depth = std::max(max_depth, s.depth); });
  // Colours span the depths shown (the legend's ramp from lo to hi), not the whole tree.
  const float top = float(std::max(lo + 1, std::min(hi, max_depth)));
  size_t n = 0;
  a.for_each_split([&](const SplitPlane& s) {
    if (s.depth < lo || s.depth > hi || out.segments() >= kMaxOverlaySegments) return;
    if (crossed_by && !crosses_split(*crossed_by, s)) return;
    out.split(s.axis, s.position, s.node_box,
              ramp((float(s.depth) - float(lo)) / (top - float(lo)), 0.8f));
    ++n;
  });
  return n;
}

size_t build_cell_overlay(const Accelerator& a, LineBatch& out, size_t* wanted) {
  uint32_t max_tris = 1;
  size_t leaves = 0;
  a.for_each_box([&](const StructureBox& b) {
    if (!b.leaf) return;
    max_tris = std::max(max_tris, b.num_triangles);
    ++leaves;
  });
  if (wanted) *wanted += leaves;
  size_t n = 0;
  a.for_each_box([&](const StructureBox& b) {
    if (!b.leaf || out.segments() + 12 > kMaxOverlaySegments) return;
    // Colour by occupancy on a log scale: most cells hold few triangles.
    const float t = std::log1p(float(b.num_triangles)) / std::log1p(float(max_tris));
    out.box(b.box, ramp(t, 0.7f));
    ++n;
  });
  return n;
}

size_t build_box_overlay(const Accelerator& a, int lo, int hi, LineBatch& out, size_t* wanted) {
  // Boxes per depth: when the range holds more than the cap allows, the deepest levels are
  // left out whole (the shallow ones drawn completely), not an arbitrary part of every level.
  std::vector<size_t> per_depth;
  a.for_each_box([&](const StructureBox& b) {
    if (b.depth < 0) return;
    if (size_t(b.depth) >= per_depth.size()) per_depth.resize(size_t(b.depth) + 1, 0);
    ++per_depth[size_t(b.depth)];
  });
  const int max_depth = std::max(1, int(per_depth.size()) - 1);
  const float top = float(std::max(lo + 1, std::min(hi, max_depth)));
  size_t in_range = 0, room = (kMaxOverlaySegments - out.segments()) / 12;
  int last = lo - 1;
  for (int d = std::max(lo, 0); d <= std::min(hi, int(per_depth.size()) - 1); ++d) {
    in_range += per_depth[size_t(d)];
    if (in_range <= room) last = d;
  }
  if (wanted) *wanted += in_range;
  // Level by level, the shallow ones first: a picture drawn a part per frame (LineRenderer)
  // fills in from the root down.
  std::vector<std::vector<Box3>> levels(size_t(std::max(last + 1, 0)));
  a.for_each_box([&](const StructureBox& b) {
    if (b.depth < lo || b.depth > last) return;
    levels[size_t(b.depth)].push_back(b.box);
  });
  size_t n = 0;
  for (int d = std::max(lo, 0); d <= last; ++d) {
    const Color c = ramp((float(d) - float(lo)) / (top - float(lo)), 0.7f);
    for (const Box3& b : levels[size_t(d)]) out.box(b, c);
    n += levels[size_t(d)].size();
  }
  return n;
}

void LineRenderer::init() {
  program_ = make_program("lines", shaders::k_lines_vert, shaders::k_lines_frag);
  u_view_proj_ = glGetUniformLocation(program_, "u_view_proj");
  u_alpha_ = glGetUniformLocation(program_, "u_alpha");
  GL_CHECK(glGenVertexArrays(1, &vao_));
  GL_CHECK(glGenBuffers(1, &vbo_));
  GL_CHECK(glBindVertexArray(vao_));
  GL_CHECK(glBindBuffer(GL_ARRAY_BUFFER, vbo_));
  // Allocated once, for the largest overlay: an upload only writes into it.
  GL_CHECK(glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(2 * kMaxOverlaySegments * sizeof(LineVertex)),
                        nullptr, GL_STATIC_DRAW));
  GL_CHECK(glEnableVertexAttribArray(0));
  GL_CHECK(glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, sizeof(LineVertex), nullptr));
  GL_CHECK(glEnableVertexAttribArray(1));
  GL_CHECK(glVertexAttribPointer(1, 4, GL_FLOAT, GL_FALSE, sizeof(LineVertex),
                                 reinterpret_cast<const void*>(3 * sizeof(float))));
  GL_CHECK(glBindVertexArray(0));
  show_program_ = make_program("picture", shaders::k_image_vert, shaders::k_picture_frag);
  GL_CHECK(glGenVertexArrays(1, &show_vao_));
  GL_CHECK(glGenFramebuffers(1, &picture_fbo_));
  GL_CHECK(glGenTextures(1, &picture_tex_));
}

void LineRenderer::destroy() {
  if (vbo_) glDeleteBuffers(1, &vbo_);
  if (vao_) glDeleteVertexArrays(1, &vao_);
  if (program_) glDeleteProgram(program_);
  if (picture_fbo_) glDeleteFramebuffers(1, &picture_fbo_);
  if (picture_tex_) glDeleteTextures(1, &picture_tex_);
  if (show_vao_) glDeleteVertexArrays(1, &show_vao_);
  if (show_program_) glDeleteProgram(show_program_);
  vbo_ = vao_ = program_ = picture_fbo_ = picture_tex_ = show_vao_ = show_program_ = 0;
}

void LineRenderer::upload(LineBatch&& batch) {
  pending_ = batch.take();
  if (pending_.size() > 2 * kMaxOverlaySegments) pending_.resize(2 * kMaxOverlaySegments);
  uploaded_ = 0;
  count_ = 0;
  ++generation_;
}

size_t LineRenderer::upload_step(size_t max_vertices) {
  size_t n = 0;
  if (uploaded_ < pending_.size()) {
    n = std::min(max_vertices, pending_.size() - uploaded_);
    GL_CHECK(glBindBuffer(GL_ARRAY_BUFFER, vbo_));
    GL_CHECK(glBufferSubData(GL_ARRAY_BUFFER, GLintptr(uploaded_ * sizeof(LineVertex)),
                             GLsizeiptr(n * sizeof(LineVertex)), pending_.data() + uploaded_));
    uploaded_ += n;
    count_ = uploaded_;
  }
  if (uploaded_ >= pending_.size()) {
    pending_ = {};
    uploaded_ = 0;
  }
  return n;
}

void LineRenderer::size_picture(int w, int h) {
  if (w == picture_w_ && h == picture_h_) return;
  GL_CHECK(glBindTexture(GL_TEXTURE_2D, picture_tex_));
  GL_CHECK(glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, w, h, 0, GL_RGBA, GL_UNSIGNED_BYTE, nullptr));
  GL_CHECK(glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST));
  GL_CHECK(glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST));
  GL_CHECK(glBindFramebuffer(GL_FRAMEBUFFER, picture_fbo_));
  GL_CHECK(
      glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, picture_tex_, 0));
  GL_CHECK(glBindFramebuffer(GL_FRAMEBUFFER, 0));
  picture_w_ = w;
  picture_h_ = h;
  picture_key_ = {};  // drawn again from the start at the new size
}

size_t LineRenderer::draw(const std::array<float, 16>& vp, float alpha, int fb_w, int fb_h) {
  if (count_ == 0 || fb_w <= 0 || fb_h <= 0) return 0;
  size_picture(fb_w, fb_h);
  const PictureKey key{vp, alpha, generation_};
  GL_CHECK(glBindFramebuffer(GL_FRAMEBUFFER, picture_fbo_));
  if (!(key == picture_key_)) {
    picture_key_ = key;
    drawn_ = 0;
    GL_CHECK(glClearColor(0, 0, 0, 0));
    GL_CHECK(glClear(GL_COLOR_BUFFER_BIT));
  }
  // The picture holds premultiplied colour: each line goes over it as it would over the image,
  // so showing the picture with (1, 1 - alpha) gives what drawing every line there would.
  GL_CHECK(glEnable(GL_BLEND));
  const size_t n = std::min(count_ - drawn_, 2 * kDrawLinesPerFrame);
  if (n > 0) {
    GL_CHECK(
        glBlendFuncSeparate(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA, GL_ONE, GL_ONE_MINUS_SRC_ALPHA));
    GL_CHECK(glUseProgram(program_));
    GL_CHECK(glUniformMatrix4fv(u_view_proj_, 1, GL_FALSE, vp.data()));
    GL_CHECK(glUniform1f(u_alpha_, alpha));
    GL_CHECK(glBindVertexArray(vao_));
    GL_CHECK(glDrawArrays(GL_LINES, GLint(drawn_), GLsizei(n)));
    drawn_ += n;
  }
  GL_CHECK(glBindFramebuffer(GL_FRAMEBUFFER, 0));
  GL_CHECK(glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA));
  draw_fullscreen(show_program_, "u_picture", picture_tex_, show_vao_);
  GL_CHECK(glDisable(GL_BLEND));
  return n / 2;
}

}  // namespace kdgrid::viewer
