// Helpers of the tests that run the built kdgrid-viewer under a virtual X display (Xvfb, with
// Mesa's software OpenGL) in its scripted mode.
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

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

inline bool have_xvfb() {
  return std::system("command -v xvfb-run >/dev/null 2>&1") == 0;
}

#ifdef KDGRID_VIEWER_PATH
/// Runs the viewer under a fresh virtual X server with software GL, in `dir` (also its config
/// directory, so no user settings leak in and none are written to the user's home).
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
  const std::string cmd = "cd '" + dir + "' && XDG_CONFIG_HOME='" + dir +
                          "' LIBGL_ALWAYS_SOFTWARE=1 xvfb-run -a -s '-screen 0 1280x1024x24' sh '" +
                          script + "'";
  RunResult r = run_command(cmd);
  std::ifstream recorded(code_file);
  int code = 0;
  if (recorded >> code) r.code = code;
  return r;
}
#endif

#define KDGRID_REQUIRE_XVFB()                                                                 \
  if (!::kdgrid::test::have_xvfb())                                                           \
  GTEST_SKIP() << "xvfb-run is not installed (Debian package xvfb): the viewer tests need a " \
                  "virtual X display"

}  // namespace kdgrid::test
