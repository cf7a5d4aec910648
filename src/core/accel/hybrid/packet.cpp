// The hybrid's packet queries (GridKdHybrid::intersect_packet, occluded_packet): up to 64 rays
// walked together as four packets of 16, one ray a float lane of 512-bit vectors, in builds for
// AVX-512; up to 32 as four packets of 8 lanes of 256-bit vectors in builds for AVX2 and FMA
// (the lane operations: packet_lanes.h); the others loop over the single-ray walk.
//
// The packets go down the kd-tree whose splits lie on the grid's cell boundaries, and down the
// leaves' subtrees, together: each lane keeps its own [t0, t1] within a node, widened
// by the kd-tree's rounding bound err (KdRay) as the single-ray kd walk widens its own, and the
// packet visits a child when any of its lanes does, front to back (the rays share their
// directions' signs), until every lane's closest hit lies before the next node. In a leaf, each
// triangle group is first culled against the packet's lanes that reach the leaf: a triangle
// whose three corners, in the watertight test's shear space (WatertightTest), lie on one side
// of the origin for every such ray is missed by all of them; the rest are tested one triangle
// against all the lanes at once, each lane by WatertightTest's own float operations in its
// order (and its double-precision cases by the scalar test), so each ray's t, u, v of a
// triangle are bit for bit its single walk's; or, where they outnumber the lanes (and in a
// leaf that at most four lanes reach), each lane against the group by the single walk's own
// group test (WatertightWide). Each ray thus finds the closest of the same intersections as its
// single walk; only of two triangles hit at exactly the same t could the packet keep the other,
// where its intervals reach a leaf holding one of them before the single walk would (none seen
// on the benchmark's rays; docs/HYBRID.md, "Packets").
//
// Why the cull is exact: a corner's sheared x for ray i is fl(fl(vx - ox_i) - fl(sx_i fl(vz -
// oz_i))) (kx, ky, kz shared by the packet). Every float operation is monotone, so the same
// operations on the lanes' extreme origin and shear values bound every lane's value, and when
// those bounds put all three corners at x > 0 (or x < 0, y > 0, y < 0), every lane's corners lie
// there as its test computes them. The test's edge functions have the exact signs of the
// sheared corners' (their float products are monotone, and an exactly zero difference is redone
// in double, where the products are exact), so the origin lies outside the triangle for every
// lane and the test finds their signs mixed: no lane can hit it.
//
// Rays from spread origins towards one point (shadow rays towards a point light) are bounded
// instead by where they cross one plane of the test's z axis, there their common end: each
// lane's sheared corner is, in exact arithmetic, the same expression with its crossing for its
// origin, so the packet is a pinhole's with its apex there. That bound is not made of the
// test's own operations, so it keeps a margin that covers their rounding (crossing_bounds).
#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstddef>
#include <cstring>

#include "accel/hybrid/hybrid.h"
#include "accel/hybrid/packet_lanes.h"

