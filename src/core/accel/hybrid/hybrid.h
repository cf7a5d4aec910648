// The hybrid regular grid / kd-tree (after D. Muñoz Díaz; docs/HYBRID.md): an SAH kd-tree
// whose split planes lie only on the boundaries of a regular grid of basic cells, plus a
// cell -> leaf map, so that a ray steps from leaf to leaf by index arithmetic, like a uniform
// grid, instead of descending the tree.
//
// Grid. Cells of edge `cell` (BuildParams::cell_size) from the scene's low corner, dims[a] =
// max(1, ceil(extent[a] / cell)) per axis. The walk works in grid space, g = (p - origin) /
// cell, in double, where cell boundaries are the integers.
//
// Auto cell size (cell_size <= 0; BuildStats::extra "auto rule"): the cell_percentile-th
// percentile (default 90) of the triangles' largest extents, lowered to give the scene box at
// least kHybridAutoCellsPerTriangle cells per triangle, then raised until the grid has at most
// kHybridAutoMaxCells cells (kHybridAutoMaxAxisCells per axis, the dense map within budget).
//
// Tree. A node is an integer box of cells; its candidates are the interior cell boundaries,
// binned per cell so one prefix sum gives exact SAH counts. References are the triangles
// clipped to the node box ("perfect splits"). Subtrees build in parallel; output is
// deterministic.
//
// Cell map. Every cell maps to the id of the leaf covering it: one uint32 per cell (the dense
// map, BuildParams::hybrid_dense_matrix), or by default a dense top array over blocks of 4^k
// cells whose entries name a leaf, a 4x4x4 brick or a kd node with a short descent, so memory
// follows the content rather than the volume. A lookup is at most k dependent loads.
//
// Leaf subtrees (BuildParams::hybrid_subtree_min). A leaf of more triangles keeps a kd subtree
// of at most kSubMaxDepth levels, built by the kd-tree's own builder and walked by its
// traversal (kd_traverse) over the ray's segment in the leaf; so a cell need not be a triangle
// wide and the grid stays small.
//
// Widened empty leaves (BuildParams::hybrid_expand_empty). Each empty leaf's box is grown over
// the empty cells around it (a summed-volume table of occupied cells), and the walk steps over
// that box: fewer steps through empty space, the same hits.
//
// Next-leaf cache (BuildParams::hybrid_guess; "guess" in the code). Each thread remembers the
// leaf it last reached across each leaf face; the walk takes it when the exit cell lies in
// that leaf's kd box (kd_boxes_ tile the grid, so the check is exact), else looks the cell up.
// Coherent rays predict the check, so the next leaf's record loads while the exit is being
// computed. A per-thread score turns the cache off while it mostly misses.
//
// Walk. Clip the ray in float to the grid's box, widened by the kd-tree's rounding bound; look
// up the entry cell's leaf; then test the leaf's triangles (through a per-ray mailbox), compute
// the exit over the leaf box's far planes in four lanes (x, y, z and a dummy axis), stop once
// the closest hit lies before the exit, else step to the cell past the exit face. Cells move
// monotonically along the ray, so at most nx+ny+nz+1 steps; the loop enforces that bound.
#pragma once

#include <atomic>
#include <bit>
#include <cstddef>
#include <cstring>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "accel/accelerator.h"
#include "accel/kd_kernel.h"
#include "math/simd.h"
#include "util/cancel.h"

