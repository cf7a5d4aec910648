// The progressive render loop on its own thread. The UI thread posts what to render (scene,
// structure, camera, size, mode) and picks up the newest completed pass; it never waits on a
// pass. A new job restarts accumulation and cancels the running pass (between tiles), except
// that a preview pass (a reduced-resolution pass of a moving camera, sized to take a few tens
// of milliseconds) runs to its end when the next job is another preview: cancelling it at
// every frame of a camera move would show nothing until the move ends, while finishing it
// shows a picture one pass behind the newest camera, and the newest job starts right after.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "accel/accelerator.h"
#include "render/renderer.h"
#include "scene/scene.h"

namespace kdgrid::viewer {

/// A scene with the structure built over its mesh. Shared between the UI thread (overlays,
/// picking) and the render worker; the last owner frees it, so swapping in a new structure
/// never frees one a pass is still using. The accelerator is declared after the scene so it
/// is destroyed first (it references the scene's mesh).
struct World {
  std::shared_ptr<const Scene> scene;
  std::string name;  ///< structure name as given to make_accelerator
  std::unique_ptr<Accelerator> accel;
  BuildParams params;  ///< what accel was built with
  double build_seconds = 0;
  double auto_cell = 0;  ///< the hybrid's auto cell size for the scene (set by a scene load)
};

/// What the worker renders.
struct RenderJob {
  std::shared_ptr<const World> world;
  Camera camera;
  RenderSettings settings;
  int max_samples = 256;  ///< stop accumulating here (the image no longer changes visibly)
  /// A reduced-resolution pass of a moving camera: a later preview job lets it finish (see
  /// the top of this file); any other job cancels it.
  bool preview = false;
};

/// One completed, resolved image.
struct RenderedImage {
  std::vector<float> rgb;  ///< linear RGB or raw counts (heat modes), row 0 at the top
  int width = 0, height = 0;
  int samples = 0;
  RenderMode mode = RenderMode::Shaded;
  Shading shading = Shading::Lights;  ///< RenderSettings::shading of that job
  uint64_t job_id = 0;                ///< which post() produced it
  bool preview = false;               ///< RenderJob::preview of that job
  double pass_seconds = 0;            ///< wall time of the pass that completed it
  uint64_t pass_rays = 0;             ///< rays traced by that pass
  RenderCounters pass_counters;       ///< the same, by kind (primary, shadow, ...)
};

class RenderWorker {
 public:
  /// `on_image` (optional) is called on the worker thread after each completed pass, and after
  /// a failure, so that a UI thread sleeping on its event queue can wake up for it.
  explicit RenderWorker(std::function<void()> on_image = {});
  ~RenderWorker();
  RenderWorker(const RenderWorker&) = delete;
  RenderWorker& operator=(const RenderWorker&) = delete;

  /// Replaces the job; cancels the running pass at once unless both it and `job` are
  /// previews. Returns the job id that images rendered from this job will carry.
  uint64_t post(RenderJob job);

  /// If a pass completed since the last call, swaps its image into `out` and returns true.
  /// Holds the hand-over mutex only for a vector swap.
  bool take_image(RenderedImage& out);

  /// True while the worker is rendering or has a job it has not finished.
  bool busy() const { return busy_.load(std::memory_order_relaxed); }
  /// Error from the renderer (e.g. an exception in a pass), empty if none.
  std::string error() const;

 private:
  void loop();

  mutable std::mutex job_mutex_;
  std::condition_variable job_cv_;
  RenderJob job_;        // guarded by job_mutex_
  uint64_t job_id_ = 0;  // guarded by job_mutex_
  bool job_changed_ = false;
  bool quit_ = false;
  std::string error_;  // guarded by job_mutex_

  std::atomic<bool> cancel_{false};
  bool running_preview_ = false;  // guarded by job_mutex_: the job being rendered is a preview
  std::atomic<bool> busy_{false};

  std::mutex image_mutex_;
  RenderedImage ready_;  // guarded by image_mutex_
  bool fresh_ = false;   // guarded by image_mutex_

  const std::function<void()> on_image_;  // set before the thread starts, then only read
  std::thread thread_;                    // last: started after every member above exists
};

}  // namespace kdgrid::viewer
