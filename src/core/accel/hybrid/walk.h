// The hybrid's ray walk (included by hybrid.h; the class is declared there). A ray is clipped
// in float to the grid's box, widened by the kd-tree's rounding bound; its entry cell's leaf
// is looked up; then each step tests the leaf's triangle groups (WatertightWide; or lane by lane
// through a per-ray mailbox, so that a triangle referenced by several leaves is tested once,
// for the other triangle tests: GridKdHybrid::kWide), computes the exit over the leaf
// box's far planes in four lanes (x, y, z and a dummy axis), stops once the closest hit lies
// before the exit, else moves to the leaf of the cell past the exit face. Cells move
// monotonically along the ray, so at most nx+ny+nz+1 steps; the loop enforces that bound. A
// ray that evicts more triangles from its mailbox than it can keep is walked again from the
// start by the exact walk, the same walk with a record of every triangle tested (rewalk).
//
// The next leaf comes from the map (cell_map.h) or from the thread's NextLeafCache
// (next_leaf_cache.h), which remembers the leaf last reached across each leaf face
// (BuildParams::hybrid_next_leaf_cache). The lane-by-lane walk's mailbox and the exact walk's
// record are in mailbox.h, the walk of a flat subtree in walk_flat.h.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

#include "accel/hybrid/hybrid.h"
#include "accel/hybrid/mailbox.h"
#include "accel/hybrid/next_leaf_cache.h"

namespace kdgrid::hybrid {

/// One ray's walk between leaf steps: the ray in grid space, the current cell and leaf,
/// the closest hit so far and the mailbox.
template <class TriangleTest>
struct WalkState {
  /// The ray in grid space, g(t) = o + t dir_grid; inv[a] is t per grid unit along axis a (0
  /// where the ray does not move) and t_at_zero = -o inv (+inf there), the t at which g[a] = 0,
  /// so the exit over a far plane p is p inv + t_at_zero. Lanes x, y, z, then a dummy axis that
  /// never exits (o, dir_grid, inv 0, t_at_zero +inf), moves "up" and stays in cell 0, so that
  /// every step computes the four lanes at once.
  Double4 o, dir_grid, inv, t_at_zero;
  Long4 up_mask;  ///< all ones on the axes the ray moves up along (the far plane is hi), and lane 3
  Int4 up;        ///< the same as int32 lanes
  Int4 down;      ///< ~up: added to a far plane's coordinate, gives the cell just past it
  Int4 cell;      ///< the current cell (lane 3: 0)
  KdRay kr;       ///< the ray as the leaf subtrees' kd traversal reads it (world space, float)
  KdRayX4 krx4;   ///< the same, as the clip to a subtree's box reads it
  float err;      ///< the largest of kr.err: widens the leaf's segment before that clip
  double t1, t_cur;
  /// Where the walk over empty leaves stops: t1, or the closest hit's t once one is found.
  double t_stop;
  uint32_t leaf_id;
  uint64_t steps_left;  ///< steps before the bound of over_step_bound (max_steps_ + 1 at the start)
  float tmin, tmax, best;
  bool found;
  Hit hit;
  typename TriangleTest::RayData rd;
  uint32_t mailbox[GridKdHybrid::kMailbox];
  /// Triangles pushed out of the mailbox so far; kAbandoned once one more would not fit.
  uint32_t evicted_count;
  uint32_t evicted[GridKdHybrid::kEvicted];  ///< those triangles
  TestedSet* tested;                         ///< the exact walk's record (unset in the fast walk)
};

/// Where a ray's counts start (counted and traced walks), so that GridKdHybrid::rewalk can take
/// back an abandoned fast walk's counts: a re-walked ray's counters, trace and next-leaf cache
/// takes (GridKdHybrid::next_leaves_from_cache) are its exact walk's.
template <class Probe>
struct StatsMark {
  explicit StatsMark(const Probe&) {}
  void restore(Probe&) const {}
};
template <>
struct StatsMark<CountProbe> {
  RayCounters c;
  uint64_t taken = thread_next_leaf_cache.taken;
  explicit StatsMark(const CountProbe& probe) : c(probe.c) {}
  void restore(CountProbe& probe) const {
    probe.c = c;
    thread_next_leaf_cache.taken = taken;
  }
};
template <>
struct StatsMark<TraceProbe> {
  RayCounters c;
  size_t steps, tested;
  uint64_t taken = thread_next_leaf_cache.taken;
  explicit StatsMark(const TraceProbe& probe)
      : c(probe.trace->counters),
        steps(probe.trace->steps.size()),
        tested(probe.trace->tested.size()) {}
  void restore(TraceProbe& probe) const {
    probe.trace->counters = c;
    probe.trace->steps.resize(steps);
    probe.trace->tested.resize(tested);
    thread_next_leaf_cache.taken = taken;
  }
};

enum class StepResult { Next, Done, Answered };
/// The closest hit of a leaf's tests, kept in the step's locals: the triangle's index
/// (kInvalidPrim: none yet) and its u, v (its t is the step's best).
struct LocalHit {
  uint32_t prim;
  float u, v;
};
/// Where the ray leaves a leaf's (step) box: the exit t, the cell just past the exit face,
/// and whether that cell lies outside the grid (the walk ends there).
struct Exit {
  double t;
  Int4 next_cell;  ///< the cell just past the exit face (lane 3: 0)
  int axis;
  bool out;
};

}  // namespace kdgrid::hybrid

