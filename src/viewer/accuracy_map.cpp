// The accuracy map: for sampled pixels, every ray of the pixel's Whitted tree (primary and
// secondary, traced by the renderer's own code) is judged against the double-precision
// reference of `kdgrid check` (AccuracyReference), in parallel batches off the UI thread,
// pixels in a shuffled order so that the map fills in evenly; the picture shows each judged
// pixel's worst verdict, the panel the disagreement rate beside the speed of the structure and
// triangle test on the same rays.
#include <imgui.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <random>

#include <tbb/parallel_for.h>

#include "viewer/viewer.h"
#include "viewer/viewer_internal.h"

namespace kdgrid::viewer {

namespace {

/// Seconds a batch aims at: short enough that a change of view restarts the map promptly.
constexpr double kBatchSeconds = 0.05;

/// Verdict colours over the picture (RGB): agree, ambiguous, disagree, leak.
constexpr uint8_t kVerdictColor[4][3] = {
    {60, 200, 90}, {230, 200, 60}, {240, 50, 40}, {240, 60, 240}};

}  // namespace

AccuracyBatch judge_accuracy_batch(std::shared_ptr<const World> world,
                                   std::shared_ptr<const AccuracyReference> ref, Camera camera,
                                   int w, int h, SecondaryOffset offset,
                                   std::vector<uint32_t> pixels) {
  AccuracyBatch b;
  b.pixels = std::move(pixels);
  b.verdicts.resize(b.pixels.size());
  RenderSettings rs;  // the render's depth and shadows, as the viewer's render worker uses
  rs.width = w;
  rs.height = h;
  rs.offset = offset;
  const Renderer renderer(*world->scene, *world->accel, rs);
  const CameraFrame f = CameraFrame::make(camera, w, h);
  const Accelerator& accel = *world->accel;
  // Every pixel's judged rays (any-hit: true) with their verdicts, judged in parallel (the
  // reference tests every triangle per ray); counted and timed below in pixel order.
  std::vector<std::vector<std::pair<Ray, bool>>> pixel_rays(b.pixels.size());
  std::vector<std::vector<uint8_t>> pixel_kinds_verdicts(b.pixels.size());
  tbb::parallel_for(size_t(0), b.pixels.size(), [&](size_t k) {
    const uint32_t p = b.pixels[k];
    const RayTree tree = renderer.trace_tree(
        f.ray(float(p % uint32_t(w)) + 0.5f, float(p / uint32_t(w)) + 0.5f), false);
    uint8_t worst = 0;
    for (const RayTreeNode& n : tree.nodes) {
      const bool any = n.kind == RayKind::Shadow;
      const AccuracyVerdict v = any ? ref->judge_occluded(n.ray, n.trace.occluded)
                                    : ref->judge_closest(n.ray, n.trace.hit.valid(), n.trace.hit);
      // Low bits the verdict, bit 2 set for a secondary ray.
      pixel_kinds_verdicts[k].push_back(uint8_t(v) | (n.kind == RayKind::Primary ? 0 : 4));
      worst = std::max(worst, uint8_t(v));
      pixel_rays[k].emplace_back(n.ray, any);
    }
    b.verdicts[k] = uint8_t(worst + 1);
  });
  std::vector<std::pair<Ray, bool>> rays;
  for (size_t k = 0; k < b.pixels.size(); ++k) {
    for (const uint8_t kv : pixel_kinds_verdicts[k]) ++b.counts[kv >> 2][kv & 3];
    rays.insert(rays.end(), pixel_rays[k].begin(), pixel_rays[k].end());
  }
  // The speed of the choice: the structure's fast queries on the same rays, one thread.
  uint64_t answers = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (const auto& [r, any] : rays) {
    Hit hit;
    answers += any ? accel.occluded(r) : accel.intersect(r, hit);
  }
  b.query_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  b.query_rays = rays.size();
  b.answers = answers;
  return b;
}

void Viewer::update_accuracy() {
  // The reference is made once per scene. Another scene's (and the scene it reads) is let go
  // once its job is done: dropping a running job would wait for it.
  if (reference_job_.ready()) reference_ = reference_job_.get();
  if (reference_scene_ && (!world_ || reference_scene_ != world_->scene) &&
      !reference_job_.valid()) {
    reference_.reset();
    reference_scene_.reset();
  }
  if (!show_accuracy_ || !world_ || posted_w_ <= 0 || posted_preview_) return;
  AccuracyMap& m = accuracy_;
  const bool stale = m.world != world_ || m.offset != offset_ || m.w != posted_w_ ||
                     m.h != posted_h_ || !same_camera(m.camera, posted_camera_);
  if (m.running.valid()) {
    if (!m.running.ready()) return;
    AccuracyBatch b = m.running.get();
    if (!stale) {
      for (size_t k = 0; k < b.pixels.size(); ++k) m.verdict[b.pixels[k]] = b.verdicts[k];
      for (int i = 0; i < 2; ++i)
        for (int v = 0; v < 4; ++v) m.counts[i][v] += b.counts[i][v];
      m.judged += b.pixels.size();
      m.query_seconds += b.query_seconds;
      m.query_rays += b.query_rays;
      // The next batch sized to take about kBatchSeconds.
      const double per_pixel = b.seconds / double(std::max<size_t>(1, b.pixels.size()));
      m.batch = size_t(std::clamp(kBatchSeconds / std::max(per_pixel, 1e-7), 4.0, 65536.0));
      recolor_ = true;
    }
  }
  if (stale) {
    m = AccuracyMap{};
    m.world = world_;
    m.offset = offset_;
    m.camera = posted_camera_;
    m.w = posted_w_;
    m.h = posted_h_;
    m.verdict.assign(size_t(m.w) * size_t(m.h), 0);
    m.order.resize(m.verdict.size());
    std::iota(m.order.begin(), m.order.end(), 0u);
    std::shuffle(m.order.begin(), m.order.end(), std::mt19937(12345));
    recolor_ = true;
  }
  if (m.next >= m.order.size()) return;  // complete
  if (!reference_scene_) {
    reference_scene_ = world_->scene;
    reference_job_ = run_in_background([scene = world_->scene] {
      return std::shared_ptr<const AccuracyReference>(
          std::make_shared<AccuracyReference>(scene->mesh));
    });
  }
  // The batches start once the reference is made (its job wakes the UI thread then).
  if (!reference_ || reference_scene_ != world_->scene) return;
  const size_t n = std::min(m.batch, m.order.size() - m.next);
  std::vector<uint32_t> pixels(m.order.begin() + long(m.next), m.order.begin() + long(m.next + n));
  m.next += n;
  // Each batch wakes the UI thread as it ends: the UI thread takes it and starts the next one
  // at once, not at its next frame (an idle viewer wakes only a few times a second).
  m.running = run_in_background([world = world_, judge = reference_, cam = m.camera, w = m.w,
                                 h = m.h, offset = m.offset, px = std::move(pixels)]() mutable {
    const auto t0 = std::chrono::steady_clock::now();
    AccuracyBatch b = judge_accuracy_batch(world, judge, cam, w, h, offset, std::move(px));
    b.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return b;
  });
}

bool Viewer::accuracy_complete() const {
  return !show_accuracy_ ||
         (accuracy_.w > 0 && accuracy_.next >= accuracy_.order.size() &&
          !accuracy_.running.valid() && accuracy_.world == world_ && accuracy_.offset == offset_);
}

void Viewer::colorize_accuracy(std::vector<uint8_t>& rgba) const {
  const AccuracyMap& m = accuracy_;
  if (!show_accuracy_ || m.w <= 0 || image_.width <= 0) return;
  for (int y = 0; y < image_.height; ++y)
    for (int x = 0; x < image_.width; ++x) {
      const size_t mi =
          size_t(y * m.h / image_.height) * size_t(m.w) + size_t(x * m.w / image_.width);
      uint8_t* px = &rgba[(size_t(y) * size_t(image_.width) + size_t(x)) * 4];
      const uint8_t v = m.verdict[mi];
      if (v == 0) {  // not judged yet: the picture, dimmed
        for (int c = 0; c < 3; ++c) px[c] = uint8_t(px[c] / 3);
        continue;
      }
      // Agreement over a greyed picture; the other verdicts in full colour.
      const uint8_t* col = kVerdictColor[v - 1];
      const float keep = v == 1 ? 0.6f : 0.0f;
      const int grey = (px[0] + px[1] + px[2]) / 3;
      for (int c = 0; c < 3; ++c)
        px[c] = uint8_t(keep * float(grey) + (1.0f - keep) * float(col[c]));
    }
}

AccuracySummary Viewer::accuracy_summary() const {
  AccuracySummary s;
  const AccuracyMap& m = accuracy_;
  s.pixels = m.verdict.size();
  s.judged = m.judged;
  for (int i = 0; i < 2; ++i)
    for (int v = 0; v < 4; ++v) s.counts[i][v] = m.counts[i][v];
  for (uint8_t v : m.verdict) s.pixel_verdicts[v == 0 ? 0 : v - 1] += v != 0;
  uint64_t rays = 0, wrong = 0;
  for (int i = 0; i < 2; ++i) {
    for (int v = 0; v < 4; ++v) rays += m.counts[i][v];
    wrong += m.counts[i][int(AccuracyVerdict::Disagree)] + m.counts[i][int(AccuracyVerdict::Leak)];
  }
  s.rays = rays;
  s.disagreement_rate = rays ? double(wrong) / double(rays) : 0.0;
  s.mrays = m.query_seconds > 0 ? double(m.query_rays) / m.query_seconds * 1e-6 : 0.0;
  return s;
}

void Viewer::draw_accuracy_panel() {
  const auto chk = [this](const char* label) { audit_.item(label); };
  if (ImGui::Checkbox("accuracy map", &show_accuracy_)) recolor_ = true;
  chk("accuracy map");
  if (!world_) return;
  // The triangle test is a build knob: a change rebuilds the structure on screen.
  int test = int(params_.triangle_test);
  const char* names[] = {"watertight", "moller"};
  if (test == int(TriangleTestKind::Watertight) || test == int(TriangleTestKind::Moller)) {
    const int before = test;
    ImGui::RadioButton(names[0], &test, int(TriangleTestKind::Watertight));
    ImGui::SameLine();
    ImGui::RadioButton(names[1], &test, int(TriangleTestKind::Moller));
    chk("moller");
    if (test != before) {
      BuildParams p = params_;
      p.triangle_test = TriangleTestKind(test);
      start_build(accel_name_, p);
    }
  }
  // Where secondary rays start: the render, the pick's ray tree and this map follow it.
  int off = int(offset_);
  ImGui::TextUnformatted("secondary rays start");
  const char* offsets[] = {"robust", "epsilon", "none"};
  for (int k = 0; k < 3; ++k) {
    if (k) ImGui::SameLine();
    ImGui::RadioButton(offsets[k], &off, k);
  }
  chk("secondary rays start");
  if (off != int(offset_)) {
    offset_ = SecondaryOffset(off);
    if (pick_) trace_pick_tree(pick_->selected);
  }
  if (is_embree(world_->name)) {
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextDisabled("%s uses its own triangle test", world_->name.c_str());
    ImGui::PopTextWrapPos();
  }
  if (!show_accuracy_) return;
  const AccuracySummary s = accuracy_summary();
  ImGui::TextWrapped("judged %zu of %zu pixels (%llu rays), %s", s.judged, s.pixels,
                     (unsigned long long)s.rays, accuracy_complete() ? "complete" : "sampling");
  ImGui::TextWrapped(
      "disagreement rate %.4g%% at %.3g Mrays/s (%s, %s test, %s offset, one thread)",
      100.0 * s.disagreement_rate, s.mrays, world_->name.c_str(),
      to_string(world_->params.triangle_test), to_string(offset_));
  static const char* const kNames[4] = {"agree", "ambiguous", "disagree", "leak"};
  if (ImGui::BeginTable("accuracy", 3, ImGuiTableFlags_SizingFixedFit)) {
    ImGui::TableNextRow();
    ImGui::TableNextColumn();
    ImGui::TextUnformatted("rays");
    ImGui::TableNextColumn();
    ImGui::TextUnformatted("primary");
    ImGui::TableNextColumn();
    ImGui::TextUnformatted("secondary");
    for (int v = 0; v < 4; ++v) {
      ImGui::TableNextRow();
      ImGui::TableNextColumn();
      const uint8_t* c = kVerdictColor[v];
      ImGui::TextColored(ImVec4(c[0] / 255.0f, c[1] / 255.0f, c[2] / 255.0f, 1), "%s", kNames[v]);
      ImGui::TableNextColumn();
      ImGui::Text("%llu", (unsigned long long)s.counts[0][v]);
      ImGui::TableNextColumn();
      ImGui::Text("%llu", (unsigned long long)s.counts[1][v]);
    }
    ImGui::EndTable();
  }
  ImGui::PushTextWrapPos(0.0f);
  ImGui::TextDisabled(
      "each pixel shows the worst verdict of its ray tree against a double-precision reference; "
      "dim: not judged yet");
  ImGui::PopTextWrapPos();
}

}  // namespace kdgrid::viewer
