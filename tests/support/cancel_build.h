// A build cancelled from another thread while it runs: the tests of cancellation
// (test_cancel.cpp) time how soon after the cancel a builder stops.
#pragma once

#include <chrono>
#include <thread>

#include "accel/accelerator.h"
#include "util/cancel.h"
#include "util/error.h"

namespace kdgrid::test {

/// How a build cancelled mid-way ended.
struct CancelledBuild {
  bool threw = false;          ///< the build threw BuildCancelled
  double build_seconds = 0.0;  ///< from the build's start to its end
  double after_cancel = 0.0;   ///< from the cancel to the build's end
};

/// Builds `acc` over `mesh` with `params`, whose cancel token (set here) another thread
/// cancels `delay` after it starts.
inline CancelledBuild build_cancelled_after(Accelerator& acc, const Mesh& mesh, BuildParams params,
                                            std::chrono::microseconds delay) {
  using Clock = std::chrono::steady_clock;
  CancelToken token;
  params.cancel = &token;
  Clock::time_point cancelled_at{};
  std::thread canceller([&] {
    std::this_thread::sleep_for(delay);
    cancelled_at = Clock::now();
    token.cancel();
  });
  CancelledBuild out;
  const auto t0 = Clock::now();
  try {
    acc.build(mesh, params);
  } catch (const BuildCancelled&) {
    out.threw = true;
  }
  const auto t1 = Clock::now();
  canceller.join();
  out.build_seconds = std::chrono::duration<double>(t1 - t0).count();
  out.after_cancel = std::chrono::duration<double>(t1 - cancelled_at).count();
  return out;
}

}  // namespace kdgrid::test
