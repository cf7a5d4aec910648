// libFuzzer harness: the .rays and .hits readers must reject any input with LoadError, never
// crash, hang or allocate what the input cannot hold; accepted rays are traced (NaN included).
#include <cstddef>
#include <cstdint>

#include "accel/brute.h"
#include "bench/rayfile.h"
#include "util/error.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const kdgrid::Mesh mesh = [] {
    kdgrid::Mesh m;
    m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
    m.triangles = {{0, 1, 2}};
    return m;
  }();
  static kdgrid::BruteForce brute = [] {
    kdgrid::BruteForce b;
    b.build(mesh, {});
    return b;
  }();
  try {
    const auto rays = kdgrid::parse_rays(data, size, "fuzz.rays");
    for (const auto& r : rays) {
      kdgrid::Hit h;
      brute.intersect(r, h);
      brute.occluded(r);
    }
  } catch (const kdgrid::Error&) {
  }
  try {
    kdgrid::parse_hits(data, size, "fuzz.hits");
  } catch (const kdgrid::Error&) {
  }
  return 0;
}