namespace kdgrid {

#if KDGRID_PACKET_LANES != 0

using namespace hybrid::packet_lanes;

namespace hybrid {

/// The packet's rays by lane: world-space origin, reciprocal direction and err (KdRay's), the
/// watertight test's ray data (its axes shared by the packet), and the points from which the
/// cull bounds every lane's sheared corners (CullBox): the origins on the test's axes, or where
/// the rays cross one plane of its z axis.
struct PacketRays {
  FloatLanes o[3], inv[3], err[3];
  FloatLanes ox, oy, oz, sx, sy, sz;
  FloatLanes tmin, tmax;  ///< the rays' (+inf and -inf in the lanes not in the packet)
  FloatLanes cx, cy, cz;  ///< the cull's points: (ox, oy, oz), or the crossings (crossing_bounds)
  int kx, ky, kz;
  bool neg[3];  ///< the packet's directions point down axis a
  /// How far inside a side the cull's bounds must put a corner: 0 for the origins, and for the
  /// crossings (crossing_bounds) a bound on the rounding their exact identity leaves out.
  float margin;
  bool crossings;   ///< the cull's points are the crossings (crossing_bounds), not the origins
  uint32_t missed;  ///< lanes whose ray misses the grid's box as the single walk clips it
  /// Lane i's WatertightTest::RayData (what prepare() gives: the same divisions).
  WatertightTest::RayData ray_data(int i) const {
    return {ox[i], oy[i], oz[i], kx, ky, kz, sx[i], sy[i], sz[i]};
  }
};

/// The lanes' closest hits so far (or, for any-hit queries, the lanes that found one).
struct PacketHits {
  FloatLanes best, u, v;
  IntLanes prim;
  uint32_t found = 0;
};

}  // namespace hybrid

namespace {

using hybrid::PacketHits;
using hybrid::PacketRays;

/// The lowest (_lo) and highest (_hi) of some lanes' cull points (x, y, z: PacketRays' cx, cy,
/// cz) and shears (sx, sy), and the packet's margin: the cull's bounds for those lanes.
struct CullBox {
  float x_lo, x_hi, y_lo, y_hi, z_lo, z_hi, sx_lo, sx_hi, sy_lo, sy_hi, margin;
};

/// The cull's bounds for the lanes m of a packet (those that reach a leaf).
[[gnu::always_inline]] inline CullBox cull_box(const PacketRays& packet, uint32_t m) {
  float lo[4], hi[4], zlo[4], zhi[4];
  lane_ranges(packet.cx, packet.cy, packet.sx, packet.sy, m, lo, hi);
  if (packet.crossings) {
    zlo[0] = zhi[0] = packet.cz[0];
  } else {
    lane_mins(packet.cz, -packet.cz, FloatLanes{}, FloatLanes{}, m, zlo);
    zhi[0] = -zlo[1];
  }
  return {lo[0], hi[0], lo[1], hi[1], zlo[0], zhi[0], lo[2], hi[2], lo[3], hi[3], packet.margin};
}

/// One triangle against the lanes `m` of the packet: WatertightTest::intersect's operations on
/// each lane (WatertightWide's, with the lanes as rays instead of triangles).
template <bool kAny>
[[gnu::always_inline]] inline void test_triangle(const PacketRays& packet, PacketHits& H,
                                                 const Vec3& v0, const Vec3& v1, const Vec3& v2,
                                                 uint32_t prim, uint32_t m) {
  const FloatLanes Az = splat(component(v0, packet.kz)) - packet.oz,
                   Bz = splat(component(v1, packet.kz)) - packet.oz,
                   Cz = splat(component(v2, packet.kz)) - packet.oz;
  const FloatLanes ax = (splat(component(v0, packet.kx)) - packet.ox) - packet.sx * Az,
                   ay = (splat(component(v0, packet.ky)) - packet.oy) - packet.sy * Az;
  const FloatLanes bx = (splat(component(v1, packet.kx)) - packet.ox) - packet.sx * Bz,
                   by = (splat(component(v1, packet.ky)) - packet.oy) - packet.sy * Bz;
  const FloatLanes cx = (splat(component(v2, packet.kx)) - packet.ox) - packet.sx * Cz,
                   cy = (splat(component(v2, packet.ky)) - packet.oy) - packet.sy * Cz;
  const FloatLanes U = cx * by - cy * bx;
  const FloatLanes V = ax * cy - ay * cx;
  const FloatLanes Wf = bx * ay - by * ax;
  const FloatLanes zero = {};
  const uint32_t zero_edge = eq(U, zero) | eq(V, zero) | eq(Wf, zero);
  const uint32_t mixed =
      (lt(U, zero) | lt(V, zero) | lt(Wf, zero)) & (lt(zero, U) | lt(zero, V) | lt(zero, Wf));
  if (((~mixed | zero_edge) & m) == 0) return;
  const FloatLanes det = U + V + Wf;
  const FloatLanes az = packet.sz * Az, bz = packet.sz * Bz, cz = packet.sz * Cz;
  const FloatLanes T = U * az + V * bz + Wf * cz;
  const FloatLanes inv_det = 1.0f / det;
  const FloatLanes t = T * inv_det;
  const uint32_t live = ~mixed & ne(det, zero);
  const uint32_t in_range = le(packet.tmin, t) & lt(t, H.best);  // false for NaN
  const uint32_t finite = eq(T - T, zero);                       // false for inf and NaN
  const uint32_t hit = live & in_range & ~zero_edge & m;
  const uint32_t slow = (zero_edge | (live & ~in_range & ~finite)) & m;
  if ((hit | slow) == 0) [[likely]]
    return;
  H.found |= hit;
  if constexpr (!kAny) {
    H.best = blend(H.best, hit, t);
    H.u = blend(H.u, hit, V * inv_det);
    H.v = blend(H.v, hit, Wf * inv_det);
    H.prim = blend(H.prim, hit, IntLanes{} + int32_t(prim));
  }
  for (uint32_t s = slow; s != 0; s &= s - 1) {
    const int i = __builtin_ctz(s);
    float ts, us, vs;
    if (WatertightTest::intersect(packet.ray_data(i), v0, v1, v2, packet.tmin[i], H.best[i], ts, us,
                                  vs)) {
      H.found |= 1u << i;
      if constexpr (!kAny) {
        H.best[i] = ts;
        H.u[i] = us;
        H.v[i] = vs;
        H.prim[i] = int32_t(prim);
      }
    }
  }
}

/// Bounds of every lane's sheared x and y of W corners (coordinates vx, vy, vz on the test's
/// axes) among `box`'s lanes: the same operations on their extreme origins or crossings and
/// shears (see the file's comment).
template <class F>
[[gnu::always_inline]] inline void corner_bounds(const CullBox& box, F vx, F vy, F vz, F& xl, F& xh,
                                                 F& yl, F& yh) {
  const F dzl = vz - box.z_hi, dzh = vz - box.z_lo;
  const auto range = [&](float sl, float sh, F& lo, F& hi) __attribute__((always_inline)) {
    const F p1 = sl * dzl, p2 = sl * dzh, p3 = sh * dzl, p4 = sh * dzh;
    const F l12 = p1 < p2 ? p1 : p2, l34 = p3 < p4 ? p3 : p4;
    const F h12 = p1 > p2 ? p1 : p2, h34 = p3 > p4 ? p3 : p4;
    lo = l12 < l34 ? l12 : l34;
    hi = h12 > h34 ? h12 : h34;
  };
  F pxl, pxh, pyl, pyh;
  range(box.sx_lo, box.sx_hi, pxl, pxh);
  range(box.sy_lo, box.sy_hi, pyl, pyh);
  xl = (vx - box.x_hi) - pxh, xh = (vx - box.x_lo) - pxl;
  yl = (vy - box.y_hi) - pyh, yh = (vy - box.y_lo) - pyl;
}

/// Codes of the 8 corners of a shared-corner group's table half (groups of 8; their coordinates
/// on the test's axes from tx, ty, tz on, the first `left` of them read, the others 0), as
/// corner_codes codes 16.
[[gnu::always_inline, maybe_unused]] inline WideVectors<8>::I corner_codes8(
    const CullBox& box, const float* tx, const float* ty, const float* tz, int32_t left) {
  using F = WideVectors<8>::F;
  const __m256i in =
      _mm256_cmpgt_epi32(_mm256_set1_epi32(left), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
  F xl, xh, yl, yh;
  corner_bounds(box, (F)_mm256_maskload_ps(tx, in), (F)_mm256_maskload_ps(ty, in),
                (F)_mm256_maskload_ps(tz, in), xl, xh, yl, yh);
  const F m = F{} + box.margin, neg_m = -m;
  return ((m < xl) & 1) | ((xh < neg_m) & 2) | ((m < yl) & 4) | ((yh < neg_m) & 8);
}

/// uncull() of a shared-corner group of 8 lanes: the codes of its table's two halves, each
/// lane's three codes taken from them by permutes and a blend (as SharedCornerGroup::sheared8
/// takes its corners).
[[gnu::always_inline, maybe_unused]] inline uint32_t uncull8(const PacketRays& packet,
                                                             const CullBox& box,
                                                             const hybrid::SharedCornerGroup& g) {
  using I = WideVectors<8>::I;
  const float* const tx = g.p + 1 + uint32_t(packet.kx) * g.u;
  const float* const ty = g.p + 1 + uint32_t(packet.ky) * g.u;
  const float* const tz = g.p + 1 + uint32_t(packet.kz) * g.u;
  const __m256i lo = (__m256i)corner_codes8(box, tx, ty, tz, int32_t(g.u));
  const __m256i hi = g.u > 8 ? (__m256i)corner_codes8(box, tx + 8, ty + 8, tz + 8, int32_t(g.u) - 8)
                             : _mm256_setzero_si256();
  I all = ~I{};
  for (int k = 0; k < 3; ++k) {
    __m256i ik;
    __m256 upper;
    g.lane_index8(k, ik, upper);
    all &= (I)_mm256_castps_si256(
        _mm256_blendv_ps(_mm256_castsi256_ps(_mm256_permutevar8x32_epi32(lo, ik)),
                         _mm256_castsi256_ps(_mm256_permutevar8x32_epi32(hi, ik)), upper));
  }
  return WatertightWide<8>::bits(all == 0) & ((1u << g.n) - 1);
}

#if KDGRID_PACKET_LANES == 16
/// Codes of 16 of a shared-corner group's corners (their coordinates on the test's axes from tx,
/// ty, tz on; the lanes `corners`): bit 1, 2, 4, 8 set where every lane of the packet sees the
/// corner at x > 0, x < 0, y > 0, y < 0 in its shear space (bounds from the packet's extreme
/// origins or crossings and shears in `box`, beyond its margin; see the file's comment).
[[gnu::always_inline]] inline __m512i corner_codes(const CullBox& box, const float* tx,
                                                   const float* ty, const float* tz,
                                                   __mmask16 corners) {
  FloatLanes xl, xh, yl, yh;
  corner_bounds(box, (FloatLanes)_mm512_maskz_loadu_ps(corners, tx),
                (FloatLanes)_mm512_maskz_loadu_ps(corners, ty),
                (FloatLanes)_mm512_maskz_loadu_ps(corners, tz), xl, xh, yl, yh);
  const FloatLanes m = splat(box.margin), neg_m = -m;
  const __m512i one = _mm512_set1_epi32(1);
  __m512i c = _mm512_maskz_mov_epi32(__mmask16(lt(m, xl)), one);
  c = _mm512_or_si512(c, _mm512_maskz_mov_epi32(__mmask16(lt(xh, neg_m)), _mm512_set1_epi32(2)));
  c = _mm512_or_si512(c, _mm512_maskz_mov_epi32(__mmask16(lt(m, yl)), _mm512_set1_epi32(4)));
  c = _mm512_or_si512(c, _mm512_maskz_mov_epi32(__mmask16(lt(yh, neg_m)), _mm512_set1_epi32(8)));
  return c;
}

/// uncull() of a shared-corner group of 16 lanes.
[[gnu::always_inline, maybe_unused]] inline uint32_t uncull16(const PacketRays& packet,
                                                              const CullBox& box,
                                                              const hybrid::SharedCornerGroup& g) {
  const float* const tx = g.p + 1 + uint32_t(packet.kx) * g.u;
  const float* const ty = g.p + 1 + uint32_t(packet.ky) * g.u;
  const float* const tz = g.p + 1 + uint32_t(packet.kz) * g.u;
  const uint32_t corners = g.u >= 32 ? ~0u : (1u << g.u) - 1;
  const __m512i lo = corner_codes(box, tx, ty, tz, __mmask16(corners));
  const __m512i hi = g.u > 16
                         ? corner_codes(box, tx + 16, ty + 16, tz + 16, __mmask16(corners >> 16))
                         : _mm512_setzero_si512();
  const uint32_t lanes = (1u << g.n) - 1;
  const uint8_t* idx = g.index();
  __m512i all = _mm512_set1_epi32(-1);
  for (uint32_t k = 0; k < 3; ++k) {
    const __m512i ik = _mm512_maskz_cvtepu8_epi32(
        __mmask16(lanes), _mm_maskz_loadu_epi8(__mmask16(lanes), idx + k * g.n));
    all = _mm512_and_si512(all, _mm512_permutex2var_epi32(lo, ik, hi));
  }
  return uint32_t(_mm512_testn_epi32_mask(all, all)) & lanes;
}
#endif

/// The lanes of a shared-corner group that some ray of `box`'s lanes may hit: those whose three
/// corners do not all share a side that every such ray sees them on. (One of the two uncull()s
/// is unused: the one for the layout the build does not store.)
[[gnu::always_inline, maybe_unused]] inline uint32_t uncull(const PacketRays& packet,
                                                            const CullBox& box,
                                                            const hybrid::SharedCornerGroup& g) {
#if KDGRID_PACKET_LANES == 16
  if constexpr (kWideLanes == 16) return uncull16(packet, box, g);
#endif
  return uncull8(packet, box, g);
}

/// The lanes of a group stored by lane that some ray of `box`'s lanes may hit: each of its three
/// corners coded as corner_codes codes a shared corner (in W-lane vectors of integer flags), and
/// the lanes whose three codes share no bit.
[[gnu::always_inline, maybe_unused]] inline uint32_t uncull(const PacketRays& packet,
                                                            const CullBox& box,
                                                            const hybrid::LaneGroup& g) {
  constexpr int W = kWideLanes >= 4 ? kWideLanes : 4;  // packets_ready(): kWideLanes >= 4
  using F = typename WideVectors<W>::F;
  using I = typename WideVectors<W>::I;
  const F m = F{} + box.margin, neg_m = -m;
  I all = ~I{};
  for (int k = 0; k < 3; ++k) {
    F vx, vy, vz, xl, xh, yl, yh;
    std::memcpy(&vx, g.p + (3 * k + packet.kx) * W, sizeof vx);
    std::memcpy(&vy, g.p + (3 * k + packet.ky) * W, sizeof vy);
    std::memcpy(&vz, g.p + (3 * k + packet.kz) * W, sizeof vz);
    corner_bounds(box, vx, vy, vz, xl, xh, yl, yh);
    all &= ((m < xl) & 1) | ((xh < neg_m) & 2) | ((m < yl) & 4) | ((yh < neg_m) & 8);
  }
  return WatertightWide<W>::bits(all == 0) & ((1u << g.n) - 1);
}

/// The packet walk takes rays whose origins, or crossings (crossing_bounds), lie at most this
/// many cells apart along each axis. The cull bounds every ray's view of a corner by their box,
/// so a wider box keeps most triangles and the packet walk is slower than the single walk
/// (docs/EXPERIMENTS.md, "Packets"). A pinhole camera's rays share their origin; shadow rays
/// towards one point light cross where they end.
constexpr double kPacketSpreadCells = 1.0;

/// A leaf reached by at most this many lanes of a packet tests them lane by lane, each against
/// its groups by the single walk's group test (PacketWalk::groups).
constexpr int kLaneGroupLanes = 4;

/// The cull's bounds of the `lanes` of a packet from spread origins by where their rays cross the
/// plane z = z0 of the test's axes: lane i's crossing is x_i = ox_i + sx_i (z0 - oz_i) (y_i
/// likewise), and in exact arithmetic its sheared corner x is (vx - x_i) - sx_i (vz - z0), which
/// the cull bounds as it bounds the origins' box, z0 in place of the origins' z. z0 is the far
/// end of the lanes' segments (`lo`, `hi`: the origins' box on axes 0 to 2, the ends' range on
/// the test's z axis in 3): for rays towards one point, their common end, where their
/// crossings meet. Parallel rays cross any plane as far apart as their origins' projections;
/// where an end is not finite, z0 is the middle of the origins. The margin bounds what the
/// identity leaves out: the rounding of the crossings, of the test's sheared corners and of
/// the cull's own operations, under 28 units of 2^-24 of the largest coordinate M (the
/// corners', origins' and z0's, the shears at most 1 in magnitude), and the margin is M 2^-18
/// (64 such units), plus FLT_MIN for underflow. Takes these bounds when the crossings' box,
/// widened by the margin, is narrower than `spread` (the origins') and within max_spread.
bool crossing_bounds(PacketRays& packet, uint32_t lanes, const float (&lo)[4], const float (&hi)[4],
                     float max_abs, float spread, float max_spread) {
  const int kz = packet.kz;
  const float far = packet.neg[kz] ? lo[3] : hi[3];
  const float z0 = std::fabs(far) <= kMaxRayCoordinate ? far : 0.5f * (lo[kz] + hi[kz]);
  const FloatLanes dz = splat(z0) - packet.oz;
  const FloatLanes cx = packet.ox + packet.sx * dz, cy = packet.oy + packet.sy * dz;
  float cl[4], ch[4];  // the crossings' x and y
  lane_ranges(cx, cy, FloatLanes{}, FloatLanes{}, lanes, cl, ch);
  float m = std::max(max_abs, std::fabs(z0));
  for (int a = 0; a < 3; ++a) m = std::max({m, std::fabs(lo[a]), std::fabs(hi[a])});
  const float margin = m * 0x1p-18f + FLT_MIN;
  const float width = std::max(ch[0] - cl[0], ch[1] - cl[1]) + 2.0f * margin;
  if (!(width < spread && width <= max_spread)) return false;
  packet.crossings = true;
  packet.margin = margin;
  packet.cx = cx, packet.cy = cy, packet.cz = splat(z0);
  return true;
}

/// Sets up `packet` for rays i < n of `rays` (n <= kPacketLanes) and returns the lanes that join
/// the packet: rays valid as ray_is_valid says, with tmin >= 0 and every direction component a
/// normal number (finite reciprocals and err), sharing the first one's direction signs and the
/// watertight test's axes; none when neither their origins' box nor their crossings'
/// (crossing_bounds) lies within max_spread along each axis. The others take the single walk,
/// except those that miss the grid's `box` as the single walk clips them (packet.missed),
/// which miss.
uint32_t prepare_packet(const Ray* rays, int n, float max_abs, const ClipBox4& box,
                        float max_spread, PacketRays& packet) {
  FloatLanes f[8];
  load_rays(rays, n, f);
  const FloatLanes o[3] = {f[0], f[1], f[2]}, d[3] = {f[4], f[5], f[6]};
  const FloatLanes tmin = f[3], tmax = f[7];
  const FloatLanes zero = {}, big = splat(kMaxRayCoordinate), tiny = splat(FLT_MIN);
  FloatLanes ao[3], ad[3];
  uint32_t ok = le(zero, tmin) & le(tmin, tmax) & lt(tmin, splat(kInf));
  for (int a = 0; a < 3; ++a) {
    ao[a] = vabs(o[a]);
    ad[a] = vabs(d[a]);
    ok &= le(ao[a], big) & le(ad[a], big) & le(tiny, ad[a]);
  }
  uint32_t lanes = ok & ((1u << n) - 1);
  packet.missed = 0;
  if (lanes == 0) return 0;
  // The single walk's first step (walk_begin's kd_begin): [tmin, tmax] clipped to the grid's
  // box, each slab widened by err; the rays it rejects miss, whatever their packet.
  const FloatLanes one = splat(1.0f);
  const FloatLanes err_scale =
      vmax(vmax(ao[0], vmax(ao[1], ao[2])), splat(max_abs)) * splat(0x1p-20f);
  FloatLanes t0 = tmin, t1 = tmax;
  for (int a = 0; a < 3; ++a) {
    packet.inv[a] = one / d[a];
    packet.err[a] = err_scale * vabs(packet.inv[a]);
    const FloatLanes tl = (splat(box.lo[a]) - o[a]) * packet.inv[a],
                     th = (splat(box.hi[a]) - o[a]) * packet.inv[a];
    t0 = vmax(t0, vmin(tl, th) - packet.err[a]);
    t1 = vmin(t1, vmax(tl, th) + packet.err[a]);
  }
  packet.missed = lt(t1, t0) & lanes;
  lanes &= ~packet.missed;
  if (lanes == 0) return 0;
  // max_dimension's axis: the first largest component.
  const uint32_t k0 = lt(ad[1], ad[0]) & lt(ad[2], ad[0]);
  const uint32_t k1 = ~k0 & lt(ad[2], ad[1]);
  const uint32_t kz_of[3] = {k0, k1, ~(k0 | k1)};
  const int first = __builtin_ctz(lanes);
  packet.kz = (k0 >> first & 1u) ? 0 : (k1 >> first & 1u) ? 1 : 2;
  lanes &= kz_of[packet.kz];
  for (int a = 0; a < 3; ++a) {
    const uint32_t neg = lt(d[a], zero);
    packet.neg[a] = neg >> first & 1u;
    lanes &= packet.neg[a] ? neg : ~neg;
  }
  packet.kx = packet.kz == 2 ? 0 : packet.kz + 1;
  packet.ky = packet.kx == 2 ? 0 : packet.kx + 1;
  if (packet.neg[packet.kz]) std::swap(packet.kx, packet.ky);  // WatertightTest::prepare's
  for (int a = 0; a < 3; ++a) {
    packet.o[a] = o[a];
    lanes &= le(packet.err[a], splat(FLT_MAX));
  }
  packet.ox = o[packet.kx], packet.oy = o[packet.ky], packet.oz = o[packet.kz];
  packet.sx = d[packet.kx] / d[packet.kz], packet.sy = d[packet.ky] / d[packet.kz],
  packet.sz = packet.inv[packet.kz];  // prepare()'s 1 / d
  packet.tmin = blend(splat(kInf), lanes, tmin);
  packet.tmax = blend(splat(-kInf), lanes, tmax);
  // The origins' box and the ends' range on the test's z axis (of these lanes: bounds for any
  // of them). Spread origins are bounded by their crossings where those lie closer together;
  // a packet bounded by neither within max_spread is left to the single walk.
  float lo[4], hi[4];
  lane_ranges(o[0], o[1], o[2], packet.oz + tmax * d[packet.kz], lanes, lo, hi);
  const float spread = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  if (spread > 0.0f && crossing_bounds(packet, lanes, lo, hi, max_abs, spread, max_spread))
    return lanes;
  if (!(spread <= max_spread)) return 0;
  packet.crossings = false;
  packet.margin = 0.0f;
  packet.cx = packet.ox, packet.cy = packet.oy, packet.cz = packet.oz;
  return lanes;
}

}  // namespace

template <bool kAny>
void GridKdHybrid::packet_call(const Ray* rays, int n, Hit* hits, bool* out) const {
  // Up to four packets of L set up; those of two rays or more that share the first one's
  // direction signs walk together, then those that share the next one's, and so on.
  constexpr int L = hybrid::kPacketLanes;
  PacketRays packets[4];
  uint32_t lanes[4] = {0, 0, 0, 0};
  const int parts = (n + L - 1) / L;
  // The rays of the later packets requested at once (two rays a line), so that their loads do
  // not wait for the first packet's set-up.
  for (int i = L; i < n; i += 2) __builtin_prefetch(rays + i);
  for (int k = 0; k < parts; ++k) {
    lanes[k] = prepare_packet(rays + L * k, std::min(L, n - L * k), max_abs_, world_clip_,
                              float(kPacketSpreadCells * cell_), packets[k]);
    if ((lanes[k] & (lanes[k] - 1)) == 0) lanes[k] = 0;
  }
  uint32_t walked[4] = {0, 0, 0, 0};
  for (int lead = 0; lead < parts; ++lead) {
    if (lanes[lead] == 0 || walked[lead] != 0) continue;
    int which[4] = {0, 0, 0, 0}, count = 0;
    for (int k = lead; k < parts; ++k)
      if (lanes[k] != 0 && walked[k] == 0 && packets[k].neg[0] == packets[lead].neg[0] &&
          packets[k].neg[1] == packets[lead].neg[1] && packets[k].neg[2] == packets[lead].neg[2])
        which[count++] = k;
    const bool done = count == 4   ? packet_walk<kAny, 4>(packets, lanes, which, hits, out)
                      : count == 3 ? packet_walk<kAny, 3>(packets, lanes, which, hits, out)
                      : count == 2 ? packet_walk<kAny, 2>(packets, lanes, which, hits, out)
                                   : packet_walk<kAny, 1>(packets, lanes, which, hits, out);
    if (!done) continue;
    for (int j = 0; j < count; ++j) walked[which[j]] = lanes[which[j]];
  }
  for (int i = 0; i < n; ++i) {
    const uint32_t bit = 1u << (i % L);
    if (packets[i / L].missed & bit)
      out[i] = false;
    else if (!(walked[i / L] & bit))
      out[i] = kAny ? occluded(rays[i]) : intersect(rays[i], hits[i]);
  }
}

/// One walk of packet_walk: its K packets, their hits and live lanes, and the walk's steps, each
/// inlined into packet_walk (the steps read as one loop; out of line, each would pay a call and
/// the packets' state in memory).
template <bool kAny, int K>
struct GridKdHybrid::PacketWalk {
  /// Each packet's [t0, t1] in a node.
  struct Span {
    FloatLanes t0[K], t1[K];
  };
  struct Entry {
    uint32_t node;
    Span s;
  };
  /// Deep enough for the leaves' subtrees (at most kKdMaxDepth levels); a deeper grid tree
  /// gives its packets to the single walk.
  static constexpr int kStack = kKdMaxDepth + 4;

