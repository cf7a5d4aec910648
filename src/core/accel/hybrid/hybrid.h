// The hybrid regular grid / kd-tree (after D. Muñoz Díaz; docs/HYBRID.md has the long form):
// an SAH kd-tree whose split planes lie only on the boundaries of a regular grid of cells,
// plus a cell -> leaf map, so that a ray steps from leaf to leaf by index arithmetic, like a
// uniform grid, instead of descending the tree. The files of accel/hybrid/:
//
//   hybrid.h          this class: parameters, records' names, the walk's declarations
//   records.h         Node, Leaf (the step box), KdBox (the kd box), the triangle groups' and the
//                     flat subtrees' layouts
//   cell_map.h, .cpp  the cell -> leaf map: dense (the paper's) or bricked (default); lookup
//   walk.h            the ray walk: clip, entry cell, leaf steps with wide tests
//   walk_flat.h       the walk of a flat subtree: its leaves' boxes clipped at once
//   next_leaf_cache.h the per-thread next-leaf cache (NextLeafCache)
//   mailbox.h         the lane-by-lane walk's mailbox and the exact walk's record
//   packet.cpp        the packet walk: up to 64 rays down the tree together, triangle groups
//                     culled against them, then tested a triangle against 16 (or 8) rays
//   packet_lanes.h    the packet walk's lane operations, for AVX-512 and for AVX2
//   build.cpp         GridKdHybrid::build; choose_cell_size (explicit size or the auto rule)
//   tree.cpp          the kd-tree on cell boundaries, its leaf subtrees, flattened
//   widen.cpp         widened empty leaves
//   build_estimate.h  HybridEstimate, the auto rule's caps and the estimate model's constants
//   estimate.cpp      GridKdHybrid::estimate: grid, bytes and seconds of a build before it runs
//   hybrid.cpp        leaf boxes, split planes and map sizes for tests and the viewer
//   build.h           what the build's files share
//
// Grid: cells of edge `cell` from the scene's low corner, dims[a] = max(1, ceil(extent[a] /
// cell)); the walk works in grid space, g = (p - origin) / cell, where cell boundaries are the
// integers. Auto cell size (cell_size <= 0): the cell_percentile-th percentile of the
// triangles' largest extents, lowered to give at least kHybridAutoCellsPerTriangle cells per
// triangle, then raised to at most kHybridAutoMaxAxisCells per axis and kHybridAutoMaxCells in
// all (kHybridAutoMaxCellsPlain with plain leaves). Leaves of more than hybrid_subtree_min
// triangles keep a kd subtree, walked by the kd-tree's traversal, or with 5 to 16 leaves holding
// triangles stored flat and tested all at once (hybrid_flat_subtrees). Empty leaves' step boxes are
// widened over the empty cells around them (hybrid_expand_empty). A walk takes at most
// nx+ny+nz+1 steps; the loop enforces that bound.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <type_traits>
#include <vector>

#include "accel/accelerator.h"
#include "accel/hybrid/build_estimate.h"
#include "accel/hybrid/cell_map.h"
#include "accel/hybrid/records.h"
#include "accel/kd_kernel.h"
#include "math/simd.h"
#include "util/cancel.h"

