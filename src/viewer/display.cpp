// kdgrid-viewer's picture: the render hand-over (what is posted to the render worker, the
// passes it hands back, their colouring and texture upload), the auto shading that follows
// the passes, drawing the frame under the panels, and the files written from it (screenshots,
// default output names).
#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>

#include "accel/guards.h"
#include "util/error.h"
#include "viewer/gl_util.h"
#include "viewer/viewer_internal.h"

namespace kdgrid::viewer {

namespace {

/// Each render mode's name (--heatmap, --stats-json) and what its heat map shows per pixel.
struct ModeText {
  RenderMode mode;
  const char* name;
  const char* heat;
};
constexpr ModeText kModeTexts[] = {{RenderMode::Shaded, "shaded", ""},
                                   {RenderMode::HeatSteps, "steps", "traversal steps"},
                                   {RenderMode::HeatTests, "tests", "triangle tests"},
                                   {RenderMode::HeatTime, "time", "nanoseconds"}};

const ModeText& mode_text(RenderMode m) {
  for (const ModeText& t : kModeTexts)
    if (t.mode == m) return t;
  return kModeTexts[0];
}

}  // namespace

const char* mode_name(RenderMode m) {
  return mode_text(m).name;
}

const char* heat_label(RenderMode m) {
  return mode_text(m).heat;
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
  if (have_image_ && brute_refusal_.empty())
    draw_fullscreen(image_program_, "u_image", tex_, empty_vao_);
  if (world_ && posted_w_ > 0) {
    // The live camera (not the displayed image's) so overlays follow the mouse at once.
    const CameraFrame f = CameraFrame::make(cam_.camera(), posted_w_, posted_h_);
    const float r = scene_radius();
    const float dist = length(f.eye - scene_bounds_.center());
    const auto vp = view_projection(f, r * 1e-4f, (dist + r) * 10.0f);
    const size_t drawn = structure_lines_.draw(vp, overlay_alpha_, fw, fh);
    overlay_frames_.max_drawn = std::max(overlay_frames_.max_drawn, drawn);
    overlay_frames_.draw_frames += drawn > 0;
  }
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

}  // namespace kdgrid::viewer
