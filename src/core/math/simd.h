// SIMD lane types shared by the traversals: GCC vector extensions (which clang also accepts), so
// one source compiles to AVX where the target has it and to SSE2 pairs in the portable build.
// Only the operations the traversals need are here: lane masks reduced to one bool, and a
// fused multiply-add that falls back to two operations where the CPU has no FMA.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>

namespace kdgrid {

/// The widest x86 SIMD extension this build targets (compile time: -march=native unless
/// KDGRID_NATIVE=OFF), stated beside every speed figure (`kdgrid bench`, docs/RESULTS.md).
inline constexpr const char* kBuildIsa =
#if defined(__AVX512F__)
    "AVX-512";
#elif defined(__AVX2__)
    "AVX2";
#elif defined(__AVX__)
    "AVX";
#elif defined(__SSE4_2__)
    "SSE4.2";
#elif defined(__SSE2__)
    "SSE2";
#else
    "none";
#endif
/// Lanes of the vectors the traversals use: every structure traces one ray at a time, and the
/// hybrid's walk holds the ray's three axes (and a padding lane) in the 4-lane types below.
inline constexpr int kTraversalLanes = 4;

/// Four float lanes (GCC's vector extensions, SSE): x, y, z and a fourth that is padding.
using Float4 = float __attribute__((vector_size(16)));
using Int4 = int32_t __attribute__((vector_size(16)));
/// Whether any lane of a lane mask (all ones or zero per lane) is set, or all four are: one
/// movemask where the target has SSE, else the two 64-bit halves.
[[gnu::always_inline]] inline bool any_lane(Int4 m) {
#ifdef __SSE__
  return __builtin_ia32_movmskps((Float4)m) != 0;  // a vector cast: the same bits
#else
  uint64_t half[2];
  std::memcpy(half, &m, sizeof half);
  return (half[0] | half[1]) != 0;
#endif
}
[[gnu::always_inline]] inline bool all_lanes(Int4 m) {
#ifdef __SSE__
  return __builtin_ia32_movmskps((Float4)m) == 0xf;
#else
  uint64_t half[2];
  std::memcpy(half, &m, sizeof half);
  return (half[0] & half[1]) == ~uint64_t(0);
#endif
}

/// Four double lanes and four int64 lanes (AVX where the target has it, else SSE2 pairs).
using Double4 = double __attribute__((vector_size(32)));
using Long4 = int64_t __attribute__((vector_size(32)));

/// a * b + c, fused (one rounding, half the latency) where the CPU has FMA, else two
/// operations: for code whose robustness does not depend on how t rounds (the hybrid's step
/// is made robust by its integer clamps).
[[gnu::always_inline]] inline double mul_add(double a, double b, double c) {
#ifdef __FMA__
  return std::fma(a, b, c);
#else
  return a * b + c;
#endif
}
/// The same lane by lane (the same results as the scalar form on each lane). Vectors pass by
/// reference: by value, a target without AVX would pass them differently (-Wpsabi).
[[gnu::always_inline]] inline void mul_add(const Double4& a, const Double4& b, const Double4& c,
                                           Double4& out) {
#ifdef __FMA__
  out = __builtin_ia32_vfmaddpd256(a, b, c);
#else
  out = a * b + c;
#endif
}

}  // namespace kdgrid
