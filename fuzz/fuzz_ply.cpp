// libFuzzer harness: the PLY reader must reject any input with LoadError, never crash or hang.
#include <cstddef>
#include <cstdint>

#include "scene/load.h"
#include "util/error.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    kdgrid::Scene s = kdgrid::parse_ply(reinterpret_cast<const char*>(data), size, "fuzz.ply");
    s.source = "fuzz.ply";
    s.finalize();
  } catch (const kdgrid::Error&) {
  }
  return 0;
}
