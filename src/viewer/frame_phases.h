// Where the UI thread's time goes within a frame: the loop marks the end of each of its phases,
// and each phase keeps its largest time and the frame it was taken in. --stats-json reports them
// ("frames.phases"), so a slow frame names the work that made it slow.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>

namespace kdgrid::viewer {

class FramePhases {
 public:
  /// The phases of one pass of the viewer's loop, in the order the loop runs them.
  enum Phase {
    kEvents,     // window events polled (the idle wait before them is not counted)
    kTasks,      // loads, builds and estimates handed over
    kInput,      // held keys and mouse: the camera
    kRenderJob,  // the render worker's job kept in step with the view
    kImage,      // a finished pass received, colourised and uploaded
    kOverlay,    // the structure overlay's geometry
    kAccuracy,   // the accuracy map's progress
    kScript,     // scripted requests (picks, rebuilds, drops, outputs)
    kDraw,       // the picture, overlays and panels drawn
    kSwap,       // the buffer swap (a software GL draws here)
    kCount
  };
  static constexpr std::array<const char*, kCount> kNames = {
      "events",  "tasks",    "input",  "render_job", "image",
      "overlay", "accuracy", "script", "draw",       "swap"};

  /// Starts the timing of frame `frame` at `now`.
  void start(std::chrono::steady_clock::time_point now, int frame) {
    mark_ = now;
    frame_ = frame;
  }

  /// Ends `phase` of the frame started last, now.
  void end(Phase phase) {
    const auto now = std::chrono::steady_clock::now();
    const float ms = std::chrono::duration<float, std::milli>(now - mark_).count();
    mark_ = now;
    if (ms > max_ms_[phase]) {
      max_ms_[phase] = ms;
      max_frame_[phase] = frame_;
    }
  }

  float max_ms(size_t phase) const { return max_ms_[phase]; }
  int max_frame(size_t phase) const { return max_frame_[phase]; }

 private:
  std::chrono::steady_clock::time_point mark_{};
  int frame_ = 0;
  std::array<float, kCount> max_ms_{};
  std::array<int, kCount> max_frame_{};
};

}  // namespace kdgrid::viewer
