// libFuzzer harness: load_obj must reject any input with LoadError, never crash or hang.
#include <cstddef>
#include <cstdint>

#include "file_input.h"
#include "scene/load.h"
#include "util/error.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = kdgrid::fuzz::write_input(data, size, ".obj");
  try {
    kdgrid::Scene s = kdgrid::load_obj(path);
    s.source = path;
    s.finalize();
  } catch (const kdgrid::Error&) {
  }
  return 0;
}
