// What the Viewer's source files (viewer.cpp, input.cpp, display.cpp, panels.cpp, ...) share
// besides the Viewer class itself.
#pragma once

#include <chrono>
#include <deque>
#include <utility>

#include <imgui.h>

#include "viewer/viewer.h"

namespace kdgrid::viewer {

using Clock = std::chrono::steady_clock;

/// Wakes the UI thread (asleep in glfwWaitEventsTimeout); callable from any thread.
void wake_ui();

/// Runs `f` off the UI thread as a BackgroundJob that wakes the UI thread once its result is
/// ready, however it ends: the UI thread takes the result at once, not at its next timeout.
template <class F>
auto run_in_background(F f) {
  return start_background_job(std::move(f), wake_ui);
}

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
