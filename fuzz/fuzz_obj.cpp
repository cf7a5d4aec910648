// libFuzzer harness: load_obj must reject any input with LoadError, never crash or hang.
#include <cstddef>
#include <cstdint>

#include "file_input.h"
#include "scene/load.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = kdgrid::fuzz::write_input(data, size, ".obj");
  kdgrid::fuzz::load_and_finalize([&] { return kdgrid::load_obj(path); }, path);
  return 0;
}
