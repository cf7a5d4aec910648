#include "accel/kdtree.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_invoke.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <string>

#include "accel/guards.h"
#include "util/cancel.h"
#include "util/cancellable_sort.h"
#include "util/error.h"
#include "util/memory.h"

namespace kdgrid {
namespace {

// Event types in sweep order at equal positions: triangles ending at p are left of a plane
// at p, planar ones are in it, starting ones are right of it (Wald & Havran, sec. 4.2).
enum EventType : uint8_t { kEnd = 0, kPlanar = 1, kStart = 2 };

struct Event {
  float pos;
  uint32_t prim;
  uint8_t axis;
  uint8_t type;
};

inline bool event_less(const Event& a, const Event& b) {
  if (a.axis != b.axis) return a.axis < b.axis;
  if (a.pos != b.pos) return a.pos < b.pos;
  if (a.type != b.type) return a.type < b.type;
  return a.prim < b.prim;
}

/// Appends the events of a triangle whose (clipped) bounds are `b`.
inline void add_events(std::vector<Event>& out, uint32_t prim, const Box3& b) {
  for (int a = 0; a < 3; ++a) {
    if (b.lo[a] == b.hi[a]) {
      out.push_back({b.lo[a], prim, uint8_t(a), kPlanar});
    } else {
      out.push_back({b.lo[a], prim, uint8_t(a), kStart});
      out.push_back({b.hi[a], prim, uint8_t(a), kEnd});
    }
  }
}

/// Bounds of triangle `c` clipped to `box` (Sutherland-Hodgman against the six box planes),
/// clamped into the box. Returns false if nothing is left.
bool clipped_bounds(const std::array<Vec3, 3>& c, const Box3& box, Box3& out) {
  Vec3d poly[12], tmp[12];
  int n = 3;
  for (int k = 0; k < 3; ++k) poly[k] = Vec3d(c[k]);
  for (int a = 0; a < 3 && n > 0; ++a) {
    for (int side = 0; side < 2 && n > 0; ++side) {
      const double plane = side == 0 ? box.lo[a] : box.hi[a];
      auto inside = [&](const Vec3d& p) { return side == 0 ? p[a] >= plane : p[a] <= plane; };
      int m = 0;
      for (int i = 0; i < n; ++i) {
        const Vec3d& p = poly[i];
        const Vec3d& q = poly[(i + 1) % n];
        const bool ip = inside(p), iq = inside(q);
        if (ip) tmp[m++] = p;
        if (ip != iq) {
          const double t = (plane - p[a]) / (q[a] - p[a]);
          Vec3d x = p + (q - p) * t;
          double xs[3] = {x.x, x.y, x.z};
          xs[a] = plane;  // exactly on the plane
          tmp[m++] = Vec3d(xs[0], xs[1], xs[2]);
        }
      }
      n = m;
      std::copy(tmp, tmp + m, poly);
    }
  }
  if (n == 0) return false;
  Box3 b;
  for (int i = 0; i < n; ++i) {
    // Round outwards so the float bounds contain the exact clipped polygon.
    const Vec3 lo(float(poly[i].x), float(poly[i].y), float(poly[i].z));
    b.grow(lo);
    for (int a = 0; a < 3; ++a) {
      if (double(b.lo[a]) > poly[i][a]) b.lo[a] = next_float_down(b.lo[a]);
      if (double(b.hi[a]) < poly[i][a]) b.hi[a] = next_float_up(b.hi[a]);
    }
  }
  out = b.intersect(box);
  return !out.empty();
}

struct Subtree {
  std::vector<KdNode> nodes;
  std::vector<uint32_t> prims;
};

KdNode make_leaf(Subtree& out, std::vector<uint32_t>& ids) {
  KdNode n;
  n.bits = (uint32_t(ids.size()) << 2) | 3u;
  if (ids.size() == 1) {
    n.one_prim = ids[0];
  } else {
    n.prim_offset = uint32_t(out.prims.size());
    out.prims.insert(out.prims.end(), ids.begin(), ids.end());
  }
  return n;
}

// Node builds of at least this many triangles, above this depth, run their children in
// parallel; below, the recursion is sequential (task overhead and subtree copies win).
constexpr uint32_t kParallelPrims = 4096;
constexpr int kParallelDepth = 12;

class Builder {
 public:
  /// `leaf_lanes`: the triangles a leaf tests at once (the hybrid's subtrees: kWideLanes); above
  /// 1 the SAH costs a leaf of n triangles as ceil(n / leaf_lanes) tests plus `lane_cost` per
  /// triangle (KdSubtreeBuilder).
  /// `account`: an account shared with other builders (the hybrid's), or null for the
  /// builder's own, which stops the build past `limit` bytes (0: the memory budget).
  Builder(const Mesh& mesh, const BuildParams& p, int max_depth, int leaf_lanes = 1,
          float lane_cost = 0.0f, MemoryAccount* account = nullptr, uint64_t limit = 0)
      : mesh_(mesh),
        kt_(p.kd_traversal_cost),
        ki_(p.kd_intersection_cost),
        empty_mult_(1.0f - p.kd_empty_bonus),
        max_depth_(max_depth),
        lanes_(uint32_t(std::max(1, leaf_lanes))),
        lane_cost_(lane_cost),
        cancel_(p.cancel),
        own_account_(limit > 0 ? limit : effective_memory_budget(p)),
        account_(account ? *account : own_account_) {}

