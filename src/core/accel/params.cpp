#include "accel/params.h"

#include <algorithm>
#include <thread>

#include "util/enum_names.h"
#include "util/error.h"
#include "util/memory.h"

namespace kdgrid {

uint64_t effective_memory_budget(const BuildParams& p) {
  if (p.memory_budget > 0) return p.memory_budget;
  return default_memory_budget_bytes();
}

namespace {
int hardware_threads() {
  const unsigned n = std::thread::hardware_concurrency();
  return n ? int(n) : 1;
}
}  // namespace

void check_threads(int threads, const std::string& option) {
  const int most = std::max(kMaxThreads, hardware_threads());
  if (threads < 0 || threads > most)
    throw ParamError(option + " " + std::to_string(threads) + " is out of range: give 0 (all " +
                     std::to_string(hardware_threads()) + " hardware threads) up to " +
                     std::to_string(most));
}

int effective_threads(int threads) {
  check_threads(threads);
  return threads > 0 ? threads : hardware_threads();
}

TriangleTestKind parse_triangle_test(const std::string& s) {
  if (s == "watertight") return TriangleTestKind::Watertight;
  if (s == "moller" || s == "moller-trumbore" || s == "fast") return TriangleTestKind::Moller;
  throw ParamError("unknown triangle test '" + s + "': use 'watertight' (default) or 'moller'");
}

const char* to_string(TriangleTestKind k) {
  static constexpr EnumName<TriangleTestKind> kNames[] = {
      {TriangleTestKind::Watertight, "watertight"},
      {TriangleTestKind::Moller, "moller"},
      {TriangleTestKind::None, "none"}};
  return enum_name(k, kNames);
}

}  // namespace kdgrid