namespace kdgrid {


/// Auto rule density floor: at least this many cells per triangle, so that scenes mixing huge
/// and tiny triangles (Sponza) still get a useful grid.
constexpr double kHybridAutoCellsPerTriangle = 16.0;
/// Auto rule cap on cells along one axis (per-node binning arrays, lookup depth).
constexpr int64_t kHybridAutoMaxAxisCells = 2048;
/// Auto rule cap on the total cell count with leaf subtrees: the subtrees resolve the geometry,
/// and a small grid keeps lookups in the caches and references few (docs/HYBRID.md, "The cell size").
constexpr double kHybridAutoMaxCells = double(uint64_t(1) << 19);
/// Auto rule cap with plain leaves (BuildParams::hybrid_subtree_min = 0), whose cells must stay
/// about a triangle wide: the per-cell binning and the dense matrix (2^24 cells: 64 MiB) bound it.
constexpr double kHybridAutoMaxCellsPlain = double(uint64_t(1) << 24);
/// Explicit cell sizes may give at most this many cells along one axis (int32 coordinates,
/// at most 12 brick levels).
constexpr int64_t kHybridMaxAxisCells = int64_t(1) << 24;

/// What a hybrid build at given parameters would make, from the mesh alone (O(triangles), no
/// allocation beyond one float per triangle): Hybrid::estimate. The viewer shows it before a
/// build; Hybrid::build refuses parameters whose estimate does not fit, with the estimate and
/// suggested_cell in the message.
struct HybridEstimate {
  double cell = 0;       ///< the cell size the build would use (the auto rule resolved)
  double auto_cell = 0;  ///< the auto rule's size for this mesh and these parameters
  std::string rule;      ///< how the cell size was chosen (BuildStats::extra "auto rule")
  double dims[3] = {1, 1, 1};
  double cells = 1;
  /// Peak bytes of the build, estimated: the cell matrix (dense: 4 bytes a cell; bricked:
  /// 256-byte bricks along the surface, about kHybridBricksPerArea x area / (4 cells)^2, the
  /// figure measured on the bunny at 1-18x finer cells than auto), the per-cell binning
  /// arrays, the empty-leaf table, and the tree (kHybridBytesPerTriangle a triangle).
  double bytes = 0;
  /// The built structure's bytes (BuildStats::bytes), estimated: bytes less what the build
  /// frees before it returns (the binning arrays, the empty-leaf table).
  double structure_bytes = 0;
  /// Build time in seconds on BuildParams::threads threads at the rates kHybridSecondsPer*
  /// (measured on a shared 2-core machine): an order of magnitude, for the refusal and the
  /// viewer.
  double seconds = 0;
  uint64_t budget = 0;         ///< the memory budget it was checked against
  double seconds_limit = 0;    ///< BuildParams::hybrid_max_build_seconds (0 = none)
  bool fits = true;            ///< bytes within the budget and seconds within the limit
  /// When !fits: the smallest cell size (two significant digits, rounded up) whose estimate
  /// fits; 0 when even one cell does not.
  double suggested_cell = 0;
  /// "a 88x87x68 grid (5.21e+05 cells), about 15 MiB and under a second to build".
  std::string describe() const;
  /// Why the size does not fit, with the estimate and the fix (the build's ParamError text).
  std::string refusal() const;
};

/// Estimate model constants (see HybridEstimate), measured with `kdgrid render --threads 1
/// --stats-json` ("build phases") on the 2-core AMD EPYC this project is developed on while other
/// builds shared it, so on the slow side: the bunny's matrix took 10-11 us a brick at 3.4x and
/// 6.7x finer cells than auto (174K and 716K bricks, 4.4 and 4.5 bricks per (4-cell)^2 of
/// area); the tree took 16 (Sponza) and 26 (the dragon) us a triangle at the auto size, and
/// 220-580 bytes a triangle (the bunny, auto to 18x finer).
constexpr double kHybridBricksPerArea = 4.5;       ///< bricks per (4-cell)^2 of triangle area
constexpr double kHybridBytesPerTriangle = 600;    ///< tree, leaves, subtrees, references
constexpr double kHybridSecondsPerBrick = 10e-6;   ///< matrix construction, one thread
constexpr double kHybridSecondsPerTriangle = 25e-6;  ///< tree and subtrees, one thread
constexpr double kHybridSecondsPerBinOp = 1e-9;    ///< one per-cell binning entry

class Hybrid final : public AcceleratorBase<Hybrid> {
 public:
  /// See HybridEstimate. Throws ParamError for invalid parameters, as build() does.
  static HybridEstimate estimate(const Mesh& mesh, const BuildParams& params);
  /// Leaf: an integer cell box [lo, hi) and its range in the reference array. 64 bytes.
  /// The box is the one the walk steps over: the kd leaf's box, or for an empty leaf that
  /// box widened over empty cells (see "Widened empty leaves").
  struct alignas(64) Leaf {
    /// The step box in cells: whole numbers, held as doubles so that the walk's exit reads
    /// them with no conversion (7 per step; one cache line per leaf all the same). lo and hi
    /// each start a 32-byte half of the line, so that the walk reads each as four lanes (the
    /// fourth: first/count's bits after lo, `pad` after hi; see leaf_exit).
    double lo[3];
    uint32_t first, count;
    double hi[3];
    double pad;
  };
  /// Leaf::count bit: `first` is the root of the leaf's kd subtree in sub_nodes_ and the low
  /// bits count the triangles the leaf references.
  static constexpr uint32_t kSubtreeFlag = 0x80000000u;
  /// A leaf subtree in sub_nodes_ starts with the box of its clipped triangles (its corners
  /// as two ClipBox4 lanes, x, y, z, -inf and x, y, z, +inf, in this many nodes' bytes), which
  /// a ray is clipped to first (kd_clip4), then the kd-tree's nodes.
  static constexpr uint32_t kSubBoxNodes = 4;
  /// Leaf subtrees are at most this many levels deep (64 leaves): deeper ones test fewer
  /// triangles but build longer and take more memory for no speed (docs/HYBRID.md, "Leaf subtrees").
  static constexpr int kSubMaxDepth = 6;
  /// A leaf with more references than this gets the kd-tree's whole depth rule (8 + 1.3
  /// log2 n) instead of kSubMaxDepth levels: 64 leaves of 16 triangles or more would be
  /// tested in bulk. Only a grid much coarser than the auto rule's makes such leaves (the auto
  /// grid's largest leaves hold 22, 310 and 187 references on the bunny, the dragon and Sponza); with
  /// one cell the whole scene is one leaf, whose subtree is then the kd-tree itself.
  static constexpr uint32_t kSubDeepMin = 1024;
  /// Tree node kept for split walks and the matrix construction; leaves point into leaves_.
  struct Node {
    int32_t split;      ///< interior: the split boundary (cell index); leaf: leaf id
    uint32_t right;     ///< interior: index of the right child (left child = this + 1)
    uint32_t axis;      ///< 0..2 interior, 3 leaf
  };
  /// The three corners of a triangle, copied once per triangle in the order in which the
  /// leaves (depth-first, so spatially coherent) first reference it: a leaf's triangles lie
  /// close together in memory without paying a vertex copy per reference (references are
  /// ~3 per triangle at the auto cell size, so per-reference copies tripled this array).
  struct TriVerts {
    Vec3 v0, v1, v2;
  };

