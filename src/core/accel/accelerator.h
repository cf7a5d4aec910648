// The accelerator contract (docs/DESIGN.md): every acceleration structure — brute force, BVH,
// uniform grid, SAH kd-tree, the hybrid grid/kd-tree, the irregular grid and Embree —
// implements this interface, so the renderer, benchmark, tests and viewer treat them alike.
//
// Counting and tracing are compile-time probes of one traversal template: the fast path
// is instantiated with NoProbe whose hooks are empty inline functions, so it pays nothing;
// CountProbe and TraceProbe instantiate the very same code with the hooks live.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "accel/params.h"
#include "accel/triangle.h"
#include "math/ray.h"
#include "scene/mesh.h"

namespace kdgrid {

/// What a build did and what it costs. Fields a structure does not have stay 0.
struct BuildStats {
  double seconds = 0.0;
  uint64_t sah_evaluations = 0;  ///< SAH cost evaluations / candidate planes tested
  uint64_t nodes = 0;            ///< all nodes (interior + leaves), or cells for grids
  uint64_t leaves = 0;
  uint64_t empty_leaves = 0;
  uint64_t references = 0;  ///< triangle references stored in leaves/cells
  uint32_t max_depth = 0;
  uint64_t bytes = 0;  ///< structure bytes (excludes the Mesh the caller owns)
  /// Peak bytes the build may use (structure and transient build memory), fixed before it
  /// allocates: an upper bound from what is known then (triangle count, resolution, depth and
  /// cell limits), capped by the memory budget. A build that would pass it stops with a
  /// ParamError (accel/guards.h), so `bytes` and `peak_accounted` never exceed it. 0 where a
  /// structure makes no estimate.
  uint64_t peak_estimate = 0;
  /// The peak a typical scene of this size needs (per-triangle figures or a computed
  /// layout): the guard's first check against the budget; equals peak_estimate where that is
  /// computed exactly.
  uint64_t peak_expected = 0;
  /// The highest bytes the build's own running account reached (structure so far and
  /// transient lists), where it keeps one; 0 otherwise.
  uint64_t peak_accounted = 0;
  /// Breakdown of `bytes` by part, e.g. {"nodes", ...}, {"references", ...}, {"matrix", ...}.
  std::vector<std::pair<std::string, uint64_t>> bytes_by_part;
  /// Structure-specific facts shown by `kdgrid trace` and the viewer ("resolution", "64x64x32").
  std::vector<std::pair<std::string, std::string>> extra;
};

/// Per-ray (or summed) traversal counts.
struct RayCounters {
  uint64_t steps = 0;          ///< nodes or cells entered, interior and leaf (docs/DESIGN.md)
  uint64_t leaves = 0;         ///< leaves/cells whose triangles were tested
  uint64_t tri_tests = 0;      ///< ray/triangle intersection tests
  uint64_t mailbox_skips = 0;  ///< tests avoided by mailboxing
  uint64_t lookups = 0;        ///< cell-matrix lookups (grids, hybrid)

