// One ray against a group of W triangles whose corners the group gives by lane (structure of
// arrays; WideTriangles here, the hybrid's groups in accel/hybrid/records.h): WatertightTest's
// arithmetic on W lanes at once, with GCC vector extensions (which clang also accepts), so one
// source compiles to AVX where the target has it and to SSE elsewhere. Per lane it performs
// exactly WatertightTest::intersect's float operations in the same order (the build's
// -ffp-contract=off keeps them unfused), and the lanes that the scalar test would take to its
// double-precision code (an edge function exactly zero, or a depth that overflowed) are given to
// the scalar test itself, so every hit is bit for bit the scalar test's.
#pragma once

#include <cstdint>
#include <cstring>
#if defined(__AVX512F__)
#include <immintrin.h>
#endif

#include "accel/triangle.h"

namespace kdgrid {

/// Triangles per group in the leaves that store them so (the hybrid's): 16 where the build targets
/// AVX-512 (sixteen float lanes), 8 with AVX, 4 with SSE, 1 elsewhere, where leaves are tested one
/// triangle at a time by the scalar test. The build option KDGRID_WIDE_LANES sets it (1, 4, 8 or
/// 16) to compare widths on one CPU (docs/HYBRID.md, "Wide leaves").
inline constexpr int kWideLanes =
#if defined(KDGRID_WIDE_LANES)
    KDGRID_WIDE_LANES;
#elif defined(__AVX512F__)
    16;
#elif defined(__AVX__)
    8;
#elif defined(__SSE2__)
    4;
#else
    1;
#endif
static_assert(kWideLanes == 1 || kWideLanes == 4 || kWideLanes == 8 || kWideLanes == 16,
              "KDGRID_WIDE_LANES: 1, 4, 8 or 16");
#if !defined(__AVX512F__)
// Without AVX-512 a 16-lane vector is two 256-bit halves passed through memory, far slower
// than groups of 8 (docs/HYBRID.md, "Wide leaves"; docs/EXPERIMENTS.md, "Wide leaves").
static_assert(kWideLanes != 16, "KDGRID_WIDE_LANES=16 needs a build for AVX-512");
#endif

/// WatertightTest under another name: a structure whose leaves WatertightWide tests runs this one
/// lane by lane, the scalar reference that tests hold the wide test to.
struct WatertightScalar : WatertightTest {};

/// W triangles' corners by lane: c[corner][axis][lane]. A group of fewer triangles repeats its
/// last one in the lanes left over, so that every lane holds a real triangle.
template <int W>
struct alignas(4 * W) WideTriangles {
  float c[3][3][W];
  /// Corner k of lane i.
  Vec3 corner(int k, int i) const;
  /// WatertightWide's view of the group (see WatertightWide::intersect).
  template <class D, class F>
  [[gnu::always_inline]] void sheared(const D& d, uint32_t, F (&out)[3][3]) const;
  void set(int i, const Vec3& v0, const Vec3& v1, const Vec3& v2) {
    const Vec3* v[3] = {&v0, &v1, &v2};
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a) c[k][a][i] = component(*v[k], a);
  }
};

/// Float and int32 vectors of W lanes (a specialization per width: GCC ignores a vector_size
/// that depends on a template parameter).
template <int W>
struct WideVectors;
template <>
struct WideVectors<4> {
  using F = float __attribute__((vector_size(16)));
  using I = int32_t __attribute__((vector_size(16)));
};
template <>
struct WideVectors<8> {
  using F = float __attribute__((vector_size(32)));
  using I = int32_t __attribute__((vector_size(32)));
};
#if defined(__AVX512F__)
template <>
struct WideVectors<16> {
  using F = float __attribute__((vector_size(64)));
  using I = int32_t __attribute__((vector_size(64)));
};
#endif

/// WatertightTest on W lanes (W = 4, 8, or 16 with AVX-512; see the file's comment).
template <int W>
struct WatertightWide {
  using F = typename WideVectors<W>::F;
  using I = typename WideVectors<W>::I;

  /// Bit i set where lane i of the mask (all ones or zero per lane) is set.
  [[gnu::always_inline]] static uint32_t bits(I m) {
#if defined(__AVX__)
    if constexpr (W == 8) return uint32_t(__builtin_ia32_movmskps256((F)m));
#if defined(__AVX512F__)
    if constexpr (W == 16) return uint32_t(_mm512_test_epi32_mask((__m512i)m, (__m512i)m));
#endif
#endif
#if defined(__SSE__)
    if constexpr (W == 4) return uint32_t(__builtin_ia32_movmskps((F)m));
#endif
    uint32_t r = 0;
    for (int i = 0; i < W; ++i) r |= uint32_t(m[i] != 0) << i;
    return r;
  }

  /// The scalar test's shear of a corner (vx, vy, vz: its coordinates kx, ky, kz) on W lanes:
  /// x = (vx - ox) - sx (vz - oz), y likewise, z = sz (vz - oz), each lane as the scalar test.
  [[gnu::always_inline]] static void shear(const WatertightTest::RayData& d, const F& vx,
                                           const F& vy, const F& vz, F& x, F& y, F& z) {
    const F dz = vz - d.oz;
    x = (vx - d.ox) - d.sx * dz;
    y = (vy - d.oy) - d.sy * dz;
    z = d.sz * dz;
  }

