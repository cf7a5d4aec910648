// Helpers of the tests that run the built kdgrid-viewer under a virtual X display (Xvfb, with
// Mesa's software OpenGL): in its scripted mode (run_viewer), or driven through its window by
// xdotool as a person's mouse and keyboard would (ViewerRun::drive). The viewer tests
// themselves are TEST_F(Viewer, ...) on the ViewerRun fixture: a directory of their own, the
// runs, their statistics and screenshots.
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "cli_util.h"
#include "image/image_io.h"
#include "temp_dir.h"
#include "test_util.h"

namespace kdgrid::test {

struct RunResult {
  int code = -1;
  std::string output;  // stdout and stderr together
};

inline RunResult run_command(const std::string& cmd) {
  RunResult r;
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) r.output.append(buf, n);
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

inline bool have_command(const std::string& check) {
  return std::system((check + " >/dev/null 2>&1").c_str()) == 0;
}

inline bool have_xvfb() {
  return have_command("command -v xvfb-run");
}

/// What a viewer test needs besides the built viewer; KDGRID_REQUIRE_VIEWER skips a test
/// whose needs this machine does not meet, saying which and where to get them.
enum ViewerNeed : unsigned {
  kNeedXvfb = 1u << 0,          // xvfb-run: a virtual X display
  kNeedXdotool = 1u << 1,       // xdotool: the driven runs' mouse and keyboard
  kNeedXrdb = 1u << 2,          // xrdb: a content scale other than 1 (Xft.dpi)
  kNeedScreenGrab = 1u << 3,    // python3 with PIL: grabs of the screen while flying
  kNeedDefaultScene = 1u << 4,  // assets/cornell.gltf
  kNeedFastAccel = 1u << 5,     // a structure faster than brute force (fast_accel)
  kNeedSmallScene = 1u << 6,    // assets/cornell.gltf or the shared bunny (small_scene)
};

/// The input tests': a driven run of the default scene (small; it has its own camera, away from
/// the canonical one, so Home visibly changes the view).
constexpr unsigned kNeedDrivenDefault = kNeedXvfb | kNeedXdotool | kNeedDefaultScene;

/// The viewer's default scene, which the viewer finds by itself when given no scene.
inline std::string default_scene() {
  return source_path("assets/cornell.gltf");
}

/// The fastest structure built into this binary for scenes too big for brute force ("" if none).
inline std::string fast_accel() {
  const auto names = accelerator_names();
  for (const char* n : {"bvh", "hybrid", "kdtree", "grid", "embree"})
    if (std::find(names.begin(), names.end(), n) != names.end()) return n;
  return "";
}

/// A small scene: the default scene, else the shared bunny ("" if neither is there).
inline std::string small_scene() {
  if (std::filesystem::exists(default_scene())) return default_scene();
  return shared_scene("bunny/bun_zipper.ply");
}

/// Why a test with `needs` cannot run on this machine, one reason a missing need ("" if it can).
inline std::string viewer_missing(unsigned needs) {
  std::string why;
  const auto lacks = [&](const std::string& reason) { why += (why.empty() ? "" : "; ") + reason; };
  if ((needs & kNeedXvfb) && !have_xvfb())
    lacks(
        "xvfb-run is not installed (Debian package xvfb): the viewer tests need a virtual X "
        "display");
  if ((needs & kNeedXdotool) && !have_command("command -v xdotool"))
    lacks(
        "xdotool is not installed (Debian package xdotool, in scripts/install-deps.sh): the "
        "input tests drive the viewer's window with it");
  if ((needs & kNeedXrdb) && !have_command("command -v xrdb"))
    lacks("xrdb is not installed (Debian package x11-xserver-utils)");
  if ((needs & kNeedScreenGrab) && !have_command("/usr/bin/python3 -c 'import PIL.ImageGrab'"))
    lacks("/usr/bin/python3 with PIL (Debian python3-pil) is needed to grab the screen");
  if ((needs & kNeedDefaultScene) && !std::filesystem::exists(default_scene()))
    lacks("default scene " + default_scene() +
          " is missing (generate it with `kdgrid gen cornell -o assets/cornell.gltf`)");
  if ((needs & kNeedFastAccel) && fast_accel().empty())
    lacks("no structure faster than brute force is built in yet");
  if ((needs & kNeedSmallScene) && small_scene().empty())
    lacks("neither assets/cornell.gltf nor the shared bunny is available");
  return why;
}

#define KDGRID_REQUIRE_VIEWER(needs)                                                               \
  if (const std::string why_skipped = ::kdgrid::test::viewer_missing(needs); !why_skipped.empty()) \
  GTEST_SKIP() << why_skipped

#define KDGRID_REQUIRE_XVFB() KDGRID_REQUIRE_VIEWER(::kdgrid::test::kNeedXvfb)

/// A viewer test on a shared scene: KDGRID_REQUIRE_VIEWER(needs), then the scene `rel` as the
/// path `var` (KDGRID_REQUIRE_SCENE).
#define KDGRID_REQUIRE_VIEWER_SCENE(needs, var, rel) \
  KDGRID_REQUIRE_VIEWER(needs);                      \
  KDGRID_REQUIRE_SCENE(var, rel)

/// The file at `path` as JSON (null if it is missing or not JSON).
inline nlohmann::json read_json(const std::string& path) {
  std::ifstream in(path);
  if (!in) return nullptr;
  try {
    return nlohmann::json::parse(in);
  } catch (const std::exception&) {
    return nullptr;
  }
}

#ifdef KDGRID_VIEWER_PATH
/// The shell command that runs `script` (with `shell`) in `dir` under a fresh virtual X server
/// of `screen` pixels with software GL; `dir` is also the viewer's config directory, so no user
/// settings leak in and none are written to the user's home. `limit` (a `timeout` prefix, or
/// "") bounds the whole run.
inline std::string xvfb_command(const std::string& dir, const std::string& shell,
                                const std::string& script, const std::string& screen,
                                const std::string& limit = "") {
  return "cd '" + dir + "' && XDG_CONFIG_HOME='" + dir + "' LIBGL_ALWAYS_SOFTWARE=1 " + limit +
         "xvfb-run -a -s '-screen 0 " + screen + "' " + shell + " '" + script + "'";
}

/// Runs the viewer under a fresh virtual X server with software GL, in `dir` (also its config
/// directory).
/// xvfb-run can fail after the program it ran has exited ("xvfb-run: error: problem while
/// cleaning up temporary directory", exit code 5: its cleanup races the X server's exit, seen
/// about once in 20 runs on a loaded machine), replacing the program's exit code with its own.
/// The runs below record the viewer's own exit code and take it from there.
/// `prefix` runs in the viewer's shell first (e.g. "ulimit -f 4;").
inline RunResult run_viewer(const std::string& dir, const std::string& args,
                            const std::string& prefix = "") {
  namespace fs = std::filesystem;
  const std::string script = dir + "/run-viewer.sh", code_file = dir + "/viewer-exit-code";
  fs::remove(code_file);
  std::ofstream(script) << prefix << "'" << KDGRID_VIEWER_PATH << "' " << args << "\necho $? > '"
                        << code_file << "'\n";
  RunResult r = run_command(xvfb_command(dir, "sh", script, "1280x1024x24"));
  std::ifstream recorded(code_file);
  int code = 0;
  if (recorded >> code) r.code = code;
  return r;
}

/// The viewer's default scene (assets/cornell.gltf).
inline const std::string kDefaultScene = default_scene();

/// Small windows and one deterministic sample per pixel keep scripted runs short and their
/// screenshots comparable pixel for pixel.
inline const std::string kSmall =
    " --width 320 --height 240 --frames 3 --min-samples 1 --max-samples 1 ";

/// A driven run's window: 640x480 leaves its right half free of the panel (330 wide at (8, 8)).
inline const std::string kDriven =
    " --accel bvh --width 640 --height 480 --threads 1 --max-samples 1 --hold 90 ";

/// A driven run of the hybrid in a window the whole panel fits, for the panel's text fields.
inline const std::string kFieldArgs =
    " --accel hybrid --width 1280 --height 720 --threads 2 --max-samples 1 ";

/// Shell helpers of a driven run's actions; window coordinates are relative to the viewer's
/// window ($wid). Pauses let the viewer draw frames between events, so ImGui sees where the
/// mouse is before a button goes down (its hover test runs once per frame).
inline const char* const kDriverHelpers = R"sh(
mv() { xdotool mousemove --window "$wid" "$1" "$2"; sleep 0.3; }
click() { mv "$1" "$2"; xdotool click 1; sleep 0.3; }
# drag BUTTON X0 Y0 X1 Y1: press, move in ten steps, release.
drag() {
  mv "$2" "$3"; xdotool mousedown "$1"; sleep 0.2
  for i in 1 2 3 4 5 6 7 8 9 10; do
    xdotool mousemove --window "$wid" $(( $2 + ($4 - $2) * i / 10 )) $(( $3 + ($5 - $3) * i / 10 ))
    sleep 0.05
  done
  sleep 0.2; xdotool mouseup "$1"; sleep 0.3
}
# wheel N BUTTON: N notches (4 = towards the scene, 5 = away).
wheel() { for i in $(seq "$1"); do xdotool click "$2"; sleep 0.1; done; sleep 0.2; }
key() { for k in "$@"; do xdotool key --clearmodifiers "$k"; sleep 0.2; done; }
# holdkey KEY SECONDS
holdkey() { xdotool keydown "$1"; sleep "$2"; xdotool keyup "$1"; sleep 0.3; }
# waitlog TEXT SECONDS: waits until the viewer has printed TEXT (viewer.log), at most SECONDS.
waitlog() {
  for i in $(seq 1 $(( $2 * 10 ))); do grep -q "$1" viewer.log && return 0; sleep 0.1; done
  echo "driver: no '$1' in viewer.log after $2 s"
}
)sh";

