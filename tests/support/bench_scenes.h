// What the benchmark, sweep and profile tests share: a gridded closed box (many shared edges and
// vertices) over a floor, the ASCII PLY writer for it, and a CLI run logged to a file.
#pragma once

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "scene/mesh.h"

namespace kdgrid::test {

inline void write_file(const std::filesystem::path& p, const std::string& text) {
  std::ofstream f(p, std::ios::binary);
  f << text;
}

/// A closed box whose faces are n x n grids of quads (two triangles each), so that rays
/// meet many shared edges and vertices, plus a separate open quad floating beside it.
inline Mesh gridded_box(int n, const Vec3& center, float half) {
  Mesh m;
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = 0; side < 2; ++side) {
      const uint32_t base = uint32_t(m.positions.size());
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      for (int j = 0; j <= n; ++j) {
        for (int i = 0; i <= n; ++i) {
          Vec3 p = center;
          p[axis] += side ? half : -half;
          p[u] += -half + 2 * half * float(i) / float(n);
          p[v] += -half + 2 * half * float(j) / float(n);
          m.positions.push_back(p);
        }
      }
      for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
          const uint32_t a = base + uint32_t(j * (n + 1) + i), b = a + 1, c = a + uint32_t(n + 1),
                         d = c + 1;
          if (side) {
            m.triangles.push_back({a, b, d});
            m.triangles.push_back({a, d, c});
          } else {
            m.triangles.push_back({a, d, b});
            m.triangles.push_back({a, c, d});
          }
        }
      }
    }
  }
  // A floor quad under the box, so shadow rays are sometimes occluded.
  const uint32_t b = uint32_t(m.positions.size());
  const float y = center.y - 2 * half, w = 4 * half;
  m.positions.push_back({center.x - w, y, center.z - w});
  m.positions.push_back({center.x + w, y, center.z - w});
  m.positions.push_back({center.x + w, y, center.z + w});
  m.positions.push_back({center.x - w, y, center.z + w});
  m.triangles.push_back({b, b + 2, b + 1});
  m.triangles.push_back({b, b + 3, b + 2});
  return m;
}

/// Writes an ASCII PLY (test data only; the project's reader parses it).
inline void write_ascii_ply(const Mesh& m, const std::filesystem::path& p) {
  std::ostringstream s;
  s << "ply\nformat ascii 1.0\nelement vertex " << m.positions.size()
    << "\nproperty float x\nproperty float y\nproperty float z\nelement face " << m.triangles.size()
    << "\nproperty list uchar int vertex_indices\nend_header\n";
  s.precision(9);
  for (const auto& v : m.positions) s << v.x << " " << v.y << " " << v.z << "\n";
  for (const auto& t : m.triangles) s << "3 " << t[0] << " " << t[1] << " " << t[2] << "\n";
  write_file(p, s.str());
}

/// Runs the CLI with `args`, its stdout and stderr to `log`; returns its exit code.
inline int run_cli(const std::string& args, const std::filesystem::path& log) {
  const std::string cmd =
      std::string("\"") + KDGRID_CLI_PATH + "\" " + args + " > \"" + log.string() + "\" 2>&1";
  const int rc = std::system(cmd.c_str());
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

/// The whole file as a string.
inline std::string slurp(const std::filesystem::path& p) {
  std::ifstream f(p);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

}  // namespace kdgrid::test
