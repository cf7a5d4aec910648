#include "viewer/settings.h"

#include <cfloat>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <optional>

#include <nlohmann/json.hpp>

#include "util/atomic_file.h"
#include "util/enum_names.h"
#include "util/error.h"
#include "util/input_file.h"

namespace kdgrid::viewer {

namespace fs = std::filesystem;

constexpr EnumName<HeatScale> kHeatScaleNames[] = {
    {HeatScale::Auto, "auto"}, {HeatScale::Fixed, "fixed"}, {HeatScale::Log, "log"}};

const char* to_string(HeatScale s) {
  return enum_name(s, kHeatScaleNames, "auto");
}

/// The scale `s` names; auto for any other text.
static HeatScale parse_heat_scale(const std::string& s) {
  return enum_value(s, kHeatScaleNames).value_or(HeatScale::Auto);
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

std::string settings_file(const std::string& dir) {
  return dir.empty() ? "" : (fs::path(dir) / "viewer.json").string();
}

namespace {

/// Largest settings file read: far above any real one (a few hundred bytes a remembered scene).
constexpr uint64_t kMaxSettingsBytes = uint64_t(16) << 20;

/// Reads the settings of `j` one field at a time: a field of the wrong type or out of its
/// range keeps its default, alone, with a warning naming `file`, the field and the value.
class FieldReader {
 public:
  FieldReader(const nlohmann::json& j, const std::string& file) : j_(j), file_(file) {}

  /// The field `key` if present, else nullptr.
  const nlohmann::json* find(const char* key) const {
    const auto it = j_.find(key);
    return it == j_.end() ? nullptr : &*it;
  }
  /// `field` is the setting as the file names it ("window_width", "cell_size_by_scene" of a
  /// scene).
  void warn(const std::string& field, const nlohmann::json& v, const std::string& why) const {
    std::fprintf(
        stderr, "kdgrid-viewer: %s: ignoring %s = %s: it %s; that setting is at its default\n",
        file_.c_str(), printable(field, 300).c_str(),
        printable(v.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace)).c_str(),
        why.c_str());
  }
  void string(const char* key, std::string& out) const {
    if (const auto* v = find(key)) {
      if (v->is_string())
        out = v->get<std::string>();
      else
        warn(key, *v, "is not a string");
    }
  }
  void integer(const char* key, int& out, int lo, int hi) const {
    if (const auto* v = find(key)) {
      if (v->is_number_integer() && v->get<int64_t>() >= lo && v->get<int64_t>() <= hi)
        out = int(v->get<int64_t>());
      else
        warn(key, *v,
             "is not a whole number from " + std::to_string(lo) + " to " + std::to_string(hi));
    }
  }
  void finite_float(const char* key, float& out) const {
    if (const auto* v = find(key)) {
      const double d = v->is_number() ? v->get<double>() : 0.0;
      if (v->is_number() && std::isfinite(d) && std::fabs(d) <= double(FLT_MAX))
        out = float(d);
      else
        warn(key, *v, "is not a number within the range of a float (+-3.4e38)");
    }
  }

 private:
  const nlohmann::json& j_;
  const std::string& file_;
};

}  // namespace

std::optional<std::string> read_config_file(const std::string& dir, const std::string& name) {
  if (dir.empty()) return std::nullopt;
  const std::string file = (fs::path(dir) / name).string();
  std::error_code ec;
  if (!fs::exists(file, ec)) return std::nullopt;
  try {
    // A regular file only (a FIFO would block the start), of a bounded size.
    return read_input_file(file, "a kdgrid-viewer settings file", kMaxSettingsBytes);
  } catch (const LoadError& e) {
    std::fprintf(stderr, "kdgrid-viewer: ignoring %s: %s\n", name.c_str(), e.what());
  }
  return std::nullopt;
}

void write_config_file(const std::string& dir, const std::string& name, const std::string& text) {
  if (dir.empty()) return;
  const std::string file = (fs::path(dir) / name).string();
  std::error_code ec;
  const fs::file_status st = fs::status(file, ec);
  if (fs::exists(st) && !fs::is_regular_file(st)) {
    std::fprintf(stderr,
                 "kdgrid-viewer: %s is not a regular file; it was not saved (remove it to have "
                 "the settings remembered)\n",
                 file.c_str());
    return;
  }
  try {
    write_file_atomically(file, text);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "kdgrid-viewer: the settings were not saved: %s\n", e.what());
  }
}