/// An action that presses Ctrl+Q and prints "driver: exit_ms N": how long the viewer ($pid)
/// took to end (exit_ms reads it back).
inline const char* const kTimedCtrlQ = R"sh(
t0=$(date +%s%N); xdotool key --clearmodifiers ctrl+q
for i in $(seq 1 300); do kill -0 $pid 2>/dev/null || break; sleep 0.01; done
echo "driver: exit_ms $(( ($(date +%s%N) - t0) / 1000000 ))"
)sh";

/// The N of kTimedCtrlQ's "driver: exit_ms N" in `output` (-1 if absent).
inline int exit_ms(const std::string& output) {
  const size_t at = output.find("driver: exit_ms ");
  return at == std::string::npos ? -1 : std::atoi(output.c_str() + at + 16);
}

/// What a run of the viewer left: its exit code and output (RunResult), its --stats-json
/// (null when it wrote none) and, for a driven run, the viewer's own log.
struct ViewerResult : RunResult {
  nlohmann::json stats;
  std::string viewer_log;

  /// The run exited with `want` and wrote its statistics; else why not, with its output.
  ::testing::AssertionResult ok(int want = 0) const {
    if (code != want)
      return ::testing::AssertionFailure() << "exit code " << code << ", not " << want << "\n"
                                           << output << viewer_log;
    if (!stats.is_object())
      return ::testing::AssertionFailure() << "no stats.json\n" << output << viewer_log;
    return ::testing::AssertionSuccess();
  }
  /// A driven run ended by its Ctrl+Q (not by its time limit) with exit code 0 and left its
  /// statistics.
  ::testing::AssertionResult ended_by_ctrl_q() const {
    auto r = ok(0);
    if (r && (!stats.contains("end") || stats["end"] != "ctrl+q"))
      return ::testing::AssertionFailure() << "ended by " << stats["end"].dump() << "\n"
                                           << output << viewer_log;
    return r;
  }
};

