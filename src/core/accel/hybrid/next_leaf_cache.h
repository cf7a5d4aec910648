// The hybrid's next-leaf cache (included by walk.h): per thread, the leaf last reached across
// each leaf face, so that coherent rays find their next leaf without the cell map's dependent
// loads (BuildParams::hybrid_next_leaf_cache; docs/HYBRID.md, "The structure").
#pragma once

#include <cstdint>

namespace kdgrid::hybrid {

/// The next-leaf cache: each thread remembers the leaf it last reached across each leaf face,
/// and the walk takes it when the exit cell lies in that leaf's kd box (the kd boxes tile the
/// grid, so the check is exact), else looks the cell up. Coherent rays predict the check, so the
/// next leaf's record loads while the exit is being computed. The entry leaf is taken the same
/// way from the thread's previous ray's. A score of recent predictions switches the cache off
/// while they mostly fail (incoherent rays), so that a wrong prediction's mispredicted branch
/// is not paid on every step. While it is off, every plain lookup records the leaf it found and
/// one in kOffSample also scores the prediction it would have made, so that the cache turns on
/// again as soon as the rays are coherent. One cache per thread, shared by every hybrid, since each
/// checks a leaf against its own kd boxes. Zero-initialized, as every thread_local is (no member
/// initializers).
struct NextLeafCache {
  /// Score: +1 per right prediction, -kMissCost per wrong one, within [kScoreMin, kScoreMax];
  /// the cache is used while it is >= 0 (more right predictions than wrong ones keep it on). A
  /// miss cost of 1 keeps it on for rays that are right most of the time but not nearly always
  /// (a scan's primary rays); a higher cost turns it off for them, no score at all leaves it on
  /// for diffuse rays, whose guesses mostly fail (docs/EXPERIMENTS.md, "The next-leaf cache").
  static constexpr int32_t kScoreMax = 64, kScoreMin = -64, kMissCost = 1;
  /// Entries per thread (direct-mapped by leaf and exit axis; 16 KiB): a larger table catches
  /// few more (docs/EXPERIMENTS.md, "The next-leaf cache").
  static constexpr uint64_t kEntries = 4096;
  /// While the cache is off, one lookup in kOffSample (a power of two) is scored: scoring every
  /// one cost diffuse rays up to 5% (docs/EXPERIMENTS.md, "The next-leaf cache").
  static constexpr uint32_t kOffSample = 8;

  /// The leaf last reached across each leaf face, by a hash of the leaf and the exit axis (the
  /// ray's direction fixes the face's side).
  uint32_t leaf[kEntries];
  uint32_t start;  ///< the entry leaf of the thread's previous ray
  int32_t score;
  uint32_t tick;   ///< lookups made while the cache was off (their sampling)
  uint64_t taken;  ///< leaves taken from the cache (GridKdHybrid::next_leaves_from_cache)
  uint64_t owner;  ///< GridKdHybrid::uid_ of the structure whose leaf ids the cache holds (0: none)

  /// The entry of leaf `from`'s face on `axis`.
  [[gnu::always_inline]] uint32_t& entry(uint32_t from, int axis) {
    return leaf[(uint64_t(from) * 3 + uint64_t(axis)) & (kEntries - 1)];
  }
  /// Makes the cache structure `uid`'s before a walk: when another structure (or an earlier
  /// build of this one) used it last, its leaf ids are replaced by leaf 0, so every entry names
  /// a leaf of this structure and GridKdHybrid::in_kd_box needs no bounds check. Structures only
  /// alternate ray by ray on one thread in tests; the reset (16 KiB) is paid once per switch.
  [[gnu::always_inline]] void claim(uint64_t uid) {
    if (owner == uid) [[likely]]
      return;
    std::memset(leaf, 0, sizeof leaf);
    start = 0;
    owner = uid;
  }
};

/// The calling thread's next-leaf cache.
inline thread_local NextLeafCache thread_next_leaf_cache;

}  // namespace kdgrid::hybrid