namespace kdgrid {

namespace hybrid {
template <class TriangleTest>
struct WalkState;
struct Exit;
struct LocalHit;
enum class StepResult;
template <class Probe>
struct StatsMark;
struct PacketRays;
}  // namespace hybrid

/// The hybrid of a regular grid and an SAH kd-tree (accelerator name "hybrid"): the kd-tree's
/// splits lie on the grid's cell boundaries, and the cell map takes a ray from leaf to leaf.
class GridKdHybrid final : public AcceleratorBase<GridKdHybrid> {
 public:
  /// See HybridEstimate. Throws ParamError for invalid parameters, as build() does.
  static HybridEstimate estimate(const Mesh& mesh, const BuildParams& params);
  using Node = hybrid::Node;
  using Leaf = hybrid::Leaf;
  using KdBox = hybrid::KdBox;
  static constexpr uint32_t kSubtreeFlag = hybrid::kSubtreeFlag;
  /// A leaf subtree in sub_nodes_ starts with the box of its clipped triangles (its corners
  /// as two ClipBox4 lanes, x, y, z, -inf and x, y, z, +inf, in this many nodes' bytes), which
  /// a ray is clipped to first (kd_clip_x4), then the kd-tree's nodes.
  static constexpr uint32_t kSubBoxNodes = 4;
  /// Leaf subtrees are at most this many levels deep (64 leaves): deeper ones test fewer
  /// triangles but build longer and take more memory for no speed (docs/HYBRID.md, "Leaf
  /// subtrees").
  static constexpr int kSubMaxDepth = 6;
  /// A leaf with more references than this gets the kd-tree's whole depth rule (8 + 1.3
  /// log2 n) instead of kSubMaxDepth levels: 64 leaves of 16 triangles or more would be
  /// tested in bulk. Few leaves of the auto grid are so large (the build's "largest leaf");
  /// with one cell the whole scene is one leaf,
  /// whose subtree is then the kd-tree itself.
  static constexpr uint32_t kSubDeepMin = 1024;
  /// Reference ranges are widened by this many cells so that geometry on a cell boundary is
  /// referenced on both sides and no rounding (1e-12 cells in double) can lose a triangle.
  static constexpr double kRangeEps = 1e-6;
  /// Direct-mapped per-ray mailbox of recently tested triangles (power of two): a triangle
  /// referenced by several leaves is tested once; 32 entries catch most repeats at no cost. The
  /// lane-by-lane walk's (not kWide): the wide walk tests every lane, as its look-ups cost more
  /// than the repeats they saved (docs/HYBRID.md, "Wide leaves").
  static constexpr int kMailbox = 32;
  /// Triangles a colliding one pushed out of the mailbox are kept too, up to this many per ray;
  /// a ray that would evict more is walked again by the exact walk (walk.h, tested_before), so
  /// no ray tests a triangle twice. 64 (256 bytes of the ray's state) covers every ray of the
  /// suite's ray sets on their default grids (docs/HYBRID.md, "The walk").
  static constexpr int kEvicted = 64;
  /// Empty-leaf boxes are computed when the occupied-cell table has at most this many
  /// entries ((nx+1)(ny+1)(nz+1), 4 bytes each: 128 MiB); the auto rule stays below 2^24 cells.
  static constexpr uint64_t kMaxExpandEntries = uint64_t(1) << 25;
  /// The top-level SAH's cost of a leaf of n triangles, in triangle tests:
  /// ceil(n / kWideLanes) group tests plus this much per triangle (with kWideLanes 1, n tests).
  /// The groups' count alone (0) makes leaves too large for rays that stop early (Sponza's
  /// primary rays); a larger cost makes more, smaller leaves and more copies for no more speed
  /// (docs/HYBRID.md, "Wide leaves"; docs/EXPERIMENTS.md, "Wide leaves").
  static constexpr float kWideLaneCost = kWideLanes > 1 ? 0.125f : 0.0f;
  /// Whether leaves are tested by WatertightWide, a group's lanes at once: for WatertightTest
  /// where groups have more than one lane. Every other test (WatertightScalar, the reference the
  /// wide test is held to, among them) runs lane by lane.
  template <class TriangleTest>
  static constexpr bool kWide = (std::is_same_v<TriangleTest, WatertightTest> && kWideLanes > 1);
  /// Whether the walk tests through the mailbox: not with wide groups, nor with no test at all
  /// (NullTest, the traversal-only timing), which walks and counts the lanes as the wide walk
  /// does, so that it times and counts that walk without its tests.
  template <class TriangleTest>
  static constexpr bool kMailboxed =
      !(kWideLanes > 1 && (kWide<TriangleTest> || std::is_same_v<TriangleTest, NullTest>));

  std::string name() const override { return "hybrid"; }
  BuildStats build(const Mesh& mesh, const BuildParams& params) override;

  /// The walk of one ray (AcceleratorBase's contract). The fast walk (kExact false) tests
  /// through the ray's mailbox and gives the ray to rewalk when the mailbox cannot tell every
  /// repeat (tested_before): one compare a ray. The exact walk, its copy with a record of every
  /// triangle tested, runs only there.
  template <class TriangleTest, class Probe, bool kAny, bool kExact = false>
  bool traverse(const Ray& ray, Hit* hit, Probe& probe) const;