  /// Bricked matrix entries: kLeafTag | leaf id, kNodeTag | kd node index, or a brick index.
  static constexpr uint32_t kLeafTag = 0x80000000u;
  static constexpr uint32_t kNodeTag = 0x40000000u;
  static constexpr uint32_t kTagMask = kLeafTag | kNodeTag;
  /// A region crossed by split planes whose kd subtree, restricted to the region, reaches at
  /// most kMaxNodeEntryLeaves leaves within kMaxNodeEntryDepth levels keeps a kd node entry,
  /// resolved at lookup by a descent of at most that many steps, instead of refining into a
  /// brick. This keeps memory proportional to content: a lone split plane across a huge empty
  /// stadium would otherwise refine every brick it crosses (its area, not content).
  static constexpr int kMaxNodeEntryLeaves = 8;
  static constexpr int kMaxNodeEntryDepth = 16;
  /// The bricked matrix starts from a dense top array over blocks of 4^k cells, k >= 1 the
  /// smallest giving at most this many blocks (1 MiB), so a lookup skips the upper levels
  /// (the dragon's lookups read one brick level instead of two; docs/HYBRID.md, "The cell map").
  static constexpr int kMaxTopEntries = 262144;
  static constexpr int kBrickLog = 2;                          ///< 4 cells per brick axis
  static constexpr int kBrickSide = 1 << kBrickLog;
  static constexpr int kBrickEntries = kBrickSide * kBrickSide * kBrickSide;
  /// Reference ranges are widened by this many cells so that geometry on a cell boundary is
  /// referenced on both sides and no rounding (1e-12 cells in double) can lose a triangle.
  static constexpr double kRangeEps = 1e-6;
  /// Direct-mapped per-ray mailbox of recently tested triangles (power of two): a triangle
  /// referenced by several leaves is tested once; 32 entries catch most repeats at no cost.
  static constexpr int kMailbox = 32;
  /// Empty-leaf boxes are computed when the occupied-cell table has at most this many
  /// entries ((nx+1)(ny+1)(nz+1), 4 bytes each: 128 MiB); the auto rule stays below 2^24 cells.
  static constexpr uint64_t kMaxExpandEntries = uint64_t(1) << 25;

  std::string name() const override { return "hybrid"; }
  BuildStats build(const Mesh& mesh, const BuildParams& params) override;

  template <class Tri, class S>
  bool closest(const Ray& ray, Hit& hit, S& s) const {
    return walk<Tri, S, false>(ray, &hit, s);
  }
  template <class Tri, class S>
  bool any(const Ray& ray, S& s) const {
    return walk<Tri, S, true>(ray, nullptr, s);
  }

  void for_each_split(const std::function<void(const SplitPlane&)>& fn) const override;
  void for_each_box(const std::function<void(const StructureBox&)>& fn) const override;

  // ---- introspection (tests, viewer) ----
  double cell_size() const { return cell_; }
  const int32_t* dims() const { return dims_; }
  Vec3 origin() const { return {float(origin_[0]), float(origin_[1]), float(origin_[2])}; }
  /// The leaf covering cell (x, y, z) (must lie inside the grid).
  uint32_t leaf_at(int32_t x, int32_t y, int32_t z) const { return lookup(x, y, z); }
  const std::vector<Leaf>& leaves() const { return leaves_; }
  /// Next leaves the calling thread took from its guesses so far, over every hybrid (tests;
  /// see "Next-leaf cache").
  static uint64_t guesses_taken() { return guess_state_.taken; }
  /// Rays whose traversal reached the nx+ny+nz+1 step bound (a correct traversal never does).
  uint64_t step_bound_errors() const { return step_errors_.load(std::memory_order_relaxed); }
  /// World box of a leaf: the box its steps cross (an empty leaf's widened box).
  Box3 leaf_box(uint32_t leaf) const;
  /// Bytes the storage selected by `dense` would take for the current tree (computed, not
  /// allocated; the bricked figure is exact).
  uint64_t matrix_bytes(bool dense) const;

 private:
  [[gnu::always_inline]] uint32_t lookup(int32_t x, int32_t y, int32_t z) const {
    if (dense_) return matrix_[uint64_t(x) + uint64_t(dims_[0]) * (uint64_t(y) + uint64_t(dims_[1]) * uint64_t(z))];
    // Strides instead of nested products: the two multiplies run in parallel.
    uint32_t e = top_[uint64_t(uint32_t(x) >> top_shift_) + top_stride_[0] * uint64_t(uint32_t(y) >> top_shift_) +
                      top_stride_[1] * uint64_t(uint32_t(z) >> top_shift_)];
    int shift = top_shift_ - kBrickLog;
    while (!(e & kTagMask)) {
      const uint32_t local = ((uint32_t(x) >> shift) & (kBrickSide - 1)) |
                             (((uint32_t(y) >> shift) & (kBrickSide - 1)) << kBrickLog) |
                             (((uint32_t(z) >> shift) & (kBrickSide - 1)) << (2 * kBrickLog));
      e = bricks_[uint64_t(e) * kBrickEntries + local];
      shift -= kBrickLog;
    }
    if (e & kLeafTag) return e & ~kTagMask;
    // A sparse region: finish with a short kd descent from the stored node.
    const int32_t c[3] = {x, y, z};
    const Node* n = nodes_.data() + (e & ~kTagMask);
    while (n->axis != 3) n = c[n->axis] < n->split ? n + 1 : nodes_.data() + n->right;
    return uint32_t(n->split);
  }

