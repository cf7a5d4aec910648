// The hybrid's record of the triangles a ray has tested, for the lane-by-lane walk (included
// by walk.h): the per-ray mailbox and its evicted list, and the exact walk's per-thread bit set
// (GridKdHybrid::rewalk), so that no ray tests a triangle twice (docs/HYBRID.md, "The walk").
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

#include "accel/hybrid/hybrid.h"

namespace kdgrid::hybrid {

/// The exact walk's record of the triangles its ray has tested (GridKdHybrid::rewalk): a bit per
/// triangle of the structure, and the words the ray set, cleared when the thread's next exact
/// walk starts, so that every bit is clear as a walk starts. One per thread, grown to the
/// largest structure the thread re-walks a ray in (a bit a triangle: 106 KiB for the dragon's
/// 871K) and kept, as a re-walked ray is mostly followed by others.
struct TestedSet {
  std::vector<uint64_t> bits;
  std::vector<uint32_t> dirty;  ///< the words of bits that the current walk set

  /// Clears the previous walk's bits and makes room for `triangles` triangle indices.
  void begin(size_t triangles) {
    for (const uint32_t i : dirty) bits[i] = 0;
    dirty.clear();
    if (bits.size() < (triangles + 63) / 64) bits.resize((triangles + 63) / 64, 0);
  }
  /// True when `prim` was recorded before; else records it.
  bool test_and_set(uint32_t prim) {
    uint64_t& word = bits[prim >> 6];
    const uint64_t bit = uint64_t(1) << (prim & 63);
    if (word & bit) return true;
    if (word == 0) dirty.push_back(prim >> 6);
    word |= bit;
    return false;
  }
};

/// The calling thread's record for exact walks.
inline thread_local TestedSet thread_tested_set;

/// The value of WalkState::evicted_count once the fast walk is abandoned.
constexpr uint32_t kAbandoned = uint32_t(GridKdHybrid::kEvicted) + 1;

/// True when triangle `prim` was tested before on this ray, so the test is skipped; else
/// records it. The fast walk (kExact false) asks the mailbox, which answers almost every repeat;
/// a triangle that a colliding one pushed out of it is kept among the ray's evicted (up to
/// GridKdHybrid::kEvicted) and looked up there, on the rays that have evicted any. When one more
/// would have to be evicted, the fast walk is abandoned: every later test is skipped, the walk
/// ends at its next step (steps_left 0, which over_step_bound does not count as an error), and
/// GridKdHybrid::traverse gives the ray to rewalk, which runs it again with the exact walk
/// (kExact), whose record holds every triangle tested. So no ray tests a triangle twice, and the
/// fast walk keeps everything inline and its triangle loop with no exit for closest hits: a call
/// anywhere in walk_step makes it save registers on every step, and leaving the loop at the
/// abandonment makes it spill registers (docs/EXPERIMENTS.md, "The walk").
template <bool kExact, class W>
[[gnu::always_inline]] inline bool tested_before(W& w, uint32_t prim) {
  if constexpr (kExact) {
    return w.tested->test_and_set(prim);
  } else {
    uint32_t& slot = w.mailbox[prim & (GridKdHybrid::kMailbox - 1)];
    if (slot == prim) return true;
    if ((w.evicted_count | (slot ^ kInvalidPrim)) != 0) [[unlikely]] {
      const uint32_t n = w.evicted_count;
      if (n == kAbandoned) return true;
      for (uint32_t i = 0; i < n; ++i)
        if (w.evicted[i] == prim) return true;
      if (slot != kInvalidPrim) {
        if (n == uint32_t(GridKdHybrid::kEvicted)) {
          w.evicted_count = kAbandoned;
          w.steps_left = 0;
          return true;
        }
        w.evicted[n] = slot;
        w.evicted_count = n + 1;
      }
    }
    slot = prim;
    return false;
  }
}

}  // namespace kdgrid::hybrid