  /// Packets of up to 16 rays (8 in builds for AVX2) walked together (packet.cpp: one ray a
  /// float lane, the kd-tree and the leaves' subtrees walked by the packet, each triangle group
  /// culled against it). Each ray's answer is its single walk's, except that of two triangles hit
  /// at exactly the same t the packet may report the other. Builds without AVX2, and triangle
  /// tests other than the watertight one, loop over the single walk.
  void intersect_packet(const Ray* rays, int n, Hit* hits, bool* found) const override;
  void occluded_packet(const Ray* rays, int n, bool* occluded_out) const override;
  int packet_width() const override;
  /// How the packet walk bounds rays [0, min(n, hybrid::kPacketLanes)) as one packet in its cull
  /// (packet.cpp): by their origins' box, by where they cross one plane (rays towards one point
  /// cross at their common end), or not at all, left to the single walk (tests).
  enum class PacketCull { Single, Origins, Crossings };
  PacketCull packet_cull(const Ray* rays, int n) const;

  void for_each_split(const std::function<void(const SplitPlane&)>& fn) const override;
  void for_each_box(const std::function<void(const StructureBox&)>& fn) const override;

  // ---- introspection (tests, viewer) ----
  double cell_size() const { return cell_; }
  const int32_t* dims() const { return dims_; }
  Vec3 origin() const { return {float(origin_[0]), float(origin_[1]), float(origin_[2])}; }
  /// The leaf covering cell (x, y, z) (must lie inside the grid).
  uint32_t leaf_at(int32_t x, int32_t y, int32_t z) const { return lookup(x, y, z); }
  const std::vector<Leaf>& leaves() const { return leaves_; }
  /// Next (and entry) leaves the calling thread took from its next-leaf cache so far, over
  /// every hybrid (tests, `kdgrid trace`; see walk.h, NextLeafCache).
  static uint64_t next_leaves_from_cache();
  /// Rays whose traversal reached the nx+ny+nz+1 step bound (a correct traversal never does).
  uint64_t step_bound_errors() const { return step_errors_.load(std::memory_order_relaxed); }
  /// Rays (queries) the fast walk gave up to the exact walk, having evicted more than kEvicted
  /// triangles from their mailbox (walk.h, tested_before).
  uint64_t rewalked_rays() const { return rewalks_.load(std::memory_order_relaxed); }
  /// World box of a leaf: the box its steps cross (an empty leaf's widened box).
  Box3 step_box(uint32_t leaf) const;
  /// Bytes the storage selected by `dense` would take for the current tree (computed, not
  /// allocated; the bricked figure is exact).
  uint64_t matrix_bytes(bool dense) const;

 private:
  // ---- the walk (defined in walk.h) ----
  template <class TriangleTest>
  using WalkState = hybrid::WalkState<TriangleTest>;
  using Exit = hybrid::Exit;
  using LocalHit = hybrid::LocalHit;
  using StepResult = hybrid::StepResult;

  [[gnu::always_inline]] uint32_t lookup(int32_t x, int32_t y, int32_t z) const {
    return map_.lookup(x, y, z, nodes_.data());
  }
  /// The leaf of cell n, which the ray reaches across the face of leaf `from` on `axis`:
  /// from the next-leaf cache when it holds a leaf whose kd box holds n, else from the map.
  [[gnu::always_inline]] inline uint32_t next_leaf(const Int4& n, uint32_t from, int axis) const;
  /// The leaf of a ray's entry cell c: the thread's previous entry leaf when its kd box holds
  /// c (rays from one camera mostly start in one leaf), else the map's.
  [[gnu::always_inline]] inline uint32_t start_leaf(const Int4& c) const;
  /// Whether cell c lies in the kd box of leaf `id`, one of this structure's (the cache holds
  /// only this structure's leaves: NextLeafCache::claim). The kd boxes tile the grid, so true
  /// means that `id` is the leaf of c.
  [[gnu::always_inline]] inline bool in_kd_box(uint32_t id, const Int4& c) const;

