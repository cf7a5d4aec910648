// Intel Embree 3 as the reference of the benchmark: one triangle geometry over the mesh's
// own index buffer (shared, not copied) and a padded copy of its positions (Embree reads
// vertices with 16-byte loads, so the buffer needs 4 spare bytes at its end).
//
// Embree's traversal is not a kdgrid template, so this implements Accelerator directly:
// the counted entry points return the same hits with zero counters (has_counters() is
// false) and trace() returns a Trace holding only the hit.
//
// Ray semantics: Embree accepts hits with tnear <= t <= tfar and requires tnear >= 0.
// kdgrid's rays accept [tmin, tmax), so tfar is set to the float just below tmax, and a
// negative tmin is handled by moving the origin to org + tmin * dir (t is shifted back).
// Barycentrics follow the same convention as Hit (u weights v1, v weights v2).
#pragma once

#include <atomic>
#include <memory>
#include <vector>

#include "accel/accelerator.h"

namespace kdgrid {

class EmbreeAccel final : public Accelerator {
 public:
  EmbreeAccel();
  ~EmbreeAccel() override;
  EmbreeAccel(const EmbreeAccel&) = delete;
  EmbreeAccel& operator=(const EmbreeAccel&) = delete;

  std::string name() const override { return "embree"; }
  BuildStats build(const Mesh& mesh, const BuildParams& params) override;

  bool intersect(const Ray& ray, Hit& hit) const override;
  bool occluded(const Ray& ray) const override;
  bool intersect_counted(const Ray& ray, Hit& hit, RayCounters&) const override {
    return intersect(ray, hit);
  }
  bool occluded_counted(const Ray& ray, RayCounters&) const override { return occluded(ray); }
  bool has_counters() const override { return false; }
  Trace trace(const Ray& ray) const override;

  uint64_t memory_bytes() const override { return stats_.bytes; }
  const BuildStats& stats() const override { return stats_; }

 private:
  void release();

  struct State;  // Embree handles, kept out of this header
  std::unique_ptr<State> state_;
  std::vector<float> vertices_;  ///< xyz per vertex plus one float of padding
  const Mesh* mesh_ = nullptr;   ///< the built mesh (Embree shares its index buffer)
  BuildStats stats_;
};

}  // namespace kdgrid
