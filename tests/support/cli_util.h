// Helpers of the tests that run the built `kdgrid` command: runners that collect the command's
// output and exit status, one of them after shell limits such as `ulimit -f` (and TempDir, for
// their files).
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "temp_dir.h"
#include "test_util.h"

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

/// `s` in single quotes, for a shell command line.
inline std::string quoted(const std::string& s) {
  return "'" + s + "'";
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

/// `prefix` without its `ulimit -v N;` under AddressSanitizer, which reserves terabytes of
/// address space for its shadow memory and cannot start under such a limit. The tests that
/// use it as a safety net (a reader that would grow without bound) still run; those that need
/// it to set the memory budget or to make a build run out of memory skip.
inline std::string without_address_limit(std::string prefix) {
  if (!kAddressSanitizer) return prefix;
  for (size_t at; (at = prefix.find("ulimit -v ")) != std::string::npos;) {
    const size_t end = prefix.find(';', at);
    prefix.erase(at, end == std::string::npos ? std::string::npos : end + 1 - at);
  }
  return prefix;
}

/// The exit status and the standard output and error, apart, of a command.
struct CliStreams {
  int exit_code = -1;  ///< -1 when killed by a signal
  std::string out, err;
};

/// Runs the built `kdgrid` with `args` (shell syntax) through bash, after `prefix` (e.g.
/// "ulimit -f 4;") in the same shell; its output goes through files in `tmp`.
inline CliStreams run_cli_streams(const std::string& args, const TempDir& tmp,
                                  const std::string& prefix = "") {
  const std::string out = tmp.file("stdout.txt"), err = tmp.file("stderr.txt");
  const std::string script = without_address_limit(prefix) + " \"" + std::string(KDGRID_CLI_PATH) +
                             "\" " + args + " >\"" + out + "\" 2>\"" + err + "\"";
  std::string quoted;
  for (char c : script) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
  const int status = std::system(("bash -c '" + quoted + "'").c_str());
  CliStreams r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = read_file_bytes(out);
  r.err = read_file_bytes(err);
  std::filesystem::remove(out);
  std::filesystem::remove(err);
  return r;
}

inline bool contains(const std::string& s, const std::string& what) {
  return s.find(what) != std::string::npos;
}

}  // namespace kdgrid::test
