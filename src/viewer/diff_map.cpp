// Difference maps: a heat map (steps or triangle tests per pixel) pinned with the structure and
// build knob it was rendered with, compared with the current heat map after any change of
// cell size, knob or structure: the difference on a signed colour scale, the pinned map, or
// both side by side (split view), with the totals, a histogram of each and the values under the
// cursor; --pin-heatmap and --diff-exr script it.
#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "image/image_io.h"
#include "util/enum_names.h"
#include "viewer/viewer.h"
#include "viewer/viewer_internal.h"

namespace kdgrid::viewer {

namespace {

double total(const RenderedImage& img) {
  double s = 0;
  for (size_t i = 0; i < img.rgb.size(); i += 3) s += img.rgb[i];
  return s;
}

/// The signed scale: blue for fewer than pinned, white for equal, red for more.
void signed_color(float d, float m, uint8_t* out) {
  const float t = m > 0 ? std::clamp(d / m, -1.0f, 1.0f) : 0.0f;
  const float a = std::fabs(t);
  // White to blue (0.15, 0.35, 1) below 0, white to red (1, 0.15, 0.1) above.
  const float r = t < 0 ? 1.0f - a * 0.85f : 1.0f;
  const float g = t < 0 ? 1.0f - a * 0.65f : 1.0f - a * 0.85f;
  const float b = t < 0 ? 1.0f : 1.0f - a * 0.9f;
  out[0] = uint8_t(std::lround(r * 255));
  out[1] = uint8_t(std::lround(g * 255));
  out[2] = uint8_t(std::lround(b * 255));
  out[3] = 255;
}

}  // namespace

std::string build_label(const World& w) {
  // accel_flags starts with " --accel NAME": the knobs follow it.
  return w.name +
         cli::accel_flags(w.name, w.params).substr(std::string(" --accel ").size() + w.name.size());
}

const char* to_string(DiffView v) {
  static constexpr EnumName<DiffView> kNames[] = {{DiffView::Current, "current"},
                                                  {DiffView::Pinned, "pinned"},
                                                  {DiffView::Difference, "difference"},
                                                  {DiffView::Split, "split"}};
  return enum_name(v, kNames);
}

void Viewer::pin_heatmap() {
  if (!have_image_ || image_.mode == RenderMode::Shaded || !world_) return;
  PinnedMap p;
  p.image = image_;
  p.camera = posted_camera_;
  p.label = build_label(*world_);
  pinned_ = std::move(p);
  recolor_ = true;
  message_ = "pinned the " + std::string(mode_name(image_.mode)) + " map of " + pinned_->label;
}

bool Viewer::diff_ready() const {
  return pinned_ && have_image_ && image_.mode == pinned_->image.mode &&
         image_.width == pinned_->image.width && image_.height == pinned_->image.height &&
         same_camera(posted_camera_, pinned_->camera) && !image_.preview;
}

void Viewer::diff_stats(DiffStats& s) const {
  s = {};
  if (!diff_ready()) return;
  const RenderedImage& a = pinned_->image;
  s.pinned_total = total(a);
  s.current_total = total(image_);
  for (size_t i = 0; i < image_.rgb.size(); i += 3) {
    const float d = image_.rgb[i] - a.rgb[i];
    s.max_abs = std::max(s.max_abs, std::fabs(d));
    s.more += d > 0;
    s.fewer += d < 0;
    s.max_value = std::max({s.max_value, image_.rgb[i], a.rgb[i]});
  }
}

bool Viewer::colorize_diff(std::vector<uint8_t>& rgba) {
  if (!diff_ready() || diff_view_ == DiffView::Current) return false;
  const RenderedImage& a = pinned_->image;
  const size_t n = size_t(image_.width) * size_t(image_.height);
  rgba.resize(n * 4);
  if (diff_view_ == DiffView::Difference) {
    DiffStats s;
    diff_stats(s);
    diff_scale_ = s.max_abs;
    for (size_t i = 0; i < n; ++i)
      signed_color(image_.rgb[i * 3] - a.rgb[i * 3], s.max_abs, &rgba[i * 4]);
    return true;
  }
  // Pinned or split: both maps on one range, the union of theirs, so colours compare.
  HeatRange r =
      heat_range(image_, settings_.heat_scale, settings_.heat_fixed_min, settings_.heat_fixed_max);
  const HeatRange rp =
      heat_range(a, settings_.heat_scale, settings_.heat_fixed_min, settings_.heat_fixed_max);
  if (settings_.heat_scale != HeatScale::Fixed) {
    r.lo = std::min(r.lo, rp.lo);
    r.hi = std::max(r.hi, rp.hi);
  }
  heat_range_ = r;
  std::vector<uint8_t> pinned_rgba;
  colorize(a, settings_.heat_scale, r, pinned_rgba);
  if (diff_view_ == DiffView::Pinned) {
    rgba = std::move(pinned_rgba);
    return true;
  }
  colorize(image_, settings_.heat_scale, r, rgba);
  const int split = int(std::lround(split_at_ * float(image_.width)));
  for (int y = 0; y < image_.height; ++y)
    for (int x = 0; x < std::min(split, image_.width); ++x) {
      const size_t i = (size_t(y) * size_t(image_.width) + size_t(x)) * 4;
      std::copy_n(&pinned_rgba[i], 4, &rgba[i]);
    }
  return true;
}

std::string Viewer::write_diff_exr(const std::string& path) const {
  if (!pinned_) return "--diff-exr: no heat map was pinned (--pin-heatmap)";
  if (!diff_ready())
    return "--diff-exr: the pinned map (" + std::to_string(pinned_->image.width) + "x" +
           std::to_string(pinned_->image.height) + ", " + mode_name(pinned_->image.mode) +
           ") and the current one differ in size, mode or camera: nothing to compare";
  const RenderedImage& a = pinned_->image;
  std::vector<float> rgb(image_.rgb.size());
  for (size_t i = 0; i < rgb.size(); i += 3) {
    rgb[i] = image_.rgb[i] - a.rgb[i];
    rgb[i + 1] = image_.rgb[i];
    rgb[i + 2] = a.rgb[i];
  }
  const std::string current = build_label(*world_);
  try {
    write_image(path, image_.width, image_.height, rgb,
                {{"description", std::string("kdgrid ") + mode_name(image_.mode) +
                                     " per pixel: R = current - pinned, G = current (" + current +
                                     "), B = pinned (" + pinned_->label + ")"}});
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

void Viewer::draw_diff_panel() {
  const auto chk = [this](const char* label) { audit_.item(label); };
  if (ImGui::Button("pin heat map")) pin_heatmap();
  chk("pin heat map");
  if (!pinned_) {
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextDisabled(
        "pin this map, then change the cell size, a build knob or the structure to see where "
        "the work changed");
    ImGui::PopTextWrapPos();
    return;
  }
  same_line_if_fits("unpin");
  if (ImGui::Button("unpin")) {
    pinned_.reset();
    recolor_ = true;
    return;
  }
  chk("unpin");
  ImGui::TextWrapped("pinned: %s, %s", mode_name(pinned_->image.mode), pinned_->label.c_str());
  int v = int(diff_view_);
  bool changed = ImGui::RadioButton("current", &v, int(DiffView::Current));
  ImGui::SameLine();
  changed |= ImGui::RadioButton("pinned", &v, int(DiffView::Pinned));
  ImGui::SameLine();
  changed |= ImGui::RadioButton("diff", &v, int(DiffView::Difference));
  ImGui::SameLine();
  changed |= ImGui::RadioButton("split", &v, int(DiffView::Split));
  chk("split");
  diff_view_ = DiffView(v);
  if (diff_view_ == DiffView::Split) {
    changed |= ImGui::SliderFloat("split at", &split_at_, 0.0f, 1.0f, "%.2f");
    chk("split at");
    ImGui::TextDisabled("left: pinned, right: current");
  }
  if (changed) recolor_ = true;
  if (!diff_ready()) {
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextColored(ImVec4(1.0f, 0.8f, 0.3f, 1.0f),
                       "the current map differs from the pinned one in mode, size or camera: "
                       "return to its view to compare");
    ImGui::PopTextWrapPos();
    if (ImGui::Button("back to the pinned view")) cam_.set_camera(pinned_->camera);
    return;
  }
  DiffStats s;
  diff_stats(s);
  const double d = s.current_total - s.pinned_total;
  ImGui::TextWrapped("totals: pinned %.6g, current %.6g, difference %+.6g (%+.2f%%)",
                     s.pinned_total, s.current_total, d,
                     s.pinned_total > 0 ? 100.0 * d / s.pinned_total : 0.0);
  ImGui::TextWrapped("pixels with more: %zu, fewer: %zu", s.more, s.fewer);
  // Histograms of both maps over the same bins, 0 .. the larger maximum.
  constexpr int kBins = 32;
  std::vector<float> hp(kBins, 0.0f), hc(kBins, 0.0f);
  const float top = std::max(s.max_value, 1.0f);
  for (size_t i = 0; i < image_.rgb.size(); i += 3) {
    hp[size_t(std::min(kBins - 1, int(pinned_->image.rgb[i] / top * kBins)))] += 1;
    hc[size_t(std::min(kBins - 1, int(image_.rgb[i] / top * kBins)))] += 1;
  }
  const float hmax =
      std::max(*std::max_element(hp.begin(), hp.end()), *std::max_element(hc.begin(), hc.end()));
  char overlay[64];
  std::snprintf(overlay, sizeof overlay, "pinned, 0 .. %.4g", top);
  ImGui::PlotHistogram("pinned", hp.data(), kBins, 0, overlay, 0.0f, hmax, ImVec2(0, 40));
  chk("pinned");
  std::snprintf(overlay, sizeof overlay, "current, 0 .. %.4g", top);
  ImGui::PlotHistogram("current", hc.data(), kBins, 0, overlay, 0.0f, hmax, ImVec2(0, 40));
  chk("current");
  if (ImGui::Button("export difference EXR")) {
    const std::string path = default_output_name("kdgrid-diff", "exr");
    const std::string err = write_diff_exr(path);
    message_ = err.empty() ? "wrote " + path : err;
    std::printf("kdgrid-viewer: %s\n", message_.c_str());
  }
  chk("export difference EXR");
}

bool Viewer::draw_diff_legend() {
  if (!diff_ready() || diff_view_ != DiffView::Difference) return false;
  ImGui::Text("%s per pixel, current - pinned", heat_label(image_.mode));
  const float w = 240 * ui_scale_, h = 14 * ui_scale_;
  const ImVec2 p = ImGui::GetCursorScreenPos();
  ImDrawList* dl = ImGui::GetWindowDrawList();
  constexpr int kSegs = 32;
  for (int i = 0; i < kSegs; ++i) {
    uint8_t c[4];
    signed_color((float(i) + 0.5f) / kSegs * 2.0f - 1.0f, 1.0f, c);
    dl->AddRectFilled(ImVec2(p.x + w * float(i) / kSegs, p.y),
                      ImVec2(p.x + w * float(i + 1) / kSegs, p.y + h),
                      IM_COL32(c[0], c[1], c[2], 255));
  }
  ImGui::Dummy(ImVec2(w, h));
  char lo[32], hi[32];
  std::snprintf(lo, sizeof lo, "%+.4g", -diff_scale_);
  std::snprintf(hi, sizeof hi, "%+.4g", diff_scale_);
  const float x0 = ImGui::GetCursorPosX();
  ImGui::TextUnformatted(lo);
  ImGui::SameLine(x0 + 0.5f * (w - ImGui::CalcTextSize("0").x));
  ImGui::TextUnformatted("0");
  ImGui::SameLine(x0 + w - ImGui::CalcTextSize(hi).x);
  ImGui::TextUnformatted(hi);
  audit_.legends.push_back(std::string("difference: ") + lo + " .. " + hi);
  return true;
}

void Viewer::update_hover() {
  hover_ = {};
  if (!have_image_ || image_.mode == RenderMode::Shaded || ImGui::GetIO().WantCaptureMouse) return;
  const ImGuiIO& io = ImGui::GetIO();
  if (io.DisplaySize.x <= 0 || io.DisplaySize.y <= 0) return;
  const int x = int(cursor_x_ / io.DisplaySize.x * float(image_.width));
  const int y = int(cursor_y_ / io.DisplaySize.y * float(image_.height));
  if (x < 0 || y < 0 || x >= image_.width || y >= image_.height) return;
  const size_t i = (size_t(y) * size_t(image_.width) + size_t(x)) * 3;
  hover_.valid = true;
  hover_.x = x;
  hover_.y = y;
  hover_.current = image_.rgb[i];
  const char* what = mode_name(image_.mode);
  if (diff_ready()) {
    hover_.has_pinned = true;
    hover_.pinned = pinned_->image.rgb[i];
    ImGui::SetTooltip("pixel %d,%d: %s %.4g, pinned %.4g, difference %+.4g", x, y, what,
                      hover_.current, hover_.pinned, hover_.current - hover_.pinned);
  } else {
    ImGui::SetTooltip("pixel %d,%d: %s %.4g", x, y, what, hover_.current);
  }
}

}  // namespace kdgrid::viewer
