#include "accel/params.h"

#include <thread>

#include "util/error.h"
#include "util/memory.h"

namespace kdgrid {

uint64_t effective_memory_budget(const BuildParams& p) {
  if (p.memory_budget > 0) return p.memory_budget;
  return default_memory_budget_bytes();
}

int effective_threads(int threads) {
  if (threads > 0) return threads;
  const unsigned n = std::thread::hardware_concurrency();
  return n ? int(n) : 1;
}

TriangleTestKind parse_triangle_test(const std::string& s) {
  if (s == "watertight") return TriangleTestKind::Watertight;
  if (s == "moller" || s == "moller-trumbore" || s == "fast") return TriangleTestKind::Moller;
  throw ParamError("unknown triangle test '" + s + "': use 'watertight' (default) or 'moller'");
}

const char* to_string(TriangleTestKind k) {
  switch (k) {
    case TriangleTestKind::Watertight:
      return "watertight";
    case TriangleTestKind::Moller:
      return "moller";
    case TriangleTestKind::None:
      return "none";
  }
  return "?";
}

}  // namespace kdgrid