  /// The leaf of cell n, which the ray reaches across the face of leaf `from` on `axis`:
  /// the leaf this thread last reached across that face (the guess) when n lies in its kd
  /// box, else the matrix's. A per-thread score of recent guesses switches guessing off while
  /// they mostly fail (incoherent rays), so that a wrong guess's mispredicted branch is not
  /// paid on every step; the plain lookups then keep scoring the guesses they would have made.
  [[gnu::always_inline]] uint32_t next_leaf(const Int4& n, uint32_t from, int axis) const {
    if (!guess_) return lookup(n[0], n[1], n[2]);
    GuessState& gs = guess_state_;
    uint32_t& g = gs.leaf[(uint64_t(from) * 3 + uint64_t(axis)) & (kGuessEntries - 1)];
    const uint32_t id = g;
    if (gs.score >= 0) {
      if (in_kd_box(id, n)) [[likely]] {
        gs.score = std::min(gs.score + 1, kGuessScoreMax);
        ++gs.taken;
        return id;
      }
    }
    const uint32_t found = lookup(n[0], n[1], n[2]);
    gs.score = found == id ? std::min(gs.score + 1, kGuessScoreMax) : std::max(gs.score - kGuessMissCost, kGuessScoreMin);
    g = found;
    return found;
  }
  /// The leaf of a ray's entry cell c: the entry leaf of this thread's previous ray when c
  /// lies in its kd box (rays from one camera mostly start in one leaf), else the matrix's.
  [[gnu::always_inline]] uint32_t start_leaf(const Int4& c) const {
    if (!guess_) return lookup(c[0], c[1], c[2]);
    claim_guesses();
    GuessState& gs = guess_state_;
    const uint32_t id = gs.start;
    if (in_kd_box(id, c)) [[likely]] {
      ++gs.taken;
      return id;
    }
    return gs.start = lookup(c[0], c[1], c[2]);
  }
  /// Whether cell c lies in the kd box of leaf `id`, one of this structure's (the thread's
  /// guesses are this structure's: see claim_guesses). The kd boxes tile the grid, so true
  /// means that `id` is the leaf of c.
  [[gnu::always_inline]] bool in_kd_box(uint32_t id, const Int4& c) const {
    const CellBox& b = kd_boxes_[id];
    Int4 lo, hi;
    std::memcpy(&lo, b.lo, sizeof lo);
    std::memcpy(&hi, b.hi, sizeof hi);
    // The four lanes at once (lane 3 always passes).
    return all_lanes((c >= lo) & (c < hi));
  }
  /// Guess score: +1 per right guess, -kGuessMissCost per wrong one, within [min, max];
  /// guessing is on while it is >= 0 (more right guesses than wrong ones keep it on). A miss
  /// cost of 3 (on above 3 right in 4) kept guessing off on most of the dragon's primary rays
  /// (71% right): a cost of 1 makes them 4-6% faster (one thread), with diffuse rays (about 20%
  /// right) within the noise; no score at all cost the dragon's diffuse rays 5%.
  static constexpr int32_t kGuessScoreMax = 64, kGuessScoreMin = -64, kGuessMissCost = 1;
  /// Guesses per thread (direct-mapped by leaf and exit axis; 16 KiB). 65536 entries would
  /// catch 1% more on Sponza's primary rays and 3% more on the dragon's.
  static constexpr uint64_t kGuessEntries = 4096;
  /// One thread's guesses (the leaf last reached across each leaf face, by a hash of the leaf
  /// and the exit axis: the ray's direction fixes the face's side), their score and the
  /// number taken; shared by every hybrid, since each checks a guess against its own kd
  /// boxes. Zero-initialized, as every thread_local is (no member initializers: GCC rejects
  /// them in a nested class used by its enclosing class's static member).
  struct GuessState {
    uint32_t leaf[kGuessEntries];
    uint32_t start;
    int32_t score;
    uint64_t taken;
    uint64_t owner;  ///< uid_ of the structure whose leaf ids the table holds (0: none)
  };
  static inline thread_local GuessState guess_state_;
  /// Makes the thread's guesses this structure's before a walk: when another structure (or an
  /// earlier build of this one) used them last, its leaf ids are replaced by leaf 0, so every
  /// guess names a leaf of this structure and in_kd_box needs no bounds check. Structures only
  /// alternate ray by ray on one thread in tests; the reset (16 KiB) is paid once per switch.
  [[gnu::always_inline]] void claim_guesses() const {
    GuessState& gs = guess_state_;
    if (gs.owner == uid_) [[likely]]
      return;
    std::memset(gs.leaf, 0, sizeof gs.leaf);
    gs.start = 0;
    gs.owner = uid_;
  }

