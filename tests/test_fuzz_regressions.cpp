// Replays the fuzzing seed corpus and every input that once crashed a fuzzer
// (tests/data/fuzz/<target>/) through the same entry points as the harnesses: each must load
// or be rejected with a kdgrid::Error, never crash (run under ASan in CI).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>

#include "scene/load.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;

std::vector<fs::path> inputs_of(const std::string& target) {
  std::vector<fs::path> out;
  for (const char* root : {"fuzz/corpus/", "tests/data/fuzz/"}) {
    const fs::path dir = test::source_path(std::string(root) + target);
    if (!fs::is_directory(dir)) continue;
    for (const auto& e : fs::directory_iterator(dir))
      if (e.is_regular_file()) out.push_back(e.path());
  }
  return out;
}

TEST(FuzzRegressions, PlyInputsNeverCrash) {
  const auto files = inputs_of("ply");
  ASSERT_FALSE(files.empty()) << "the PLY seed corpus fuzz/corpus/ply is missing";
  for (const auto& f : files) {
    std::ifstream in(f, std::ios::binary);
    const std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    try {
      Scene s = parse_ply(data.data(), data.size(), f.string());
      s.source = f.string();
      s.finalize();
    } catch (const Error&) {
    }
  }
}

TEST(FuzzRegressions, ObjAndGltfInputsNeverCrash) {
  size_t n = 0;
  for (const std::string target : {"obj", "gltf"}) {
    for (const auto& f : inputs_of(target)) {
      ++n;
      try {
        load_scene(f.string());
      } catch (const Error&) {
      }
    }
  }
  EXPECT_GT(n, 0u) << "the OBJ/glTF seed corpora are missing";
}

}  // namespace
}  // namespace kdgrid
