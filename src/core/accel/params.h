// Build parameters of every acceleration structure, in one place so the CLI, the
// benchmark and the viewer set them the same way. Each knob says its default, unit and why.
#pragma once

#include <cstdint>
#include <string>

namespace kdgrid {

class CancelToken;  // util/cancel.h

enum class TriangleTestKind {
  /// Woop, Benthin & Wald 2013: no ray passes between triangles sharing an edge or vertex.
  Watertight,
  /// Möller & Trumbore 1997: fewer operations, may leak through shared edges/vertices.
  Moller,
  /// No test at all: every ray misses and crosses the whole structure, so a timing measures
  /// the traversal alone (`kdgrid trace --traversal-only`). Not a rendering choice: the CLI's
  /// --triangle-test does not accept it, and Embree refuses it.
  None,
};

struct BuildParams {
  /// Ray/triangle test used by every traversal (measured by `kdgrid sweep triangle`).
  TriangleTestKind triangle_test = TriangleTestKind::Watertight;
  /// Threads used by builders that parallelise; 0 = all hardware threads.
  int threads = 0;

  // ---- binned-SAH BVH -------------------------------------------------------------------
  /// SAH bins per axis per split. 16 is the usual quality/speed knee (Wald 2007).
  int bvh_bins = 16;
  /// Leaves hold at most this many triangles; a node with fewer always becomes a leaf
  /// when the SAH says splitting does not pay.
  int bvh_max_leaf = 8;
  /// SAH cost of one traversal step relative to one triangle test (1.0 = equal).
  float bvh_traversal_cost = 1.0f;

  // ---- uniform grid ---------------------------------------------------------------------
  /// Density heuristic: cells ~ lambda * triangles (Wald et al. 2006 use 4-8). Unitless.
  float grid_lambda = 4.0f;
  /// Upper bound on cells along any axis, so a sparse scene cannot ask for 1e9 cells.
  int grid_max_resolution = 1024;

  // ---- SAH kd-tree (Wald & Havran 2006) --------------------------------------------------
  /// Cost of one traversal step (K_T) and of one triangle test (K_I). Only the ratio matters.
  float kd_traversal_cost = 1.0f;
  float kd_intersection_cost = 1.5f;
  /// Fraction the cost of a split is reduced by when one side is empty (pbrt uses 0.5 as
  /// bonus 1-0.5; we use 0.8 multiplier = 20% bonus, Wald & Havran's lambda).
  float kd_empty_bonus = 0.2f;
  /// Maximum depth; 0 = auto, 8 + 1.3 log2(N) (pbrt).
  int kd_max_depth = 0;

  // ---- hybrid regular grid / kd-tree -----------------------------------------------------
  /// Basic cell size in scene units; <= 0 means auto (see hybrid.h for the rule).
  /// Written as a value here; the CLI parses "auto" to 0.
  float cell_size = 0.0f;
  /// Auto rule: the cell edge is this percentile of the triangles' largest bounding-box
  /// extent ("the minimum cell size that can fit most of the primitives"). 0..100.
  float cell_percentile = 90.0f;
  /// Use the dense cell matrix of the paper (memory ~ scene volume in cells) instead of
  /// the default bricked storage (memory ~ occupied content).
  bool hybrid_dense_matrix = false;
  /// An explicit cell size whose estimated extra build time (HybridEstimate: the cell
  /// matrix's bricks along the surface and the per-cell binning, beyond the triangles' own
  /// share) exceeds this many seconds is refused before the build starts, with the estimate
  /// and the smallest cell size that fits: cells a thousand times finer than the triangles
  /// otherwise build for hours. 10 s is many times the auto size's build on the suite's scenes
  /// (docs/LIMITS.md, "The guards' constants"); 0 = no limit (the memory budget still
  /// applies). The auto size is never refused by it.
  double hybrid_max_build_seconds = 10.0;
  /// Hybrid traversal/intersection costs for its top-level SAH. A group test costs 2.5 steps
  /// (the kd-tree's ratio is 1.5): a step of the grid is a lookup, and at the kd-tree's ratio the
  /// SAH keeps the cell layer holding a large flat polygon (a ceiling, a wall) in one leaf with
  /// the empty room beside it, which every ray crossing the room then tests (docs/HYBRID.md,
  /// "Large flat polygons").
  float hybrid_traversal_cost = 1.0f;
  float hybrid_intersection_cost = 2.5f;
  /// Leaves referencing more than this many triangles get a kd subtree built by the
  /// kd-tree's builder over the leaf's triangles (split planes anywhere inside the leaf, the
  /// kd_* costs, at most GridKdHybrid::kSubMaxDepth levels), walked by the kd-tree's traversal over
  /// the ray's segment in the leaf. A cell is then not a triangle wide (the auto rule caps the
  /// grid at 2^16 cells), so a plain leaf would test tens of triangles a ray mostly misses.
  /// 0 = the paper's plain leaves (`scripts/hybrid-variants.sh` measures both).
  uint32_t hybrid_subtree_min = 4;
  /// Flat subtrees: a leaf subtree with 5 to 16 leaves holding triangles is stored as the
  /// list of those leaves, tested against the ray all at once and visited in the kd walk's
  /// order (AVX2 and AVX-512 builds only; hybrid::kFlatSubtrees). The same leaves, in the same
  /// order, so the same hits. false = every subtree walked by its kd nodes.
  bool hybrid_flat_subtrees = true;
  /// Empty-leaf boxes (an extension of the paper): the walk steps over each empty leaf's box
  /// widened over the empty cells around it, so a ray crosses empty space in fewer steps
  /// (docs/HYBRID.md, "Widened empty leaves"). The leaves, the
  /// matrix and the triangle tests are unchanged. false = the paper's kd leaf boxes.
  bool hybrid_expand_empty = true;
  /// Next-leaf cache (an extension of the paper): each thread remembers the leaf reached
  /// across each leaf face, and the walk takes it when the exit cell lies in that leaf's kd
  /// box, else looks the cell up. The same leaves, hits and counters either way. false = every
  /// next leaf looked up in the matrix, as in the paper.
  bool hybrid_next_leaf_cache = true;

