// Numbers as text for reports, messages and tables: one place, so that every output spells a
// size or a figure the same way.
#pragma once

#include <string>

namespace kdgrid {

/// `v` through one printf conversion (`printf_format` holds exactly one, for a double), e.g.
/// format_double("%.3g", x).
std::string format_double(const char* printf_format, double v);

/// "12.3 MiB", "1.50 GiB", "512 bytes" (three significant digits, binary units).
std::string format_bytes_iec(double bytes);

/// The local time now in ISO 8601 with its UTC offset ("2026-12-06T21:50:53+0000"), for reports.
std::string now_iso8601();

}  // namespace kdgrid