  const GridKdHybrid& g;
  const PacketRays* packets[K];  ///< the packets of the walk (at most 4), each its rays
  PacketHits H[K];               ///< and its hits
  uint32_t alive[K];             ///< lanes still walking: any-hit lanes leave at their first hit
  const bool* neg;               ///< the packets' direction signs (shared)

  [[gnu::always_inline]] PacketWalk(const GridKdHybrid& grid, const PacketRays* call_packets,
                                    const uint32_t* lanes_of, const int* which)
      : g(grid) {
    for (int k = 0; k < K; ++k) {
      packets[k] = &call_packets[which[k]];
      H[k].best = packets[k]->tmax;
      H[k].u = H[k].v = FloatLanes{};
      H[k].prim = IntLanes{} + int32_t(kInvalidPrim);
      alive[k] = lanes_of[which[k]];
    }
    neg = packets[0]->neg;
  }

  /// The triangles `tris` of group gr against each lane of m of packet k by the single walk's
  /// group test (WatertightWide: the group's triangles against one ray); returns m less the
  /// lanes an any-hit query retires.
  [[gnu::always_inline]] uint32_t lane_group(int k, const hybrid::GroupView& gr, uint32_t tris,
                                             uint32_t m) {
    const PacketRays& r = *packets[k];
    PacketHits& h = H[k];
    for (uint32_t left = m; left != 0; left &= left - 1) {
      const int i = __builtin_ctz(left);
      float t, u, v;
      const int j = WatertightWide<kWideLanes>::intersect(r.ray_data(i), gr, tris, r.tmin[i],
                                                          h.best[i], t, u, v);
      if (j < 0) continue;
      h.found |= 1u << i;
      if constexpr (kAny) {
        alive[k] &= ~(1u << i);
        m &= ~(1u << i);
      } else {
        h.best[i] = t;
        h.u[i] = u;
        h.v[i] = v;
        h.prim[i] = int32_t(gr.prim(uint32_t(j)));
      }
    }
    return m;
  }

