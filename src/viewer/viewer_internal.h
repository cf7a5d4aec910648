// What the Viewer's source files (viewer.cpp, input.cpp, display.cpp, panels.cpp, ...) share
// besides the Viewer class itself.
#pragma once

#include <chrono>
#include <deque>

#include <imgui.h>

#include "viewer/viewer.h"

namespace kdgrid::viewer {

using Clock = std::chrono::steady_clock;

/// Wakes the UI thread (asleep in glfwWaitEventsTimeout) when a background task ends, however
/// it ends; it polls the task's future at once instead of at its next timeout.
struct WakeUiOnExit {
  WakeUiOnExit() = default;
  WakeUiOnExit(const WakeUiOnExit&) = delete;
  WakeUiOnExit& operator=(const WakeUiOnExit&) = delete;
  ~WakeUiOnExit();
};

/// Colour of the brute-force refusal: orange, apart from the errors' red.
inline const ImVec4 kRefusalColor(1.0f, 0.6f, 0.1f, 1.0f);

/// The same camera, exactly (a moved camera restarts what depends on the view).
inline bool same_camera(const Camera& a, const Camera& b) {
  return a.eye == b.eye && a.target == b.target && a.up == b.up && a.fov_deg == b.fov_deg;
}

/// Appends `v` to a plot's history, which keeps the last 120 values.
inline void push_history(std::deque<float>& h, float v) {
  h.push_back(v);
  while (h.size() > 120) h.pop_front();
}

/// The render mode as --heatmap and --stats-json spell it ("shaded", "steps", "tests").
const char* mode_name(RenderMode m);
/// What a heat map of mode `m` shows per pixel: "traversal steps", "triangle tests" or
/// "nanoseconds" (of the primary ray's query).
const char* heat_label(RenderMode m);

}  // namespace kdgrid::viewer
