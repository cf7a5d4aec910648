// Each `kdgrid` subcommand lives in its own cmd_*.cpp and registers itself on the app.
#pragma once

#include <CLI/CLI.hpp>

namespace kdgrid::cli {

void add_info_command(CLI::App& app);
void add_bench_command(CLI::App& app);
void add_sweep_command(CLI::App& app);
void add_render_command(CLI::App& app);
void add_gen_command(CLI::App& app);
void add_rays_command(CLI::App& app);
void add_trace_command(CLI::App& app);
void add_check_command(CLI::App& app);
void add_profile_command(CLI::App& app);

}  // namespace kdgrid::cli