  /// The groups of a leaf for the lanes m of packet k (those that reach the leaf). Each group is
  /// culled against those lanes' bounds, then its triangles left are tested one at a time
  /// against the lanes, or, where they outnumber the lanes, each lane is tested against them by
  /// the group test; with kLaneGroupLanes lanes or fewer every group goes to the group test
  /// uncut, as the cull would cost about what it saves.
  [[gnu::always_inline]] void groups(int k, uint32_t first, uint32_t count, uint32_t m) {
    const PacketRays& r = *packets[k];
    PacketHits& h = H[k];
    const bool by_lane = __builtin_popcount(m) <= kLaneGroupLanes;
    const CullBox box = by_lane ? CullBox{} : cull_box(r, m);
    const float* p = g.groups_[0].f + first;
    for (uint32_t left = count; left != 0;) {
      const hybrid::GroupView gr = hybrid::GroupView::at(p, left);
      p = gr.end();
      left -= gr.n;
      if (by_lane) {
        m = lane_group(k, gr, (1u << gr.n) - 1, m);
        if (m == 0) return;
        continue;
      }
      uint32_t keep = uncull(r, box, gr);
      if (__builtin_popcount(keep) > __builtin_popcount(m)) {
        m = lane_group(k, gr, keep, m);
        if (m == 0) return;
        continue;
      }
      for (; keep != 0; keep &= keep - 1) {
        const int i = __builtin_ctz(keep);
        test_triangle<kAny>(r, h, gr.corner(0, i), gr.corner(1, i), gr.corner(2, i),
                            gr.prim(uint32_t(i)), m);
        if constexpr (kAny) {
          m &= ~h.found;
          alive[k] &= ~h.found;
          if (m == 0) return;
        }
      }
    }
  }
  /// The lanes of packet k that still have something to find in [t0, t1].
  [[gnu::always_inline]] uint32_t active(int k, const FloatLanes& t0, const FloatLanes& t1) const {
    uint32_t m = le(t0, t1) & alive[k];
    if constexpr (!kAny) m &= le(t0, H[k].best);
    return m;
  }
  [[gnu::always_inline]] bool any_active(const Span& s) const {
    uint32_t m = 0;
    for (int k = 0; k < K; ++k) m |= active(k, s.t0[k], s.t1[k]);
    return m != 0;
  }
  /// A leaf's triangles (groups from `first`, `count` triangles) for every packet with lanes in
  /// it: the groups' first lines requested at once (up to hybrid::kFlatPrefetchLines), as the
  /// packets would otherwise wait for the header, then the corners, of each in turn.
  [[gnu::always_inline]] void leaf(uint32_t first, uint32_t count, const Span& s) {
    const char* p = reinterpret_cast<const char*>(g.groups_[0].f + first);
    const uint32_t lines = std::min<uint32_t>(hybrid::kFlatPrefetchLines, (count * 48 + 127) / 64);
    for (uint32_t l = 0; l < lines; ++l) __builtin_prefetch(p + 64 * l);
    for (int k = 0; k < K; ++k) {
      const uint32_t m = active(k, s.t0[k], s.t1[k]);
      if (m != 0) groups(k, first, count, m);
    }
  }
  /// Each packet's [t0, t1] clipped to a box (each slab widened by err, as kd_clip).
  [[gnu::always_inline]] void clip(const float* lo, const float* hi, Span& s) const {
    for (int k = 0; k < K; ++k)
      for (int a = 0; a < 3; ++a) {
        const FloatLanes tl = (splat(lo[a]) - packets[k]->o[a]) * packets[k]->inv[a];
        const FloatLanes th = (splat(hi[a]) - packets[k]->o[a]) * packets[k]->inv[a];
        const FloatLanes near = packets[k]->neg[a] ? th : tl, far = packets[k]->neg[a] ? tl : th;
        s.t0[k] = vmax(s.t0[k], near - packets[k]->err[a]);
        s.t1[k] = vmin(s.t1[k], far + packets[k]->err[a]);
      }
  }
  /// A split on axis a at `plane`: whether the packets go to the near side, to the far side or
  /// both (then `far` gets the far side's t's and s keeps the near side's).
  [[gnu::always_inline]] void split(int a, float plane, Span& s, Span& far, bool& to_near,
                                    bool& to_far) const {
    uint32_t need_near = 0, need_far = 0;
    FloatLanes ts[K];
    for (int k = 0; k < K; ++k) {
      ts[k] = (splat(plane) - packets[k]->o[a]) * packets[k]->inv[a];
      const uint32_t m = active(k, s.t0[k], s.t1[k]);
      need_near |= le(s.t0[k], ts[k] + packets[k]->err[a]) & m;
      const FloatLanes far_t0 = ts[k] - packets[k]->err[a];
      uint32_t far_lanes = le(far_t0, s.t1[k]) & m;
      // Not for the lanes whose closest hit lies before the far side.
      if constexpr (!kAny) far_lanes &= le(far_t0, H[k].best);
      need_far |= far_lanes;
    }
    to_near = need_near != 0;
    to_far = need_far != 0;
    if (to_near && to_far)
      for (int k = 0; k < K; ++k) {
        far.t0[k] = vmax(s.t0[k], ts[k] - packets[k]->err[a]);
        far.t1[k] = s.t1[k];
        s.t1[k] = vmin(s.t1[k], ts[k] + packets[k]->err[a]);
      }
  }
  /// Pops the next entry of `st` whose span has lanes left into node and s; false once none is.
  [[gnu::always_inline]] bool pop(Entry* st, int& sp, uint32_t& node, Span& s) const {
    do {
      if (sp == 0) return false;
      --sp;
      node = st[sp].node;
      s = st[sp].s;
    } while (!any_active(s));
    return true;
  }

