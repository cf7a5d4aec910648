// `kdgrid`: the command-line front end of kdgrid_core (render, info, rays, trace, bench, gen).
#include <cerrno>
#include <cstdio>
#include <exception>
#include <iostream>
#include <new>
#include <string>

#include "cli/commands.h"
#include "util/atomic_file.h"
#include "util/cancel.h"
#include "util/error.h"
#include "util/memory.h"

namespace {

/// Every command's standard output (tables, JSON, CSV, help) is checked here, in one place: a
/// write that failed (a full disk, /dev/full, a closed pipe's EIO) turns a successful exit
/// into status 1 with a message, so a caller never takes a truncated or empty output for a
/// result.
int check_stdout(int code) {
  errno = 0;
  const bool flush_failed = std::fflush(stdout) != 0;
  const int err = errno;
  std::cout.flush();  // through stdout (synced with stdio): already flushed, its state checked
  if (!flush_failed && !std::ferror(stdout) && !std::cout.fail()) return code;
  const std::string cause =
      flush_failed && err != 0 ? kdgrid::write_error_text(err) : std::string("a write failed");
  std::fprintf(stderr,
               "kdgrid: error: writing to standard output failed (%s): the output is incomplete; "
               "free space or redirect it to another file, then run again\n",
               cause.c_str());
  return code == 0 ? 1 : code;
}

int run(int argc, char** argv) {
  CLI::App app{"kdgrid: a ray tracer for studying acceleration structures (hybrid grid/kd-tree)"};
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "Show help for every subcommand");
  kdgrid::cli::add_info_command(app);
  kdgrid::cli::add_bench_command(app);
  kdgrid::cli::add_sweep_command(app);
  kdgrid::cli::add_render_command(app);
  kdgrid::cli::add_gen_command(app);
  kdgrid::cli::add_rays_command(app);
  kdgrid::cli::add_trace_command(app);
  kdgrid::cli::add_check_command(app);
  kdgrid::cli::add_profile_command(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const kdgrid::BuildCancelled& e) {
    // Ctrl-C during a build (cli::build_interruptible): 128 + SIGINT, as the shell reports it.
    std::fprintf(stderr, "kdgrid: %s\n", e.what());
    return 130;
  } catch (const kdgrid::Error& e) {
    std::fprintf(stderr, "kdgrid: error: %s\n", e.what());
    return 1;
  } catch (const std::bad_alloc&) {
    // Builds report their own (accel/guards.h); this is any other allocation that failed.
    std::fprintf(stderr,
                 "kdgrid: error: %s: use a smaller scene, resolution or ray count, or run with "
                 "more memory\n",
                 kdgrid::out_of_memory_message().c_str());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "kdgrid: internal error: %s\n", e.what());
    return 2;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return check_stdout(run(argc, argv));
}
