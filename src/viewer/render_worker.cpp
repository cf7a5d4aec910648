#include "viewer/render_worker.h"

#include <chrono>
#include <exception>
#include <utility>

namespace kdgrid::viewer {

RenderWorker::RenderWorker(std::function<void()> on_image)
    : on_image_(std::move(on_image)), thread_([this] { loop(); }) {}

RenderWorker::~RenderWorker() {
  {
    std::lock_guard lk(job_mutex_);
    quit_ = true;
    cancel_.store(true);
  }
  job_cv_.notify_all();
  thread_.join();
}

uint64_t RenderWorker::post(RenderJob job) {
  uint64_t id;
  {
    std::lock_guard lk(job_mutex_);
    const bool let_finish = job.preview && running_preview_;
    job_ = std::move(job);
    id = ++job_id_;
    job_changed_ = true;
    // Under the lock so the worker cannot clear it between taking the old job and starting
    // its pass: any pass that starts on the old job is cancelled. A preview pass followed by
    // another preview runs to its end, so that a moving camera always gets pictures (the
    // worker takes the newest job as soon as it is done).
    if (!let_finish) cancel_.store(true);
    busy_.store(true, std::memory_order_relaxed);
  }
  job_cv_.notify_all();
  return id;
}

bool RenderWorker::take_image(RenderedImage& out) {
  std::lock_guard lk(image_mutex_);
  if (!fresh_) return false;
  std::swap(out, ready_);
  fresh_ = false;
  return true;
}

std::string RenderWorker::error() const {
  std::lock_guard lk(job_mutex_);
  return error_;
}

void RenderWorker::loop() {
  // Everything below is owned by this thread; only job_/ready_ cross threads.
  std::unique_ptr<Renderer> renderer;
  std::shared_ptr<const World> world;  // keeps the scene and structure alive while in use
  RenderJob job;
  uint64_t id = 0;
  bool failed = false;
  RenderCounters rays_before;
  RenderedImage local;
  for (;;) {
    bool changed = false;
    {
      std::unique_lock lk(job_mutex_);
      busy_.store(job_changed_ || (renderer && !failed && renderer->samples() < job.max_samples),
                  std::memory_order_relaxed);
      job_cv_.wait(lk, [&] {
        return quit_ || job_changed_ ||
               (renderer && !failed && renderer->samples() < job.max_samples);
      });
      if (quit_) break;
      busy_.store(true, std::memory_order_relaxed);
      if (job_changed_) {
        job = job_;
        id = job_id_;
        job_changed_ = false;
        running_preview_ = job.preview;
        cancel_.store(false);
        changed = true;
        error_.clear();
      }
    }
    try {
      if (changed) {
        failed = false;
        if (!job.world || !job.world->accel) {
          renderer.reset();
          world.reset();
          continue;
        }
        // A new scene needs a new renderer; a new structure or view only resets the film.
        if (!renderer || !world || world->scene != job.world->scene) {
          renderer = std::make_unique<Renderer>(*job.world->scene, *job.world->accel, job.settings);
        } else {
          renderer->set_accelerator(*job.world->accel);
          renderer->set_settings(job.settings);
        }
        renderer->set_camera(job.camera);
        // Only now that the renderer no longer points at the old world may it be released.
        world = job.world;
        rays_before = RenderCounters{};
      }
      const auto t0 = std::chrono::steady_clock::now();
      if (!renderer->render_pass(&cancel_)) continue;  // cancelled: a new job is waiting
      const double secs =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      renderer->resolve(local.rgb);
      local.width = job.settings.width;
      local.height = job.settings.height;
      local.samples = renderer->samples();
      local.mode = job.settings.mode;
      local.shading = job.settings.shading;
      local.job_id = id;
      local.preview = job.preview;
      local.pass_seconds = secs;
      const RenderCounters& rc = renderer->counters();
      local.pass_counters.primary = rc.primary - rays_before.primary;
      local.pass_counters.shadow = rc.shadow - rays_before.shadow;
      local.pass_counters.reflection = rc.reflection - rays_before.reflection;
      local.pass_counters.refraction = rc.refraction - rays_before.refraction;
      local.pass_counters.probed = rc.probed - rays_before.probed;
      local.pass_counters.lit = rc.lit - rays_before.lit;
      local.pass_rays = local.pass_counters.total();
      rays_before = rc;
      {
        std::lock_guard lk(image_mutex_);
        std::swap(local, ready_);
        fresh_ = true;
      }
      if (on_image_) on_image_();
    } catch (const std::exception& e) {
      failed = true;
      {
        std::lock_guard lk(job_mutex_);
        error_ = e.what();
      }
      if (on_image_) on_image_();
    }
  }
}

}  // namespace kdgrid::viewer