Settings load_settings(const std::string& dir) {
  Settings s;
  const std::optional<std::string> text = read_config_file(dir, "viewer.json");
  if (!text) return s;
  const std::string file = settings_file(dir);
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(*text);
  } catch (const std::exception& e) {
    std::fprintf(stderr,
                 "kdgrid-viewer: ignoring %s: it is not valid JSON (%s); every setting is at its "
                 "default (delete the file to reset the settings)\n",
                 file.c_str(), e.what());
    return s;
  }
  if (!j.is_object()) {
    std::fprintf(stderr,
                 "kdgrid-viewer: ignoring %s: not a JSON object of settings; every setting is at "
                 "its default (delete the file to reset the settings)\n",
                 file.c_str());
    return s;
  }
  const FieldReader r(j, file);
  r.string("accel", s.accel);
  if (const auto* v = r.find("cell_size")) {
    std::string why = "is not a string";
    if (v->is_string()) {
      try {
        const CellChoice c = CellChoice::parse(v->get<std::string>(), "cell_size");
        why = c.kind == CellChoice::Kind::Units
                  ? "is a size in scene units: such a size is remembered per scene "
                    "(cell_size_by_scene), never applied to another scene"
                  : "";
        if (why.empty()) s.cell_size = c.text();
      } catch (const ParamError&) {
        why = "is not 'auto' or a multiple of the auto size such as '0.5x'";
      }
    }
    if (!why.empty()) r.warn("cell_size", *v, why);
  }
  if (const auto* v = r.find("cell_size_by_scene")) {
    if (!v->is_object()) r.warn("cell_size_by_scene", *v, "is not an object");
    if (v->is_object())
      for (const auto& [k, size] : v->items()) {
        bool ok = false;
        try {
          const CellChoice c = size.is_string()
                                   ? CellChoice::parse(size.get<std::string>(), "cell size")
                                   : CellChoice{};
          ok = c.kind != CellChoice::Kind::Auto;
        } catch (const ParamError&) {
        }
        if (ok)
          s.cell_size_by_scene[k] = size.get<std::string>();
        else
          r.warn("cell_size_by_scene of " + k, size,
                 "is not a size in scene units or a multiple of auto ('0.5x') within the range "
                 "of a float");
      }
  }
  r.integer("window_width", s.window_width, 1, kMaxWindowSide);
  r.integer("window_height", s.window_height, 1, kMaxWindowSide);
  if (const auto* v = r.find("heat_scale")) {
    const std::string t = v->is_string() ? v->get<std::string>() : "";
    if (t == "auto" || t == "fixed" || t == "log")
      s.heat_scale = parse_heat_scale(t);
    else
      r.warn("heat_scale", *v, "is not \"auto\", \"fixed\" or \"log\"");
  }
  r.finite_float("heat_fixed_min", s.heat_fixed_min);
  r.finite_float("heat_fixed_max", s.heat_fixed_max);
  return s;
}

void save_settings(const std::string& dir, const Settings& s) {
  if (dir.empty()) return;
  nlohmann::json j = {{"accel", s.accel},
                      {"cell_size", s.cell_size},
                      {"cell_size_by_scene", s.cell_size_by_scene},
                      {"window_width", s.window_width},
                      {"window_height", s.window_height},
                      {"heat_scale", to_string(s.heat_scale)}};
  // JSON has no infinity (nlohmann writes null): a value typed past float's range is not
  // remembered, the next start takes the default.
  if (std::isfinite(s.heat_fixed_min)) j["heat_fixed_min"] = s.heat_fixed_min;
  if (std::isfinite(s.heat_fixed_max)) j["heat_fixed_max"] = s.heat_fixed_max;
  write_config_file(dir, "viewer.json",
                    j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
}

CellChoice CellChoice::parse(const std::string& s, const std::string& what) {
  CellChoice c;
  if (s == "auto") return c;
  const bool multiple = !s.empty() && (s.back() == 'x' || s.back() == 'X');
  const std::string num = multiple ? s.substr(0, s.size() - 1) : s;
  char* end = nullptr;
  const double v = std::strtod(num.c_str(), &end);
  // Within float's range (a cell size is a float): 1e39 would build with an infinite size,
  // 1e-46 with 0, the auto rule.
  if (num.empty() || end != num.c_str() + num.size() || !(v > 0.0) || !(v <= double(FLT_MAX)) ||
      !(float(v) > 0.0f))
    throw ParamError(what + " '" + s +
                     "' must be 'auto', a multiple of the auto size such as '0.5x', "
                     "or a positive size in scene units such as 0.01 (within a float's range, "
                     "1.2e-38 to 3.4e38)");
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
