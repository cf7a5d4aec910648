// Cancelling a build from another thread (the viewer's Cancel button and Esc, a superseding
// request, quitting) or from a signal handler (the CLI's Ctrl-C). The requester sets the token;
// the builders poll it in their loops, at least once per node, per block of triangles or per
// block of cells, so a cancel takes effect within about 100 ms even on the largest scenes, and
// throw BuildCancelled. Everything a build allocated is owned by containers, so the unwinding
// frees it; the structure is left empty, as after a failed build.
#pragma once

#include <atomic>

#include "util/error.h"

namespace kdgrid {

/// Thrown by a build whose token was set. Derives from Error so that a caller that reports
/// errors reports it with its message; callers that cancel on purpose catch it first.
class BuildCancelled : public Error {
 public:
  BuildCancelled() : Error("the build was cancelled") {}
  explicit BuildCancelled(const std::string& message) : Error(message) {}
};

/// A cancellation flag shared by the requester and a build (BuildParams::cancel points at it).
/// cancel() is lock-free, so a signal handler may call it.
class CancelToken {
 public:
  void cancel() noexcept { flag_.store(true, std::memory_order_relaxed); }
  void reset() noexcept { flag_.store(false, std::memory_order_relaxed); }
  bool cancelled() const noexcept { return flag_.load(std::memory_order_relaxed); }
  /// Throws BuildCancelled once cancel() has been called.
  void check() const {
    if (cancelled()) throw BuildCancelled();
  }

 private:
  std::atomic<bool> flag_{false};
  static_assert(std::atomic<bool>::is_always_lock_free);
};

/// check() for an optional token (builds without one never stop).
inline void check_cancel(const CancelToken* token) {
  if (token) token->check();
}

}  // namespace kdgrid
