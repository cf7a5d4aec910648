// Uniform grid (the classic comparator of the hybrid).
//
// Resolution — the density heuristic of Cleary et al. and Wald et al. 2006 ("Ray tracing
// animated scenes using coherent grid traversal"): aim for cells = lambda * N for N
// triangles (BuildParams::grid_lambda, 4 by default), with cubical cells, so along axis a
// the grid has n_a = round(extent_a * k) cells where k = cbrt(lambda * N / volume). A flat
// or thin scene would make k explode, so axes whose n_a would come out below 1 get one cell
// and k is recomputed over the remaining axes (k = (lambda * N / prod extents)^(1/m) for m
// axes). Each n_a is finally clamped to [1, grid_max_resolution].
//
// Storage: a prefix-sum array of uint32 cell offsets (cells + 1 entries) into one flat array
// of triangle indices. A triangle is referenced by every cell its box overlaps AND that the
// triangle itself touches, decided by the exact separating-axis test of Akenine-Möller
// (2001) in double precision against the cell slightly enlarged (see kCellPad in grid.cpp),
// so that rounding in the traversal can never step past a cell that holds a hit.
//
// Traversal: 3D-DDA (Amanatides & Woo 1987) from the ray's entry into the grid box. The
// closest hit found so far is kept across cells (its t is the test's tmax), and traversal
// stops after the first cell whose exit t is >= that hit's t: the "hit inside the cell"
// rule. Triangles spanning several cells would be re-tested in each, so a per-ray mailbox
// (a 16-entry direct-mapped cache of tested triangle ids) skips repeats; this is safe
// because a tested triangle's hit, if any, is already the current closest or farther.
#pragma once

#include <array>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <vector>

#include "accel/accelerator.h"

namespace kdgrid {

class UniformGrid final : public AcceleratorBase<UniformGrid> {
 public:
  std::string name() const override { return "grid"; }
  BuildStats build(const Mesh& mesh, const BuildParams& params) override;

  /// The traversal of one ray (AcceleratorBase's contract).
  template <class TriangleTest, class Probe, bool kAny>
  bool traverse(const Ray& ray, Hit* hit, Probe& s) const;

  void for_each_box(const std::function<void(const StructureBox&)>& fn) const override;

  /// Cells along x, y, z.
  std::array<int, 3> resolution() const { return res_; }
  /// Box the cells cover (the mesh box, padded on degenerate axes).
  const Box3& bounds() const { return box_; }
  /// A bound on cells visited per ray that a correct DDA can never reach.
  uint64_t max_steps() const { return uint64_t(res_[0]) + res_[1] + res_[2] + 3; }

 private:
  /// The build's steps and scratch state (grid.cpp).
  struct Builder;

  Box3 cell_box(const int c[3]) const {
    Box3 b;
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = box_.lo[a] + float(c[a]) * cell_[a];
      b.hi[a] = c[a] + 1 == res_[a] ? box_.hi[a] : box_.lo[a] + float(c[a] + 1) * cell_[a];
    }
    return b;
  }

  const Mesh* mesh_ = nullptr;
  Box3 box_;
  std::array<int, 3> res_{1, 1, 1};
  Vec3 cell_{1.0f}, inv_cell_{1.0f};
  std::vector<uint32_t> offsets_;  ///< cells + 1 prefix sums into refs_
  std::vector<uint32_t> refs_;     ///< triangle indices, grouped by cell, ascending per cell
};