  /// A leaf's kd subtree, walked by the packets from its box on (`stack`: kStack entries).
  [[gnu::always_inline]] void subtree(uint32_t root, Span s, Entry* stack) {
    const KdNode* nodes = g.sub_nodes_.data();
    const float* box = reinterpret_cast<const float*>(nodes + root);
    clip(box, box + 4, s);
    if (!any_active(s)) return;
    int sp = 0;
    uint32_t node = root + kSubBoxNodes;
    for (;;) {
      const KdNode& nd = nodes[node];
      if (!nd.leaf()) {
        const int a = nd.axis();
        const uint32_t below = node + 1, above = nd.above();
        bool to_near, to_far;
        split(a, nd.split, s, stack[sp].s, to_near, to_far);
        const uint32_t near = neg[a] ? above : below, far = neg[a] ? below : above;
        if (to_near && to_far) stack[sp++].node = far;
        node = to_near ? near : far;
        if (to_near || to_far) continue;
      } else if (nd.count() != 0) {
        leaf(nd.prim_offset, nd.count(), s);
      }
      if (!pop(stack, sp, node, s)) return;
    }
  }

  /// A flat subtree: its leaves in the kd walk's order for the packets' octant.
  [[gnu::always_inline]] void flat(uint32_t at, Span s) {
    const float* fb = g.flat_subtree_floats_[0].f + at;
    clip(fb, fb + 4, s);
    if (!any_active(s)) return;
    uint32_t count;
    std::memcpy(&count, fb + 8, sizeof count);
    const float* q = fb + 16;
    const uint32_t oct = uint32_t(neg[0]) | uint32_t(neg[1]) << 1 | uint32_t(neg[2]) << 2;
    const uint8_t* order = reinterpret_cast<const uint8_t*>(q + 8 * count) + oct * count;
    // The leaves some packet meets, with their t's, in that order; their groups requested
    // before the first is tested (as walk_flat does).
    Span met[hybrid::kFlatLeaves];
    uint32_t met_leaf[hybrid::kFlatLeaves], n_met = 0;
    for (uint32_t j = 0; j < count; ++j) {
      const uint32_t i = order[j];
      const float lo[3] = {q[i], q[count + i], q[2 * count + i]};
      const float hi[3] = {q[3 * count + i], q[4 * count + i], q[5 * count + i]};
      met[n_met] = s;
      clip(lo, hi, met[n_met]);
      if (!any_active(met[n_met])) continue;
      uint32_t first;  // stored as floats' bits (records.h)
      std::memcpy(&first, q + 6 * count + i, sizeof first);
      const char* p = reinterpret_cast<const char*>(g.groups_[0].f + first);
      for (int l = 0; l < hybrid::kFlatPrefetchLines; ++l) __builtin_prefetch(p + 64 * l);
      met_leaf[n_met++] = i;
    }
    for (uint32_t j = 0; j < n_met; ++j) {
      const uint32_t i = met_leaf[j];
      uint32_t first, n;
      std::memcpy(&first, q + 6 * count + i, sizeof first);
      std::memcpy(&n, q + 7 * count + i, sizeof n);
      for (int k = 0; k < K; ++k) {
        const uint32_t m = active(k, met[j].t0[k], met[j].t1[k]);
        if (m != 0) groups(k, first, n, m);
      }
    }
  }

