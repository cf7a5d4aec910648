// splitmix64: the small, fast random stream of the generated scenes, ray sets, sweeps and
// renders. Identical on every platform and standard library (std distributions are not), so a
// seed gives the same scene, rays and samples everywhere.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "math/vec.h"

namespace kdgrid {

/// splitmix64's finalizer: a 64-bit integer hash that spreads every input bit over the output.
constexpr uint64_t splitmix64_mix(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

/// The stream: each draw adds the golden-ratio increment to the state and mixes it.
class SplitMix64 {
 public:
  static constexpr uint64_t kIncrement = 0x9E3779B97F4A7C15ull;

  explicit SplitMix64(uint64_t seed) : state_(seed) {}
  uint64_t next() { return splitmix64_mix(state_ += kIncrement); }
  /// Uniform in [0, 1): the top 24 bits of a draw.
  float uniform() { return float(next() >> 40) * (1.0f / 16777216.0f); }
  float uniform(float lo, float hi) { return lo + (hi - lo) * uniform(); }
  int integer(int lo, int hi_exclusive) { return lo + int(next() % uint64_t(hi_exclusive - lo)); }
  Vec3 in_box(float lo, float hi) { return {uniform(lo, hi), uniform(lo, hi), uniform(lo, hi)}; }
  /// Uniform on the unit sphere.
  Vec3 unit_vector() {
    const float z = uniform(-1.0f, 1.0f), phi = uniform(0.0f, 2.0f * 3.14159265358979f);
    const float s = std::sqrt(std::max(0.0f, 1.0f - z * z));
    return {s * std::cos(phi), s * std::sin(phi), z};
  }

 private:
  uint64_t state_;
};

}  // namespace kdgrid
