// The memory kdgrid may use: the default of BuildParams::memory_budget and of the input file
// and texture limits.
#pragma once

#include <atomic>
#include <cstdint>
#include <string>

namespace kdgrid {

/// Bytes of memory available to this process: the smallest of physical memory, the cgroup
/// limit (v2 memory.max, v1 memory.limit_in_bytes, of this process's own cgroup) and the
/// address-space/data rlimits (ulimit -v, RLIMIT_DATA). Missing limits are ignored.
uint64_t available_memory_bytes();

/// Half of available_memory_bytes() (the rest for the scene, the renderer and the system);
/// 4 GiB if nothing can be read.
uint64_t default_memory_budget_bytes();

/// "ran out of memory (an allocation failed); N MiB are available to kdgrid (...)": the
/// start of the message for a std::bad_alloc caught outside a build; callers add the fix.
std::string out_of_memory_message();

/// A parallel build's running account of the memory it holds (reference lists alive in the
/// recursion, nodes, leaf lists), charged and refunded from any thread. Straddling triangles
/// go to both children, so long thin or overlapping triangles multiply references with depth:
/// once the account passes its budget, over_budget() tells the builder to stop splitting and
/// throw instead of the process running out of memory.
class MemoryAccount {
 public:
  explicit MemoryAccount(uint64_t budget_bytes = UINT64_MAX)
      : budget_(int64_t(budget_bytes < uint64_t(INT64_MAX) ? budget_bytes : uint64_t(INT64_MAX))) {}
  /// Adds `bytes` (negative: a refund) and records the peak.
  void charge(int64_t bytes) {
    const int64_t now = live_.fetch_add(bytes, std::memory_order_relaxed) + bytes;
    int64_t peak = peak_.load(std::memory_order_relaxed);
    while (now > peak && !peak_.compare_exchange_weak(peak, now, std::memory_order_relaxed)) {
    }
    if (bytes > 0 && now > budget_) over_.store(true, std::memory_order_relaxed);
  }
  bool over_budget() const { return over_.load(std::memory_order_relaxed); }
  int64_t live_bytes() const { return live_.load(); }
  int64_t peak_bytes() const { return peak_.load(); }

 private:
  int64_t budget_;
  std::atomic<int64_t> live_{0}, peak_{0};
  std::atomic<bool> over_{false};
};

}  // namespace kdgrid
