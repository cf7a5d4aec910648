#include "util/format.h"

#include <cstdint>
#include <cstdio>
#include <ctime>

namespace kdgrid {

std::string format_double(const char* printf_format, double v) {
  char buf[128];
  std::snprintf(buf, sizeof buf, printf_format, v);
  return buf;
}

std::string format_bytes_iec(double b) {
  if (b >= double(uint64_t(1) << 30))
    return format_double("%.3g GiB", b / double(uint64_t(1) << 30));
  if (b >= double(1 << 20)) return format_double("%.3g MiB", b / double(1 << 20));
  if (b >= 1024.0) return format_double("%.3g KiB", b / 1024.0);
  return format_double("%.0f bytes", b);
}

std::string now_iso8601() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  localtime_r(&now, &tm);
  char buf[64];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%S%z", &tm);
  return buf;
}

}  // namespace kdgrid