  template <class Tri, class S, bool kAny>
  bool walk(const Ray& ray, Hit* hit, S& s) const;
  /// One ray's walk between leaf steps: the ray in grid space, the current cell and leaf,
  /// the closest hit so far and the mailbox.
  template <class Tri>
  struct WalkState {
    /// The ray in grid space, g(t) = o + t dg; inv[a] is t per grid unit along axis a (0 where
    /// the ray does not move) and oc = -o inv (+inf there), so the exit over a far plane p is
    /// p inv + oc. Lanes x, y, z, then a dummy axis that never exits (o, dg, inv 0, oc +inf),
    /// moves "up" and stays in cell 0, so that every step computes the four lanes at once.
    Double4 o, dg, inv, oc;
    Long4 up_d;  ///< all ones on the axes the ray moves up along (the far plane is hi), and lane 3
    Int4 up;     ///< the same as int32 lanes
    Int4 down;   ///< ~up: added to a far plane's coordinate, gives the cell just past it
    Int4 c;      ///< the current cell (lane 3: 0)
    KdRay kr;    ///< the ray as the leaf subtrees' kd traversal reads it (world space, float)
    KdRay4 kr4;  ///< the same, as the clip to a subtree's box reads it
    float err;   ///< the largest of kr.err: widens the leaf's segment before that clip
    double t1, t_cur;
    /// Where the walk over empty leaves stops: t1, or the closest hit's t once one is found.
    double t_stop;
    uint32_t leaf_id;
    uint64_t steps_left;  ///< steps before the bound of over_step_bound (max_steps_ + 1 at the start)
    float tmin, tmax, best;
    bool found;
    Hit hit;
    typename Tri::RayData rd;
    uint32_t mailbox[kMailbox];
  };
  enum class StepResult { Next, Done, Answered };
  /// Where the ray leaves a leaf's (step) box: the exit t, the cell just past the exit face,
  /// and whether that cell lies outside the grid (the walk ends there).
  struct Exit {
    double t;
    Int4 n;  ///< lane 3: 0
    int axis;
    bool out;
  };
  template <class Tri>
  [[gnu::always_inline]] inline Exit leaf_exit(const WalkState<Tri>& w, const Leaf& L) const;
  /// The rest of leaf_exit once the exit axis A is known (a branch per axis: see leaf_exit).
  template <int A, class Tri>
  [[gnu::always_inline]] inline void exit_through(const WalkState<Tri>& w, const Double4& lo,
                                                  const Double4& hi, const Double4& far, double t,
                                                  Exit& ex) const;
  /// Counts one leaf step; true (and a step-bound error counted) once the ray has taken more
  /// than the nx+ny+nz+1 steps a correct walk can take.
  template <class Tri>
  [[gnu::always_inline]] bool over_step_bound(WalkState<Tri>& w) const {
    if (w.steps_left-- == 0) [[unlikely]] {
      step_errors_.fetch_add(1, std::memory_order_relaxed);
      return true;
    }
    return false;
  }
  /// Clips the ray to the grid and finds its entry cell's leaf; false if it misses the grid.
  /// Inlined into walk(): out of line, every ray pays a call and the stores that build the
  /// walk's state (3% of a dragon ray's instructions; docs/HYBRID.md, "The walk").
  template <class Tri>
  [[gnu::always_inline]] inline bool walk_begin(WalkState<Tri>& w, const Ray& ray) const;
  /// One leaf step: tests the leaf's triangles and moves to the next leaf. Out of line on
  /// purpose: as its own function, with the ray's state in memory, the step compiled better
  /// than inlined in the ray's loop (5-8% faster primary rays; docs/HYBRID.md, "The walk").
  /// Empty leaves do not come here (traced walks excepted): walk() steps over them inline,
  /// with nothing to test.
  template <class Tri, class S, bool kAny>
  [[gnu::noinline]] StepResult walk_step(WalkState<Tri>& w, S& s) const;

  void build_tree(const Mesh& mesh, const BuildParams& params);
  void build_matrix(uint64_t budget, const CancelToken* cancel);
  /// Widens every empty leaf's box over the empty cells around it (see "Widened empty
  /// leaves" above); returns the BuildStats text. Skipped when its table exceeds `budget` bytes.
  std::string expand_empty_leaves(uint64_t budget, const CancelToken* cancel);
  struct BrickBudget {
    std::atomic<uint64_t> bytes{0};
    uint64_t limit = ~uint64_t(0);
  };
  /// The entry for the region of 4^level cells at (x0, y0, z0), appending bricks to `out`
  /// (nullptr: only count their bytes in `budget`). Brick indices are local to `out`.
  uint32_t build_brick_entry(int32_t x0, int32_t y0, int32_t z0, int level, uint32_t node,
                             std::vector<uint32_t>* out, BrickBudget& budget) const;
  int count_region_leaves(uint32_t node, const int32_t r0[3], const int32_t r1[3], int limit, int depth) const;

