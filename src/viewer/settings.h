// What the viewer remembers between runs, in $XDG_CONFIG_HOME/kdgrid (or ~/.config/kdgrid):
// imgui.ini (window layout, written by ImGui) and viewer.json (these settings).
#pragma once

#include <string>

namespace kdgrid::viewer {

enum class HeatScale { Auto, Fixed, Log };

struct Settings {
  std::string accel;             ///< last structure; empty = the command line's default
  std::string cell_size = "auto";
  int window_width = 1280, window_height = 800;
  HeatScale heat_scale = HeatScale::Auto;
  float heat_fixed_min = 0.0f, heat_fixed_max = 100.0f;
};

/// $XDG_CONFIG_HOME/kdgrid, else $HOME/.config/kdgrid; created if missing. Empty if neither
/// variable is set or the directory cannot be created (then nothing is remembered).
std::string config_dir();

/// Reads viewer.json from `dir`; missing or malformed files give defaults (with a warning
/// for malformed ones, naming the file).
Settings load_settings(const std::string& dir);
/// Writes viewer.json into `dir`; failures are reported on stderr, never fatal.
void save_settings(const std::string& dir, const Settings& s);

const char* to_string(HeatScale s);

}  // namespace kdgrid::viewer
