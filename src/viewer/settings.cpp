#include "viewer/settings.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "util/error.h"

namespace kdgrid::viewer {

namespace fs = std::filesystem;

const char* to_string(HeatScale s) {
  switch (s) {
    case HeatScale::Auto:
      return "auto";
    case HeatScale::Fixed:
      return "fixed";
    case HeatScale::Log:
      return "log";
  }
  return "auto";
}

static HeatScale parse_heat_scale(const std::string& s) {
  if (s == "fixed") return HeatScale::Fixed;
  if (s == "log") return HeatScale::Log;
  return HeatScale::Auto;
}

std::string config_dir() {
  fs::path base;
  if (const char* x = std::getenv("XDG_CONFIG_HOME"); x && *x)
    base = x;
  else if (const char* h = std::getenv("HOME"); h && *h)
    base = fs::path(h) / ".config";
  else
    return "";
  const fs::path dir = base / "kdgrid";
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) {
    std::fprintf(stderr, "kdgrid-viewer: cannot create %s (%s); settings will not be saved\n",
                 dir.c_str(), ec.message().c_str());
    return "";
  }
  return dir.string();
}

Settings load_settings(const std::string& dir) {
  Settings s;
  if (dir.empty()) return s;
  const fs::path file = fs::path(dir) / "viewer.json";
  std::ifstream in(file);
  if (!in) return s;
  try {
    const auto j = nlohmann::json::parse(in);
    s.accel = j.value("accel", s.accel);
    s.cell_size = j.value("cell_size", s.cell_size);
    try {
      if (CellChoice::parse(s.cell_size, "cell_size").kind == CellChoice::Kind::Units) {
        std::fprintf(stderr,
                     "kdgrid-viewer: %s: ignoring cell_size \"%s\": a size in scene units is "
                     "remembered per scene (cell_size_by_scene), never applied to another scene\n",
                     file.c_str(), s.cell_size.c_str());
        s.cell_size = "auto";
      }
    } catch (const std::exception&) {
      s.cell_size = "auto";
    }
    if (j.contains("cell_size_by_scene") && j["cell_size_by_scene"].is_object())
      for (const auto& [k, v] : j["cell_size_by_scene"].items())
        if (v.is_string()) s.cell_size_by_scene[k] = v.get<std::string>();
    s.window_width = j.value("window_width", s.window_width);
    s.window_height = j.value("window_height", s.window_height);
    s.heat_scale = parse_heat_scale(j.value("heat_scale", std::string("auto")));
    s.heat_fixed_min = j.value("heat_fixed_min", s.heat_fixed_min);
    s.heat_fixed_max = j.value("heat_fixed_max", s.heat_fixed_max);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "kdgrid-viewer: ignoring %s: %s (delete it to reset the settings)\n",
                 file.c_str(), e.what());
    return Settings{};
  }
  return s;
}

void save_settings(const std::string& dir, const Settings& s) {
  if (dir.empty()) return;
  const nlohmann::json j = {{"accel", s.accel},
                            {"cell_size", s.cell_size},
                            {"cell_size_by_scene", s.cell_size_by_scene},
                            {"window_width", s.window_width},
                            {"window_height", s.window_height},
                            {"heat_scale", to_string(s.heat_scale)},
                            {"heat_fixed_min", s.heat_fixed_min},
                            {"heat_fixed_max", s.heat_fixed_max}};
  const fs::path file = fs::path(dir) / "viewer.json";
  std::ofstream out(file);
  out << j.dump(2) << "\n";
  if (!out) std::fprintf(stderr, "kdgrid-viewer: could not write %s\n", file.c_str());
}

CellChoice CellChoice::parse(const std::string& s, const std::string& what) {
  CellChoice c;
  if (s == "auto") return c;
  const bool multiple = !s.empty() && (s.back() == 'x' || s.back() == 'X');
  const std::string num = multiple ? s.substr(0, s.size() - 1) : s;
  char* end = nullptr;
  const double v = std::strtod(num.c_str(), &end);
  if (num.empty() || end != num.c_str() + num.size() || !std::isfinite(v) || !(v > 0.0))
    throw ParamError(what + " '" + s +
                     "' must be 'auto', a multiple of the auto size such as '0.5x', "
                     "or a positive size in scene units such as 0.01");
  c.kind = multiple ? Kind::Multiple : Kind::Units;
  c.value = v;
  return c;
}

std::string CellChoice::text() const {
  char buf[64];
  switch (kind) {
    case Kind::Auto:
      return "auto";
    case Kind::Multiple:
      std::snprintf(buf, sizeof buf, "%.6gx", value);
      return buf;
    case Kind::Units:
      std::snprintf(buf, sizeof buf, "%.6g", value);
      return buf;
  }
  return "auto";
}

float CellChoice::resolve(double auto_cell) const {
  switch (kind) {
    case Kind::Auto:
      return 0.0f;
    case Kind::Multiple:
      return float(value * auto_cell);
    case Kind::Units:
      return float(value);
  }
  return 0.0f;
}

static std::string scene_key(const std::string& path) {
  std::error_code ec;
  const fs::path abs = fs::weakly_canonical(fs::absolute(path, ec), ec);
  return ec ? path : abs.string();
}

CellChoice remembered_cell_choice(const Settings& s, const std::string& path) {
  const auto it = s.cell_size_by_scene.find(scene_key(path));
  try {
    if (it != s.cell_size_by_scene.end())
      return CellChoice::parse(it->second, "cell_size_by_scene");
    const CellChoice g = CellChoice::parse(s.cell_size, "cell_size");
    if (g.kind != CellChoice::Kind::Units) return g;
  } catch (const std::exception&) {
  }
  return {};
}

void remember_cell_choice(Settings& s, const std::string& path, const CellChoice& c) {
  if (c.kind == CellChoice::Kind::Auto)
    s.cell_size_by_scene.erase(scene_key(path));
  else
    s.cell_size_by_scene[scene_key(path)] = c.text();
}

}  // namespace kdgrid::viewer