  /// The grid's kd-tree from its root, the packets clipped to the grid's box first; false when
  /// its stack would overflow.
  [[gnu::always_inline]] bool walk() {
    Span s;
    for (int k = 0; k < K; ++k) {
      s.t0[k] = packets[k]->tmin;
      s.t1[k] = packets[k]->tmax;
    }
    {
      const float lo[3] = {g.world_box_.lo.x, g.world_box_.lo.y, g.world_box_.lo.z};
      const float hi[3] = {g.world_box_.hi.x, g.world_box_.hi.y, g.world_box_.hi.z};
      clip(lo, hi, s);
    }
    Entry top[kStack], stack[kStack];  // the grid tree's and the leaf subtrees'
    int sp = 0;
    uint32_t node = 0;
    bool walking = any_active(s);
    while (walking) {
      const Node& nd = g.nodes_[node];
      if (nd.axis != 3) {
        const int a = int(nd.axis);
        if (sp == kStack) return false;
        bool to_near, to_far;
        split(a, float(g.origin_[a] + double(nd.split) * g.cell_), s, top[sp].s, to_near, to_far);
        const uint32_t below = node + 1, above = nd.right;
        const uint32_t near = neg[a] ? above : below, far = neg[a] ? below : above;
        if (to_near && to_far) top[sp++].node = far;
        node = to_near ? near : far;
        if (to_near || to_far) continue;
      } else {
        const Leaf& L = g.leaves_[uint32_t(nd.split)];
        uint32_t flat_at;
        std::memcpy(&flat_at, &L.pad, sizeof flat_at);
        if (hybrid::kFlatSubtrees && flat_at != 0) {
          flat(flat_at, s);
        } else if (L.count & kSubtreeFlag) {
          subtree(L.first, s, stack);
        } else if (L.count != 0) {
          leaf(L.first, L.count, s);
        }
      }
      walking = pop(top, sp, node, s);
    }
    return true;
  }

