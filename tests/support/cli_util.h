// Helpers of the tests that run the built `kdgrid` command: a runner that collects the
// command's output and exit status (and TempDir, for their files).
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <string>

#include "temp_dir.h"

namespace kdgrid::test {

struct CliResult {
  int code = -1;       ///< exit status; -1 when killed by a signal
  std::string output;  ///< stdout and stderr together
};

/// Runs the shell command `cmd` and collects what it writes to the pipe and its exit status.
inline CliResult run_shell_command(const std::string& cmd) {
  CliResult r;
  FILE* pipe = ::popen(cmd.c_str(), "r");
  if (!pipe) return r;
  char buf[4096];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, pipe)) > 0) r.output.append(buf, n);
  const int status = ::pclose(pipe);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

/// Runs the built `kdgrid` with `args` (shell syntax) and collects its output.
inline CliResult run_cli(const std::string& args) {
  return run_shell_command(std::string(KDGRID_CLI_PATH) + " " + args + " 2>&1");
}

/// Runs the built `kdgrid` with `args` (shell syntax), its standard output sent to
/// `stdout_target` (a file, /dev/full, /dev/null); `output` collects its standard error.
inline CliResult run_cli_stdout_to(const std::string& args, const std::string& stdout_target) {
  return run_shell_command(std::string(KDGRID_CLI_PATH) + " " + args + " 2>&1 >'" + stdout_target +
                           "'");
}

inline bool contains(const std::string& s, const std::string& what) {
  return s.find(what) != std::string::npos;
}

}  // namespace kdgrid::test