template <class TriangleTest, class Probe, bool kAny>
bool UniformGrid::traverse(const Ray& ray, Hit* hit, Probe& s) const {
  if (refs_.empty()) return false;
  // Clip the ray to the grid box. Axes with a zero (+0 or -0) direction never bound t and
  // never step; the ray misses unless its origin lies within the slab (boundary included).
  float t0 = ray.tmin, t1 = ray.tmax;
  Vec3 inv_dir;
  for (int a = 0; a < 3; ++a) {
    const float o = ray.org[a], d = ray.dir[a];
    if (d == 0.0f) {
      if (o < box_.lo[a] || o > box_.hi[a]) return false;
      inv_dir[a] = 0.0f;
      continue;
    }
    inv_dir[a] = 1.0f / d;
    float tn = (box_.lo[a] - o) * inv_dir[a], tf = (box_.hi[a] - o) * inv_dir[a];
    if (tn > tf) std::swap(tn, tf);
    // Widen by a few ulps so rays grazing an edge of the box are not lost to rounding.
    tf *= 1.0f + 4.0f * std::numeric_limits<float>::epsilon();
    t0 = tn > t0 ? tn : t0;
    t1 = tf < t1 ? tf : t1;
  }
  if (!(t0 <= t1)) return false;

  // Entry cell, and per axis the step direction and the t of the next cell boundary.
  int cell[3], step[3];
  float t_next[3];
  for (int a = 0; a < 3; ++a) {
    const float d = ray.dir[a];
    const float p = d == 0.0f ? ray.org[a] : ray.org[a] + d * t0;
    float f = std::floor((p - box_.lo[a]) * inv_cell_[a]);
    f = std::min(std::max(f, 0.0f), float(res_[a] - 1));
    cell[a] = int(f);
    if (d > 0.0f) {
      step[a] = 1;
      t_next[a] = (box_.lo[a] + float(cell[a] + 1) * cell_[a] - ray.org[a]) * inv_dir[a];
    } else if (d < 0.0f) {
      step[a] = -1;
      t_next[a] = (box_.lo[a] + float(cell[a]) * cell_[a] - ray.org[a]) * inv_dir[a];
    } else {
      step[a] = 0;
      t_next[a] = kInf;
    }
  }
  const int64_t stride[3] = {1, int64_t(res_[0]), int64_t(res_[0]) * res_[1]};
  int64_t idx = cell[0] + stride[1] * cell[1] + stride[2] * cell[2];

  const auto rd = TriangleTest::prepare(ray);
  const auto& pos = mesh_->positions;
  const auto& tris = mesh_->triangles;
  uint32_t mailbox[16];
  for (uint32_t& m : mailbox) m = kInvalidPrim;
  float best = ray.tmax;
  bool found = false;
  float t_in = t0;
  [[maybe_unused]] uint64_t iterations = 0;
  for (;;) {
    assert(++iterations <= max_steps() && "grid DDA exceeded its step bound");
    s.step();
    s.lookup();
    // Rounding can put a boundary a hair before the entry point; keep intervals monotone.
    const float t_exit =
        std::max(t_in, std::min(std::min(std::min(t_next[0], t_next[1]), t_next[2]), t1));
    if constexpr (Probe::kTrace)
      s.visit({StepKind::Cell, 0, uint64_t(idx), cell_box(cell), t_in, t_exit});
    const uint32_t begin = offsets_[idx], end = offsets_[idx + 1];
    if (begin != end) {
      s.leaf();
      if (hit_triangles_mailboxed<TriangleTest, kAny>(rd, pos, tris, refs_.data(), begin, end,
                                                      mailbox, ray.tmin, best, hit, s)) {
        if constexpr (kAny) return true;
        found = true;
      }
    }
    if (found && best <= t_exit) break;
    // Step across the nearest cell boundary; ties (the ray passes through an edge or corner)
    // step one axis now and the other next iteration, through a zero-length cell.
    int a = t_next[0] < t_next[1] ? 0 : 1;
    if (t_next[2] < t_next[a]) a = 2;
    if (t_next[a] > t1) break;
    cell[a] += step[a];
    if (cell[a] < 0 || cell[a] >= res_[a]) break;
    idx += step[a] * stride[a];
    t_in = std::max(t_in, t_next[a]);
    const float plane = box_.lo[a] + float(cell[a] + (step[a] > 0 ? 1 : 0)) * cell_[a];
    t_next[a] = (plane - ray.org[a]) * inv_dir[a];
  }
  return found;
}

}  // namespace kdgrid