namespace kdgrid {

inline uint64_t GridKdHybrid::next_leaves_from_cache() {
  return hybrid::thread_next_leaf_cache.taken;
}

inline uint32_t GridKdHybrid::next_leaf(const Int4& n, uint32_t from, int axis) const {
  if (!next_leaf_cache_) return lookup(n[0], n[1], n[2]);
  using Cache = hybrid::NextLeafCache;
  Cache& cache = hybrid::thread_next_leaf_cache;
  uint32_t& entry = cache.entry(from, axis);
  // Switched off, it scores one lookup in kOffSample; the others only record the leaf found.
  if (cache.score < 0 && (++cache.tick & (Cache::kOffSample - 1)) != 0)
    return entry = lookup(n[0], n[1], n[2]);
  const uint32_t id = entry;
  if (cache.score >= 0) {
    if (in_kd_box(id, n)) [[likely]] {
      cache.score = std::min(cache.score + 1, Cache::kScoreMax);
      ++cache.taken;
      return id;
    }
  }
  const uint32_t found = lookup(n[0], n[1], n[2]);
  cache.score = found == id ? std::min(cache.score + 1, Cache::kScoreMax)
                            : std::max(cache.score - Cache::kMissCost, Cache::kScoreMin);
  entry = found;
  return found;
}

inline uint32_t GridKdHybrid::start_leaf(const Int4& c) const {
  if (!next_leaf_cache_) return lookup(c[0], c[1], c[2]);
  hybrid::NextLeafCache& cache = hybrid::thread_next_leaf_cache;
  cache.claim(uid_);
  const uint32_t id = cache.start;
  if (in_kd_box(id, c)) [[likely]] {
    ++cache.taken;
    return id;
  }
  return cache.start = lookup(c[0], c[1], c[2]);
}

inline bool GridKdHybrid::in_kd_box(uint32_t id, const Int4& c) const {
  const KdBox& b = kd_boxes_[id];
  Int4 lo, hi;
  std::memcpy(&lo, b.lo, sizeof lo);
  std::memcpy(&hi, b.hi, sizeof hi);
  // The four lanes at once (lane 3 always passes).
  return all_lanes((c >= lo) & (c < hi));
}

template <class TriangleTest>
inline bool GridKdHybrid::over_step_bound(WalkState<TriangleTest>& w) const {
  if (w.steps_left-- == 0) [[unlikely]] {
    // An abandoned fast walk (tested_before) ends here, with no error.
    if (w.evicted_count != hybrid::kAbandoned) step_errors_.fetch_add(1, std::memory_order_relaxed);
    return true;
  }
  return false;
}

template <class TriangleTest, class Probe, bool kAny, bool kExact>
bool GridKdHybrid::traverse(const Ray& ray, Hit* hit, Probe& probe) const {
  if (leaves_.empty()) return false;
  [[maybe_unused]] const hybrid::StatsMark<Probe> mark(probe);
  WalkState<TriangleTest> w;
  if (!walk_begin(w, ray)) return false;
  if constexpr (kExact) {
    w.tested = &hybrid::thread_tested_set;
    w.tested->begin(mesh_->num_triangles());
  }
  probe.lookup();
  StepResult r;
  for (;;) {
    if constexpr (!Probe::kTrace) {
      // An empty leaf is only stepped over: inline, with the ray's state in registers.
      const Leaf& leaf_rec = leaves_[w.leaf_id];
      if (leaf_rec.count == 0) {
        if (over_step_bound(w)) {
          r = StepResult::Done;
          break;
        }
        probe.step();
        const Exit e = leaf_exit(w, leaf_rec);
        // The end of the ray's segment, the grid or the walk (a hit found before this exit).
        if (e.out || e.t >= w.t_stop) {
          r = StepResult::Done;
          break;
        }
        w.cell = e.next_cell;
        w.t_cur = e.t;
        w.leaf_id = next_leaf(e.next_cell, w.leaf_id, e.axis);
        probe.lookup();
        continue;
      }
    }
    if ((r = walk_step<TriangleTest, Probe, kAny, kExact>(w, probe)) != StepResult::Next) break;
  }
  // A walk abandoned by tested_before skipped every test after it (so it is never Answered):
  // the exact walk answers the ray.
  if constexpr (!kExact)
    if (w.evicted_count == hybrid::kAbandoned) [[unlikely]]
      return rewalk<TriangleTest, Probe, kAny>(ray, hit, probe, mark);
  if (r == StepResult::Answered) return true;
  if constexpr (!kAny)
    if (w.found) *hit = w.hit;
  return w.found;
}

template <class TriangleTest, class Probe, bool kAny>
bool GridKdHybrid::rewalk(const Ray& ray, Hit* hit, Probe& probe,
                          const hybrid::StatsMark<Probe>& mark) const {
  rewalks_.fetch_add(1, std::memory_order_relaxed);
  mark.restore(probe);
  return traverse<TriangleTest, Probe, kAny, true>(ray, hit, probe);
}

template <class TriangleTest>
bool GridKdHybrid::walk_begin(WalkState<TriangleTest>& w, const Ray& ray) const {
  // Cheap rejection first, in float as the kd-tree clips (most primary rays of a scanned model
  // miss its box, and they cost only this clip), against the
  // grid's world box (world_box_, widened beyond the grid's rounding) with each slab widened as the
  // kd-tree widens its own, by err (KdRay): the rounding of (lo - o) grows with the origin's
  // coordinates, so a ray from far away that grazes the box at an edge or a corner would be
  // lost without it (tests/test_hybrid_walk.cpp holds far origins to it). So this clip never
  // rejects a ray that reaches the grid, and its entry t is never later than the ray's entry
  // into the grid: the walk starts there (below). Its reciprocals and err serve the leaf
  // subtrees' traversal. kd_begin computes the three axes at once, as the grid-space ray
  // below does in double (GCC's vector extensions: AVX where the target has it, else SSE2
  // pairs): the set-up is most of a short ray's work.
  float f0, f1;
  if (!kd_begin(ray, world_clip_, max_abs_, w.kr, f0, f1, &w.krx4)) return false;
  w.err = std::max({w.kr.err[0], w.kr.err[1], w.kr.err[2]});
  Float4 of, df;
  load_ray4(ray, of, df);
  // Grid-space ray: g(t) = o + t * dir_grid. inv[a] is t per grid unit along axis a. Zero (and
  // negative-zero) direction components never exit on their axis: their inv is 0 and their
  // t_at_zero +inf, so their exit t is +inf without a branch. Lane 3 (tmin, tmax in the ray's
  // layout) is zeroed first: a fourth axis with a zero direction, in cell 0, that never exits.
  // The exit over a leaf's far plane p on axis a is t = p * inv[a] + t_at_zero[a] (t_at_zero =
  // -o * inv, +inf on a non-moving axis): one multiply and one add after the leaf's load.
  constexpr double kDInf = std::numeric_limits<double>::infinity();
  const Double4 zero = {0.0, 0.0, 0.0, 0.0};
  const Long4 xyz = {-1, -1, -1, 0};
  const Double4 od = xyz ? __builtin_convertvector(of, Double4) : zero;
  const Double4 d = xyz ? __builtin_convertvector(df, Double4) : zero;
  const Double4 o = (od - origin4_) * inv_cell_;
  const Long4 moving = d != zero;
  const Double4 inv = moving ? cell_ / d : zero;
  w.o = o;
  w.inv = inv;
  w.t_at_zero = moving ? -o * inv : zero + kDInf;
  w.dir_grid = d * inv_cell_;
  w.up_mask = (d > zero) | ~xyz;
  w.up = __builtin_convertvector(w.up_mask, Int4);
  w.down = ~w.up;
  // The walk runs over the float clip's [f0, f1], not an exact clip to the grid: f0 is at most
  // the ray's entry t, and the entry cell below is clamped into the grid, so the walk starts
  // in a cell the ray reaches at or after that cell on every axis (a point at an earlier t lies
  // behind along each axis it moves on), and its steps, monotone on every axis, cross all the
  // cells the ray does. Past the grid the walk ends at the face it leaves by (out_of_grid in
  // leaf_exit), so a t1 beyond the grid's exit changes nothing. (An exact clip in double costs
  // more instructions and loses rays touching the box at an edge: docs/EXPERIMENTS.md.)
  // The entry cell: clamped into the grid in double, then truncated (the floor, as the value
  // is >= 0; a NaN clamps to 0).
  const double t0 = f0, t1 = f1;
  const Double4 x = o + t0 * w.dir_grid;
  const Double4 xl = x > zero ? x : zero;
  w.cell = __builtin_convertvector(xl < last_cell4_ ? xl : last_cell4_, Int4);
  w.rd = TriangleTest::prepare(ray);
  w.tmin = ray.tmin;
  w.tmax = ray.tmax;
  w.best = ray.tmax;
  w.found = false;
  if constexpr (kMailboxed<TriangleTest>)
    for (auto& m : w.mailbox) m = kInvalidPrim;
  w.evicted_count = 0;
  w.t1 = t1;
  w.t_cur = t0;
  w.t_stop = t1;
  w.steps_left = max_steps_ + 1;
  w.leaf_id = start_leaf(w.cell);
  return true;
}

template <class TriangleTest>
GridKdHybrid::Exit GridKdHybrid::leaf_exit(const WalkState<TriangleTest>& w,
                                           const Leaf& leaf_rec) const {
  // The leaf's box as four lanes each (lo's fourth holds first/count's bits, hi's the pad, 0:
  // lane 3 always takes hi, so its exit t is 0 * 0 + inf). The exit is the nearest far plane,
  // the first axis winning ties, found by compares on the three lanes that GCC turns into
  // branches: on coherent rays they are predicted, so the CPU computes the exit cell and starts
  // the next lookup (whose cache entry is keyed by the exit axis) before the compares resolve. The
  // axis is a constant in each branch (exit_through<A>). (A form that computes all three exit
  // cells and then overrides the exit axis's compiles to selects, whose chain the lookup has
  // to wait for: docs/EXPERIMENTS.md, "The walk".)
  static_assert(offsetof(Leaf, first) == 24 && offsetof(Leaf, hi) == 32 &&
                offsetof(Leaf, pad) == 56 && sizeof(Leaf) == 64);
  Double4 lo, hi;
  const char* bytes = reinterpret_cast<const char*>(&leaf_rec);  // the record's two halves
  std::memcpy(&lo, bytes, sizeof lo);
  std::memcpy(&hi, bytes + offsetof(Leaf, hi), sizeof hi);
  const Double4 far = w.up_mask ? hi : lo;
  Double4 e;
  mul_add(far, w.inv, w.t_at_zero, e);
  const double e0 = e[0], e1 = e[1], e2 = e[2];
  Exit ex;
  if (e0 <= e1 && e0 <= e2)
    exit_through<0>(w, lo, hi, far, e0, ex);
  else if (e1 <= e2)
    exit_through<1>(w, lo, hi, far, e1, ex);
  else
    exit_through<2>(w, lo, hi, far, e2, ex);
  return ex;
}

template <int A, class TriangleTest>
void GridKdHybrid::exit_through(const WalkState<TriangleTest>& w, const Double4& lo,
                                const Double4& hi, const Double4& far, double t, Exit& ex) const {
  // Next cell: on the other axes the exit point's cell, clamped into the leaf (the point
  // lies on the leaf's face, so this only removes rounding) and never moving against the
  // ray; on the exit axis A the integer cell just past the leaf's face (the far plane, minus
  // one when moving down). All four lanes are computed, then lane A is taken from the face.
  // The clamp is done in double before a truncating conversion: the clamped value is at
  // least lo >= 0, where truncation is the floor, so it needs no floor instruction (a NaN
  // coordinate would clamp to lo).
  ex.axis = A;
  ex.t = t;
  Double4 x;
  mul_add(Double4{t, t, t, t}, w.dir_grid, w.o, x);
  const Double4 hm = hi - 0.5;
  const Double4 xl = x > lo ? x : lo;
  const Int4 v = __builtin_convertvector(xl < hm ? xl : hm, Int4);
  const Int4 mono = w.up ? (v > w.cell ? v : w.cell) : (v < w.cell ? v : w.cell);
  const Int4 face = __builtin_convertvector(far, Int4) + w.down;
  ex.next_cell =
      __builtin_shufflevector(mono, face, A == 0 ? 4 : 0, A == 1 ? 5 : 1, A == 2 ? 6 : 2, 3);
  ex.out = uint32_t(face[A]) >= uint32_t(dims_[A]);
}

template <class TriangleTest, class Probe, bool kAny, bool kExact>
bool GridKdHybrid::test_groups(WalkState<TriangleTest>& w, Probe& probe,
                               const typename TriangleTest::RayData& rd, float tmin, uint32_t first,
                               uint32_t count, float& best, bool& found, LocalHit& h) const {
  probe.leaf();
  using Wide = WatertightWide<kWideLanes>;
  // The leaf's groups, one after the other (records.h, "Triangle groups").
  const float* p = groups_[0].f + first;
  for (uint32_t left = count; left != 0;) {
    const hybrid::GroupView g = hybrid::GroupView::at(p, left);
    const uint32_t n = g.n;
    p = g.end();
    left -= n;
    uint32_t lanes = 0;
    if constexpr (!kMailboxed<TriangleTest>) {
      // Every lane, without the mailbox: a repeated test cannot change the closest hit (best
      // only decreases and a hit must be closer than best) nor an any-hit answer, and the
      // look-ups cost more than the repeats they saved (docs/HYBRID.md, "Wide leaves").
      lanes = uint32_t((uint64_t(1) << n) - 1);
      if constexpr (Probe::kCount)
        for (uint32_t i = 0; i < n; ++i) probe.tri_test(g.prim(i));
    } else {
      // The lanes whose triangle the ray has not tested before.
      for (uint32_t i = 0; i < n; ++i) {
        const uint32_t prim = g.prim(i);
        if (hybrid::tested_before<kExact>(w, prim)) {
          probe.mailbox_skip();
          continue;
        }
        if constexpr (Probe::kCount) probe.tri_test(prim);
        lanes |= 1u << i;
      }
    }
    if (lanes == 0) continue;
    if constexpr (kWide<TriangleTest>) {
      float t, u, v;
      const int i = Wide::intersect(rd, g, lanes, tmin, best, t, u, v);
      if (i >= 0) {
        if constexpr (kAny) return true;
        best = t;
        found = true;
        h = {g.prim(uint32_t(i)), u, v};
      }
    } else {
      for (; lanes != 0; lanes &= lanes - 1) {
        const int i = __builtin_ctz(lanes);
        float t, u, v;
        if (TriangleTest::intersect(rd, g.corner(0, i), g.corner(1, i), g.corner(2, i), tmin, best,
                                    t, u, v)) {
          if constexpr (kAny) return true;
          best = t;
          found = true;
          h = {g.prim(uint32_t(i)), u, v};
        }
      }
    }
  }
  return false;
}

/// After a subtree's walk (kd or flat), which kept the closest hit in its locals: the hit it
/// found, if any, becomes the ray's.
template <class TriangleTest>
[[gnu::always_inline]] inline void keep_subtree_hit(hybrid::WalkState<TriangleTest>& w, float best,
                                                    const hybrid::LocalHit& h) {
  if (h.prim == kInvalidPrim) return;
  w.best = best;
  w.found = true;
  w.hit = {best, h.prim, h.u, h.v};
}

template <class TriangleTest, class Probe, bool kAny, bool kExact>
GridKdHybrid::StepResult GridKdHybrid::walk_step(WalkState<TriangleTest>& w, Probe& probe) const {
  if (over_step_bound(w)) return StepResult::Done;
  const uint32_t leaf_id = w.leaf_id;
  const Leaf& leaf_rec = leaves_[leaf_id];
  probe.step();
  const Exit ex = leaf_exit(w, leaf_rec);
  const double t_exit = ex.t;
  const bool last = ex.out || t_exit >= w.t1;
  if constexpr (Probe::kTrace) {
    const float tin = float(w.t_cur);
    probe.visit(TraceStep{StepKind::Leaf, int(leaf_depth_[leaf_id]), leaf_id, step_box(leaf_id),
                          tin, std::max(tin, float(std::min(t_exit, double(w.tmax))))});
  }
  // The next cell's leaf is looked up before this leaf's triangles are tested, so the
  // dependent loads of the lookup (top array, bricks, leaf record) overlap with the tests
  // instead of following them; most leaves entered are left again (a ray takes several steps:
  // docs/HYBRID.md, "The walk"), so the lookup is rarely wasted.
  uint32_t next_id = 0;
  if (!last) {
    next_id = next_leaf(ex.next_cell, leaf_id, ex.axis);
    probe.lookup();
    __builtin_prefetch(leaves_.data() + next_id);
  }
  // The closest hit's triangle and u, v are written to w once after the leaf.
  const auto& rd = w.rd;
  const float tmin = w.tmin;
  LocalHit h{kInvalidPrim, 0.0f, 0.0f};
  uint32_t flat_at;  // the leaf's flat subtree (records.h, "Flat subtrees"), 0 if none
  std::memcpy(&flat_at, &leaf_rec.pad, sizeof flat_at);
  if (hybrid::kFlatSubtrees && flat_at != 0) {
    if (walk_flat<TriangleTest, Probe, kAny, kExact>(w, probe, leaf_id, flat_at, t_exit, h))
      return StepResult::Answered;
  } else if (leaf_rec.count & kSubtreeFlag) {
    // The kd-tree's walk of the leaf's subtree over the ray's segment in the leaf, clipped to
    // the subtree's box first (the two t's widened by err as the kd-tree widens its own).
    const KdNode* sub = sub_nodes_.data() + leaf_rec.first;
    Float4 sub_lo, sub_hi;
    std::memcpy(&sub_lo, sub, sizeof sub_lo);
    std::memcpy(&sub_hi, sub + 2, sizeof sub_hi);
    [[maybe_unused]] Box3 sub_box;
    if constexpr (Probe::kTrace)
      sub_box = Box3(Vec3(sub_lo[0], sub_lo[1], sub_lo[2]), Vec3(sub_hi[0], sub_hi[1], sub_hi[2]));
    // The ray in a local: the loop then keeps it in registers (read through w, it was
    // reloaded at every node).
    const KdRay kr = w.kr;
    float ta = float(w.t_cur) - w.err, tb = float(std::min(t_exit, w.t1)) + w.err;
    if (kd_clip_x4(w.krx4, sub_lo, sub_hi, ta, tb)) {
      // Tested as the kd-tree tests, but through the ray's mailbox: a triangle that crosses
      // cell boundaries is referenced by every grid leaf it touches and by several leaves of a
      // subtree, and a second test of the whole triangle can only repeat the first (best only
      // decreases).
      auto leaf = [&](const KdNode& sn, float& b, bool& f) __attribute__((always_inline)) {
        return test_groups<TriangleTest, Probe, kAny, kExact>(w, probe, rd, tmin, sn.prim_offset,
                                                              sn.count(), b, f, h);
      };
      // Traces: each node's segment as the walk sees it, within the leaf's segment and never
      // starting before the previous node's (the walk widens its intervals by err, a bound on
      // rounding, so a popped node may start up to 2 err before the leaf it follows).
      [[maybe_unused]] float trace_in = float(w.t_cur);
      auto visit = [&](StepKind kind, int depth, uint32_t, const Box3& box, float tn, float tf) {
        // Clamped to the leaf's segment: a subtree node's interval, widened by err, may start
        // past the leaf's exit, where the next leaf's step starts.
        const float leaf_out = float(std::min(t_exit, double(w.tmax)));
        trace_in = std::max(trace_in, std::min(tn, leaf_out));
        const float out = std::max(trace_in, std::min(tf, leaf_out));
        probe.visit(
            TraceStep{kind, int(leaf_depth_[leaf_id]) + 1 + depth, leaf_id, box, trace_in, out});
      };
      // The closest hit in the walk's own locals here: through w, the compiler keeps it in
      // memory across the subtree's steps.
      float best = w.best;
      bool found = w.found;
      if (kd_traverse(sub_nodes_.data(), leaf_rec.first + kSubBoxNodes, kr, ta, tb, sub_box, best,
                      found, probe, leaf, visit))
        return StepResult::Answered;
      if constexpr (!kAny) keep_subtree_hit(w, best, h);
    }
  } else if (leaf_rec.count) {
    if (test_groups<TriangleTest, Probe, kAny, kExact>(w, probe, rd, tmin, leaf_rec.first,
                                                       leaf_rec.count, w.best, w.found, h))
      return StepResult::Answered;
    if constexpr (!kAny)
      if (h.prim != kInvalidPrim) w.hit = {w.best, h.prim, h.u, h.v};
  }
  if (w.found && double(w.best) <= t_exit) return StepResult::Done;
  if (last) return StepResult::Done;
  if (w.found) w.t_stop = std::min(w.t1, double(w.best));
  w.cell = ex.next_cell;
  w.t_cur = t_exit;
  w.leaf_id = next_id;
  return StepResult::Next;
}

}  // namespace kdgrid

// GridKdHybrid::walk_flat, which walk_step calls; it uses keep_subtree_hit above.
#include "accel/hybrid/walk_flat.h"
