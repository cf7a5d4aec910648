#include "bench/suite.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "render/camera.h"
#include "util/error.h"
#include "util/paths.h"

namespace kdgrid {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// Reads a [x, y, z] array of finite numbers; returns an error message or "".
std::string read_vec3(const json& j, const char* key, Vec3& out) {
  if (!j.contains(key)) return std::string("camera has no \"") + key + "\" [x, y, z]";
  const json& a = j.at(key);
  if (!a.is_array() || a.size() != 3)
    return std::string("camera \"") + key + "\" must be an array of three numbers [x, y, z]";
  for (int i = 0; i < 3; ++i) {
    if (!a[i].is_number()) return std::string("camera \"") + key + "\" has a non-number element";
    out[i] = a[i].get<float>();
    if (!std::isfinite(out[i])) return std::string("camera \"") + key + "\" is not finite";
  }
  return "";
}

SuiteScene parse_entry(const json& e, size_t index, const fs::path& base, const std::string& src) {
  SuiteScene s;
  const std::string where = src + ": scene " + std::to_string(index);
  if (!e.is_object()) {
    s.name = "scene" + std::to_string(index);
    s.error = where + " is not an object; write {\"name\": ..., \"file\": ..., \"camera\": null}";
    return s;
  }
  if (e.contains("name") && e["name"].is_string()) s.name = e["name"].get<std::string>();
  if (!e.contains("file") || !e["file"].is_string() || e["file"].get<std::string>().empty()) {
    if (s.name.empty()) s.name = "scene" + std::to_string(index);
    s.error = where + " (" + s.name +
              ") has no \"file\" string; give the scene file relative to "
              "the suite file";
    return s;
  }
  const fs::path f = e["file"].get<std::string>();
  s.file = (f.is_absolute() ? f : base / f).lexically_normal().string();
  if (s.name.empty()) s.name = f.stem().string();
  if (e.contains("camera") && !e["camera"].is_null()) {
    const json& c = e["camera"];
    const std::string at = where + " (" + s.name + "): ";
    if (!c.is_object()) {
      s.error = at + "\"camera\" must be null or {\"eye\": [..], \"target\": [..], \"fov\": deg}";
      return s;
    }
    Camera cam;
    cam.name = "suite";
    std::string err = read_vec3(c, "eye", cam.eye);
    if (err.empty()) err = read_vec3(c, "target", cam.target);
    if (err.empty() && c.contains("fov")) {
      if (!c["fov"].is_number())
        err = "camera \"fov\" must be a number of degrees";
      else
        cam.fov_deg = c["fov"].get<float>();
      if (err.empty() && !(cam.fov_deg > 0.0f && cam.fov_deg < 180.0f))
        err = "camera \"fov\" must be between 0 and 180 degrees";
    }
    if (err.empty()) {
      // The range, view direction and fov rules of every other camera (docs/LIMITS.md): an eye
      // past the ray range would give every structure only misses, a black image.
      try {
        check_camera(cam, "camera");
      } catch (const ParamError& bad) {
        err = bad.what();
      }
    }
    if (!err.empty()) {
      s.error = at + err;
      return s;
    }
    s.camera = cam;
  }
  return s;
}

}  // namespace

std::string suite_name_problem(const std::string& name) {
  if (name.empty()) return "is empty";
  if (name.size() > kMaxSuiteNameBytes)
    return "is " + std::to_string(name.size()) + " bytes long, more than " +
           std::to_string(kMaxSuiteNameBytes);
  if (name == "." || name == "..") return "is a folder reference, not a name";
  for (const char c : name) {
    if (c == '/' || c == '\\') return std::string("contains a path separator '") + c + "'";
    if (static_cast<unsigned char>(c) < 32 || c == 127) return "contains a control character";
  }
  return "";
}

void check_suite_names(const Suite& suite) {
  for (size_t i = 0; i < suite.scenes.size(); ++i) {
    const SuiteScene& s = suite.scenes[i];
    if (!s.error.empty()) continue;
    const std::string problem = suite_name_problem(s.name);
    if (!problem.empty())
      throw ParamError("scene name '" + printable(s.name) + "' (" + printable(s.file, 200) + ") " +
                       problem +
                       "; a name labels the tables and names its ray files: give the scene a "
                       "plain name in a suite file");
    for (size_t k = 0; k < i; ++k)
      if (suite.scenes[k].error.empty() && suite.scenes[k].name == s.name)
        throw ParamError("two scenes are named '" + printable(s.name) + "' (" +
                         printable(suite.scenes[k].file, 200) + " and " + printable(s.file, 200) +
                         "): they would share their ray files and table rows; give each its "
                         "own name in a suite file");
  }
}

Suite parse_suite(const std::string& text, const std::string& base_dir, const std::string& source) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::parse_error& e) {
    throw LoadError(
        source + ": not valid JSON (" + e.what() +
        "); a suite is {\"scenes\": [{\"name\": ..., \"file\": ..., \"camera\": null}]}");
  }
  if (!j.is_object() || !j.contains("scenes") || !j["scenes"].is_array())
    throw LoadError(source +
                    ": has no \"scenes\" array; a suite is "
                    "{\"scenes\": [{\"name\": ..., \"file\": ..., \"camera\": null}]}");
  Suite suite;
  suite.path = source;
  const fs::path base = base_dir.empty() ? fs::path(".") : fs::path(base_dir);
  size_t i = 0;
  for (const json& e : j["scenes"]) {
    SuiteScene entry = parse_entry(e, i, base, source);
    if (entry.error.empty()) {
      const std::string where = source + ": scene " + std::to_string(i) + " (\"name\": \"" +
                                printable(entry.name) + "\")";
      const std::string problem = suite_name_problem(entry.name);
      if (!problem.empty())
        entry.error = where + ": the name " + problem +
                      "; a name labels the tables and names the scene's ray files, give a "
                      "plain name such as \"bunny\"";
      for (size_t k = 0; k < suite.scenes.size() && entry.error.empty(); ++k)
        if (suite.scenes[k].error.empty() && suite.scenes[k].name == entry.name)
          entry.error = where + ": scene " + std::to_string(k) +
                        " has the same name; the two would share their ray files and table "
                        "rows, give each scene its own name";
    }
    suite.scenes.push_back(std::move(entry));
    ++i;
  }
  return suite;
}

Suite load_suite(const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec))
    throw LoadError(path + ": suite file not found; give --suite FILE.json (see docs/RAYSETS.md)");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw LoadError(path + ": cannot open the suite file for reading");
  std::stringstream ss;
  ss << in.rdbuf();
  const fs::path base = fs::absolute(fs::path(path), ec).parent_path();
  return parse_suite(ss.str(), base.string(), path);
}

std::string default_suite_path(const std::string& project_dir) {
  std::error_code ec;
  const std::string dir = scenes_dir(project_dir);
  if (!dir.empty() && fs::is_regular_file(fs::path(dir) / "suite.json", ec))
    return (fs::path(dir) / "suite.json").string();
  return find_asset("suite.json", project_dir);
}

Suite single_scene_suite(const std::string& file, const std::optional<Camera>& camera) {
  Suite s;
  SuiteScene e;
  e.file = file;
  e.name = fs::path(file).stem().string();
  e.camera = camera;
  s.scenes.push_back(e);
  return s;
}

}  // namespace kdgrid
