// What the loader harnesses share: the input written to a per-process file in /dev/shm (or /tmp)
// for the loaders that read from a path, and a load that may only end in a scene or an Error.
#pragma once

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <string>

#include "scene/scene.h"
#include "util/error.h"

namespace kdgrid::fuzz {

inline std::string write_input(const uint8_t* data, size_t size, const char* ext) {
  static const std::string dir = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
  const std::string path = dir + "/kdgrid-fuzz-" + std::to_string(getpid()) + ext;
  if (FILE* f = std::fopen(path.c_str(), "wb")) {
    std::fwrite(data, 1, size, f);
    std::fclose(f);
  }
  return path;
}

/// Runs `load()` and finalizes the scene it returns under the name `source`; an Error (the
/// loaders' LoadError) is the expected answer to bad input, anything else reaches libFuzzer.
template <class Load>
void load_and_finalize(Load load, const std::string& source) {
  try {
    Scene s = load();
    s.source = source;
    s.finalize();
  } catch (const Error&) {
  }
}

}  // namespace kdgrid::fuzz
