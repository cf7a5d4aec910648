// The viewer's settings file (src/viewer/settings.cpp, compiled into the tests): read only
// from a regular file, validated field by field (a bad field falls back alone, named in a
// warning that names the file), written through the atomic writer.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <future>
#include <limits>
#include <string>

#include <nlohmann/json.hpp>

#include "temp_dir.h"
#include "test_util.h"
#include "util/error.h"
#include "viewer/settings.h"

namespace kdgrid::viewer {
namespace {

namespace fs = std::filesystem;
using test::TempDir;

/// load_settings(dir) with what it printed on stderr.
Settings load_capturing(const std::string& dir, std::string& err) {
  ::testing::internal::CaptureStderr();
  Settings s = load_settings(dir);
  err = ::testing::internal::GetCapturedStderr();
  return s;
}

TEST(ViewerSettings, AFifoIsNotReadAndTheStartDoesNotWait) {
  TempDir tmp;
  const std::string fifo = tmp.file("viewer.json");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  ::testing::internal::CaptureStderr();
  auto loaded = std::async(std::launch::async, [&] { return load_settings(tmp.path().string()); });
  const bool done = loaded.wait_for(std::chrono::seconds(5)) == std::future_status::ready;
  if (!done) {
    // Opening the FIFO for writing releases a reader blocked in open(); closing it ends the read.
    const int fd = ::open(fifo.c_str(), O_WRONLY | O_NONBLOCK);
    if (fd >= 0) ::close(fd);
  }
  const Settings s = loaded.get();
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_TRUE(done) << "load_settings waited on the FIFO";
  EXPECT_EQ(s.window_width, Settings{}.window_width);
  EXPECT_CONTAINS(err, fifo);
  EXPECT_CONTAINS(err, "not a regular file");
  // Nor is a FIFO replaced by the settings (or read as imgui.ini).
  ::testing::internal::CaptureStderr();
  save_settings(tmp.path().string(), s);
  EXPECT_FALSE(read_config_file(tmp.path().string(), "viewer.json"));
  EXPECT_CONTAINS(::testing::internal::GetCapturedStderr(), "not a regular file");
  struct stat st {};
  ASSERT_EQ(::stat(fifo.c_str(), &st), 0);
  EXPECT_TRUE(S_ISFIFO(st.st_mode));
}

TEST(ViewerSettings, ABadFieldFallsBackAloneAndIsNamed) {
  TempDir tmp;
  const std::string file = tmp.write("viewer.json", R"({
      "accel": "kdtree", "window_width": 900, "window_height": 1e39,
      "heat_scale": "fixed", "heat_fixed_min": null, "heat_fixed_max": 1e39,
      "cell_size": "0.5x",
      "cell_size_by_scene": {"/a.ply": "0.01", "/b.ply": "1e39", "/c.ply": 7}})");
  std::string err;
  const Settings s = load_capturing(tmp.path().string(), err);
  const Settings d;
  // The good fields are kept...
  EXPECT_EQ(s.accel, "kdtree");
  EXPECT_EQ(s.window_width, 900);
  EXPECT_EQ(s.heat_scale, HeatScale::Fixed);
  EXPECT_EQ(s.cell_size, "0.5x");
  ASSERT_EQ(s.cell_size_by_scene.size(), 1u);
  EXPECT_EQ(s.cell_size_by_scene.at("/a.ply"), "0.01");
  // ...each bad one is at its default, named with the file.
  EXPECT_EQ(s.window_height, d.window_height);
  EXPECT_EQ(s.heat_fixed_min, d.heat_fixed_min);
  EXPECT_EQ(s.heat_fixed_max, d.heat_fixed_max);
  for (const char* field :
       {"window_height = 1e+39", "heat_fixed_min = null", "heat_fixed_max = 1e+39",
        "cell_size_by_scene of /b.ply = \"1e39\"", "cell_size_by_scene of /c.ply = 7"}) {
    EXPECT_CONTAINS(err, file + ": ignoring " + field);
  }
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 5) << err;
}

TEST(ViewerSettings, AValueBeyondFloatIsNotWrittenAsNullAndTheRestSurvives) {
  TempDir tmp;
  Settings s;
  s.accel = "grid";
  s.heat_fixed_min = std::numeric_limits<float>::infinity();  // "1e39" typed into the panel
  s.heat_fixed_max = 5.0f;
  save_settings(tmp.path().string(), s);
  EXPECT_EQ(test::read_file_bytes(tmp.file("viewer.json")).find("null"), std::string::npos);
  std::string err;
  const Settings back = load_capturing(tmp.path().string(), err);
  EXPECT_EQ(err, "");
  EXPECT_EQ(back.accel, "grid");
  EXPECT_EQ(back.heat_fixed_min, Settings{}.heat_fixed_min);
  EXPECT_EQ(back.heat_fixed_max, 5.0f);
}

TEST(ViewerSettings, CellSizesOutsideFloatAreRefused) {
  EXPECT_THROW(CellChoice::parse("1e39", "cell_size"), ParamError);
  EXPECT_THROW(CellChoice::parse("1e39x", "cell_size"), ParamError);
  EXPECT_THROW(CellChoice::parse("1e-50", "cell_size"), ParamError);
  EXPECT_NO_THROW(CellChoice::parse("3e38", "cell_size"));
  TempDir tmp;
  tmp.write("viewer.json", R"({"cell_size": "1e39x", "accel": "bvh"})");
  std::string err;
  const Settings s = load_capturing(tmp.path().string(), err);
  EXPECT_EQ(s.cell_size, "auto");
  EXPECT_EQ(s.accel, "bvh");
  EXPECT_CONTAINS(err, tmp.file("viewer.json") + ": ignoring cell_size = \"1e39x\"");
}

TEST(ViewerSettings, AFullDiskAtQuitKeepsTheOldFile) {
  TempDir tmp;
  Settings old;
  old.accel = "kdtree";
  save_settings(tmp.path().string(), old);
  const std::string before = test::read_file_bytes(tmp.file("viewer.json"));
  ASSERT_NE(before.find("kdtree"), std::string::npos);
  Settings next;
  for (int i = 0; i < 50; ++i)
    next.cell_size_by_scene["/scenes/scene" + std::to_string(i) + ".ply"] = "0.01";
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    // A 64-byte file-size limit: the write fails part way, as on a full disk.
    const rlimit lim{64, 64};
    ::setrlimit(RLIMIT_FSIZE, &lim);
    ::signal(SIGXFSZ, SIG_IGN);
    save_settings(tmp.path().string(), next);
    ::_exit(0);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  EXPECT_TRUE(WIFEXITED(status)) << "the save killed the process";
  EXPECT_EQ(test::read_file_bytes(tmp.file("viewer.json")), before);
  EXPECT_TRUE(tmp.hidden().empty());
}

}  // namespace
}  // namespace kdgrid::viewer