  void build(std::vector<Event>& events, uint32_t n, const Box3& box, int depth, Subtree& out);
  /// build() of a subtree limited to `max_depth` levels (at most the builder's own limit):
  /// it starts deeper, which also keeps it sequential (see kParallelDepth).
  void build_subtree(std::vector<Event>& events, uint32_t n, const Box3& box, int max_depth,
                     Subtree& out) {
    build(events, n, box, max_depth_ - std::min(max_depth, max_depth_), out);
  }
  uint64_t sah_evaluations() const { return sah_evals_.load(); }

  /// Running account of the build's memory: event lists alive in the recursion, the tree
  /// built so far and the per-thread flags. Straddling triangles are copied into both
  /// children, so on long thin or overlapping triangles the events multiply with depth; once
  /// the account passes its limit (the build's peak bound) every pending node becomes an empty
  /// leaf at once and build() of KdTree throws, instead of the process running out of memory.
  void charge(int64_t bytes) { account_.charge(bytes); }
  bool over_budget() const { return account_.over_budget(); }
  int64_t peak_bytes() const { return account_.peak_bytes(); }
  uint64_t nodes_made() const { return nodes_made_.load(); }
  static int64_t tree_capacity(const Subtree& t) {
    return int64_t(t.nodes.capacity() * sizeof(KdNode) + t.prims.capacity() * sizeof(uint32_t));
  }

 private:
  struct Split {
    float cost = kInf;
    int axis = -1;
    float pos = 0;
    bool planar_left = true;
  };
  Split find_split(const std::vector<Event>& events, uint32_t n, const Box3& box);
  void leaf(std::vector<Event>& events, Subtree& out);
  /// Frees an event list and takes it off the account.
  void release(std::vector<Event>& events) {
    charge(-int64_t(events.capacity() * sizeof(Event)));
    std::vector<Event>().swap(events);
  }

