#include "viewer/settings.h"

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

namespace kdgrid::viewer {

namespace fs = std::filesystem;

const char* to_string(HeatScale s) {
  switch (s) {
    case HeatScale::Auto: return "auto";
    case HeatScale::Fixed: return "fixed";
    case HeatScale::Log: return "log";
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

}  // namespace kdgrid::viewer