  RayCounters& operator+=(const RayCounters& o) {
    steps += o.steps;
    leaves += o.leaves;
    tri_tests += o.tri_tests;
    mailbox_skips += o.mailbox_skips;
    lookups += o.lookups;
    return *this;
  }
  bool operator==(const RayCounters& o) const = default;
};

enum class StepKind : uint8_t { Inner, Leaf, Cell };

/// One node/leaf/cell a ray visited, with its box and the ray's [t_in, t_out] inside it.
struct TraceStep {
  StepKind kind = StepKind::Leaf;
  int depth = 0;
  uint64_t id = 0;  ///< node index or linear cell index
  Box3 box;
  float t_in = 0, t_out = 0;
  uint32_t first_tested = 0;  ///< range into Trace::tested
  uint32_t num_tested = 0;
};

/// The ordered traversal of one ray: what the viewer draws for a picked pixel.
struct Trace {
  std::vector<TraceStep> steps;
  std::vector<uint32_t> tested;  ///< triangles tested, in order, grouped by step
  Hit hit;
  RayCounters counters;
  bool occluded = false;  ///< the answer of an any-hit trace (Accelerator::trace_occluded)
};

/// A kd split plane (kd-tree, hybrid) with the box of the node it splits.
struct SplitPlane {
  int axis = 0;
  float position = 0;
  Box3 node_box;
  int depth = 0;
};

/// A box of the structure for overlays: BVH nodes, kd/hybrid leaves, grid cells.
struct StructureBox {
  Box3 box;
  int depth = 0;
  bool leaf = false;
  uint32_t num_triangles = 0;
};

// ---- traversal policies ---------------------------------------------------------------

/// Fast path: every hook is empty and compiles away.
struct NoProbe {
  static constexpr bool kCount = false;
  static constexpr bool kTrace = false;
  void step() {}
  void leaf() {}
  void tri_test(uint32_t) {}
  void mailbox_skip() {}
  void lookup() {}
  void visit(const TraceStep&) {}
};

/// Counts per ray.
struct CountProbe {
  static constexpr bool kCount = true;
  static constexpr bool kTrace = false;
  RayCounters c;
  void step() { ++c.steps; }
  void leaf() { ++c.leaves; }
  void tri_test(uint32_t) { ++c.tri_tests; }
  void mailbox_skip() { ++c.mailbox_skips; }
  void lookup() { ++c.lookups; }
  void visit(const TraceStep&) {}
};

/// Counts and records the ordered list of visited nodes and tested triangles. Traversals
/// call visit() (guarded by `if constexpr (Probe::kTrace)`) for each node/cell they enter,
/// before the tri_test() calls of that node.
struct TraceProbe {
  static constexpr bool kCount = true;
  static constexpr bool kTrace = true;
  Trace* trace = nullptr;
  explicit TraceProbe(Trace* t) : trace(t) {}
  void step() { ++trace->counters.steps; }
  void leaf() { ++trace->counters.leaves; }
  void tri_test(uint32_t prim) {
    ++trace->counters.tri_tests;
    trace->tested.push_back(prim);
    if (!trace->steps.empty()) ++trace->steps.back().num_tested;
  }
  void mailbox_skip() { ++trace->counters.mailbox_skips; }
  void lookup() { ++trace->counters.lookups; }
  void visit(TraceStep s) {
    s.first_tested = static_cast<uint32_t>(trace->tested.size());
    s.num_tested = 0;
    trace->steps.push_back(s);
  }
};

// ---- the interface ----------------------------------------------------------------------

class Accelerator {
 public:
  virtual ~Accelerator() = default;

  /// Short name used on the command line ("bvh", "kdtree", "hybrid", ...).
  virtual std::string name() const = 0;

  /// Builds over `mesh`, which must outlive the accelerator. Throws ParamError for bad
  /// parameters (with the fix in the message). Rebuilding replaces the previous structure.
  virtual BuildStats build(const Mesh& mesh, const BuildParams& params) = 0;

  /// Closest hit in [ray.tmin, ray.tmax). Invalid rays (NaN, zero direction) miss. For a ray
  /// that starts on a surface (its origin on a triangle's plane within rounding, see
  /// render/offset.h) whether that triangle is reported is implementation-defined.
  virtual bool intersect(const Ray& ray, Hit& hit) const = 0;
  /// Any hit in [ray.tmin, ray.tmax).
  virtual bool occluded(const Ray& ray) const = 0;

  /// Closest hits of `n` rays traced together (the primary rays of an image tile, in rows):
  /// found[i] and, where it is true, hits[i] are bitwise what intersect(rays[i], hits[i])
  /// gives; hits[i] is left as it was where found[i] is false. Any n >= 0 is accepted;
  /// structures with a packet walk cut the rays into packets of packet_width(). This default
  /// loops over intersect(), so every structure answers it.
  virtual void intersect_packet(const Ray* rays, int n, Hit* hits, bool* found) const {
    for (int i = 0; i < n; ++i) found[i] = intersect(rays[i], hits[i]);
  }
  /// Any hits of `n` rays traced together: occluded[i] is occluded(rays[i]).
  virtual void occluded_packet(const Ray* rays, int n, bool* occluded_out) const {
    for (int i = 0; i < n; ++i) occluded_out[i] = occluded(rays[i]);
  }
  /// Rays the structure's own packet query walks together (1: the default loop over single
  /// rays), for reports.
  virtual int packet_width() const { return 1; }

  /// Same traversals as above, counting. Adds to `counters`.
  virtual bool intersect_counted(const Ray& ray, Hit& hit, RayCounters& counters) const = 0;
  virtual bool occluded_counted(const Ray& ray, RayCounters& counters) const = 0;
  /// False for structures that cannot count (Embree): their counts stay zero.
  virtual bool has_counters() const { return true; }

