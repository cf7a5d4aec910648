#include "util/paths.h"

#include <cstdlib>
#include <filesystem>

namespace kdgrid {

namespace fs = std::filesystem;

std::string scenes_dir(const std::string& project_dir) {
  if (const char* env = std::getenv("KDGRID_SCENES"); env && *env) return env;
  std::error_code ec;
  // ../shared/scenes beside the checkout, seen from the checkout or a build dir inside it.
  for (const fs::path& base : {fs::current_path(ec), fs::path(project_dir)}) {
    if (base.empty()) continue;
    fs::path p = base;
    for (int up = 0; up < 3; ++up, p = p.parent_path()) {
      const fs::path cand = p / ".." / "shared" / "scenes";
      if (fs::is_directory(cand, ec)) return fs::weakly_canonical(cand, ec).string();
    }
  }
  return "";
}

std::string resolve_scene_path(const std::string& path, const std::string& project_dir) {
  std::error_code ec;
  if (fs::exists(path, ec)) return path;
  const std::string dir = scenes_dir(project_dir);
  if (!dir.empty() && fs::exists(fs::path(dir) / path, ec)) return (fs::path(dir) / path).string();
  return path;
}

}  // namespace kdgrid