/// The viewer tests' fixture: a fresh directory per test (also the viewer's config
/// directory), removed after the test unless it failed, when it is kept for a look at its
/// screenshots and logs and its path printed.
class ViewerRun : public ::testing::Test {
 public:
  const std::string dir = fresh_dir();

  void TearDown() override {
    if (HasFailure()) {
      std::printf("[ kept     ] %s\n", dir.c_str());
      return;
    }
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
  }

  /// The path of `name` in the test's directory.
  std::string path(const std::string& name) const { return dir + "/" + name; }
  ImageRGB image(const std::string& name) const { return read_image(path(name)); }
  nlohmann::json json(const std::string& name) const { return read_json(path(name)); }

  /// bad.ply in the test's directory: a PLY file whose vertex data is not numbers.
  std::string write_bad_ply() const {
    std::ofstream(path("bad.ply"))
        << "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\nnot a number\n";
    return path("bad.ply");
  }

  /// A scripted run under Xvfb with `args` (see run_viewer).
  RunResult run(const std::string& args, const std::string& prefix = "") const {
    return run_viewer(dir, args, prefix);
  }
  /// A scripted run with `args` and --stats-json stats.json, and the statistics it wrote.
  ViewerResult run_stats(const std::string& args) const {
    std::filesystem::remove(path("stats.json"));
    ViewerResult r;
    static_cast<RunResult&>(r) = run(args + " --stats-json stats.json");
    r.stats = json("stats.json");
    return r;
  }
  /// The viewer with `args` and no display at all, in the test's directory.
  RunResult run_without_display(const std::string& args) const {
    return run_command("cd '" + dir + "' && env -u DISPLAY -u WAYLAND_DISPLAY '" +
                       std::string(KDGRID_VIEWER_PATH) + "' " + args);
  }