  /// The closest-hit traversal of one ray, step by step.
  virtual Trace trace(const Ray& ray) const = 0;
  /// The any-hit traversal of one ray, step by step, as occluded() walks it (it stops at the
  /// first hit found); Trace::occluded holds the answer and Trace::hit stays invalid. This
  /// default, for structures that cannot trace (Embree), holds only the answer.
  virtual Trace trace_occluded(const Ray& ray) const {
    Trace t;
    t.occluded = occluded(ray);
    return t;
  }

  /// Structure bytes, as in BuildStats::bytes.
  virtual uint64_t memory_bytes() const = 0;
  virtual const BuildStats& stats() const = 0;

  /// Split planes of tree structures, in depth-first order (nothing for others).
  virtual void for_each_split(const std::function<void(const SplitPlane&)>& fn) const {}
  /// Boxes for overlays: BVH nodes, kd/hybrid leaves, grid cells (non-empty ones).
  virtual void for_each_box(const std::function<void(const StructureBox&)>& fn) const {}
};

/// Implements the virtual entry points from one templated traversal in Derived:
///
///   template <class TriangleTest, class Probe, bool kAny>
///   bool traverse(const Ray&, Hit* hit, Probe&) const;
///
/// TriangleTest is WatertightTest, MollerTest or NullTest (chosen by BuildParams::triangle_test at
/// build time), Probe is NoProbe / CountProbe / TraceProbe, and kAny asks for any hit (an
/// occlusion query: `hit` is null and never written) instead of the closest (written to *hit).
/// Derived stores its BuildStats in stats_ and the chosen triangle test in triangle_test_.
template <class Derived>
class AcceleratorBase : public Accelerator {
 public:
  bool intersect(const Ray& ray, Hit& hit) const final {
    NoProbe s;
    return dispatch<false>(ray, &hit, s);
  }
  bool occluded(const Ray& ray) const final {
    NoProbe s;
    return dispatch<true>(ray, nullptr, s);
  }
  bool intersect_counted(const Ray& ray, Hit& hit, RayCounters& counters) const final {
    CountProbe s;
    const bool r = dispatch<false>(ray, &hit, s);
    counters += s.c;
    return r;
  }
  bool occluded_counted(const Ray& ray, RayCounters& counters) const final {
    CountProbe s;
    const bool r = dispatch<true>(ray, nullptr, s);
    counters += s.c;
    return r;
  }
  Trace trace(const Ray& ray) const final {
    Trace t;
    TraceProbe s(&t);
    Hit h;
    dispatch<false>(ray, &h, s);
    t.hit = h;
    return t;
  }
  Trace trace_occluded(const Ray& ray) const final {
    Trace t;
    TraceProbe s(&t);
    t.occluded = dispatch<true>(ray, nullptr, s);
    return t;
  }
  uint64_t memory_bytes() const override { return stats_.bytes; }
  const BuildStats& stats() const final { return stats_; }

 protected:
  BuildStats stats_;
  TriangleTestKind triangle_test_ = TriangleTestKind::Watertight;

 private:
  const Derived& self() const { return static_cast<const Derived&>(*this); }
  template <bool kAny, class Probe>
  bool dispatch(const Ray& ray, Hit* hit, Probe& s) const {
    if (!ray_is_valid(ray)) return false;
    if (triangle_test_ == TriangleTestKind::Watertight)
      return self().template traverse<WatertightTest, Probe, kAny>(ray, hit, s);
    if (triangle_test_ == TriangleTestKind::Moller)
      return self().template traverse<MollerTest, Probe, kAny>(ray, hit, s);
    return self().template traverse<NullTest, Probe, kAny>(ray, hit, s);
  }
};

/// Names accepted by make_accelerator, in the order tables list them.
std::vector<std::string> accelerator_names();
/// Whether `name` is one of Embree's configurations (embree, embree-robust, embree-high;
/// accel/embree.h): the external reference, with its own triangle test and no counters.
bool is_embree(const std::string& name);
/// Creates an (unbuilt) accelerator by name. Throws ParamError naming the valid choices.
std::unique_ptr<Accelerator> make_accelerator(const std::string& name);
/// Convenience: create and build, returning the structure (its stats() hold BuildStats).
std::unique_ptr<Accelerator> build_accelerator(const std::string& name, const Mesh& mesh,
                                               const BuildParams& params);

}  // namespace kdgrid
