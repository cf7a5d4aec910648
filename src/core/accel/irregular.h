// The irregular grid of Pérard-Gayot, Kalojanov & Slusallek, "GPU Ray Tracing Using Irregular
// Grids" (Computer Graphics Forum 36(2), 2017), built and traversed on the CPU.
//
// Build (irregular.cpp and irregular_merge.cpp have the details of each step):
//   1. A top-level uniform grid with irregular_top_density * N cells, shaped by the scene box
//      (Cleary / Wald et al. rule: resolution_a = round(extent_a * cbrt(density * N / volume))).
//   2. Each non-empty top cell is subdivided again with irregular_sub_density cells per
//      reference it holds; the per-axis sub-resolution is rounded to a power of two so that
//      every sub-cell is a box of the finest "virtual" lattice, whose resolution is the top
//      resolution times 2^S (S = the largest sub-level). References are assigned by exact
//      triangle/box overlap (separating axis test), not by bounding boxes.
//   3. Cells are integer boxes on that lattice plus a reference range. The voxel map, which
//      maps every lattice voxel to a cell, is the two-level grid itself: one entry per top
//      cell (a cell id, or an offset into the sub-level array), so empty top cells cost one
//      entry and memory follows the content, not the volume.
//   4. Merge: passes along x, y, z join aligned neighbours when the cost of the union is no
//      larger than the two apart (cost below), until a round of three passes merges < 0.1%.
//   5. Expansion: each cell's exit box grows over neighbouring cells whose references are a
//      subset of its own, so rays leave it later and skip cells that cannot add a hit. The
//      cell count does not change; BuildStats::extra "cells expanded" counts grown boxes.
//
// Traversal: clip to the grid box, look up the voxel of the entry point, test the cell's
// triangles, intersect the far planes of its exit box; stop if the closest hit is before the
// exit, else look up the voxel just past the exit face. Lattice arithmetic is in double and
// voxel coordinates only move forward along the ray, so every step makes progress and the
// number of steps is bounded by the sum of the lattice resolutions.
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <vector>

#include "accel/accelerator.h"

namespace kdgrid {

class IrregularGrid final : public AcceleratorBase<IrregularGrid> {
 public:
  // ---- fixed constants of the build (documented here rather than in BuildParams because
  // they are the paper's choices, not knobs anyone needs to tune) -------------------------

  /// Largest sub-level per axis: a top cell is split into at most 2^6 = 64 slices per axis,
  /// which bounds the virtual lattice at 64x the top resolution.
  static constexpr int kMaxSubLog = 6;
  /// Merge cost of a cell: half surface area * (references + kMergeTraversalCost), the SAH
  /// with one traversal step costing as much as one triangle test (hagrid's unit cost).
  static constexpr double kMergeTraversalCost = 1.0;
  /// Merging stops when a round of x, y, z passes removes fewer than this fraction of the
  /// cells (or fewer than kMergeMinCells cells).
  static constexpr double kMergeStopFraction = 0.001;
  static constexpr uint64_t kMergeMinCells = 4;
  /// Upper bound on merge rounds, a safety net; convergence is normally reached far earlier.
  static constexpr int kMergeMaxRounds = 64;
  /// Rounds of expansion: in each round every face of a cell's exit box tries to move out by
  /// one layer of neighbouring cells (the paper and hagrid use 3 iterations).
  static constexpr int kExpansionRounds = 3;
  /// Mailbox slots per ray (direct-mapped by triangle index): a triangle referenced by several
  /// cells along the ray is tested once while it stays in its slot. A power of two.
  static constexpr uint32_t kMailboxSlots = 8;

  std::string name() const override { return "irregular"; }
  BuildStats build(const Mesh& mesh, const BuildParams& params) override;

  /// The walk of one ray (AcceleratorBase's contract).
  template <class TriangleTest, class Probe, bool kAny>
  bool traverse(const Ray& ray, Hit* hit, Probe& s) const;

  /// Cell boxes (their own box, not the expanded exit box) with their reference counts.
  void for_each_box(const std::function<void(const StructureBox&)>& fn) const override;

