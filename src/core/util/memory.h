// The memory kdgrid may use: the default of BuildParams::memory_budget and of the input file
// and texture limits.
#pragma once

#include <cstdint>

namespace kdgrid {

/// Bytes of memory available to this process: the smallest of physical memory, the cgroup
/// limit (v2 memory.max, v1 memory.limit_in_bytes, of this process's own cgroup) and the
/// address-space/data rlimits (ulimit -v, RLIMIT_DATA). Missing limits are ignored.
uint64_t available_memory_bytes();

/// Half of available_memory_bytes() (the rest for the scene, the renderer and the system);
/// 4 GiB if nothing can be read.
uint64_t default_memory_budget_bytes();

}  // namespace kdgrid