  /// G::sheared for corners stored by lane: coordinate a of corner k of lane i at
  /// p[(3k + a) W + i] (WideTriangles, the hybrid's groups by lane).
  [[gnu::always_inline]] static void sheared_by_lane(const WatertightTest::RayData& d,
                                                     const float* p, F (&c)[3][3]) {
    for (int k = 0; k < 3; ++k) {
      F v[3];
      std::memcpy(&v[0], p + (3 * k + d.kx) * W, sizeof(F));
      std::memcpy(&v[1], p + (3 * k + d.ky) * W, sizeof(F));
      std::memcpy(&v[2], p + (3 * k + d.kz) * W, sizeof(F));
      shear(d, v[0], v[1], v[2], c[k][0], c[k][1], c[k][2]);
    }
  }
  /// G::corner for the same layout.
  static Vec3 corner_by_lane(const float* p, int k, int i) {
    const float* q = p + 3 * k * W + i;
    return {q[0], q[W], q[2 * W]};
  }

  /// The closest hit with tmin <= t < tmax among the lanes of group g whose bit is set in
  /// `lanes`: its lane, t, u and v, or -1. Among equal t the lowest lane wins, as a scalar loop
  /// over the lanes in order keeps the first triangle at equal t (it accepts only t < best).
  /// G gives its lanes' corners sheared (WideTriangles, or the hybrid's group views, records.h):
  /// G::sheared(d, lanes, c) sets c[k] to corner k of every lane in `lanes` after shear() (the
  /// other lanes may hold anything), G::corner(k, i) gives corner k of lane i.
  template <class G>
  [[gnu::always_inline]] static int intersect(const WatertightTest::RayData& d, const G& g,
                                              uint32_t lanes, float tmin, float tmax, float& t_out,
                                              float& u_out, float& v_out) {
    F c[3][3];
    g.sheared(d, lanes, c);
    const F &ax = c[0][0], &ay = c[0][1], &az = c[0][2];
    const F &bx = c[1][0], &by = c[1][1], &bz = c[1][2];
    const F &cx = c[2][0], &cy = c[2][1], &cz = c[2][2];
    const F U = cx * by - cy * bx;
    const F V = ax * cy - ay * cx;
    const F Wf = bx * ay - by * ax;
    const F zero = {};
    const I zero_edge = (U == zero) | (V == zero) | (Wf == zero);
    const I mixed =
        ((U < zero) | (V < zero) | (Wf < zero)) & ((U > zero) | (V > zero) | (Wf > zero));
    const F det = U + V + Wf;
    const F T = U * az + V * bz + Wf * cz;
    const F inv_det = 1.0f / det;
    const F t = T * inv_det;
    const I live = ~mixed & (det != zero);
    const I in_range = (t >= tmin) & (t < tmax);  // false for NaN
    const I finite = (T - T) == zero;             // false for inf and NaN
    // Hits in float; the scalar test's double-precision lanes go to the scalar test.
    const uint32_t hit = bits(live & in_range & ~zero_edge) & lanes;
    const uint32_t slow = bits(zero_edge | (live & ~in_range & ~finite)) & lanes;
    if ((hit | slow) == 0) [[likely]]
      return -1;
    return resolve(d, g, hit, slow, t, V, Wf, inv_det, tmin, tmax, t_out, u_out, v_out);
  }

  /// The lanes with a hit or a scalar test to run, in lane order (the first at equal t wins).
  template <class G>
  [[gnu::noinline]] static int resolve(const WatertightTest::RayData& d, const G& g, uint32_t hit,
                                       uint32_t slow, const F& t, const F& V, const F& Wf,
                                       const F& inv_det, float tmin, float tmax, float& t_out,
                                       float& u_out, float& v_out) {
    int best = -1;
    float bt = tmax;
    for (uint32_t m = hit | slow; m != 0; m &= m - 1) {
      const int i = __builtin_ctz(m);
      if (slow >> i & 1u) {
        float ts, us, vs;
        if (WatertightTest::intersect(d, g.corner(0, i), g.corner(1, i), g.corner(2, i), tmin, bt,
                                      ts, us, vs)) {
          best = i;
          bt = ts;
          u_out = us;
          v_out = vs;
        }
      } else if (t[i] < bt) {
        best = i;
        bt = t[i];
        u_out = V[i] * inv_det[i];
        v_out = Wf[i] * inv_det[i];
      }
    }
    if (best >= 0) t_out = bt;
    return best;
  }
};

template <int W>
inline Vec3 WideTriangles<W>::corner(int k, int i) const {
  return WatertightWide<W>::corner_by_lane(&c[0][0][0], k, i);
}

template <int W>
template <class D, class F>
inline void WideTriangles<W>::sheared(const D& d, uint32_t, F (&out)[3][3]) const {
  WatertightWide<W>::sheared_by_lane(d, &c[0][0][0], out);
}

}  // namespace kdgrid