  /// Takes back the abandoned fast walk's counts (to `mark`) and walks the ray again exactly:
  /// the same leaves and tests in the same order, each triangle once, so the same closest hit.
  /// Out of line and cold, so that the fast walk only pays the branch to it.
  template <class TriangleTest, class Probe, bool kAny>
  [[gnu::noinline, gnu::cold]] bool rewalk(const Ray& ray, Hit* hit, Probe& probe,
                                           const hybrid::StatsMark<Probe>& mark) const;
  /// Where the ray leaves a leaf's step box (the nearest far plane) and the cell past it.
  template <class TriangleTest>
  [[gnu::always_inline]] inline Exit leaf_exit(const WalkState<TriangleTest>& w,
                                               const Leaf& leaf_rec) const;
  /// The rest of leaf_exit once the exit axis A is known (a branch per axis: see leaf_exit).
  template <int A, class TriangleTest>
  [[gnu::always_inline]] inline void exit_through(const WalkState<TriangleTest>& w,
                                                  const Double4& lo, const Double4& hi,
                                                  const Double4& far, double t, Exit& ex) const;
  /// Counts one leaf step; true (and a step-bound error counted) once the ray has taken more
  /// than the nx+ny+nz+1 steps a correct walk can take.
  template <class TriangleTest>
  [[gnu::always_inline]] inline bool over_step_bound(WalkState<TriangleTest>& w) const;
  /// Clips the ray to the grid and finds its entry cell's leaf; false if it misses the grid.
  /// Inlined into traverse(): out of line, every ray pays a call and the stores that build the
  /// walk's state (docs/EXPERIMENTS.md, "The walk").
  template <class TriangleTest>
  [[gnu::always_inline]] inline bool walk_begin(WalkState<TriangleTest>& w, const Ray& ray) const;
  /// One leaf step: tests the leaf's triangles and moves to the next leaf. Out of line on
  /// purpose: as its own function, with the ray's state in memory, the step compiled better
  /// than inlined in the ray's loop (docs/EXPERIMENTS.md, "The walk").
  /// Empty leaves do not come here (traced walks excepted): traverse() steps over them inline,
  /// with nothing to test.
  template <class TriangleTest, class Probe, bool kAny, bool kExact>
  [[gnu::noinline]] StepResult walk_step(WalkState<TriangleTest>& w, Probe& probe) const;
  /// Walks the flat subtree at float `at` of flat_subtree_floats_ (records.h, "Flat subtrees") over
  /// the ray's segment in leaf `leaf_id`, which ends at t_exit: the leaves the ray meets, found all
  /// at once, tested in the kd walk's order until the closest hit lies before the next one. The
  /// closest hit goes to w (its triangle and u, v through h). True: an any-hit query answered.
  template <class TriangleTest, class Probe, bool kAny, bool kExact>
  [[gnu::always_inline]] inline bool walk_flat(WalkState<TriangleTest>& w, Probe& probe,
                                               uint32_t leaf_id, uint32_t at, double t_exit,
                                               LocalHit& h) const;
  /// Tests the `count` triangles of a leaf (or a subtree's leaf), from group `first` on, the one
  /// loop of both: with kWide, each group's lanes together by WatertightWide, without the
  /// mailbox; else lane by lane in order, through the ray's mailbox. The closest hit goes to
  /// best, found and h, which the subtree's walk keeps in its locals. True: an any-hit query
  /// answered.
  template <class TriangleTest, class Probe, bool kAny, bool kExact>
  [[gnu::always_inline]] inline bool test_groups(WalkState<TriangleTest>& w, Probe& probe,
                                                 const typename TriangleTest::RayData& rd,
                                                 float tmin, uint32_t first, uint32_t count,
                                                 float& best, bool& found, LocalHit& h) const;

  // ---- packets (packet.cpp) ----
  /// Whether the packet walk answers packets: a build with packet lanes (AVX-512, or AVX2 and
  /// FMA; hybrid::kPacketLanes), the watertight test, a built structure.
  bool packets_ready() const {
    return hybrid::kPacketLanes != 0 && triangle_test_ == TriangleTestKind::Watertight &&
           !leaves_.empty() && !nodes_.empty();
  }
  /// Up to 4 hybrid::kPacketLanes rays (64, or 32 with AVX2) as up to four packets of
  /// kPacketLanes lanes: those that can share a walk (valid, their direction components normal
  /// numbers, one sign per axis and, within a packet, the test's shear axes of its first) by
  /// packet_walk, the others (and a packet of one) by the single walk.
  template <bool kAny>
  void packet_call(const Ray* rays, int n, Hit* hits, bool* out) const;
  /// The walk of the K (1 to 4) packets which[0..K) of R (rays kPacketLanes which[k] + i for the
  /// lanes i of lanes[which[k]], all with one direction sign per axis), down the grid's kd-tree
  /// together; false (and nothing written) when its stack would overflow, for the single walk to
  /// answer.
  template <bool kAny, int K>
  bool packet_walk(const hybrid::PacketRays* R, const uint32_t* lanes, const int* which, Hit* hits,
                   bool* out) const;
  /// One packet walk's state and steps (packet.cpp).
  template <bool kAny, int K>
  struct PacketWalk;