  const Mesh* mesh_ = nullptr;
  double origin_[3] = {0, 0, 0};
  Double4 origin4_ = {0, 0, 0, 0};  ///< origin_ and 0, for the walk's set-up
  Double4 top4_ = {0, 0, 0, 0};     ///< the last cell on each axis (dims_ - 1) and 0, in double
  double cell_ = 1.0, inv_cell_ = 1.0;
  int32_t dims_[3] = {1, 1, 1};
  int top_shift_ = kBrickLog;       ///< log2 of the top blocks' side in cells
  int32_t top_dims_[3] = {1, 1, 1};
  uint64_t top_stride_[2] = {1, 1};  ///< top array strides of y and z
  bool dense_ = false;
  Box3 wbox_;            ///< the grid's world box, widened beyond rounding (walk_begin)
  ClipBox4 wclip_;       ///< wbox_ as kd_begin reads it
  float max_abs_ = 0.0f;  ///< largest coordinate magnitude of the grid's box (KdRay::err)
  bool guess_ = true;  ///< BuildParams::hybrid_guess
  uint64_t uid_ = 0;   ///< unique per build, never 0 (GuessState::owner)
  uint64_t max_steps_ = 0;

  std::vector<Node> nodes_;
  std::vector<Leaf> leaves_;
  /// Each leaf's kd box (an empty leaf's before widening): they tile the grid.
  struct CellBox {
    /// x, y, z and a fourth lane that every cell passes (INT32_MIN, INT32_MAX; a walk's lane 3 is 0).
    alignas(16) int32_t lo[4];
    int32_t hi[4];
  };
  std::vector<CellBox> kd_boxes_;
  std::vector<uint8_t> leaf_depth_;
  std::vector<KdNode> sub_nodes_;   ///< leaf subtrees (world space, KdNode layout)
  std::vector<uint32_t> refs_;      ///< per leaf, indices into tris_ (local triangle ids)
  std::vector<TriVerts> tris_;      ///< corners by local id (first-reference order)
  std::vector<uint32_t> prim_of_;   ///< local id -> the mesh's triangle index
  std::vector<uint32_t> matrix_;   ///< dense storage
  std::vector<uint32_t> bricks_;   ///< bricked storage, kBrickEntries per brick
  std::vector<uint32_t> top_;      ///< bricked storage: entries of the top blocks
  mutable std::atomic<uint64_t> step_errors_{0};
};

// ---- traversal --------------------------------------------------------------------------

template <class Tri, class S, bool kAny>
bool Hybrid::walk(const Ray& ray, Hit* hit, S& s) const {
  if (leaves_.empty()) return false;
  WalkState<Tri> w;
  if (!walk_begin(w, ray)) return false;
  s.lookup();
  StepResult r;
  for (;;) {
    if constexpr (!S::kTrace) {
      // An empty leaf is only stepped over: inline, with the ray's state in registers.
      const Leaf& L = leaves_[w.leaf_id];
      if (L.count == 0) {
        if (over_step_bound(w)) {
          r = StepResult::Done;
          break;
        }
        s.step();
        const Exit e = leaf_exit(w, L);
        // The end of the ray's segment, the grid or the walk (a hit found before this exit).
        if (e.out || e.t >= w.t_stop) {
          r = StepResult::Done;
          break;
        }
        w.c = e.n;
        w.t_cur = e.t;
        w.leaf_id = next_leaf(e.n, w.leaf_id, e.axis);
        s.lookup();
        continue;
      }
    }
    if ((r = walk_step<Tri, S, kAny>(w, s)) != StepResult::Next) break;
  }
  if (r == StepResult::Answered) return true;
  if constexpr (!kAny)
    if (w.found) *hit = w.hit;
  return w.found;
}

template <class Tri>
bool Hybrid::walk_begin(WalkState<Tri>& w, const Ray& ray) const {
  // Cheap rejection first, in float as the kd-tree clips (most primary rays of a scanned model
  // miss its box; `kdgrid profile` of the dragon: those rays 17.6 -> 12.9 ns), against the
  // grid's world box (wbox_, widened beyond the grid's rounding) with each slab widened as the
  // kd-tree widens its own, by err (KdRay): the rounding of (lo - o) grows with the origin's
  // coordinates, so a ray from far away that grazes the box at an edge or a corner was lost
  // without it (origins 1e4 away from a unit cube: 99 rays in 6000). So this clip never
  // rejects a ray that reaches the grid, and its entry t is never later than the ray's entry
  // into the grid: the walk starts there (below). Its reciprocals and err serve the leaf
  // subtrees' traversal. kd_begin computes the three axes at once, as the grid-space ray
  // below does in double (GCC's vector extensions: AVX where the target has it, else SSE2
  // pairs): the set-up is most of a short ray's work.
  float f0, f1;
  if (!kd_begin(ray, wclip_, max_abs_, w.kr, f0, f1, &w.kr4)) return false;
  w.err = std::max({w.kr.err[0], w.kr.err[1], w.kr.err[2]});
  Float4 of, df;
  load_ray4(ray, of, df);
  // Grid-space ray: g(t) = o + t * dg. inv[a] is t per grid unit along axis a. Zero (and
  // negative-zero) direction components never exit on their axis: their inv is 0 and their
  // oc +inf, so their exit t is +inf without a branch. Lane 3 (tmin, tmax in the ray's layout)
  // is zeroed first: a fourth axis with a zero direction, in cell 0, that never exits.
  // The exit over a leaf's far plane p on axis a is t = p * inv[a] + oc[a] (oc = -o * inv,
  // +inf on a non-moving axis): one multiply and one add after the leaf's load.
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
  w.oc = moving ? -o * inv : zero + kDInf;
  w.dg = d * inv_cell_;
  w.up_d = (d > zero) | ~xyz;
  w.up = __builtin_convertvector(w.up_d, Int4);
  w.down = ~w.up;
  // The walk runs over the float clip's [f0, f1], not an exact clip to the grid: f0 is at most
  // the ray's entry t, and the entry cell below is clamped into the grid, so the walk starts
  // in a cell the ray reaches at or after that cell on every axis (a point at an earlier t lies
  // behind along each axis it moves on), and its steps, monotone on every axis, cross all the
  // cells the ray does. Past the grid the walk ends at the face it leaves by (out_of_grid in
  // leaf_exit), so a t1 beyond the grid's exit changes nothing. (An exact clip in double cost
  // 50 instructions a ray, 3% of a dragon ray's, and lost rays touching the box at an edge.)
  // The entry cell: clamped into the grid in double, then truncated (the floor, as the value
  // is >= 0; a NaN clamps to 0).
  const double t0 = f0, t1 = f1;
  const Double4 x = o + t0 * w.dg;
  const Double4 xl = x > zero ? x : zero;
  w.c = __builtin_convertvector(xl < top4_ ? xl : top4_, Int4);
  w.rd = Tri::prepare(ray);
  w.tmin = ray.tmin;
  w.tmax = ray.tmax;
  w.best = ray.tmax;
  w.found = false;
  for (auto& m : w.mailbox) m = kInvalidPrim;
  w.t1 = t1;
  w.t_cur = t0;
  w.t_stop = t1;
  w.steps_left = max_steps_ + 1;
  w.leaf_id = start_leaf(w.c);
  return true;
}

template <class Tri>
Hybrid::Exit Hybrid::leaf_exit(const WalkState<Tri>& w, const Leaf& L) const {
  // The leaf's box as four lanes each (lo's fourth holds first/count's bits, hi's the pad, 0:
  // lane 3 always takes hi, so its exit t is 0 * 0 + inf). The exit is the nearest far plane,
  // the first axis winning ties, found by compares on the three lanes that GCC turns into
  // branches: on coherent rays they are predicted, so the CPU computes the exit cell and starts
  // the next lookup (whose guess is keyed by the exit axis) before the compares resolve. The
  // axis is a constant in each branch (exit_through<A>). (The scalar form that computed all
  // three exit cells and then overrode the exit axis's compiled to selects, whose chain the
  // lookup had to wait for: Sponza's primary rays were 7% slower.)
  static_assert(offsetof(Leaf, first) == 24 && offsetof(Leaf, hi) == 32 && offsetof(Leaf, pad) == 56 &&
                sizeof(Leaf) == 64);
  Double4 lo, hi;
  const char* bytes = reinterpret_cast<const char*>(&L);  // the record's two halves
  std::memcpy(&lo, bytes, sizeof lo);
  std::memcpy(&hi, bytes + offsetof(Leaf, hi), sizeof hi);
  const Double4 far = w.up_d ? hi : lo;
  Double4 e;
  mul_add(far, w.inv, w.oc, e);
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

template <int A, class Tri>
void Hybrid::exit_through(const WalkState<Tri>& w, const Double4& lo, const Double4& hi,
                          const Double4& far, double t, Exit& ex) const {
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
  mul_add(Double4{t, t, t, t}, w.dg, w.o, x);
  const Double4 hm = hi - 0.5;
  const Double4 xl = x > lo ? x : lo;
  const Int4 v = __builtin_convertvector(xl < hm ? xl : hm, Int4);
  const Int4 mono = w.up ? (v > w.c ? v : w.c) : (v < w.c ? v : w.c);
  const Int4 face = __builtin_convertvector(far, Int4) + w.down;
  ex.n = __builtin_shufflevector(mono, face, A == 0 ? 4 : 0, A == 1 ? 5 : 1, A == 2 ? 6 : 2, 3);
  ex.out = uint32_t(face[A]) >= uint32_t(dims_[A]);
}

template <class Tri, class S, bool kAny>
Hybrid::StepResult Hybrid::walk_step(WalkState<Tri>& w, S& s) const {
  if (over_step_bound(w)) return StepResult::Done;
  const uint32_t leaf_id = w.leaf_id;
  const Leaf& L = leaves_[leaf_id];
  s.step();
  // Tests a list of references (mailboxed); true = any-hit query answered.
  auto test = [&](const uint32_t* r, uint32_t count) {
    s.leaf();
    for (uint32_t i = 0; i < count; ++i) {
      const uint32_t local = r[i];
      uint32_t& slot = w.mailbox[local & (kMailbox - 1)];
      if (slot == local) {
        s.mailbox_skip();
        continue;
      }
      slot = local;
      if constexpr (S::kCount) s.tri_test(prim_of_[local]);
      const TriVerts& tv = tris_[local];
      float t, u, v;
      if (Tri::intersect(w.rd, tv.v0, tv.v1, tv.v2, w.tmin, w.best, t, u, v)) {
        if constexpr (kAny) {
          return true;
        } else {
          w.best = t;
          w.hit = {t, prim_of_[local], u, v};
          w.found = true;
        }
      }
    }
    return false;
  };
  const Exit ex = leaf_exit(w, L);
  const double t_exit = ex.t;
  const bool last = ex.out || t_exit >= w.t1;
  if constexpr (S::kTrace) {
    const float tin = float(w.t_cur);
    s.visit(TraceStep{StepKind::Leaf, int(leaf_depth_[leaf_id]), leaf_id, leaf_box(leaf_id), tin,
                      std::max(tin, float(std::min(t_exit, double(w.tmax))))});
  }
  // The next cell's leaf is looked up before this leaf's triangles are tested, so the
  // dependent loads of the lookup (top array, bricks, leaf record) overlap with the tests
  // instead of following them; most leaves entered are left again (2.8 steps per primary
  // ray on the dragon), so the lookup is rarely wasted.
  uint32_t next_id = 0;
  if (!last) {
    next_id = next_leaf(ex.n, leaf_id, ex.axis);
    s.lookup();
    __builtin_prefetch(leaves_.data() + next_id);
  }
  if (L.count & kSubtreeFlag) {
    // The kd-tree's walk of the leaf's subtree over the ray's segment in the leaf, clipped to
    // the subtree's box first (the two t's widened by err as the kd-tree widens its own).
    const KdNode* sub = sub_nodes_.data() + L.first;
    Float4 sub_lo, sub_hi;
    std::memcpy(&sub_lo, sub, sizeof sub_lo);
    std::memcpy(&sub_hi, sub + 2, sizeof sub_hi);
    [[maybe_unused]] Box3 sub_box;
    if constexpr (S::kTrace)
      sub_box = Box3(Vec3(sub_lo[0], sub_lo[1], sub_lo[2]), Vec3(sub_hi[0], sub_hi[1], sub_hi[2]));
    // The ray in a local: the loop then keeps it in registers (read through w, it was
    // reloaded at every node).
    const KdRay kr = w.kr;
    float ta = float(w.t_cur) - w.err, tb = float(std::min(t_exit, w.t1)) + w.err;
    if (kd_clip4(w.kr4, sub_lo, sub_hi, ta, tb)) {
      // Tested as the kd-tree tests, with the closest hit in the walk's own locals (through
      // test() and w, primary rays on the dragon were 5% slower), but through the ray's
      // mailbox: a triangle that crosses cell boundaries is referenced by every grid leaf it
      // touches and by several leaves of a subtree, and a second test of the whole triangle
      // can only repeat the first (best only decreases).
      const auto& rd = w.rd;
      const float tmin = w.tmin;
      uint32_t hit_local = kInvalidPrim;
      float hit_u = 0.0f, hit_v = 0.0f;
      auto leaf = [&](const KdNode& sn, float& best, bool& found) __attribute__((always_inline)) {
        s.leaf();
        const uint32_t* r = refs_.data() + sn.prim_offset;
        for (uint32_t i = 0, count = sn.count(); i < count; ++i) {
          const uint32_t local = r[i];
          uint32_t& slot = w.mailbox[local & (kMailbox - 1)];
          if (slot == local) {
            s.mailbox_skip();
            continue;
          }
          slot = local;
          if constexpr (S::kCount) s.tri_test(prim_of_[local]);
          const TriVerts& tv = tris_[local];
          float t, u, v;
          if (Tri::intersect(rd, tv.v0, tv.v1, tv.v2, tmin, best, t, u, v)) {
            if constexpr (kAny) return true;
            best = t;
            found = true;
            hit_local = local;
            hit_u = u;
            hit_v = v;
          }
        }
        return false;
      };
      // Traces: each node's segment as the walk sees it, within the leaf's segment and never
      // starting before the previous node's (the walk widens its intervals by err, a bound on
      // rounding, so a popped node may start up to 2 err before the leaf it follows).
      [[maybe_unused]] float trace_in = float(w.t_cur);
      auto visit = [&](StepKind kind, int depth, uint32_t, const Box3& box, float tn, float tf) {
        trace_in = std::max(trace_in, tn);
        const float out = std::max(trace_in, std::min(tf, float(std::min(t_exit, double(w.tmax)))));
        s.visit(TraceStep{kind, int(leaf_depth_[leaf_id]) + 1 + depth, leaf_id, box, trace_in, out});
      };
      float best = w.best;
      bool found = w.found;
      if (kd_traverse(sub_nodes_.data(), L.first + kSubBoxNodes, kr, ta, tb, sub_box, best, found, s, leaf, visit))
        return StepResult::Answered;
      if constexpr (!kAny)
        if (hit_local != kInvalidPrim) {
          w.best = best;
          w.found = true;
          w.hit = {best, prim_of_[hit_local], hit_u, hit_v};
        }
    }
  } else if (L.count) {
    if (test(refs_.data() + L.first, L.count)) return StepResult::Answered;
  }
  if (w.found && double(w.best) <= t_exit) return StepResult::Done;
  if (last) return StepResult::Done;
  if (w.found) w.t_stop = std::min(w.t1, double(w.best));
  w.c = ex.n;
  w.t_cur = t_exit;
  w.leaf_id = next_id;
  return StepResult::Next;
}

}  // namespace kdgrid