  /// A driven run on a virtual display of its own (`screen` pixels), in `in` (the test's
  /// directory if ""): the viewer starts with `args` and --stats-json stats.json; once its
  /// title names `title_file` (the scene is installed and the camera reset), `actions` run
  /// (shell using kDriverHelpers; $wid is the window, $pid the viewer); then Ctrl+Q, and the
  /// viewer's exit. `setup` runs first on the display (e.g. xrdb). Every wait is bounded: the
  /// window must appear within 60 s, the viewer must end within 60 s of Ctrl+Q, and the whole
  /// run is killed after 240 s.
  ViewerResult drive(const std::string& args, const std::string& title_file,
                     const std::string& actions, const std::string& setup = "",
                     const std::string& screen = "1600x1200", std::string in = "") const {
    if (in.empty()) in = dir;
    const std::string driver = in + "/driver.sh";
    std::ofstream(driver)
        << "#!/bin/bash\nset -u\ncd '" << in << "'\n"
        << setup << "\n"
        << "'" << KDGRID_VIEWER_PATH << "' " << args
        << " --stats-json stats.json > viewer.log 2>&1 &\n"
        << "pid=$!\n"
        << "wid=$(timeout 60 xdotool search --sync --name 'kdgrid-viewer - " << title_file
        << "' 2>/dev/null | head -1)\n"
        << "if [ -z \"$wid\" ]; then\n"
        << "  echo 'driver: the viewer window never showed " << title_file << " within 60 s'\n"
        << "  kill $pid 2>/dev/null; wait $pid; cat viewer.log; exit 90\n"
        << "fi\n"
        << "echo \"driver: window $wid\"\n"
        // No window manager runs on Xvfb: give the window the keyboard focus ourselves.
        << "timeout 10 xdotool windowfocus --sync \"$wid\" || echo 'driver: windowfocus failed'\n"
        << kDriverHelpers << "\n"
        << actions << "\n"
        << "xdotool key --clearmodifiers ctrl+q\n"
        << "for i in $(seq 1 600); do kill -0 $pid 2>/dev/null || break; sleep 0.1; done\n"
        << "if kill -0 $pid 2>/dev/null; then echo 'driver: viewer still running 60 s after "
           "Ctrl+Q, killing it'; kill $pid; fi\n"
        << "wait $pid; rc=$?\n"
        << "echo \"driver: viewer exit code $rc\"\n"
        << "exit $rc\n";
    ViewerResult d;
    static_cast<RunResult&>(d) = run_command(
        xvfb_command(in, "bash", driver, screen + "x24 -noreset", "timeout -k 10 240 "));
    // The viewer's own exit code, as the driver printed it (see run_viewer on xvfb-run's).
    const std::string tag = "driver: viewer exit code ";
    const size_t at = d.output.rfind(tag);
    if (at != std::string::npos && d.code != 124 && d.code != 137)
      d.code = std::atoi(d.output.c_str() + at + tag.size());
    d.viewer_log = read_file_bytes(in + "/viewer.log");
    d.stats = read_json(in + "/stats.json");
    return d;
  }
  /// A driven run of the default scene in the kDriven window, with `extra` arguments.
  ViewerResult drive_default(const std::string& actions,
                             const std::string& extra = "--hide-ui") const {
    return drive(quoted(kDefaultScene) + kDriven + extra, "cornell.gltf", actions);
  }

  /// The statistics of a first driven run with `args` (null, and a failure, if it failed):
  /// its ui.rects place the panel's text fields for a second run to click into.
  nlohmann::json field_rects(const std::string& args, const std::string& title) const {
    const ViewerResult d = drive(args + " --hold 30", title, "sleep 0.3");
    if (d.code != 0 || !d.stats.is_object()) {
      ADD_FAILURE() << d.output << d.viewer_log;
      return nullptr;
    }
    return d.stats;
  }

  /// Two scripted screenshots of `scene` (UI hidden, one sample, two threads) that differ by
  /// the arguments `a` and `b`, written as a.png and b.png; both runs must succeed (a fatal
  /// failure otherwise: check HasFatalFailure).
  void two_shots(const std::string& scene, const std::string& size, const std::string& a,
                 const std::string& b, ImageRGB& img_a, ImageRGB& img_b) const {
    const std::string common = "'" + scene + "' --width " + size +
                               " --frames 3 --min-samples 1 --max-samples 1 "
                               "--hide-ui --threads 2 --timeout 120 ";
    const RunResult ra = run(common + a + " --screenshot a.png");
    ASSERT_EQ(ra.code, 0) << ra.output;
    const RunResult rb = run(common + b + " --screenshot b.png");
    ASSERT_EQ(rb.code, 0) << rb.output;
    img_a = image("a.png");
    img_b = image("b.png");
    ASSERT_EQ(img_a.width, img_b.width);
  }

 private:
  static std::string fresh_dir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    const auto d = std::filesystem::temp_directory_path() /
                   ("kdgrid_viewer_" + std::string(info ? info->name() : "run") + "_" +
                    std::to_string(::getpid()));
    std::filesystem::remove_all(d);
    std::filesystem::create_directories(d);
    return d.string();
  }
};

/// The viewer tests' suite: TEST_F(Viewer, ...) runs on the ViewerRun fixture.
using Viewer = ViewerRun;
#endif

}  // namespace kdgrid::test
