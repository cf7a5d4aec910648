// Where kdgrid finds the shared scenes and its own assets. Nothing here depends on where the
// sources were when the binaries were built: an installed or copied binary finds its files
// relative to itself, the current directory or $KDGRID_SCENES.
#pragma once

#include <optional>
#include <string>

namespace kdgrid {

/// The directory of the running executable (from /proc/self/exe); empty if unknown.
std::string executable_dir();

/// The shared scenes directory: $KDGRID_SCENES if set, else ../shared/scenes relative to the
/// current directory, to `project_dir` (if given) or to the executable's checkout (the
/// executable built in build/PRESET/src/...), when it exists. Empty if none.
std::string scenes_dir(const std::string& project_dir = "");

/// Resolves a scene path: as given if it exists, else relative to scenes_dir().
std::string resolve_scene_path(const std::string& path, const std::string& project_dir = "");

/// The project's own asset `name` (e.g. "cornell.gltf"): assets/NAME under the current
/// directory, `project_dir` (if given) or the checkout the executable was built in, or
/// installed beside the executable (PREFIX/share/kdgrid/assets for PREFIX/bin). Empty if none.
std::string find_asset(const std::string& name, const std::string& project_dir = "");

}  // namespace kdgrid
