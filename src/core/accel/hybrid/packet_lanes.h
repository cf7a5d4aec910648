// Lanes of 16 floats for the hybrid's packet walk (packet.cpp), in builds for AVX-512: splats,
// comparisons straight to lane masks, blends, reductions of four vectors' lanes at once, and
// the transpose that reads 16 rays into lanes. Included by packet.cpp alone.
#pragma once

#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)

#include <immintrin.h>

#include <cstddef>
#include <cstdint>

#include "accel/triangle_wide.h"
#include "math/ray.h"
#include "math/vec.h"

namespace kdgrid::hybrid::packet_lanes {

using FloatLanes = WideVectors<16>::F;
using IntLanes = WideVectors<16>::I;

[[gnu::always_inline]] inline FloatLanes splat(float x) {
  return FloatLanes{} + x;
}
[[gnu::always_inline]] inline FloatLanes vmin(FloatLanes a, FloatLanes b) {
  return a < b ? a : b;
}
[[gnu::always_inline]] inline FloatLanes vmax(FloatLanes a, FloatLanes b) {
  return a > b ? a : b;
}
/// Comparisons straight to lane masks (a vector compare's result would go through a vector of
/// all-ones lanes and back): ordered, so false where either side is NaN, except ne.
template <int kPredicate>
[[gnu::always_inline]] inline uint32_t cmp(FloatLanes a, FloatLanes b) {
  return _mm512_cmp_ps_mask((__m512)a, (__m512)b, kPredicate);
}
[[gnu::always_inline]] inline uint32_t lt(FloatLanes a, FloatLanes b) {
  return cmp<_CMP_LT_OQ>(a, b);
}
[[gnu::always_inline]] inline uint32_t le(FloatLanes a, FloatLanes b) {
  return cmp<_CMP_LE_OQ>(a, b);
}
[[gnu::always_inline]] inline uint32_t eq(FloatLanes a, FloatLanes b) {
  return cmp<_CMP_EQ_OQ>(a, b);
}
[[gnu::always_inline]] inline uint32_t ne(FloatLanes a, FloatLanes b) {
  return cmp<_CMP_NEQ_UQ>(a, b);
}
[[gnu::always_inline]] inline FloatLanes blend(FloatLanes a, uint32_t m, FloatLanes b) {
  return (FloatLanes)_mm512_mask_mov_ps((__m512)a, __mmask16(m), (__m512)b);
}
[[gnu::always_inline]] inline IntLanes blend(IntLanes a, uint32_t m, IntLanes b) {
  return (IntLanes)_mm512_mask_mov_epi32((__m512i)a, __mmask16(m), (__m512i)b);
}
/// The least of each of four vectors' lanes `m`, at once: halves folded together, two vectors'
/// eight to a vector, then quarters, then pairs.
[[gnu::always_inline]] inline void lane_mins(FloatLanes a, FloatLanes b, FloatLanes c, FloatLanes d,
                                             uint32_t m, float (&out)[4]) {
  const FloatLanes inf = splat(kInf);
  a = blend(inf, m, a), b = blend(inf, m, b), c = blend(inf, m, c), d = blend(inf, m, d);
  // Lanes 0-7: a's (or c's) sixteen folded to eight; lanes 8-15: b's (or d's).
  const FloatLanes ab = vmin(
      __builtin_shufflevector(a, b, 0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23),
      __builtin_shufflevector(a, b, 8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31));
  const FloatLanes cd = vmin(
      __builtin_shufflevector(c, d, 0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23),
      __builtin_shufflevector(c, d, 8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31));
  // Lanes 4q to 4q + 3: four candidates of vector q (a, b, c, d).
  FloatLanes x = vmin(
      __builtin_shufflevector(ab, cd, 0, 1, 2, 3, 8, 9, 10, 11, 16, 17, 18, 19, 24, 25, 26, 27),
      __builtin_shufflevector(ab, cd, 4, 5, 6, 7, 12, 13, 14, 15, 20, 21, 22, 23, 28, 29, 30, 31));
  x = vmin(x, __builtin_shufflevector(x, x, 2, 3, 0, 1, 6, 7, 4, 5, 10, 11, 8, 9, 14, 15, 12, 13));
  x = vmin(x, __builtin_shufflevector(x, x, 1, 0, 3, 2, 5, 4, 7, 6, 9, 8, 11, 10, 13, 12, 15, 14));
  out[0] = x[0], out[1] = x[4], out[2] = x[8], out[3] = x[12];
}
/// The least and the greatest of each of four vectors' lanes `m`.
[[gnu::always_inline]] inline void lane_ranges(FloatLanes a, FloatLanes b, FloatLanes c,
                                               FloatLanes d, uint32_t m, float (&lo)[4],
                                               float (&hi)[4]) {
  lane_mins(a, b, c, d, m, lo);
  lane_mins(-a, -b, -c, -d, m, hi);
  for (float& h : hi) h = -h;
}

/// Rays i < n of `rays` by lane: f[k] holds float k of each (Ray: origin, tmin, direction,
/// tmax), 0 in lanes n and up; rays past n are not read. Rays j and j + 8 are loaded into vector
/// j, then three rounds of two-source permutes each swap a bit of the vector's index (the ray's
/// bits 0, 1, 2) with a bit of the lane's (the float's bits 0, 1, 2): the transpose of the 16 x 8
/// floats, with no gather.
[[gnu::always_inline]] inline void load_rays(const Ray* rays, int n, FloatLanes (&f)[8]) {
  static_assert(sizeof(Ray) == 32 && offsetof(Ray, tmin) == 12 && offsetof(Ray, dir) == 16 &&
                offsetof(Ray, tmax) == 28);
  const float* p = reinterpret_cast<const float*>(rays);
  __m512 v[8];
  for (int j = 0; j < 8; ++j) {
    const __m256 lo = _mm256_maskz_loadu_ps(__mmask8(j < n ? 0xff : 0), p + 8 * j);
    const __m256 hi = _mm256_maskz_loadu_ps(__mmask8(j + 8 < n ? 0xff : 0), p + 8 * (j + 8));
    v[j] = _mm512_insertf32x8(_mm512_castps256_ps512(lo), hi, 1);
  }
  // Round k's lane indices for the vector whose ray bit k is 0 and for its partner: lane l takes
  // lane l with bit k cleared (set) from the first source where lane l's bit k is 0, else from
  // the second.
  alignas(64) static constexpr int32_t kIndex[3][2][16] = {
      {{0, 16, 2, 18, 4, 20, 6, 22, 8, 24, 10, 26, 12, 28, 14, 30},
       {1, 17, 3, 19, 5, 21, 7, 23, 9, 25, 11, 27, 13, 29, 15, 31}},
      {{0, 1, 16, 17, 4, 5, 20, 21, 8, 9, 24, 25, 12, 13, 28, 29},
       {2, 3, 18, 19, 6, 7, 22, 23, 10, 11, 26, 27, 14, 15, 30, 31}},
      {{0, 1, 2, 3, 16, 17, 18, 19, 8, 9, 10, 11, 24, 25, 26, 27},
       {4, 5, 6, 7, 20, 21, 22, 23, 12, 13, 14, 15, 28, 29, 30, 31}}};
  for (int k = 0; k < 3; ++k) {
    const __m512i il = _mm512_load_si512(kIndex[k][0]), ih = _mm512_load_si512(kIndex[k][1]);
    for (int j = 0; j < 8; ++j) {
      if (j >> k & 1) continue;
      const __m512 a = v[j], b = v[j | 1 << k];
      v[j] = _mm512_permutex2var_ps(a, il, b);
      v[j | 1 << k] = _mm512_permutex2var_ps(a, ih, b);
    }
  }
  for (int j = 0; j < 8; ++j) f[j] = (FloatLanes)v[j];
}

}  // namespace kdgrid::hybrid::packet_lanes

#endif