  const Mesh& mesh_;
  float kt_, ki_, empty_mult_;
  int max_depth_;
  uint32_t lanes_;   ///< see the constructor
  float lane_cost_;  ///< see the constructor
  /// The tests a leaf of n triangles costs: groups of lanes_.
  float tests(uint32_t n) const {
    if (lanes_ == 1) return float(n);
    return float((n + lanes_ - 1) / lanes_) + lane_cost_ * float(n);
  }
  const CancelToken* cancel_;  // polled once per node
  std::atomic<uint64_t> sah_evals_{0};
  MemoryAccount own_account_;
  MemoryAccount& account_;
  std::atomic<uint64_t> nodes_made_{0};
  // Per-thread classification flags indexed by triangle: a node writes and reads them within
  // one task, so concurrent subtrees never see each other's flags.
  tbb::enumerable_thread_specific<std::vector<uint8_t>> flags_;
};

Builder::Split Builder::find_split(const std::vector<Event>& events, uint32_t n, const Box3& box) {
  Split best;
  const float area = box.area();
  if (!(area > 0.0f)) return best;
  const float inv_area = 1.0f / area;
  uint64_t evals = 0;
  size_t i = 0;
  const size_t size = events.size();
  for (int a = 0; a < 3; ++a) {
    check_cancel(cancel_);  // the root's sweep over millions of events takes a while
    uint32_t nl = 0, nr = n;
    const float lo = box.lo[a], hi = box.hi[a];
    while (i < size && events[i].axis == a) {
      const float p = events[i].pos;
      uint32_t pe = 0, pp = 0, ps = 0;
      while (i < size && events[i].axis == a && events[i].pos == p && events[i].type == kEnd)
        ++pe, ++i;
      while (i < size && events[i].axis == a && events[i].pos == p && events[i].type == kPlanar)
        ++pp, ++i;
      while (i < size && events[i].axis == a && events[i].pos == p && events[i].type == kStart)
        ++ps, ++i;
      const uint32_t np = pp;
      nr -= pp + pe;
      if (p >= lo && p <= hi) {
        ++evals;
        Box3 bl = box, br = box;
        bl.hi[a] = p;
        br.lo[a] = p;
        const float pl = bl.area() * inv_area, pr = br.area() * inv_area;
        const bool boundary = p == lo || p == hi;
        auto cost = [&](uint32_t cl, uint32_t cr) {
          if (boundary && (cl == 0 || cr == 0)) return kInf;
          float c = kt_ + ki_ * (pl * tests(cl) + pr * tests(cr));
          if (!boundary && (cl == 0 || cr == 0)) c *= empty_mult_;
          return c;
        };
        const float c_left = cost(nl + np, nr), c_right = cost(nl, nr + np);
        const bool left = c_left <= c_right;
        const float c = left ? c_left : c_right;
        if (c < best.cost) best = {c, a, p, left};
      }
      nl += ps + pp;
    }
  }
  sah_evals_.fetch_add(evals, std::memory_order_relaxed);
  return best;
}

void Builder::leaf(std::vector<Event>& events, Subtree& out) {
  std::vector<uint32_t> ids;
  // Over budget: an empty leaf, so the recursion unwinds at once (the tree is discarded).
  if (!over_budget())
    for (const Event& e : events)
      if (e.axis == 0 && e.type != kEnd) ids.push_back(e.prim);
  std::sort(ids.begin(), ids.end());
  const int64_t cap = tree_capacity(out);
  nodes_made_.fetch_add(1, std::memory_order_relaxed);
  out.nodes.push_back(make_leaf(out, ids));
  charge(tree_capacity(out) - cap);  // capacity, not size: vector growth keeps slack
  release(events);
}

void Builder::build(std::vector<Event>& events, uint32_t n, const Box3& box, int depth,
                    Subtree& out) {
  check_cancel(cancel_);
  if (n == 0 || depth >= max_depth_ || over_budget()) return leaf(events, out);
  const Split sp = find_split(events, n, box);
  if (sp.axis < 0 || !(sp.cost < ki_ * tests(n))) return leaf(events, out);

  // Classify (Wald & Havran sec. 5.1): on the split axis, a triangle ending at or before
  // the plane is left only, one starting at or after it right only, planar ones by position
  // and the chosen side; everything else straddles and goes to both.
  enum : uint8_t { kBoth = 0, kLeft = 1, kRight = 2 };
  auto& flags = flags_.local();
  if (flags.size() < mesh_.num_triangles()) flags.assign(mesh_.num_triangles(), kBoth);
  for (const Event& e : events)
    if (e.axis == 0 && e.type != kEnd) flags[e.prim] = kBoth;
  for (const Event& e : events) {
    if (e.axis != sp.axis) continue;
    if (e.type == kEnd && e.pos <= sp.pos)
      flags[e.prim] = kLeft;
    else if (e.type == kStart && e.pos >= sp.pos)
      flags[e.prim] = kRight;
    else if (e.type == kPlanar) {
      if (e.pos < sp.pos || (e.pos == sp.pos && sp.planar_left))
        flags[e.prim] = kLeft;
      else
        flags[e.prim] = kRight;
    }
  }
  std::vector<Event> left, right;
  std::vector<uint32_t> both;
  uint32_t n_left_only = 0, n_right_only = 0;
  for (const Event& e : events) {
    const uint8_t f = flags[e.prim];
    if (f == kLeft) {
      left.push_back(e);
      n_left_only += e.axis == 0 && e.type != kEnd;
    } else if (f == kRight) {
      right.push_back(e);
      n_right_only += e.axis == 0 && e.type != kEnd;
    } else if (e.axis == 0 && e.type != kEnd) {
      both.push_back(e.prim);
    }
  }
  charge(int64_t((left.capacity() + right.capacity()) * sizeof(Event) +
                 both.capacity() * sizeof(uint32_t)));
  release(events);
  check_cancel(cancel_);

  // Perfect splits: straddling triangles get new events from their bounds clipped to each
  // child; only these are sorted, then merged with the (already sorted) one-sided events.
  Box3 box_l = box, box_r = box;
  box_l.hi[sp.axis] = sp.pos;
  box_r.lo[sp.axis] = sp.pos;
  std::vector<Event> new_l, new_r;
  for (uint32_t prim : both) {
    const auto c = mesh_.corners(prim);
    for (int side = 0; side < 2; ++side) {
      const Box3& cb = side == 0 ? box_l : box_r;
      Box3 b;
      // Rounding may clip away a triangle that touches the child: keep its bounds instead.
      if (!clipped_bounds(c, cb, b)) b = mesh_.triangle_bounds(prim).intersect(cb);
      if (b.empty()) b = cb;
      add_events(side == 0 ? new_l : new_r, prim, b);
    }
  }
  auto merge_in = [](std::vector<Event>& sorted, std::vector<Event>& extra) {
    if (extra.empty()) return;
    std::sort(extra.begin(), extra.end(), event_less);
    std::vector<Event> merged;
    merged.reserve(sorted.size() + extra.size());
    std::merge(sorted.begin(), sorted.end(), extra.begin(), extra.end(), std::back_inserter(merged),
               event_less);
    sorted.swap(merged);
  };
  const size_t before = left.capacity() + right.capacity();
  charge(int64_t((new_l.capacity() + new_r.capacity()) * sizeof(Event)));
  merge_in(left, new_l);
  merge_in(right, new_r);
  release(new_l);
  release(new_r);
  charge(int64_t(left.capacity() + right.capacity()) * int64_t(sizeof(Event)) -
         int64_t(before * sizeof(Event)));
  const uint32_t nb = uint32_t(both.size());
  charge(-int64_t(both.capacity() * sizeof(uint32_t)));
  std::vector<uint32_t>().swap(both);
  const uint32_t nl = n_left_only + nb, nr = n_right_only + nb;
  check_cancel(cancel_);

  const size_t self = out.nodes.size();
  int64_t cap = tree_capacity(out);
  out.nodes.push_back({});
  charge(tree_capacity(out) - cap);
  nodes_made_.fetch_add(1, std::memory_order_relaxed);
  if (depth < kParallelDepth && n >= kParallelPrims) {
    Subtree sl, sr;
    tbb::parallel_invoke([&] { build(left, nl, box_l, depth + 1, sl); },
                         [&] { build(right, nr, box_r, depth + 1, sr); });
    auto append = [&](const Subtree& s) {
      const uint32_t node_base = uint32_t(out.nodes.size());
      const uint32_t prim_base = uint32_t(out.prims.size());
      for (KdNode nd : s.nodes) {
        if (!nd.leaf())
          nd.bits += node_base << 2;
        else if (nd.count() > 1)
          nd.prim_offset += prim_base;
        out.nodes.push_back(nd);
      }
      out.prims.insert(out.prims.end(), s.prims.begin(), s.prims.end());
    };
    // The subtrees are copied into `out`, then freed: both exist for a moment.
    const int64_t sub_bytes = tree_capacity(sl) + tree_capacity(sr);
    cap = tree_capacity(out);
    append(sl);
    charge(tree_capacity(out) - cap);
    const uint32_t above = uint32_t(out.nodes.size());
    cap = tree_capacity(out);
    append(sr);
    charge(tree_capacity(out) - cap);
    sl = {};
    sr = {};
    charge(-sub_bytes);
    out.nodes[self].split = sp.pos;
    out.nodes[self].bits = (above << 2) | uint32_t(sp.axis);
  } else {
    build(left, nl, box_l, depth + 1, out);
    const uint32_t above = uint32_t(out.nodes.size());
    build(right, nr, box_r, depth + 1, out);
    out.nodes[self].split = sp.pos;
    out.nodes[self].bits = (above << 2) | uint32_t(sp.axis);
  }
  if (out.nodes.size() >= (size_t(1) << 30))
    throw ParamError(
        "kdtree: more than 2^30 nodes; lower kd_max_depth or raise "
        "kd_intersection_cost relative to kd_traversal_cost");
}

}  // namespace

double kd_build_worst_case_bytes(double n, int depth, int threads) {
  // An event list holds at most 6 events of each of the node's triangles, each at most once,
  // in a vector with up to 2x slack: 144 bytes a triangle. The recursion holds the pending
  // siblings' lists along its path and, at a split, the node's list, both children's, the
  // straddlers' new events and a merge buffer; the parallel levels one such path a thread
  // more.
  const double list = 2.0 * 6.0 * n * double(sizeof(Event));
  const double paths = n >= double(kParallelPrims) ? double(threads) + 1.0 : 1.0;
  // At most 2^depth leaves of at most n references each and 2^(depth+1) nodes, with 2x
  // vector slack, the parallel levels' copies of their subtrees, and the final copy.
  const double leaves = std::ldexp(1.0, std::min(depth, 1000));
  const double tree = leaves * (2.0 * sizeof(KdNode) + n * sizeof(uint32_t));
  return (double(depth) + 8.0) * list * paths + 5.0 * tree + n * double(threads);
}

struct KdSubtreeBuilder::Impl {
  Impl(const Mesh& m, const BuildParams& p, int lanes, float cost, MemoryAccount* acc)
      : mesh(m), params(p), leaf_lanes(lanes), lane_cost(cost), account(acc) {}
  const Mesh& mesh;
  BuildParams params;
  int leaf_lanes;
  float lane_cost;
  MemoryAccount* account;
  /// One builder per thread: a Builder's classification flags are per thread already, but
  /// its memory account then follows each thread's share of the subtrees.
  mutable tbb::enumerable_thread_specific<std::unique_ptr<Builder>> builders;
};

KdSubtreeBuilder::KdSubtreeBuilder(const Mesh& mesh, const BuildParams& params, int max_depth,
                                   int leaf_lanes, float lane_cost, MemoryAccount* account)
    : impl_(std::make_unique<Impl>(mesh, params, leaf_lanes, lane_cost, account)),
      max_depth_(std::clamp(max_depth, 1, KdTree::kMaxDepth)) {}
KdSubtreeBuilder::~KdSubtreeBuilder() = default;

void KdSubtreeBuilder::build(const std::vector<uint32_t>& prims, const Box3& box,
                             std::vector<KdNode>& nodes, std::vector<uint32_t>& prims_out,
                             Box3& bounds) const {
  const Mesh& mesh = impl_->mesh;
  auto& b = impl_->builders.local();
  if (!b)
    b = std::make_unique<Builder>(mesh, impl_->params, KdTree::kMaxDepth, impl_->leaf_lanes,
                                  impl_->lane_cost, impl_->account);
  std::vector<Event> events;
  events.reserve(prims.size() * 6);
  bounds = Box3();
  for (uint32_t prim : prims) {
    Box3 cb;
    // As in the kd-tree's perfect splits: rounding may clip away a triangle that touches the
    // box, whose bounds are kept instead.
    const Box3 tb = mesh.triangle_bounds(prim);
    if (box.contains(tb.lo) && box.contains(tb.hi))
      cb = tb;
    else if (!clipped_bounds(mesh.corners(prim), box, cb))
      cb = tb.intersect(box);
    if (cb.empty()) cb = box;
    add_events(events, prim, cb);
    bounds.grow(cb.lo);
    bounds.grow(cb.hi);
  }
  bounds = bounds.intersect(box);
  cancellable_sort(events.begin(), events.end(), event_less, impl_->params.cancel);
  // The kd-tree's depth rule (8 + 1.3 log2 n, pbrt) for the subtree's triangles, at most
  // max_depth_.
  const int depth =
      std::min(max_depth_,
               int(std::lround(8.0 + 1.3 * std::log2(double(std::max<size_t>(1, prims.size()))))));
  Subtree out;
  b->charge(int64_t(events.capacity() * sizeof(Event)));
  b->build_subtree(events, uint32_t(prims.size()), bounds, depth, out);
  // The caller holds the subtree from here (and accounts for it).
  b->charge(-Builder::tree_capacity(out));
  if (b->over_budget())
    throw ParamError(
        "hybrid: the leaf subtrees outgrew the memory budget of " +
        format_bytes_iec(double(effective_memory_budget(impl_->params))) +
        ": triangles straddling many split planes are copied into every node they cross; "
        "a larger --cell-size, a lower --kd-intersection-cost, or raise --memory-budget-mb");
  nodes = std::move(out.nodes);
  prims_out = std::move(out.prims);
  // One-triangle leaves hold their triangle in the node; the hybrid's leaves index its
  // reference array (remapped to its own triangle order), so move it there.
  for (KdNode& n : nodes)
    if (n.leaf() && n.count() == 1) {
      const uint32_t p = n.one_prim;
      n.prim_offset = uint32_t(prims_out.size());
      prims_out.push_back(p);
    }
}

BuildStats KdTree::build(const Mesh& mesh, const BuildParams& params) {
  const auto t_start = std::chrono::steady_clock::now();
  if (!(params.kd_intersection_cost > 0.0f) || !(params.kd_traversal_cost >= 0.0f) ||
      !std::isfinite(params.kd_intersection_cost) || !std::isfinite(params.kd_traversal_cost))
    throw ParamError(
        "kdtree: kd_traversal_cost must be >= 0 and kd_intersection_cost > 0 "
        "(--kd-intersection-cost), e.g. 1 and 1.5");
  if (!(params.kd_empty_bonus >= 0.0f && params.kd_empty_bonus < 1.0f))
    throw ParamError("kdtree: kd_empty_bonus must be in [0, 1), e.g. 0.2; got " +
                     std::to_string(params.kd_empty_bonus));
  if (params.kd_max_depth < 0 || params.kd_max_depth > kMaxDepth)
    throw ParamError("kdtree: kd_max_depth must be 0 (auto) or 1.." + std::to_string(kMaxDepth) +
                     " (the traversal stack's size); got " + std::to_string(params.kd_max_depth));
  // Memory guard before any allocation. The peak of a typical build is the first split: the
  // sorted events (6 per triangle) and the children's copies (straddling triangles in both),
  // with the tree growing to ~40 bytes per triangle (landscape, dragon: 200-220 bytes per
  // triangle in all). Scenes whose triangles straddle many planes need far more; the builder
  // keeps a running account and stops at the budget (Builder::charge).
  const size_t n = mesh.num_triangles();
  const int threads = effective_threads(params.threads);
  const double nt = double(n);
  const std::string fix =
      "fewer splits need less: lower --kd-intersection-cost (e.g. 0.75) or set "
      "kd_max_depth";
  const uint64_t expected = check_memory_budget(
      "kdtree", n,
      {{"sorted events", 6.0 * nt * sizeof(Event)},
       {"children's events at the first split", 1.25 * 6.0 * nt * sizeof(Event)},
       {"tree (~40 bytes per triangle, measured)", 40.0 * nt},
       {"classification flags", nt * threads}},
      params, fix);

  mesh_ = &mesh;
  triangle_test_ = params.triangle_test;
  stats_ = {};
  nodes_.clear();
  prims_.clear();
  bounds_ = mesh.bounds();
  if (n == 0 || bounds_.empty()) {
    bounds_ = Box3();
    stats_.seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
    return stats_;
  }
  max_abs_ = std::max(max_component(abs(bounds_.lo)), max_component(abs(bounds_.hi)));
  clip_box_.set(bounds_);
  const int max_depth =
      params.kd_max_depth > 0
          ? params.kd_max_depth
          : std::min(kMaxDepth, int(std::lround(8.0 + 1.3 * std::log2(double(n)))));

  // The bound the build's account enforces: the most a build to max_depth can hold, within
  // the budget.
  const uint64_t estimate =
      build_peak_bound(kd_build_worst_case_bytes(nt, max_depth, threads), expected, params);
  tbb::task_arena arena(threads);
  Subtree tree;
  Builder builder(mesh, params, max_depth, 1, 0.0f, nullptr, estimate);
  builder.charge(int64_t(n) * threads + int64_t(n * 6 * sizeof(Event)));
  arena.execute([&] {
    std::vector<Event> events;
    events.reserve(n * 6);
    for (size_t i = 0; i < n; ++i) {
      if (i % 65536 == 0) check_cancel(params.cancel);
      add_events(events, uint32_t(i), mesh.triangle_bounds(i));
    }
    cancellable_sort(events.begin(), events.end(), event_less, params.cancel);
    builder.build(events, uint32_t(n), bounds_, 0, tree);
  });
  auto throw_over_budget = [&](uint64_t nodes) {
    throw ParamError(
        "kdtree: the build outgrew its peak bound of " + format_bytes_iec(double(estimate)) +
        " (the memory budget of " + format_bytes_iec(double(effective_memory_budget(params))) +
        ", or less: the most a tree of depth " + std::to_string(max_depth) +
        " can need; its account reached " + format_bytes_iec(double(builder.peak_bytes())) +
        " after " + std::to_string(nodes) + " nodes over " + std::to_string(n) +
        " triangles; a typical scene needs " + format_bytes_iec(double(expected)) +
        "): triangles straddling many split planes are copied into every node they "
        "cross; " +
        fix +
        ", or raise --memory-budget-mb (0 = half of physical "
        "memory) if the machine has the memory");
  };
  if (builder.over_budget()) {
    const uint64_t nodes = builder.nodes_made();
    tree = {};
    bounds_ = Box3();
    throw_over_budget(nodes);
  }
  // shrink_to_fit copies the tree once more: count the copy too.
  builder.charge(
      int64_t(tree.nodes.size() * sizeof(KdNode) + tree.prims.size() * sizeof(uint32_t)));
  if (builder.over_budget()) {
    const uint64_t nodes = builder.nodes_made();
    tree = {};
    bounds_ = Box3();
    throw_over_budget(nodes);
  }
  nodes_ = std::move(tree.nodes);
  prims_ = std::move(tree.prims);
  nodes_.shrink_to_fit();
  prims_.shrink_to_fit();

  // Statistics from a walk of the finished tree.
  stats_.sah_evaluations = builder.sah_evaluations();
  stats_.peak_estimate = estimate;
  stats_.peak_expected = expected;
  stats_.peak_accounted = uint64_t(std::max<int64_t>(0, builder.peak_bytes()));
  stats_.nodes = nodes_.size();
  struct Item {
    uint32_t node;
    uint32_t depth;
  };
  std::vector<Item> todo{{0, 0}};
  while (!todo.empty()) {
    const Item it = todo.back();
    todo.pop_back();
    const KdNode& nd = nodes_[it.node];
    stats_.max_depth = std::max(stats_.max_depth, it.depth);
    if (nd.leaf()) {
      ++stats_.leaves;
      stats_.empty_leaves += nd.count() == 0;
      stats_.references += nd.count();
    } else {
      todo.push_back({it.node + 1, it.depth + 1});
      todo.push_back({nd.above(), it.depth + 1});
    }
  }
  const uint64_t b_nodes = nodes_.size() * sizeof(KdNode),
                 b_refs = prims_.size() * sizeof(uint32_t);
  stats_.bytes = b_nodes + b_refs;
  stats_.bytes_by_part = {{"nodes", b_nodes}, {"references", b_refs}};
  stats_.extra = {{"max_depth_limit", std::to_string(max_depth)},
                  {"build account peak", format_bytes_iec(double(builder.peak_bytes()))}};
  stats_.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return stats_;
}

namespace {
template <class Fn>
void walk(const std::vector<KdNode>& nodes, uint32_t node, const Box3& box, int depth, Fn&& fn) {
  fn(node, box, depth);
  const KdNode& n = nodes[node];
  if (n.leaf()) return;
  Box3 lo = box, hi = box;
  lo.hi[n.axis()] = n.split;
  hi.lo[n.axis()] = n.split;
  walk(nodes, node + 1, lo, depth + 1, fn);
  walk(nodes, n.above(), hi, depth + 1, fn);
}
}  // namespace

void KdTree::for_each_split(const std::function<void(const SplitPlane&)>& fn) const {
  if (nodes_.empty()) return;
  walk(nodes_, 0, bounds_, 0, [&](uint32_t i, const Box3& box, int depth) {
    const KdNode& n = nodes_[i];
    if (!n.leaf()) fn({n.axis(), n.split, box, depth});
  });
}

void KdTree::for_each_box(const std::function<void(const StructureBox&)>& fn) const {
  if (nodes_.empty()) return;
  walk(nodes_, 0, bounds_, 0, [&](uint32_t i, const Box3& box, int depth) {
    const KdNode& n = nodes_[i];
    if (n.leaf()) fn({box, depth, true, n.count()});
  });
}

}  // namespace kdgrid
