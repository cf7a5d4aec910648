// The viewer's background jobs (src/viewer/background_job.h: live rebuilds, cell-size estimates,
// the structure overlay, the accuracy map): the wake-up that tells the sleeping UI thread to
// poll comes after the result is ready, so the poll it triggers finds the result.
#include <gtest/gtest.h>

#include <atomic>
#include <future>
#include <stdexcept>
#include <string>

#include "viewer/background_job.h"

namespace kdgrid::viewer {
namespace {

/// Runs a job of `f` whose function waits until the job object is in place, and returns
/// whether the job was ready when its wake-up came (what a UI thread woken then would see).
template <class F>
bool ready_at_wake_up(F f, BackgroundJob<std::invoke_result_t<F&>>& job) {
  std::promise<void> placed;
  std::promise<bool> woke;
  std::future<bool> seen = woke.get_future();
  const BackgroundJob<std::invoke_result_t<F&>>* self = nullptr;
  job = BackgroundJob<std::invoke_result_t<F&>>(
      [f = std::move(f), go = placed.get_future().share()]() mutable {
        go.wait();
        return f();
      },
      [&] { woke.set_value(self->ready()); });
  self = &job;
  placed.set_value();
  return seen.get();
}

TEST(BackgroundJob, WakesTheUiThreadOnlyOnceItsResultIsReady) {
  BackgroundJob<std::string> job;
  EXPECT_FALSE(job.valid());
  EXPECT_TRUE(ready_at_wake_up([] { return std::string("built"); }, job));
  EXPECT_TRUE(job.valid());
  EXPECT_EQ(job.get(), "built");
  EXPECT_FALSE(job.valid());  // taken: the UI thread starts the next one
}

TEST(BackgroundJob, AFailedJobWakesOnceItsExceptionIsReady) {
  BackgroundJob<int> job;
  EXPECT_TRUE(
      ready_at_wake_up([]() -> int { throw std::runtime_error("cell size refused"); }, job));
  EXPECT_THROW(job.get(), std::runtime_error);
  EXPECT_FALSE(job.valid());
}

TEST(BackgroundJob, ReleasingAJobWaitsForItsWakeUp) {
  // The viewer lets a job go (replaced, or with the viewer) only after its wake-up has run:
  // no wake-up reaches a window that is gone.
  std::atomic<bool> woke{false};
  std::promise<void> go;
  {
    BackgroundJob<int> job(
        [g = go.get_future()]() mutable {
          g.wait();
          return 1;
        },
        [&] { woke = true; });
    go.set_value();
  }
  EXPECT_TRUE(woke.load());
  std::promise<void> go2;
  BackgroundJob<int> job = start_background_job(
      [g = go2.get_future()]() mutable {
        g.wait();
        return 2;
      },
      [&] { woke = false; });
  go2.set_value();
  job = BackgroundJob<int>();  // replaced: waits as a release does
  EXPECT_FALSE(woke.load());
}

}  // namespace
}  // namespace kdgrid::viewer
