// libFuzzer harness: the PLY reader must reject any input with LoadError, never crash or hang.
#include <cstddef>
#include <cstdint>

#include "file_input.h"
#include "scene/load.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  kdgrid::fuzz::load_and_finalize(
      [&] { return kdgrid::parse_ply(reinterpret_cast<const char*>(data), size, "fuzz.ply"); },
      "fuzz.ply");
  return 0;
}
