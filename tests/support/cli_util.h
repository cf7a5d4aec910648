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

/// Runs the built `kdgrid` with `args` (shell syntax) and collects its output.
inline CliResult run_cli(const std::string& args) {
  const std::string cmd = std::string(KDGRID_CLI_PATH) + " " + args + " 2>&1";
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

inline bool contains(const std::string& s, const std::string& what) {
  return s.find(what) != std::string::npos;
}

}  // namespace kdgrid::test
