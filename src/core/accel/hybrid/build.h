// Internals shared by the hybrid's build files (hybrid.cpp, cell_map.cpp); not part of the
// structure's interface, which is hybrid.h.
#pragma once

#include <cstdint>
#include <string>

namespace kdgrid::hybrid {

/// printf of one number, for the build's texts and errors.
std::string fmt(const char* f, double v);
/// "12.3 MiB", "1.5 GiB" or "812 bytes", as the build's errors and notes print sizes.
std::string bytes_str(double b);

}  // namespace kdgrid::hybrid
