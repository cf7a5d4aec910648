// Brute force: every ray tests every triangle. The reference all structures are checked
// against; O(N) per ray, so only for tests and small scenes.
#pragma once

#include "accel/accelerator.h"

namespace kdgrid {

class BruteForce final : public AcceleratorBase<BruteForce> {
 public:
  std::string name() const override { return "brute"; }
  BuildStats build(const Mesh& mesh, const BuildParams& params) override;

  /// The traversal of one ray (AcceleratorBase's contract): every triangle in index order.
  template <class TriangleTest, class Probe, bool kAny>
  bool traverse(const Ray& ray, Hit* hit, Probe& s) const {
    const auto rd = TriangleTest::prepare(ray);
    float tmax = ray.tmax;
    bool found = false;
    s.step();
    s.leaf();
    if constexpr (Probe::kTrace) s.visit({StepKind::Leaf, 0, 0, bounds_, ray.tmin, ray.tmax});
    const auto& pos = mesh_->positions;
    for (uint32_t i = 0; i < static_cast<uint32_t>(mesh_->triangles.size()); ++i) {
      s.tri_test(i);
      if (hit_triangle<TriangleTest, kAny>(rd, pos, mesh_->triangles[i], i, ray.tmin, tmax, hit)) {
        if constexpr (kAny) return true;
        found = true;
      }
    }
    return found;
  }

  void for_each_box(const std::function<void(const StructureBox&)>& fn) const override {
    fn({bounds_, 0, true, static_cast<uint32_t>(mesh_ ? mesh_->num_triangles() : 0)});
  }

 private:
  const Mesh* mesh_ = nullptr;
  Box3 bounds_;
};

/// Double-precision brute force closest hit, the reference of the extreme-ray suite.
/// Returns the hit with t rounded to float; t_exact receives the double t.
bool brute_force_double(const Mesh& mesh, const Ray& ray, Hit& hit, double* t_exact = nullptr);

}  // namespace kdgrid
