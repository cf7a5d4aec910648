// Benchmark suite files (docs/RAYSETS.md): a JSON list of scenes, each a file relative to the
// suite file and a camera (null = the canonical camera). `kdgrid bench` reads them so that
// anyone can run the same suite on their own scenes.
//
//   {"scenes": [{"name": "bunny", "file": "bunny/bun_zipper.ply", "camera": null},
//               {"name": "sponza", "file": "sponza.obj",
//                "camera": {"eye": [-14, 3, 0], "target": [10, 5, 0], "fov": 60}}]}
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "scene/scene.h"

namespace kdgrid {

/// One scene of a suite. An entry that cannot be used (no file, malformed camera) keeps its
/// problem in `error`, so that the runner reports it and still runs the other scenes.
struct SuiteScene {
  std::string name;              ///< label in the tables; defaults to the file's stem
  std::string file;              ///< absolute or relative to the working directory
  std::optional<Camera> camera;  ///< empty = canonical camera of docs/RAYSETS.md
  std::string error;             ///< non-empty if the entry is unusable
};

struct Suite {
  std::string path;  ///< file it came from ("" if built in code)
  std::vector<SuiteScene> scenes;
};

/// Longest scene name of a suite, in bytes: NAME.SET.rays must fit a file name (255 bytes).
inline constexpr size_t kMaxSuiteNameBytes = 200;

/// "" when `name` can name a suite scene, else what is wrong with it. A name labels the
/// tables and names the scene's ray files in --rays-dir (NAME.SET.rays), so it must be a plain
/// file-name part: not empty, at most kMaxSuiteNameBytes bytes, no '/' or '\\', not "." or
/// "..", no control characters (bytes below 32, and 127).
std::string suite_name_problem(const std::string& name);

/// ParamError before any work when two usable scenes (no `error`) of `suite` share a name or a
/// usable scene's name is not a name (suite_name_problem): they would share one ray file in
/// --rays-dir and one row label. Names both scenes' files.
void check_suite_names(const Suite& suite);

/// Parses suite JSON text. Scene files are resolved relative to `base_dir`. `source` names
/// the text in error messages. Throws LoadError if the text is not JSON or has no "scenes"
/// array; problems of a single entry go to that entry's `error` instead: a name that is not a
/// name (suite_name_problem) or the name of an earlier entry is such a problem.
Suite parse_suite(const std::string& text, const std::string& base_dir, const std::string& source);

/// Reads and parses a suite file (LoadError naming the file if it cannot be read or parsed).
Suite load_suite(const std::string& path);

/// The default suite: $KDGRID_SCENES/suite.json or ../shared/scenes/suite.json (scenes_dir()),
/// else the project's assets/suite.json (find_asset). Empty if none exists.
std::string default_suite_path(const std::string& project_dir = "");

/// A suite with a single scene file (what `kdgrid bench SCENE` runs).
Suite single_scene_suite(const std::string& file, const std::optional<Camera>& camera = {});

}  // namespace kdgrid
