// The hybrid's records: the tree's nodes, the leaves the walk steps over, the leaves' kd boxes
// and the leaves' triangle groups (accel/hybrid/hybrid.h holds them; docs/HYBRID.md explains them).
#pragma once

#include <cstdint>
#include <cstring>
#include <type_traits>
#if defined(__AVX2__)
#include <immintrin.h>
#endif

#include "accel/triangle_wide.h"
#include "math/vec.h"

namespace kdgrid::hybrid {

/// Tree node, kept for the cell map's node entries, its construction and split walks
/// (for_each_split); leaves point into the leaf array.
struct Node {
  int32_t split;   ///< interior: the split boundary (cell index); leaf: leaf id
  uint32_t right;  ///< interior: index of the right child (left child = this + 1)
  uint32_t axis;   ///< 0..2 interior, 3 leaf
};

/// Leaf: an integer cell box [lo, hi), where its triangle groups start (a float offset into
/// GridKdHybrid::groups_, "Triangle groups" below) and its triangle count. 64 bytes.
/// The box is the one the walk steps over: the kd leaf's box, or for an empty leaf that
/// box widened over empty cells (widen.cpp).
struct alignas(64) Leaf {
  /// The step box in cells: whole numbers, held as doubles so that the walk's exit reads
  /// them with no conversion (7 per step; one cache line per leaf all the same). lo and hi
  /// each start a 32-byte half of the line, so that the walk reads each as four lanes (the
  /// fourth: first/count's bits after lo, `pad` after hi; see leaf_exit in walk.h).
  double lo[3];
  uint32_t first, count;
  double hi[3];
  /// Low 32 bits: the float offset of the leaf's flat subtree in GridKdHybrid::flat_subtree_floats_
  /// (0: none; "Flat subtrees" below); high 32 bits 0, so that as the fourth lane of hi it is a
  /// tiny number that the walk's exit ignores.
  double pad;
};

/// Leaf::count bit: `first` is the root of the leaf's kd subtree in the subtree node array (whose
/// leaves hold their first group and triangle count) and the low bits count the triangles the
/// leaf references.
constexpr uint32_t kSubtreeFlag = 0x80000000u;

/// A leaf's kd box (an empty leaf's before widening): the kd boxes tile the grid, so a cell
/// inside one names its leaf (the next-leaf cache's check, walk.h).
struct KdBox {
  /// x, y, z and a fourth lane that every cell passes (INT32_MIN, INT32_MAX; a walk's lane 3 is 0).
  alignas(16) int32_t lo[4];
  int32_t hi[4];
};

/// Triangle groups. A leaf's triangles are stored as consecutive groups of up to kWideLanes lanes
/// in the order the leaf references them (which decides ties between equal hits). A triangle
/// referenced by several leaves is copied into each. Two layouts, by build target:
///
/// - Shared corners (groups of 16 in builds for AVX-512 with its byte and 128-bit forms, groups
///   of 8 in builds for AVX2): a group of n lanes stores its u distinct corners once (u <=
///   kMaxGroupCorners, twice the lanes) and, per lane, the index of each of its three corners
///   in that table. At float offsets from the group's start: a header (as uint32: n | u << 8
///   | the group's floats << 16, and kNarrowIds set where the lanes' mesh indices are stored
///   in 16 bits); the u corners' x, then their y, then their z (u floats each); the corner
///   indices (shared_index_floats): groups of 16 a byte each (corner k of lane i at byte
///   k n + i, padded to a whole float), groups of 8 a nibble each (corner k of lane i in bits
///   4i to 4i + 3 of uint32 k); then the lanes' mesh indices (shared_id_floats): n uint32, or
///   where there are at least 4 and they all lie within 65535 of the smallest, that one as
///   uint32 and each lane's difference from it as uint16 (lane i's at byte 4 + 2i), padded to a
///   whole float. The walk gathers each coordinate of a corner of all lanes from the table
///   (AVX-512: one two-table permute, vpermt2ps; AVX2: a permute of each 8-float half, vpermps,
///   and a blend on the index's bit 3), so a hit is bit for bit the one from stored
///   coordinates. A group ends early where its next triangle would bring more than
///   kMaxGroupCorners distinct corners.
/// - By lane (other builds): a group holds kWideLanes lanes, for each corner k and axis a the
///   lanes' coordinates one after the other (lane i's at float (3k + a) kWideLanes + i), then
///   the lanes' mesh indices (as uint32, at 9 kWideLanes + i); a leaf's last group repeats its
///   last triangle in the lanes left over.
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
constexpr bool kSharedCorners = kWideLanes == 16 || kWideLanes == 8;
#elif defined(__AVX2__)
constexpr bool kSharedCorners = kWideLanes == 8;
#else
constexpr bool kSharedCorners = false;
#endif
/// Rays a packet of the packet walk holds (accel/hybrid/packet_lanes.h): the float lanes of a
/// 512-bit vector in builds for AVX-512, of a 256-bit vector in builds for AVX2 and FMA; 0 (no
/// packet walk: the packet queries loop over the single walk) elsewhere, and where groups hold
/// fewer than 4 lanes.
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
#define KDGRID_PACKET_LANES 16
#elif defined(__AVX2__) && defined(__FMA__)
#define KDGRID_PACKET_LANES 8
#else
#define KDGRID_PACKET_LANES 0
#endif
constexpr int kPacketLanes = kWideLanes >= 4 ? KDGRID_PACKET_LANES : 0;
/// Floats a lane takes by lane: nine corner coordinates and the mesh's index.
constexpr uint32_t kGroupLaneFloats = 10;
/// The most distinct corners a shared-corner group holds: two tables of a vector's floats per
/// axis (32 with groups of 16, 16 with groups of 8).
constexpr uint32_t kMaxGroupCorners = 2 * uint32_t(kWideLanes);
/// The fewest lanes of a group that is not a leaf's last: kWideLanes, or with shared corners the
/// lanes whose corners reach kMaxGroupCorners when each brings three new ones.
constexpr uint32_t kFullGroupLanesAtLeast =
    kSharedCorners ? kMaxGroupCorners / 3 : uint32_t(kWideLanes);
/// Header bit of a shared-corner group whose lanes' mesh indices are stored in 16 bits.
constexpr uint32_t kNarrowIds = 1u << 24;
/// The bytes of one corner's indices in a shared-corner group of n lanes: a uint32 of a nibble
/// a lane in groups of 8, a byte a lane in groups of 16.
constexpr uint32_t shared_index_stride(uint32_t n) {
  return kWideLanes == 8 ? 4 : n;
}
/// The floats of a shared-corner group's corner indices (n lanes).
constexpr uint32_t shared_index_floats(uint32_t n) {
  return (3 * shared_index_stride(n) + 3) / 4;
}
/// The floats of a shared-corner group's mesh indices (n lanes; narrow: 16-bit differences).
constexpr uint32_t shared_id_floats(uint32_t n, bool narrow) {
  return narrow ? 1 + (n + 1) / 2 : n;
}
/// Whether a shared-corner group stores its n lanes' mesh indices `ids` as 16-bit differences:
/// where that takes fewer floats and they fit.
inline bool narrow_ids(const uint32_t* ids, uint32_t n) {
  if (shared_id_floats(n, true) >= shared_id_floats(n, false)) return false;
  uint32_t lo = ids[0], hi = ids[0];
  for (uint32_t i = 1; i < n; ++i) {
    lo = ids[i] < lo ? ids[i] : lo;
    hi = ids[i] > hi ? ids[i] : hi;
  }
  return hi - lo <= 0xffffu;
}
/// The floats of a shared-corner group of n lanes and u corners.
constexpr uint32_t shared_group_floats(uint32_t n, uint32_t u, bool narrow) {
  return 1 + 3 * u + shared_index_floats(n) + shared_id_floats(n, narrow);
}
static_assert(shared_group_floats(kWideLanes, kMaxGroupCorners, false) < 256,
              "a shared-corner group's floats fit the header's byte");
/// The most floats a lane takes in either layout, its group's share included: with shared
/// corners a group of 1 lane (14 floats in groups of 8, 12 in groups of 16; a larger group takes
/// no more a lane, as checked below).
constexpr uint32_t kGroupLaneFloatsAtMost =
    kSharedCorners ? shared_group_floats(1, 3, false) : kGroupLaneFloats;
static_assert(!kSharedCorners || [] {
  for (uint32_t n = 2; n <= uint32_t(kWideLanes); ++n) {
    const uint32_t u = 3 * n < kMaxGroupCorners ? 3 * n : kMaxGroupCorners;
    if (shared_group_floats(n, u, false) > n * kGroupLaneFloatsAtMost) return false;
  }
  return true;
}());
/// The least bytes a lane takes, its group's share included (the memory guard's "at least"):
/// by lane its 40; with shared corners those of a full group whose lanes name the same 3
/// corners and store narrow mesh indices.
constexpr double kGroupLaneBytesAtLeast =
    kSharedCorners ? shared_group_floats(kWideLanes, 3, true) * 4.0 / kWideLanes
                   : kGroupLaneFloats * 4.0;

/// A group by lane, as WatertightWide and the walk read it.
struct LaneGroup {
  const float* p;
  uint32_t n;  ///< the lanes that hold the leaf's triangles (the others repeat the last)

