// The image module (src/core/image/image_module.h): OpenImageIO is loaded only by processes
// that read or write an image, an installed or copied kdgrid finds the module from its own
// place, and one that cannot find it says so before rendering.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "cli_util.h"
#include "image/image_module.h"
#include "loader_inputs.h"
#include "temp_dir.h"
#include "test_util.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;

using test::quoted;
using test::TempDir;

/// A small render of the Cornell box to `out`: the command line's arguments after `render`.
std::string render_args(const std::string& out) {
  std::string args = quoted(test::source_path("assets/cornell.gltf"));
  args += " --res 16x12 --spp 1 --threads 1 -o ";
  args += quoted(out);
  return args;
}

// glibc's LD_DEBUG=files names every library the process loads, on its standard error.
TEST(ImageModule, OpenImageIOIsLoadedOnlyByProcessesThatTouchAnImage) {
  TempDir tmp;
  const std::string ply = tmp.write("fan.ply", test::kAsciiPly);
  const test::CliStreams info =
      test::run_cli_streams("info " + quoted(ply), tmp, "export LD_DEBUG=files;");
  ASSERT_EQ(info.exit_code, 0) << info.err;
  EXPECT_CONTAINS(info.err, "libembree3");  // LD_DEBUG works here
  EXPECT_FALSE(test::contains(info.err, "libOpenImageIO")) << "kdgrid info loaded OpenImageIO";
  EXPECT_FALSE(test::contains(info.err, image_module::kFileName));

  const std::string png = tmp.file("out.png");
  const test::CliStreams render =
      test::run_cli_streams("render " + render_args(png), tmp, "export LD_DEBUG=files;");
  ASSERT_EQ(render.exit_code, 0) << render.err;
  EXPECT_CONTAINS(render.err, image_module::kFileName);
  EXPECT_CONTAINS(render.err, "libOpenImageIO");
  EXPECT_TRUE(fs::is_regular_file(png));
}

// `cmake --install` puts the programs in PREFIX/bin and the module in PREFIX/lib/kdgrid; a copy
// of the program with no module near it renders nothing and names the module.
TEST(ImageModule, AProgramFindsItsInstalledModuleOrRefusesBeforeRendering) {
  TempDir tmp;
  const fs::path bin = tmp / "prefix/bin", lib = tmp / "prefix/lib/kdgrid";
  fs::create_directories(bin);
  fs::create_directories(lib);
  const fs::path kdgrid = bin / "kdgrid";
  fs::copy_file(KDGRID_CLI_PATH, kdgrid);
  const std::string command = quoted(kdgrid.string()) + " render ";

  const std::string lone_png = tmp.file("lone.png");
  const test::CliResult lone = test::run_shell_command(command + render_args(lone_png) + " 2>&1");
  EXPECT_EQ(lone.code, 1) << lone.output;
  EXPECT_CONTAINS(lone.output, image_module::kFileName);
  EXPECT_CONTAINS(lone.output, "reinstall or rebuild");
  EXPECT_FALSE(test::contains(lone.output, "spp")) << "it rendered before failing:\n"
                                                   << lone.output;
  EXPECT_FALSE(fs::exists(lone_png));

  fs::copy_file(KDGRID_IMAGE_MODULE_PATH, lib / image_module::kFileName);
  const std::string installed_png = tmp.file("installed.png");
  const test::CliResult installed =
      test::run_shell_command(command + render_args(installed_png) + " 2>&1");
  EXPECT_EQ(installed.code, 0) << installed.output;
  EXPECT_TRUE(fs::is_regular_file(installed_png));
}

}  // namespace
}  // namespace kdgrid