  // ---- inspection (tests, viewer) -------------------------------------------------------
  /// Resolution of the finest (virtual) lattice per axis.
  std::array<int32_t, 3> lattice_resolution() const { return {res_[0], res_[1], res_[2]}; }
  std::array<int32_t, 3> top_resolution() const { return {top_res_[0], top_res_[1], top_res_[2]}; }
  /// World position of lattice plane k on `axis` (k = 0 .. resolution).
  double lattice_plane(int axis, int32_t k) const { return lo_[axis] + double(k) * vs_[axis]; }
  /// Number of traversals that reached the step bound (sum of lattice resolutions + 2).
  /// A correct traversal never does; tests assert this stays 0.
  uint64_t step_bound_hits() const { return bound_hits_.load(std::memory_order_relaxed); }
  size_t num_cells() const { return cells_.size(); }

 private:
  /// A cell as traversal sees it: its exit box (own box after expansion) on the lattice, in
  /// voxel units [lo, hi), and its range in refs_.
  struct Cell {
    int32_t lo[3], hi[3];
    uint32_t begin, end;
  };
  /// One top-level voxel-map entry: a cell id (leaf), or the offset in sub_ of a
  /// 2^log[0] x 2^log[1] x 2^log[2] block of cell ids.
  struct TopEntry {
    uint32_t base = 0;
    uint8_t log[3] = {0, 0, 0};
    uint8_t leaf = 1;
  };
  struct Builder;

  /// Cell id of lattice voxel v (which must be inside the lattice).
  uint32_t lookup(const int32_t v[3]) const {
    const int32_t tx = v[0] >> shift_, ty = v[1] >> shift_, tz = v[2] >> shift_;
    const TopEntry& e = top_[(size_t(tz) * top_res_[1] + ty) * top_res_[0] + tx];
    if (e.leaf) return e.base;
    const int32_t m = (1 << shift_) - 1;
    const int32_t lx = (v[0] & m) >> (shift_ - e.log[0]);
    const int32_t ly = (v[1] & m) >> (shift_ - e.log[1]);
    const int32_t lz = (v[2] & m) >> (shift_ - e.log[2]);
    return sub_[e.base +
                ((size_t(lz) << (e.log[1] + e.log[0])) | (size_t(ly) << e.log[0]) | size_t(lx))];
  }

  /// Lattice coordinate of world coordinate p on `axis`, clamped into the lattice.
  int32_t voxel_of(int axis, double p) const {
    const double f = std::floor((p - lo_[axis]) * inv_vs_[axis]);
    if (!(f >= 0.0)) return 0;  // also catches NaN
    if (f >= double(res_[axis] - 1)) return res_[axis] - 1;
    return int32_t(f);
  }

  Box3 world_box(const int32_t lo[3], const int32_t hi[3]) const {
    return {Vec3(float(lattice_plane(0, lo[0])), float(lattice_plane(1, lo[1])),
                 float(lattice_plane(2, lo[2]))),
            Vec3(float(lattice_plane(0, hi[0])), float(lattice_plane(1, hi[1])),
                 float(lattice_plane(2, hi[2])))};
  }

