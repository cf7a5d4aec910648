// What the viewer tests measure in the viewer's screenshots and read from its --stats-json:
// image differences, the camera, the panel's items and cut labels.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <ostream>
#include <string>
#include <utility>

#include <nlohmann/json.hpp>

#include "image/image_io.h"
#include "scene/scene.h"

namespace kdgrid {
// Readable failure messages for camera vectors.
inline void PrintTo(const Vec3& v, std::ostream* os) {
  *os << "(" << v.x << ", " << v.y << ", " << v.z << ")";
}
}  // namespace kdgrid

namespace kdgrid::test {

/// The variance of the image's luminance: near 0 for a blank picture.
inline double luminance_variance(const ImageRGB& img) {
  double s = 0, s2 = 0;
  const size_t n = size_t(img.width) * size_t(img.height);
  for (size_t i = 0; i < n; ++i) {
    const double y =
        0.2126 * img.rgb[i * 3] + 0.7152 * img.rgb[i * 3 + 1] + 0.0722 * img.rgb[i * 3 + 2];
    s += y;
    s2 += y * y;
  }
  const double m = s / double(n);
  return s2 / double(n) - m * m;
}

/// Pixels within `radius` of (cx, cy) whose colour differs between a and b by more than 0.05
/// in some channel.
inline int changed_pixels_near(const ImageRGB& a, const ImageRGB& b, int cx, int cy, int radius) {
  int n = 0;
  for (int y = std::max(0, cy - radius); y <= std::min(a.height - 1, cy + radius); ++y)
    for (int x = std::max(0, cx - radius); x <= std::min(a.width - 1, cx + radius); ++x) {
      const size_t i = (size_t(y) * size_t(a.width) + size_t(x)) * 3;
      float d = 0;
      for (int c = 0; c < 3; ++c) d = std::max(d, std::fabs(a.rgb[i + c] - b.rgb[i + c]));
      if (d > 0.05f) ++n;
    }
  return n;
}

inline Vec3 json_vec(const nlohmann::json& j) {
  return {j[0].get<float>(), j[1].get<float>(), j[2].get<float>()};
}

/// The statistics' camera (state.camera or state.start_camera) as a Camera.
inline Camera json_camera(const nlohmann::json& j) {
  Camera c;
  c.eye = json_vec(j["eye"]);
  c.target = json_vec(j["target"]);
  c.up = json_vec(j["up"]);
  c.fov_deg = j["fov"].get<float>();
  return c;
}

/// The camera a run started with and the one it ended with: its statistics' state.start_camera
/// and state.camera.
inline std::pair<Camera, Camera> start_and_end_cameras(const nlohmann::json& stats) {
  return {json_camera(stats["state"]["start_camera"]), json_camera(stats["state"]["camera"])};
}

/// Whether `stats`' ui.items holds an item starting with `prefix`.
inline bool has_item(const nlohmann::json& stats, const std::string& prefix) {
  for (const auto& i : stats["ui"]["items"])
    if (i.get<std::string>().rfind(prefix, 0) == 0) return true;
  return false;
}

/// The labels and values --stats-json's ui.clipped lists as cut, one per line ("" if none).
inline std::string clipped_list(const nlohmann::json& stats) {
  std::string cut;
  for (const auto& c : stats["ui"]["clipped"]) cut += "\n  " + c.get<std::string>();
  return cut;
}

/// Occurrences of `what` in `text`.
inline int count_of(const std::string& text, const std::string& what) {
  int n = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + what.size()))
    ++n;
  return n;
}

/// "click X Y" (a driven run's action) at the middle of the field `name` of `stats`' ui.rects.
inline std::string click_field(const nlohmann::json& stats, const std::string& name) {
  const auto& r = stats["ui"]["rects"][name];
  if (!r.is_array()) return "echo 'driver: no field " + name + "'";
  return "click " + std::to_string(int(r[0].get<double>() + r[2].get<double>() * 0.5)) + " " +
         std::to_string(int(r[1].get<double>() + r[3].get<double>() * 0.5));
}

}  // namespace kdgrid::test
