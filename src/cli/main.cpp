// `kdgrid`: the command-line front end of kdgrid_core (render, info, rays, trace, bench, gen).
#include <cstdio>
#include <exception>
#include <new>

#include "cli/commands.h"
#include "util/cancel.h"
#include "util/error.h"
#include "util/memory.h"

int main(int argc, char** argv) {
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
