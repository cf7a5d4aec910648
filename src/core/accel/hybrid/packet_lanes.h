// The packet walk's operations on its lanes (accel/hybrid/packet.cpp), one ray a float lane:
// kPacketLanes lanes, 16 of a 512-bit vector in builds for AVX-512 (compares straight to mask
// registers, masked moves and stores), 8 of a 256-bit vector in builds for AVX2 and FMA
// (compares and blends through vectors of all-ones lanes, their masks by movemask). The walk is
// written once over these; each lane's arithmetic is the same float operations in both.
#pragma once

#include <cstddef>
#include <cstdint>

#include "accel/hybrid/records.h"
#include "accel/triangle_wide.h"
#include "math/ray.h"

namespace kdgrid::hybrid::packet_lanes {

#if KDGRID_PACKET_LANES != 0

using FloatLanes = WideVectors<kPacketLanes>::F;
using IntLanes = WideVectors<kPacketLanes>::I;

[[gnu::always_inline]] inline FloatLanes splat(float x) {
  return FloatLanes{} + x;
}
[[gnu::always_inline]] inline FloatLanes vmin(FloatLanes a, FloatLanes b) {
  return a < b ? a : b;
}
[[gnu::always_inline]] inline FloatLanes vmax(FloatLanes a, FloatLanes b) {
  return a > b ? a : b;
}
/// |x|, lane by lane (the sign bit cleared).
[[gnu::always_inline]] inline FloatLanes vabs(FloatLanes x) {
  return (FloatLanes)((IntLanes)x & 0x7fffffff);
}

#if KDGRID_PACKET_LANES == 16
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
/// b in the lanes of m, a in the others.
[[gnu::always_inline]] inline FloatLanes blend(FloatLanes a, uint32_t m, FloatLanes b) {
  return (FloatLanes)_mm512_mask_mov_ps((__m512)a, __mmask16(m), (__m512)b);
}
[[gnu::always_inline]] inline IntLanes blend(IntLanes a, uint32_t m, IntLanes b) {
  return (IntLanes)_mm512_mask_mov_epi32((__m512i)a, __mmask16(m), (__m512i)b);
}
#else
/// Comparisons to lane masks (bit i: lane i), through the vector compare's all-ones lanes:
/// ordered, so false where either side is NaN, except ne.
[[gnu::always_inline]] inline uint32_t lt(FloatLanes a, FloatLanes b) {
  return WatertightWide<kPacketLanes>::bits(a < b);
}
[[gnu::always_inline]] inline uint32_t le(FloatLanes a, FloatLanes b) {
  return WatertightWide<kPacketLanes>::bits(a <= b);
}
[[gnu::always_inline]] inline uint32_t eq(FloatLanes a, FloatLanes b) {
  return WatertightWide<kPacketLanes>::bits(a == b);
}
[[gnu::always_inline]] inline uint32_t ne(FloatLanes a, FloatLanes b) {
  return WatertightWide<kPacketLanes>::bits(a != b);
}
/// All-ones in the lanes of the mask m: its bits spread to lanes by a table of each lane's bit.
[[gnu::always_inline]] inline IntLanes spread(uint32_t m) {
  const IntLanes bit = {1, 2, 4, 8, 16, 32, 64, 128};
  return ((IntLanes{} + int32_t(m)) & bit) != 0;
}
/// b in the lanes of m, a in the others.
[[gnu::always_inline]] inline FloatLanes blend(FloatLanes a, uint32_t m, FloatLanes b) {
  return spread(m) ? b : a;
}
[[gnu::always_inline]] inline IntLanes blend(IntLanes a, uint32_t m, IntLanes b) {
  return spread(m) ? b : a;
}
#endif

/// The least of each of four vectors' lanes `m`, at once: halves folded together, two vectors'
/// halves to a vector, then quarters, then pairs.
[[gnu::always_inline]] inline void lane_mins(FloatLanes a, FloatLanes b, FloatLanes c, FloatLanes d,
                                             uint32_t m, float (&out)[4]) {
  const FloatLanes inf = splat(kInf);
  a = blend(inf, m, a), b = blend(inf, m, b), c = blend(inf, m, c), d = blend(inf, m, d);
#if KDGRID_PACKET_LANES == 16
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
#else
  // Lanes 0-3: a's eight folded to four; lanes 4-7: b's (or c's, d's).
  const FloatLanes ab = vmin(__builtin_shufflevector(a, b, 0, 1, 2, 3, 8, 9, 10, 11),
                             __builtin_shufflevector(a, b, 4, 5, 6, 7, 12, 13, 14, 15));
  const FloatLanes cd = vmin(__builtin_shufflevector(c, d, 0, 1, 2, 3, 8, 9, 10, 11),
                             __builtin_shufflevector(c, d, 4, 5, 6, 7, 12, 13, 14, 15));
  // Lanes 0-1: two candidates of a, 2-3 of c, 4-5 of b, 6-7 of d.
  FloatLanes x = vmin(__builtin_shufflevector(ab, cd, 0, 1, 8, 9, 4, 5, 12, 13),
                      __builtin_shufflevector(ab, cd, 2, 3, 10, 11, 6, 7, 14, 15));
  x = vmin(x, __builtin_shufflevector(x, x, 1, 0, 3, 2, 5, 4, 7, 6));
  out[0] = x[0], out[1] = x[4], out[2] = x[2], out[3] = x[6];
#endif
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
/// tmax), 0 in lanes n and up; rays past n are not read. With 16 lanes, rays j and j + 8 are
/// loaded into vector j, then three rounds of two-source permutes each swap a bit of the
/// vector's index (the ray's bits 0, 1, 2) with a bit of the lane's (the float's bits 0, 1, 2):
/// the transpose of the 16 x 8 floats, with no gather. With 8 lanes, ray j is vector j, and
/// the three rounds are unpacks, then shuffles of pairs, then swaps of halves.
[[gnu::always_inline]] inline void load_rays(const Ray* rays, int n, FloatLanes (&f)[8]) {
  static_assert(sizeof(Ray) == 32 && offsetof(Ray, tmin) == 12 && offsetof(Ray, dir) == 16 &&
                offsetof(Ray, tmax) == 28);
  const float* p = reinterpret_cast<const float*>(rays);
#if KDGRID_PACKET_LANES == 16
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
#else
  FloatLanes v[8];
  for (int j = 0; j < 8; ++j) {
    v[j] = FloatLanes{};
    if (j < n) __builtin_memcpy(&v[j], p + 8 * j, sizeof v[j]);
  }
  // Rays 2i, 2i + 1 interleaved: u[2i] their floats 0, 1, 4, 5, u[2i + 1] their 2, 3, 6, 7.
  FloatLanes u[8];
  for (int i = 0; i < 4; ++i) {
    u[2 * i] = __builtin_shufflevector(v[2 * i], v[2 * i + 1], 0, 8, 1, 9, 4, 12, 5, 13);
    u[2 * i + 1] = __builtin_shufflevector(v[2 * i], v[2 * i + 1], 2, 10, 3, 11, 6, 14, 7, 15);
  }
  // Rays 4q to 4q + 3: w[4q + r] holds float r of each in its low half, float r + 4 in its high.
  FloatLanes w[8];
  for (int q = 0; q < 2; ++q)
    for (int h = 0; h < 2; ++h) {
      const FloatLanes a = u[4 * q + h], b = u[4 * q + 2 + h];
      w[4 * q + 2 * h] = __builtin_shufflevector(a, b, 0, 1, 8, 9, 4, 5, 12, 13);
      w[4 * q + 2 * h + 1] = __builtin_shufflevector(a, b, 2, 3, 10, 11, 6, 7, 14, 15);
    }
  for (int r = 0; r < 4; ++r) {
    f[r] = __builtin_shufflevector(w[r], w[4 + r], 0, 1, 2, 3, 8, 9, 10, 11);
    f[r + 4] = __builtin_shufflevector(w[r], w[4 + r], 4, 5, 6, 7, 12, 13, 14, 15);
  }
#endif
}

/// hits[i] = {t, prim, u, v} of lane i for the lanes `found` (Hit's 16 bytes), the others
/// untouched: the four vectors transposed into vectors of hits, then stored with a mask (16
/// lanes) or hit by hit (8).
[[gnu::always_inline]] inline void store_hits(FloatLanes t, IntLanes prim, FloatLanes u,
                                              FloatLanes v, uint32_t found, Hit* hits) {
  static_assert(sizeof(Hit) == 16 && offsetof(Hit, prim) == 4 && offsetof(Hit, u) == 8 &&
                offsetof(Hit, v) == 12);
  const FloatLanes p = (FloatLanes)prim;
  float* out = reinterpret_cast<float*>(hits);
#if KDGRID_PACKET_LANES == 16
  // Lane 4j + r's hit in 128-bit block j of h[r] (the unpacks' orders).
  const FloatLanes tp_lo =
      __builtin_shufflevector(t, p, 0, 16, 1, 17, 4, 20, 5, 21, 8, 24, 9, 25, 12, 28, 13, 29);
  const FloatLanes tp_hi =
      __builtin_shufflevector(t, p, 2, 18, 3, 19, 6, 22, 7, 23, 10, 26, 11, 27, 14, 30, 15, 31);
  const FloatLanes uv_lo =
      __builtin_shufflevector(u, v, 0, 16, 1, 17, 4, 20, 5, 21, 8, 24, 9, 25, 12, 28, 13, 29);
  const FloatLanes uv_hi =
      __builtin_shufflevector(u, v, 2, 18, 3, 19, 6, 22, 7, 23, 10, 26, 11, 27, 14, 30, 15, 31);
  const auto lo = [](FloatLanes x, FloatLanes y) __attribute__((always_inline)) {
    return __builtin_shufflevector(x, y, 0, 1, 16, 17, 4, 5, 20, 21, 8, 9, 24, 25, 12, 13, 28, 29);
  };
  const auto hi = [](FloatLanes x, FloatLanes y) __attribute__((always_inline)) {
    return __builtin_shufflevector(x, y, 2, 3, 18, 19, 6, 7, 22, 23, 10, 11, 26, 27, 14, 15, 30,
                                   31);
  };
  const FloatLanes h0 = lo(tp_lo, uv_lo), h1 = hi(tp_lo, uv_lo), h2 = lo(tp_hi, uv_hi),
                   h3 = hi(tp_hi, uv_hi);
  // Hits 4q to 4q + 3 are block q of h0, h1, h2, h3.
  const auto blocks01 = [](FloatLanes x, FloatLanes y) __attribute__((always_inline)) {
    return __builtin_shufflevector(x, y, 0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23);
  };
  const auto blocks23 = [](FloatLanes x, FloatLanes y) __attribute__((always_inline)) {
    return __builtin_shufflevector(x, y, 8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30,
                                   31);
  };
  const auto even = [](FloatLanes x, FloatLanes y) __attribute__((always_inline)) {
    return __builtin_shufflevector(x, y, 0, 1, 2, 3, 8, 9, 10, 11, 16, 17, 18, 19, 24, 25, 26, 27);
  };
  const auto odd = [](FloatLanes x, FloatLanes y) __attribute__((always_inline)) {
    return __builtin_shufflevector(x, y, 4, 5, 6, 7, 12, 13, 14, 15, 20, 21, 22, 23, 28, 29, 30,
                                   31);
  };
  const FloatLanes a = blocks01(h0, h1), b = blocks01(h2, h3), c = blocks23(h0, h1),
                   d = blocks23(h2, h3);
  const FloatLanes q[4] = {even(a, b), odd(a, b), even(c, d), odd(c, d)};
  for (int j = 0; j < 4; ++j) {
    const uint32_t four = found >> (4 * j) & 0xfu;
    if (four == 0) continue;
    const uint32_t mask = _pdep_u32(four, 0x1111u) * 0xfu;
    _mm512_mask_storeu_ps(out + 16 * j, __mmask16(mask), (__m512)q[j]);
  }
#else
  // h[r] holds lane r's hit in its low half and lane r + 4's in its high half.
  const FloatLanes tp_lo = __builtin_shufflevector(t, p, 0, 8, 1, 9, 4, 12, 5, 13);
  const FloatLanes tp_hi = __builtin_shufflevector(t, p, 2, 10, 3, 11, 6, 14, 7, 15);
  const FloatLanes uv_lo = __builtin_shufflevector(u, v, 0, 8, 1, 9, 4, 12, 5, 13);
  const FloatLanes uv_hi = __builtin_shufflevector(u, v, 2, 10, 3, 11, 6, 14, 7, 15);
  const FloatLanes h[4] = {__builtin_shufflevector(tp_lo, uv_lo, 0, 1, 8, 9, 4, 5, 12, 13),
                           __builtin_shufflevector(tp_lo, uv_lo, 2, 3, 10, 11, 6, 7, 14, 15),
                           __builtin_shufflevector(tp_hi, uv_hi, 0, 1, 8, 9, 4, 5, 12, 13),
                           __builtin_shufflevector(tp_hi, uv_hi, 2, 3, 10, 11, 6, 7, 14, 15)};
  for (uint32_t s = found; s != 0; s &= s - 1) {
    const uint32_t i = uint32_t(__builtin_ctz(s));
    __builtin_memcpy(out + 4 * i, reinterpret_cast<const float*>(&h[i & 3]) + 4 * (i >> 2),
                     4 * sizeof(float));
  }
#endif
}

/// out[i] = whether lane i is in `found`, for the lanes i of `lanes` (the others untouched).
[[gnu::always_inline]] inline void store_found(uint32_t lanes, uint32_t found, bool* out) {
#if KDGRID_PACKET_LANES == 16
  _mm_mask_storeu_epi8(out, __mmask16(lanes),
                       _mm_maskz_mov_epi8(__mmask16(found), _mm_set1_epi8(1)));
#else
  for (uint32_t s = lanes; s != 0; s &= s - 1) {
    const int i = __builtin_ctz(s);
    out[i] = (found >> i & 1u) != 0;
  }
#endif
}

#endif  // KDGRID_PACKET_LANES != 0

}  // namespace kdgrid::hybrid::packet_lanes
