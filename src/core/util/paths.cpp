#include "util/paths.h"

#include <cstdlib>
#include <filesystem>
#include <vector>

namespace kdgrid {

namespace fs = std::filesystem;

namespace {

/// The directories searched, each with up to `levels` of its ancestors: the current
/// directory, `project_dir` and the executable's directory. A build tree's executable lies
/// four levels below its checkout (build/PRESET/src/cli).
std::vector<fs::path> search_roots(const std::string& project_dir, int levels) {
  std::error_code ec;
  std::vector<fs::path> out;
  for (const fs::path& base :
       {fs::current_path(ec), fs::path(project_dir), fs::path(executable_dir())}) {
    if (base.empty()) continue;
    fs::path p = base;
    for (int up = 0; up < levels && !p.empty(); ++up, p = p.parent_path()) {
      out.push_back(p);
      if (p == p.parent_path()) break;
    }
  }
  return out;
}

}  // namespace

std::string executable_dir() {
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  return ec ? std::string() : exe.parent_path().string();
}

std::string scenes_dir(const std::string& project_dir) {
  if (const char* env = std::getenv("KDGRID_SCENES"); env && *env) return env;
  std::error_code ec;
  // ../shared/scenes beside the checkout, seen from the checkout or a build dir inside it.
  for (const fs::path& p : search_roots(project_dir, 5)) {
    const fs::path cand = p / ".." / "shared" / "scenes";
    if (fs::is_directory(cand, ec)) return fs::weakly_canonical(cand, ec).string();
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

std::string find_asset(const std::string& name, const std::string& project_dir) {
  std::error_code ec;
  for (const fs::path& p : search_roots(project_dir, 5)) {
    for (const fs::path& cand : {p / "assets" / name, p / "share" / "kdgrid" / "assets" / name})
      if (fs::is_regular_file(cand, ec)) return cand.lexically_normal().string();
  }
  return "";
}

}  // namespace kdgrid