  const Mesh* mesh_ = nullptr;
  double lo_[3] = {0, 0, 0}, hi_[3] = {0, 0, 0};      ///< grid box (padded scene box)
  double vs_[3] = {1, 1, 1}, inv_vs_[3] = {1, 1, 1};  ///< finest voxel size and its inverse
  int32_t res_[3] = {0, 0, 0};  ///< finest lattice resolution = top_res_ << shift_
  int32_t top_res_[3] = {0, 0, 0};
  int shift_ = 0;  ///< S: log2 of the finest voxels per top cell per axis
  std::vector<TopEntry> top_;
  std::vector<uint32_t> sub_;
  std::vector<Cell> cells_;
  /// Own (unexpanded) box of each cell, lo[3] then hi[3]; only for for_each_box().
  std::vector<std::array<int32_t, 6>> own_boxes_;
  std::vector<uint32_t> refs_;
  mutable std::atomic<uint64_t> bound_hits_{0};
};

// ---- traversal ----------------------------------------------------------------------------

template <class TriangleTest, class Probe, bool kAny>
bool IrregularGrid::traverse(const Ray& ray, Hit* hit, Probe& s) const {
  if (cells_.empty()) return false;
  // Clip to the grid box in double. Zero components (+0 or -0) are handled explicitly so that
  // no 0 * inf NaN can arise: such a ray either lies within the slab for all t or misses.
  double o[3], d[3], inv[3];
  double t0 = ray.tmin, t1 = ray.tmax;
  for (int a = 0; a < 3; ++a) {
    o[a] = ray.org[a];
    d[a] = ray.dir[a];
    if (d[a] == 0.0) {
      if (o[a] < lo_[a] || o[a] > hi_[a]) return false;
      inv[a] = 0.0;
    } else {
      inv[a] = 1.0 / d[a];
      double ta = (lo_[a] - o[a]) * inv[a], tb = (hi_[a] - o[a]) * inv[a];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
  }
  if (!(t0 <= t1)) return false;

  int32_t v[3];
  for (int a = 0; a < 3; ++a) v[a] = voxel_of(a, d[a] == 0.0 ? o[a] : o[a] + d[a] * t0);

  const auto rd = TriangleTest::prepare(ray);
  const auto& pos = mesh_->positions;
  const auto& tris = mesh_->triangles;
  float best = ray.tmax;
  bool found = false;
  double t_in = t0;
  // Re-testing a triangle cannot change the result (best only decreases), so skip repeats.
  uint32_t mailbox[kMailboxSlots];
  std::fill(mailbox, mailbox + kMailboxSlots, kInvalidPrim);
  // Each step moves the exit-axis coordinate by at least one voxel and no coordinate ever
  // moves backwards, so a traversal takes at most res_x + res_y + res_z steps.
  const int64_t bound = int64_t(res_[0]) + res_[1] + res_[2] + 2;
  for (int64_t step = 0;; ++step) {
    if (step >= bound) {
      bound_hits_.fetch_add(1, std::memory_order_relaxed);
      break;
    }
    s.lookup();
    const uint32_t ci = lookup(v);
    const Cell& c = cells_[ci];
    s.step();
    // Far planes of the exit box; the clip end t1 (grid exit or tmax) caps it.
    double t_exit = t1;
    int exit_axis = -1;
    for (int a = 0; a < 3; ++a) {
      if (d[a] == 0.0) continue;
      const int32_t plane = d[a] > 0.0 ? c.hi[a] : c.lo[a];
      const double t = (lo_[a] + double(plane) * vs_[a] - o[a]) * inv[a];
      if (t < t_exit) {
        t_exit = t;
        exit_axis = a;
      }
    }
    t_exit = std::max(t_exit, t_in);  // rounding must not move the ray backwards
    if constexpr (Probe::kTrace)
      s.visit(TraceStep{StepKind::Cell, 0, ci, world_box(c.lo, c.hi), float(t_in), float(t_exit)});
    if (c.end > c.begin) {
      s.leaf();
      if (hit_triangles_mailboxed<TriangleTest, kAny>(rd, pos, tris, refs_.data(), c.begin, c.end,
                                                      mailbox, ray.tmin, best, hit, s)) {
        if constexpr (kAny) return true;
        found = true;
      }
    }
    // Every triangle the ray can meet inside the exit box has been tested, so a hit before
    // the exit is final.
    if (exit_axis < 0 || (found && double(best) <= t_exit)) break;
    // Next voxel: exactly one past the exit face on the exit axis (integer arithmetic); on the
    // other axes from the point at t_exit, kept inside the exit box and never behind the
    // current voxel in the direction of travel.
    int32_t nv[3];
    for (int a = 0; a < 3; ++a) {
      if (a == exit_axis) {
        nv[a] = d[a] > 0.0 ? c.hi[a] : c.lo[a] - 1;
      } else if (d[a] == 0.0) {
        nv[a] = v[a];
      } else {
        int32_t w = voxel_of(a, o[a] + d[a] * t_exit);
        w = std::clamp(w, c.lo[a], c.hi[a] - 1);
        nv[a] = d[a] > 0.0 ? std::max(w, v[a]) : std::min(w, v[a]);
      }
    }
    if (nv[exit_axis] < 0 || nv[exit_axis] >= res_[exit_axis]) break;
    v[0] = nv[0];
    v[1] = nv[1];
    v[2] = nv[2];
    t_in = t_exit;
  }
  return found;
}

}  // namespace kdgrid
