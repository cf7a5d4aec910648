#include "util/memory.h"

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <string>

namespace kdgrid {

namespace {

/// The number in a cgroup limit file ("max" or anything unreadable: no limit).
uint64_t read_limit(const std::string& path) {
  std::ifstream in(path);
  std::string word;
  if (!(in >> word) || word == "max") return UINT64_MAX;
  try {
    return std::stoull(word);
  } catch (...) {
    return UINT64_MAX;
  }
}

/// The memory limit of this process's cgroup: /proc/self/cgroup names it, under
/// /sys/fs/cgroup (v2: "0::/PATH"; v1: "N:memory:/PATH").
uint64_t cgroup_limit() {
  std::ifstream in("/proc/self/cgroup");
  std::string line;
  uint64_t limit = UINT64_MAX;
  while (std::getline(in, line)) {
    const size_t a = line.find(':'), b = line.find(':', a + 1);
    if (a == std::string::npos || b == std::string::npos) continue;
    const std::string controllers = line.substr(a + 1, b - a - 1), rel = line.substr(b + 1);
    if (controllers.empty()) {
      limit = std::min(limit, read_limit("/sys/fs/cgroup" + rel + "/memory.max"));
      // Inside a container the cgroup root is the container's own: its limit sits at the top.
      limit = std::min(limit, read_limit("/sys/fs/cgroup/memory.max"));
    } else if (("," + controllers + ",").find(",memory,") != std::string::npos) {
      limit = std::min(limit, read_limit("/sys/fs/cgroup/memory" + rel + "/memory.limit_in_bytes"));
      limit = std::min(limit, read_limit("/sys/fs/cgroup/memory/memory.limit_in_bytes"));
    }
  }
  return limit;
}

uint64_t rlimit_bytes(int resource) {
  struct rlimit r {};
  if (::getrlimit(resource, &r) != 0 || r.rlim_cur == RLIM_INFINITY) return UINT64_MAX;
  return uint64_t(r.rlim_cur);
}

}  // namespace

uint64_t available_memory_bytes() {
  uint64_t bytes = UINT64_MAX;
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  if (pages > 0 && page > 0) bytes = uint64_t(pages) * uint64_t(page);
  bytes = std::min({bytes, cgroup_limit(), rlimit_bytes(RLIMIT_AS), rlimit_bytes(RLIMIT_DATA)});
  return bytes;
}

uint64_t default_memory_budget_bytes() {
  const uint64_t avail = available_memory_bytes();
  if (avail == UINT64_MAX) return uint64_t(4) << 30;
  return avail / 2;
}

std::string out_of_memory_message() {
  char buf[200];
  std::snprintf(buf, sizeof buf,
                "ran out of memory (an allocation failed); %.0f MiB are available to kdgrid (the "
                "smallest of physical memory, the cgroup limit and ulimit -v)",
                double(available_memory_bytes()) / double(1 << 20));
  return buf;
}

}  // namespace kdgrid