  // ---- the build (build.cpp, tree.cpp) ----
  /// Where build_tree puts the groups (records.h, "Triangle groups"): group g's lanes (mesh
  /// indices) from lanes[start[g]], fill[g] of them holding the leaf's triangles (by lane, the
  /// others repeat the last), corners[g] distinct corners (shared corners: lane l's corner k is
  /// corner index[3 l + k] of its group), its float offset; and the floats of all groups.
  struct GroupPlan {
    std::vector<uint32_t> lanes, start, offset, fill, corners;
    std::vector<uint8_t> index;
    std::vector<uint8_t> narrow;  ///< per group: its triangle ids as 16-bit differences
    uint64_t floats = 0;
    /// What a group adds to the plan (start, offset, fill, corners, narrow), for the build's
    /// memory account.
    static constexpr double kBytesPerGroup = 4 * sizeof(uint32_t) + sizeof(uint8_t);
  };
  /// Builds nodes_, leaves_ and sub_nodes_; `plan` gets the groups and `references` the leaves'
  /// references.
  void build_tree(const Mesh& mesh, const BuildParams& params, GroupPlan& plan,
                  uint64_t& references);
  /// build's steps (build.cpp), in order: the state emptied, the grid's box and the walk's
  /// constants set, the parts built (tree, groups, matrix, empty-leaf boxes; `bound`: the peak
  /// bound), the figures reported.
  struct BuildPhases;
  void reset_for_build(const Mesh& mesh, const BuildParams& params, uint64_t estimate);
  void set_grid_box();
  void build_parts(const Mesh& mesh, const BuildParams& params, uint64_t bound,
                   BuildPhases& phases);
  void fill_groups(const Mesh& mesh, const GroupPlan& plan);
  void report_build(const BuildParams& params, const std::string& rule, const BuildPhases& phases);
  std::string subtrees_text(const BuildParams& params) const;
  std::string groups_text(uint64_t references) const;
  /// build_tree's flattening of the build tree (tree.cpp).
  struct TreeFlattener;

  const Mesh* mesh_ = nullptr;
  double origin_[3] = {0, 0, 0};
  Double4 origin4_ = {0, 0, 0, 0};     ///< origin_ and 0, for the walk's set-up
  Double4 last_cell4_ = {0, 0, 0, 0};  ///< the last cell on each axis (dims_ - 1) and 0, in double
  double cell_ = 1.0, inv_cell_ = 1.0;
  int32_t dims_[3] = {1, 1, 1};
  hybrid::CellMap map_;   ///< cell -> leaf (BuildParams::hybrid_dense_matrix selects the form)
  Box3 world_box_;        ///< the grid's world box, widened beyond rounding (walk_begin)
  ClipBox4 world_clip_;   ///< world_box_ as kd_begin reads it
  float max_abs_ = 0.0f;  ///< largest coordinate magnitude of the grid's box (KdRay::err)
  bool next_leaf_cache_ = true;  ///< BuildParams::hybrid_next_leaf_cache
  uint64_t uid_ = 0;             ///< unique per build, never 0 (NextLeafCache::owner)
  uint64_t max_steps_ = 0;

  std::vector<Node> nodes_;
  std::vector<Leaf> leaves_;
  std::vector<KdBox> kd_boxes_;  ///< each leaf's kd box; kept only for the next-leaf cache
  std::vector<uint8_t> leaf_depth_;
  std::vector<KdNode> sub_nodes_;          ///< leaf subtrees (world space, KdNode layout)
  std::vector<hybrid::GroupLine> groups_;  ///< the leaves' triangle groups (records.h)
  std::vector<hybrid::GroupLine> flat_subtree_floats_;  ///< flat subtrees (records.h)
  /// Groups, lanes and (shared corners) distinct corners stored (BuildStats)
  uint64_t group_count_ = 0, group_lanes_ = 0, group_corners_ = 0;
  /// The lanes of shared-corner groups whose mesh indices are stored in 16 bits (records.h,
  /// kNarrowIds).
  uint64_t group_narrow_ = 0;
  uint64_t flat_subtrees_ = 0;  ///< leaf subtrees stored flat (BuildStats)
  mutable std::atomic<uint64_t> step_errors_{0};
  mutable std::atomic<uint64_t> rewalks_{0};  ///< rewalked_rays()
};

}  // namespace kdgrid

// The walk's definitions (templates, inlined into every query).
#include "accel/hybrid/walk.h"