  /// Each packet's answers to its rays' places in hits and out.
  [[gnu::always_inline]] void store(const uint32_t* lanes_of, const int* which, Hit* hits,
                                    bool* out) const {
    for (int k = 0; k < K; ++k) {
      const int base = hybrid::kPacketLanes * which[k];
      const uint32_t lanes = lanes_of[which[k]], found = H[k].found & lanes;
      store_found(lanes, found, out + base);
      if constexpr (!kAny) store_hits(H[k].best, H[k].prim, H[k].u, H[k].v, found, hits + base);
    }
  }
};

template <bool kAny, int K>
bool GridKdHybrid::packet_walk(const hybrid::PacketRays* call_packets, const uint32_t* lanes_of,
                               const int* which, Hit* hits, bool* out) const {
  PacketWalk<kAny, K> w(*this, call_packets, lanes_of, which);
  if (!w.walk()) return false;
  w.store(lanes_of, which, hits, out);
  return true;
}

GridKdHybrid::PacketCull GridKdHybrid::packet_cull(const Ray* rays, int n) const {
  if (!packets_ready() || n < 1) return PacketCull::Single;
  PacketRays packet;
  const uint32_t lanes = prepare_packet(rays, std::min(hybrid::kPacketLanes, n), max_abs_,
                                        world_clip_, float(kPacketSpreadCells * cell_), packet);
  if ((lanes & (lanes - 1)) == 0) return PacketCull::Single;
  return packet.crossings ? PacketCull::Crossings : PacketCull::Origins;
}

void GridKdHybrid::intersect_packet(const Ray* rays, int n, Hit* hits, bool* found) const {
  if (!packets_ready()) return Accelerator::intersect_packet(rays, n, hits, found);
  constexpr int kCall = 4 * hybrid::kPacketLanes;
  for (int b = 0; b < n; b += kCall)
    packet_call<false>(rays + b, std::min(kCall, n - b), hits + b, found + b);
}

void GridKdHybrid::occluded_packet(const Ray* rays, int n, bool* occluded_out) const {
  if (!packets_ready()) return Accelerator::occluded_packet(rays, n, occluded_out);
  constexpr int kCall = 4 * hybrid::kPacketLanes;
  for (int b = 0; b < n; b += kCall)
    packet_call<true>(rays + b, std::min(kCall, n - b), nullptr, occluded_out + b);
}

#else

GridKdHybrid::PacketCull GridKdHybrid::packet_cull(const Ray*, int) const {
  return PacketCull::Single;
}

void GridKdHybrid::intersect_packet(const Ray* rays, int n, Hit* hits, bool* found) const {
  Accelerator::intersect_packet(rays, n, hits, found);
}

void GridKdHybrid::occluded_packet(const Ray* rays, int n, bool* occluded_out) const {
  Accelerator::occluded_packet(rays, n, occluded_out);
}

#endif

int GridKdHybrid::packet_width() const {
  return packets_ready() ? 4 * hybrid::kPacketLanes : 1;
}

}  // namespace kdgrid