  [[gnu::always_inline]] static LaneGroup at(const float* p, uint32_t left) {
    return {p, left < uint32_t(kWideLanes) ? left : uint32_t(kWideLanes)};
  }
  [[gnu::always_inline]] const float* end() const {
    return p + kGroupLaneFloats * uint32_t(kWideLanes);
  }
  [[gnu::always_inline]] uint32_t prim(uint32_t i) const {
    uint32_t v;
    std::memcpy(&v, p + 9 * kWideLanes + i, sizeof v);
    return v;
  }
  Vec3 corner(int k, int i) const { return WatertightWide<kWideLanes>::corner_by_lane(p, k, i); }
  template <class F>
  [[gnu::always_inline]] void sheared(const WatertightTest::RayData& d, uint32_t,
                                      F (&c)[3][3]) const {
    WatertightWide<kWideLanes>::sheared_by_lane(d, p, c);
  }
};

#if defined(__AVX2__)
/// A shared-corner group, as WatertightWide and the walk read it.
struct SharedCornerGroup {
  const float* p;
  uint32_t n, u;

  [[gnu::always_inline]] static SharedCornerGroup at(const float* p, uint32_t) {
    uint32_t h;
    std::memcpy(&h, p, sizeof h);
    return {p, h & 0xffu, (h >> 8) & 0xffu};
  }
  [[gnu::always_inline]] uint32_t header() const {
    uint32_t h;
    std::memcpy(&h, p, sizeof h);
    return h;
  }
  [[gnu::always_inline]] bool narrow() const { return (header() & kNarrowIds) != 0; }
  [[gnu::always_inline]] const float* end() const { return p + ((header() >> 16) & 0xffu); }
  [[gnu::always_inline]] uint32_t prim(uint32_t i) const {
    const bool narrow_ids = narrow();
    const float* const ids = end() - shared_id_floats(n, narrow_ids);
    uint32_t v;
    std::memcpy(&v, ids + (narrow_ids ? 0 : i), sizeof v);
    if (narrow_ids) {
      uint16_t d;
      std::memcpy(&d, reinterpret_cast<const char*>(ids + 1) + 2 * i, sizeof d);
      v += d;
    }
    return v;
  }
  [[gnu::always_inline]] const uint8_t* index() const {
    return reinterpret_cast<const uint8_t*>(p + 1 + 3 * u);
  }
  /// The table index of corner k of lane i.
  uint32_t corner_index(int k, int i) const {
    const uint8_t* const corner_k = index() + uint32_t(k) * shared_index_stride(n);
    if constexpr (kWideLanes == 8)
      return (corner_k[uint32_t(i) / 2] >> (4 * (i & 1))) & 0xfu;
    else
      return corner_k[i];
  }
  Vec3 corner(int k, int i) const {
    const uint32_t j = corner_index(k, i);
    return {p[1 + j], p[1 + u + j], p[1 + 2 * u + j]};
  }
  /// Groups of 8: corner k's table index of every lane (its low 3 bits pick within a half of
  /// the table, as vpermps reads them) and, in each lane's sign bit, its bit 3 (which half: the
  /// blend's selector).
  [[gnu::always_inline]] void lane_index8(int k, __m256i& ik, __m256& upper) const {
    int32_t w;
    std::memcpy(&w, index() + uint32_t(k) * shared_index_stride(n), sizeof w);
    const __m256i all = _mm256_set1_epi32(w);
    ik = _mm256_srlv_epi32(all, _mm256_setr_epi32(0, 4, 8, 12, 16, 20, 24, 28));
    upper =
        _mm256_castsi256_ps(_mm256_sllv_epi32(all, _mm256_setr_epi32(28, 24, 20, 16, 12, 8, 4, 0)));
  }
  /// The table's corners sheared (16 at a time, so once a corner however many lanes name it),
  /// then each lane's corner taken from them by a permute. Masked loads: the lanes outside
  /// `lanes` read no memory (and hold corner 0).
  template <class F>
  [[gnu::always_inline]] void sheared(const WatertightTest::RayData& d, uint32_t lanes,
                                      F (&c)[3][3]) const {
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
    if constexpr (kWideLanes == 16)
      sheared16(d, lanes, c);
    else
#endif
      sheared8(d, c);
  }
  /// Groups of 8 (AVX2): each axis's table as two 8-float halves (masked loads: the corners
  /// past u read no memory and hold 0), sheared, then each lane's corner j taken from the half
  /// that bit 3 of j picks by a permute of each half and a blend on that bit.
  template <class F>
  [[gnu::always_inline]] void sheared8(const WatertightTest::RayData& d, F (&c)[3][3]) const {
    using Wide = WatertightWide<8>;
    const __m256i iota = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    const __m256i in_lo = _mm256_cmpgt_epi32(_mm256_set1_epi32(int32_t(u)), iota);
    const __m256i in_hi = _mm256_cmpgt_epi32(_mm256_set1_epi32(int32_t(u) - 8), iota);
    const float* const tx = p + 1 + uint32_t(d.kx) * u;
    const float* const ty = p + 1 + uint32_t(d.ky) * u;
    const float* const tz = p + 1 + uint32_t(d.kz) * u;
    F s[2][3];
    Wide::shear(d, (F)_mm256_maskload_ps(tx, in_lo), (F)_mm256_maskload_ps(ty, in_lo),
                (F)_mm256_maskload_ps(tz, in_lo), s[0][0], s[0][1], s[0][2]);
    Wide::shear(d, (F)_mm256_maskload_ps(tx + 8, in_hi), (F)_mm256_maskload_ps(ty + 8, in_hi),
                (F)_mm256_maskload_ps(tz + 8, in_hi), s[1][0], s[1][1], s[1][2]);
    for (int k = 0; k < 3; ++k) {
      __m256i ik;
      __m256 upper;
      lane_index8(k, ik, upper);
      for (int j = 0; j < 3; ++j)
        c[k][j] = (F)_mm256_blendv_ps(_mm256_permutevar8x32_ps((__m256)s[0][j], ik),
                                      _mm256_permutevar8x32_ps((__m256)s[1][j], ik), upper);
    }
  }
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
  /// Groups of 16 (AVX-512): each axis's table as two 16-float halves, one two-table permute a
  /// coordinate.
  template <class F>
  [[gnu::always_inline]] void sheared16(const WatertightTest::RayData& d, uint32_t lanes,
                                        F (&c)[3][3]) const {
    using Wide = WatertightWide<16>;
    const float* const tx = p + 1 + uint32_t(d.kx) * u;
    const float* const ty = p + 1 + uint32_t(d.ky) * u;
    const float* const tz = p + 1 + uint32_t(d.kz) * u;
    const uint32_t corners = u >= 32 ? ~0u : (1u << u) - 1;
    const __mmask16 lo = __mmask16(corners);
    F s[2][3];
    Wide::shear(d, (F)_mm512_maskz_loadu_ps(lo, tx), (F)_mm512_maskz_loadu_ps(lo, ty),
                (F)_mm512_maskz_loadu_ps(lo, tz), s[0][0], s[0][1], s[0][2]);
    const uint8_t* idx = index();
    __m512i ik[3];
    for (int k = 0; k < 3; ++k)
      ik[k] = _mm512_maskz_cvtepu8_epi32(
          __mmask16(lanes), _mm_maskz_loadu_epi8(__mmask16(lanes), idx + uint32_t(k) * n));
    const __mmask16 hi = __mmask16(corners >> 16);
    Wide::shear(d, (F)_mm512_maskz_loadu_ps(hi, tx + 16), (F)_mm512_maskz_loadu_ps(hi, ty + 16),
                (F)_mm512_maskz_loadu_ps(hi, tz + 16), s[1][0], s[1][1], s[1][2]);
    for (int k = 0; k < 3; ++k)
      for (int j = 0; j < 3; ++j)
        c[k][j] = (F)_mm512_permutex2var_ps((__m512)s[0][j], ik[k], (__m512)s[1][j]);
  }
#endif
};
/// The layout this build stores (kSharedCorners).
using GroupView = std::conditional_t<kSharedCorners, SharedCornerGroup, LaneGroup>;
#else
using GroupView = LaneGroup;
#endif

/// Flat subtrees. A leaf subtree with kFlatMinLeaves to kFlatLeaves leaves holding triangles is
/// stored instead as the list of those leaves, which the walk tests against the ray all at
/// once (per box coordinate one 16-lane vector, or two 8-lane halves with AVX2) and visits in the
/// kd walk's order for the ray's octant (walk.h, walk_flat); its kd nodes are not kept. At float
/// offset F of GridKdHybrid::flat_subtree_floats_ (a multiple of 16; the Leaf record's `pad` holds
/// F, 0 for none): the subtree's box (ClipBox4's layout, 8 floats), the leaf count n (as uint32),
/// padding to 16 floats; then the leaves' boxes as six runs of n floats (lo x, y, z, hi x, y, z:
/// each kd leaf's box within the subtree's box), their first groups (n uint32) and their triangle
/// counts (n uint32), in the subtree's depth-first order (below first); then for each octant of
/// ray directions (bit a set: negative along axis a) the leaves' order, n bytes; padding to a
/// multiple of 16 floats. Builds for AVX-512 (16 lanes, masked loads) and for AVX2 without it
/// (two 8-lane halves, whole-vector loads: flat_walk_reads_fit) only; the others walk every
/// subtree by its kd nodes.
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
constexpr bool kFlatSubtrees = true;
constexpr uint32_t kFlatLeaves = 16;
#elif defined(__AVX2__)
constexpr bool kFlatSubtrees = true;
constexpr uint32_t kFlatLeaves = 16;
#else
constexpr bool kFlatSubtrees = false;
constexpr uint32_t kFlatLeaves = 16;
#endif
/// Below this many leaves with triangles the kd walk is faster: it descends a few predicted
/// nodes, where the flat walk pays its box tests and their latency before the first leaf
/// (docs/HYBRID.md, "Flat subtrees").
constexpr uint32_t kFlatMinLeaves = 5;
/// Cache lines of each met leaf's groups that the flat walk prefetches before its first test
/// (512 bytes; docs/HYBRID.md, "Flat subtrees").
constexpr int kFlatPrefetchLines = 8;
/// The floats of a flat subtree of n leaves, before padding to a multiple of 16.
constexpr uint32_t flat_subtree_floats(uint32_t n) {
  return 16 + 8 * n + 2 * n;
}
/// Whether the AVX2 walk's whole-vector reads of every flat subtree (kFlatMinLeaves to
/// kFlatLeaves leaves) stay inside its padded floats: 8 floats (16 past 8 leaves) from each of the
/// six box runs (the last ends 5n + 8 or 5n + 16 floats past the header) and 8 order bytes (16)
/// from the last octant's (ending at byte 4 (16 + 8n) + 7n + 8 or + 16).
constexpr bool flat_walk_reads_fit() {
  for (uint32_t n = kFlatMinLeaves; n <= kFlatLeaves; ++n) {
    const uint32_t padded = (flat_subtree_floats(n) + 15) / 16 * 16, v = n > 8 ? 16 : 8;
    if (16 + 5 * n + v > padded || 4 * (16 + 8 * n) + 7 * n + v > 4 * padded) return false;
  }
  return true;
}
static_assert(flat_walk_reads_fit(),
              "the AVX2 flat walk reads whole vectors of every subtree it is given");

/// 64 bytes of group storage (the array is 64-byte aligned).
struct alignas(64) GroupLine {
  float f[16];
};

}  // namespace kdgrid::hybrid
