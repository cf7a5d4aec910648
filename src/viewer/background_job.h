// A background job of the viewer: a function run on a thread of its own, whose result the UI
// thread polls between frames, and a wake-up (glfwPostEmptyEvent in the viewer) called once
// that result, or the exception the function threw, is ready. A UI thread asleep until the
// next event then finds the result ready when the wake-up arrives, not at its next timeout.
#pragma once

#include <chrono>
#include <exception>
#include <functional>
#include <future>
#include <type_traits>
#include <utility>

namespace kdgrid::viewer {

template <class R>
class BackgroundJob {
  static_assert(!std::is_void_v<R>, "a background job returns a result");

 public:
  /// No job (valid() is false).
  BackgroundJob() = default;
  /// Starts `f` on a thread of its own; `wake` runs on that thread after the result of `f` (or
  /// the exception it threw) is ready.
  template <class F>
  BackgroundJob(F f, std::function<void()> wake) {
    std::promise<R> promise;
    result_ = promise.get_future();
    thread_ = std::async(std::launch::async, [f = std::move(f), promise = std::move(promise),
                                              wake = std::move(wake)]() mutable {
      try {
        promise.set_value(f());
      } catch (...) {
        promise.set_exception(std::current_exception());
      }
      if (wake) wake();
    });
  }
  BackgroundJob(BackgroundJob&&) noexcept = default;
  /// Replacing a job waits for the old one's thread (its wake-up included), as destroying it does.
  BackgroundJob& operator=(BackgroundJob&&) noexcept = default;

  /// Started and its result not taken yet.
  bool valid() const { return result_.valid(); }
  /// Started, its result not taken and ready to take.
  bool ready() const {
    return valid() && result_.wait_for(std::chrono::seconds(0)) == std::future_status::ready;
  }
  /// Waits until the result is ready.
  void wait() const { result_.wait(); }
  /// Takes the result (waiting for it) or rethrows what the function threw, and lets the
  /// thread and what the function holds go; valid() is then false.
  R get() {
    std::future<void> thread = std::move(thread_);  // released on return, even on a throw
    return result_.get();
  }

 private:
  std::future<R> result_;
  /// The thread (std::async's future, whose release waits for it): declared after result_, so
  /// destroyed first and a job never outlives its owner.
  std::future<void> thread_;
};

/// Starts a BackgroundJob of `f` (callable with no arguments).
template <class F>
auto start_background_job(F f, std::function<void()> wake) {
  return BackgroundJob<std::invoke_result_t<F&>>(std::move(f), std::move(wake));
}

}  // namespace kdgrid::viewer
