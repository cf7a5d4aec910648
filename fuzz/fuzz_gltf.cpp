// libFuzzer harness: load_gltf must reject any input with LoadError, never crash or hang.
#include <cstddef>
#include <cstdint>

#include "file_input.h"
#include "scene/load.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  // Binary glTF starts with the magic "glTF"; anything else goes through the JSON path.
  const bool glb =
      size >= 4 && data[0] == 'g' && data[1] == 'l' && data[2] == 'T' && data[3] == 'F';
  const std::string path = kdgrid::fuzz::write_input(data, size, glb ? ".glb" : ".gltf");
  kdgrid::fuzz::load_and_finalize([&] { return kdgrid::load_gltf(path); }, path);
  return 0;
}
