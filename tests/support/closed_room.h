// A closed room for the shading tests: an OBJ whose walls face in, with pillars and a block
// inside and no lights, so that the default light sits outside, above it, and reaches nothing.
#pragma once

#include <fstream>
#include <string>

namespace kdgrid::test {

/// Writes the room (20 x 6 x 20 about the origin, floor at y = 0) to `path` and returns it.
inline std::string write_closed_room(const std::string& path) {
  std::ofstream f(path);
  int base = 0;
  const auto box = [&](float x0, float y0, float z0, float x1, float y1, float z1) {
    for (int i = 0; i < 8; ++i)
      f << "v " << (i & 1 ? x1 : x0) << " " << (i & 2 ? y1 : y0) << " " << (i & 4 ? z1 : z0)
        << "\n";
    static const int q[6][4] = {{0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1},
                                {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}};
    for (const auto& r : q)
      f << "f " << base + r[0] + 1 << " " << base + r[1] + 1 << " " << base + r[2] + 1 << " "
        << base + r[3] + 1 << "\n";
    base += 8;
  };
  box(-10, 0, -10, 10, 6, 10);
  for (float x : {-5.0f, 5.0f})
    for (float z : {-5.0f, 5.0f}) box(x - 0.5f, 0, z - 0.5f, x + 0.5f, 6, z + 0.5f);
  box(-1.5f, 0, -2, 1.5f, 1.5f, 0);
  return path;
}

}  // namespace kdgrid::test
