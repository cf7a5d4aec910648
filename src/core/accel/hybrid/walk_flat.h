// The hybrid's walk of a flat subtree (included by walk.h): the boxes of the subtree's leaves
// clipped against the ray at once, the leaves it meets tested in the kd walk's order
// (records.h, "Flat subtrees"; docs/HYBRID.md, "Flat subtrees").
#pragma once

#include <cstdint>
#include <cstring>
#if defined(__AVX2__)
#include <immintrin.h>
#endif

#include "accel/hybrid/walk.h"

namespace kdgrid {

#if defined(__AVX2__) && !(defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__))
namespace hybrid {

/// The AVX2 flat walk's clip: the n leaves' boxes (n <= 16) clipped as kd_clip clips them, in
/// two 8-lane halves (the second only for n > 8; whole-vector reads, records.h,
/// flat_walk_reads_fit), each leaf's [t0, t1] stored to t0s, t1s (leaf i at i); returns the met
/// leaves as bits in the octant's order (bit k: leaf order[k]), by a byte shuffle of the met
/// bits.
[[gnu::always_inline]] inline uint32_t flat_clip_x8(const KdRayX4& r, const float* q, uint32_t n,
                                                    const uint8_t* order, float ta, float tb,
                                                    float* t0s, float* t1s) {
  using F = WideVectors<8>::F;
  using I = WideVectors<8>::I;
  using Wide = WatertightWide<8>;
  const I lane_bit = {1, 2, 4, 8, 16, 32, 64, 128};
  uint32_t met_bits = 0;
  for (uint32_t h = 0; h < 16; h += 8) {
    if (h != 0 && n <= 8) break;
    F t0 = F{} + ta, t1 = F{} + tb;
    uint32_t inside = 0xffu;
    for (int a = 0; a < 3; ++a) {
      F lo, hi;
      std::memcpy(&lo, q + uint32_t(a) * n + h, sizeof lo);
      std::memcpy(&hi, q + uint32_t(3 + a) * n + h, sizeof hi);
      const F o = F{} + r.org[a];
      if (r.fixed[a]) {
        inside &= Wide::bits((lo <= o) & (o <= hi));
        continue;
      }
      const F inv = F{} + r.inv[a], e = F{} + r.err[a];
      const F tl = (lo - o) * inv, th = (hi - o) * inv;
      const F near = (tl < th ? tl : th) - e, far = (tl > th ? tl : th) + e;
      t0 = near > t0 ? near : t0;
      t1 = far < t1 ? far : t1;
    }
    const I met = (t0 <= t1) & (((I{} + int(inside)) & lane_bit) != 0);
    met_bits |= Wide::bits(met) << h;
    std::memcpy(t0s + h, &t0, sizeof t0);
    std::memcpy(t1s + h, &t1, sizeof t1);
  }
  const uint32_t all = (1u << n) - 1;
  // Byte i: all ones where leaf i is met; then byte k: leaf order[k]'s.
  const __m128i bit = _mm_setr_epi8(1, 2, 4, 8, 16, 32, 64, -128, 1, 2, 4, 8, 16, 32, 64, -128);
  const __m128i spread =
      _mm_shuffle_epi8(_mm_cvtsi32_si128(int(met_bits & all)),
                       _mm_setr_epi8(0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1));
  const __m128i met_bytes = _mm_cmpeq_epi8(_mm_and_si128(spread, bit), bit);
  const __m128i ord = n > 8 ? _mm_loadu_si128(reinterpret_cast<const __m128i*>(order))
                            : _mm_loadl_epi64(reinterpret_cast<const __m128i*>(order));
  return uint32_t(_mm_movemask_epi8(_mm_shuffle_epi8(met_bytes, ord))) & all;
}

}  // namespace hybrid
#endif

template <class TriangleTest, class Probe, bool kAny, bool kExact>
bool GridKdHybrid::walk_flat(WalkState<TriangleTest>& w, Probe& probe, uint32_t leaf_id,
                             uint32_t at, double t_exit, LocalHit& h) const {
#if defined(__AVX2__)
  // The ray's segment in the leaf, clipped to the subtree's box as the kd walk clips it.
  const float* fb = flat_subtree_floats_[0].f + at;
  Float4 sub_lo, sub_hi;
  std::memcpy(&sub_lo, fb, sizeof sub_lo);
  std::memcpy(&sub_hi, fb + 4, sizeof sub_hi);
  float ta = float(w.t_cur) - w.err, tb = float(std::min(t_exit, w.t1)) + w.err;
  if (!kd_clip_x4(w.krx4, sub_lo, sub_hi, ta, tb)) return false;
  uint32_t n;
  std::memcpy(&n, fb + 8, sizeof n);
  const float* q = fb + 16;
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
  using F = WideVectors<16>::F;
  using I = WideVectors<16>::I;
  using Wide = WatertightWide<16>;
  // The leaves in the kd walk's order for the ray's octant: at each split the side the ray
  // meets first (a ray with a zero component takes the positive side's order; it lies in one
  // slab of that axis, so the order of the others does not matter).
  const uint32_t oct = uint32_t(w.kr.dir.x < 0.0f) | uint32_t(w.kr.dir.y < 0.0f) << 1 |
                       uint32_t(w.kr.dir.z < 0.0f) << 2;
  const uint8_t* order = reinterpret_cast<const uint8_t*>(q + 8 * n) + oct * n;
  const uint32_t all = (1u << n) - 1;
  // Each leaf's box clipped as kd_clip clips it (each slab widened by err, a zero direction
  // component never bounding t), all leaves at once: the same [t0, t1] per leaf, except that
  // a NaN slab t (a subnormal direction component) leaves the interval wider.
  F t0 = F{} + ta, t1 = F{} + tb;
  uint32_t inside = all;
  for (int a = 0; a < 3; ++a) {
    const F lo = (F)_mm512_maskz_loadu_ps(__mmask16(all), q + uint32_t(a) * n);
    const F hi = (F)_mm512_maskz_loadu_ps(__mmask16(all), q + uint32_t(3 + a) * n);
    const F o = F{} + w.krx4.org[a];
    if (w.krx4.fixed[a]) {
      inside &= Wide::bits((lo <= o) & (o <= hi));
      continue;
    }
    const F inv = F{} + w.krx4.inv[a], e = F{} + w.krx4.err[a];
    const F tl = (lo - o) * inv, th = (hi - o) * inv;
    const F near = (tl < th ? tl : th) - e, far = (tl > th ? tl : th) + e;
    t0 = near > t0 ? near : t0;
    t1 = far < t1 ? far : t1;
  }
  // The leaves the ray meets, and their entry t's, in that order (lane k: the k-th leaf).
  const I perm =
      (I)_mm512_maskz_cvtepu8_epi32(__mmask16(all), _mm_maskz_loadu_epi8(__mmask16(all), order));
  const I lane_bit = {1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096, 8192, 16384, 32768};
  const I met = (t0 <= t1) & (((I{} + int(inside)) & lane_bit) != 0);
  const __mmask16 lanes = __mmask16(all);
  uint32_t left = Wide::bits((I)_mm512_maskz_permutexvar_epi32(lanes, (__m512i)perm, (__m512i)met));
  const F entry = (F)_mm512_maskz_permutexvar_ps(lanes, (__m512i)perm, (__m512)t0);
  // Whether the closest hit lies before the k-th leaf's entry.
  const auto before = [&](float best_t, uint32_t k) {
    return ((Wide::bits(F{} + best_t < entry) >> k) & 1u) != 0;
  };
#else
  const uint32_t oct = uint32_t(w.kr.dir.x < 0.0f) | uint32_t(w.kr.dir.y < 0.0f) << 1 |
                       uint32_t(w.kr.dir.z < 0.0f) << 2;
  const uint8_t* order = reinterpret_cast<const uint8_t*>(q + 8 * n) + oct * n;
  alignas(32) float t0[16], t1[16];
  uint32_t left = hybrid::flat_clip_x8(w.krx4, q, n, order, ta, tb, t0, t1);
  const auto before = [&](float best_t, uint32_t k) { return best_t < t0[order[k]]; };
#endif
  float best = w.best;
  bool found = w.found;
  [[maybe_unused]] float trace_in = float(w.t_cur);
  // The leaves' groups requested at once, 512 bytes from each one's first (a group of 16 lanes
  // and 16 corners is about 300 bytes; a subtree's leaves' groups follow one another): an
  // incoherent ray would otherwise wait for each leaf's group in turn, its header first.
  for (uint32_t m = left; m != 0; m &= m - 1) {
    uint32_t first;
    std::memcpy(&first, q + 6 * n + order[__builtin_ctz(m)], sizeof first);
    const char* g = reinterpret_cast<const char*>(groups_[0].f + first);
    for (int l = 0; l < hybrid::kFlatPrefetchLines; ++l) __builtin_prefetch(g + 64 * l);
  }
  while (left) {
    const uint32_t k = uint32_t(__builtin_ctz(left));
    // Done once the closest hit lies before the next leaf's entry (the kd walk's rule).
    if (found && before(best, k)) break;
    left &= left - 1;
    const uint32_t i = order[k];
    probe.step();
    if constexpr (Probe::kTrace) {
      // The leaf's segment within the grid leaf's, as the kd walk's traces clamp theirs.
      const Box3 box(Vec3(q[i], q[n + i], q[2 * n + i]),
                     Vec3(q[3 * n + i], q[4 * n + i], q[5 * n + i]));
      const float leaf_out = float(std::min(t_exit, double(w.tmax)));
      trace_in = std::max(trace_in, std::min(t0[i], leaf_out));
      probe.visit(TraceStep{StepKind::Leaf, int(leaf_depth_[leaf_id]) + 1, leaf_id, box, trace_in,
                            std::max(trace_in, std::min(t1[i], leaf_out))});
    }
    uint32_t first, count;  // stored as floats' bits (records.h)
    std::memcpy(&first, q + 6 * n + i, sizeof first);
    std::memcpy(&count, q + 7 * n + i, sizeof count);
    if (test_groups<TriangleTest, Probe, kAny, kExact>(w, probe, w.rd, w.tmin, first, count, best,
                                                       found, h))
      return true;
  }
  if constexpr (!kAny) keep_subtree_hit(w, best, h);
#else
  (void)w, (void)probe, (void)leaf_id, (void)at, (void)t_exit, (void)h;
#endif
  return false;
}

}  // namespace kdgrid
