// Where kdgrid finds the shared scenes and its own assets.
#pragma once

#include <optional>
#include <string>

namespace kdgrid {

/// The shared scenes directory: $KDGRID_SCENES if set, else ../shared/scenes relative to
/// the current directory or to `project_dir` (if given), when it exists. Empty if none.
std::string scenes_dir(const std::string& project_dir = "");

/// Resolves a scene path: as given if it exists, else relative to scenes_dir().
std::string resolve_scene_path(const std::string& path, const std::string& project_dir = "");

}  // namespace kdgrid
