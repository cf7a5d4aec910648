// What every scene loader must do with hostile input, whatever the format: FIFOs and devices
// are refused as scenes, byte-order marks are skipped, and no file under tests/data causes an
// error or warning line over a kilobyte. The format's own refusals: test_loader_errors_ply.cpp,
// test_loader_errors_obj.cpp, test_loader_errors_gltf.cpp.
#include <gtest/gtest.h>

#include <sys/stat.h>

#include <cctype>
#include <filesystem>
#include <sstream>
#include <string>

#include "cli_util.h"
#include "image/image_io.h"
#include "loader_inputs.h"
#include "scene/load.h"
#include "temp_dir.h"
#include "test_util.h"
#include "util/error.h"
#include "util/input_file.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;
using namespace test;

TEST(HostileFiles, FifoAndDevicesAreRefusedAsScenes) {
  TempDir tmp;
  const std::string fifo = tmp.file("fifo.ply");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  // Run through the CLI with a CPU/time bound: before the check the FIFO blocked forever.
  CliStreams r = run_cli_streams("info \"" + fifo + "\"", tmp, "ulimit -t 10;");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_CONTAINS(r.err, "is not a regular file");
  fs::create_symlink("/dev/zero", tmp.file("zero.obj"));
  EXPECT_CONTAINS(load_error_of(tmp.file("zero.obj")), "not a regular file");
  fs::create_symlink("/dev/zero", tmp.file("zero.rays"));
  r = run_cli_streams("trace gen:sphere --rays \"" + tmp.file("zero.rays") + "\"", tmp,
                      "ulimit -t 10;");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_CONTAINS(r.err, "not a regular file");
  EXPECT_CONTAINS(load_error([] { check_input_file("/etc/hostname", "", 1); }),
                  "larger than the input file limit");
}

TEST(HostileLoaders, ByteOrderMarksAreSkipped) {
  // OBJ and MTL: the first line is read (3 vertices, the material 'red' found).
  std::string err;
  const std::string out = capture_stderr([&] {
    const Scene s = load_scene(hostile("bom.obj"));
    ASSERT_EQ(s.mesh.num_triangles(), 1u);
    ASSERT_FALSE(s.materials.empty());
    EXPECT_EQ(s.materials[0].name, "red");
    EXPECT_EQ(s.materials[0].base_color, Vec3(1, 0, 0));
  });
  EXPECT_EQ(out.find("not found"), std::string::npos) << out;
  EXPECT_EQ(load_scene(hostile("bom.ply")).mesh.num_triangles(), 1u);
  EXPECT_EQ(load_scene(hostile("bom.gltf")).mesh.num_triangles(), 1u);
}

TEST(HostileLoaders, NoMessageOverOneKilobyteForAnyFileInTestData) {
  size_t files = 0;
  for (const auto& entry : fs::recursive_directory_iterator(test::source_path("tests/data"))) {
    if (!entry.is_regular_file()) continue;
    const std::string path = entry.path().string();
    std::string ext = entry.path().extension().string();
    for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
    std::string error;
    const std::string out = capture_stderr([&] {
      try {
        if (ext == ".obj" || ext == ".ply" || ext == ".gltf" || ext == ".glb")
          load_scene(path);
        else if (ext != ".mtl" && ext != ".bin")
          read_image(path);
      } catch (const Error& e) {
        error = e.what();
      }
    });
    ++files;
    EXPECT_LE(error.size(), 1024u) << path << ": " << error.substr(0, 2000);
    std::istringstream lines(out);
    for (std::string line; std::getline(lines, line);)
      EXPECT_LE(line.size(), 1024u) << path << ": " << line.substr(0, 2000);
  }
  EXPECT_GE(files, 10u);
}

}  // namespace
}  // namespace kdgrid