  // ---- irregular grid (Pérard-Gayot et al. 2017) -----------------------------------------
  /// Top-level density: top cells per triangle, shaped by the scene box (resolution per axis
  /// round(extent * cbrt(density * N / volume)), Cleary/Wald rule). 0.12 is the paper's default
  /// for static scenes. > 0; a density whose cells exceed memory_budget throws ParamError.
  float irregular_top_density = 0.12f;
  /// Second-level density: cells per reference inside each non-empty top cell (per-axis
  /// resolution rounded to a power of two, at most 64). 2.4 is the paper's static default.
  float irregular_sub_density = 2.4f;
  /// Merge aligned neighbour cells while the SAH-like cost (half area * (refs + 1)) does not
  /// grow. On by default, as in the paper; off only to measure its effect.
  bool irregular_merge = true;
  /// Expand each cell's exit box over neighbours whose references are a subset of its own,
  /// so rays skip cells that cannot add a hit. On by default, as in the paper.
  bool irregular_expand = true;

  // ---- Embree ----------------------------------------------------------------------------
  /// "low", "medium" or "high" (RTC_BUILD_QUALITY_*) of `embree` and `embree-robust`. Medium
  /// is Embree's default; `embree-high` always builds at high (accel/embree.h).
  std::string embree_quality = "medium";
  /// The ISA every Embree build's kernels are restricted to (rtcNewDevice's "isa=" config):
  /// "sse4.2", "avx", "avx2" or "avx512"; "" = the widest Embree and the CPU support. A value
  /// the CPU lacks, or another name, throws ParamError (accel/embree.h, embree_isa_names).
  std::string embree_isa = "";

  // ---- memory guard ----------------------------------------------------------------------
  /// Every structure estimates the peak bytes of its build before allocating (accel/guards.h)
  /// and refuses with a ParamError above this many bytes; 0 = auto (half of the memory
  /// available: the smallest of physical memory, the cgroup limit and ulimit -v; util/memory.h).
  /// The mesh itself is not counted: it belongs to the caller.
  uint64_t memory_budget = 0;

  // ---- brute-force work limit ------------------------------------------------------------
  /// Brute force tests every triangle for every ray, so a render (per progressive pass) or a
  /// benchmark (all its rays) refuses up front when rays x triangles exceeds this many
  /// ray/triangle tests, instead of appearing to hang. 5e9 is under a minute of primary rays
  /// on 2 cores (docs/LIMITS.md, "The guards' constants"; shadow rays can double it); 0 = no
  /// limit. Other structures ignore it.
  double brute_work_limit = 5e9;

  // ---- cancellation ----------------------------------------------------------------------
  /// Set from another thread (or a signal handler) to stop the build: every builder polls it
  /// in its loops and throws BuildCancelled (util/cancel.h) within about 100 ms. Not owned;
  /// it must outlive the build, and is not used once build() has returned. nullptr = the
  /// build cannot be cancelled.
  const CancelToken* cancel = nullptr;
};

/// Resolves memory_budget = 0 to default_memory_budget_bytes() (util/memory.h).
uint64_t effective_memory_budget(const BuildParams& p);
/// The most threads `--threads` (and BuildParams::threads) may ask for. Every thread has its
/// own stack and per-thread build buffers (bins, classification flags) sized by the scene, so
/// millions of threads exhaust memory before any work is done; more threads than this gain
/// nothing on any machine that runs kdgrid today.
inline constexpr int kMaxThreads = 1024;
/// ParamError naming `option` unless 0 <= threads <= kMaxThreads, or up to the hardware
/// thread count on a machine that has more (0 = all hardware threads).
void check_threads(int threads, const std::string& option = "--threads");
/// Resolves threads = 0 to the hardware thread count (check_threads first: ParamError when
/// `threads` is out of range).
int effective_threads(int threads);
/// Parses "watertight" / "moller" (ParamError otherwise).
TriangleTestKind parse_triangle_test(const std::string& s);
const char* to_string(TriangleTestKind k);

}  // namespace kdgrid
