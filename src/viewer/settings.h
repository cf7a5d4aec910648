// What the viewer remembers between runs, in $XDG_CONFIG_HOME/kdgrid (or ~/.config/kdgrid):
// imgui.ini (window layout, written by ImGui) and viewer.json (these settings).
#pragma once

#include <map>
#include <optional>
#include <string>

namespace kdgrid::viewer {

enum class HeatScale { Auto, Fixed, Log };

struct Settings {
  std::string accel;  ///< last structure; empty = the command line's default
  /// The hybrid's cell size for any scene without its own: "auto" or a multiple of the auto
  /// size ("0.5x"), set by hand (the viewer remembers its choices per scene). A size in scene
  /// units is remembered per scene only (cell_size_by_scene): one scene's 0.0008 is a
  /// 43526x20701x19501 grid on another. A bare number here (an older file) is ignored with a
  /// warning.
  std::string cell_size = "auto";
  /// Choices (sizes in scene units or multiples of auto) by the scene file's absolute path.
  std::map<std::string, std::string> cell_size_by_scene;
  int window_width = 1280, window_height = 800;
  HeatScale heat_scale = HeatScale::Auto;
  float heat_fixed_min = 0.0f, heat_fixed_max = 100.0f;
};

/// $XDG_CONFIG_HOME/kdgrid, else $HOME/.config/kdgrid; created if missing. Empty if neither
/// variable is set or the directory cannot be created (then nothing is remembered).
std::string config_dir();

/// Largest remembered window side (a larger one is not used); the window itself is clamped to
/// 64..16384 when it opens.
inline constexpr int kMaxWindowSide = 16384;

/// ImGui's window layout, in the settings folder.
inline constexpr const char* kLayoutFile = "imgui.ini";

/// viewer.json in `dir` ("" if `dir` is).
std::string settings_file(const std::string& dir);

/// The text of the file `name` in `dir`, read only when it is a regular file of at most
/// 16 MiB (a FIFO would block the start); nullopt when it does not exist, and with a warning
/// naming the file when it cannot be read.
std::optional<std::string> read_config_file(const std::string& dir, const std::string& name);
/// Writes the file `name` in `dir` through the atomic writer (a full disk leaves the old file
/// as it was); a failure, or an existing non-regular file of that name, is a warning on
/// stderr, never fatal.
void write_config_file(const std::string& dir, const std::string& name, const std::string& text);

/// Reads viewer.json from `dir` field by field: a missing file gives the defaults; a field of
/// the wrong type or out of range keeps its default, alone, with a warning naming the file,
/// the field and the value; a file that is not JSON (or not an object) gives every default,
/// with a warning.
Settings load_settings(const std::string& dir);
/// Writes viewer.json into `dir` (write_config_file); failures are warnings, never fatal.
void save_settings(const std::string& dir, const Settings& s);

const char* to_string(HeatScale s);

/// A cell-size choice: the auto rule, a multiple of it, or a size in scene units.
struct CellChoice {
  enum class Kind { Auto, Multiple, Units } kind = Kind::Auto;
  double value = 0;  ///< the multiple, or the size in scene units
  /// "auto", "0.5x" (a multiple of auto) or "0.004" (scene units); throws ParamError naming
  /// `what` otherwise.
  static CellChoice parse(const std::string& s, const std::string& what);
  std::string text() const;  ///< the form parse() reads
  /// The cell size for a scene whose auto size is `auto_cell` (0 = the auto rule itself).
  float resolve(double auto_cell) const;
};

/// The remembered choice for the scene at `path` (absolute or relative): its own choice (a
/// size in scene units or a multiple of auto) if one is remembered, else the global auto or
/// multiple.
CellChoice remembered_cell_choice(const Settings& s, const std::string& path);
/// Remembers `c` for the scene at `path` only: a size or a multiple under that scene, auto by
/// forgetting the scene's own choice. The global cell_size is never written here: a choice
/// made on one scene does not apply to every other.
void remember_cell_choice(Settings& s, const std::string& path, const CellChoice& c);

}  // namespace kdgrid::viewer
