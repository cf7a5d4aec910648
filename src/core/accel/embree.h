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
//
// Configurations (registered names of the factory, accel/factory.cpp):
//   embree         Embree's default scene flags (no RTC_SCENE_FLAG_ROBUST) at the build quality
//                  of BuildParams::embree_quality (default medium, Embree's own default): what a
//                  user of Embree runs, so the benchmark's reference and every ratio to Embree.
//   embree-robust  RTC_SCENE_FLAG_ROBUST: Embree's robust traversal and triangle test, fewer
//                  rays slipping through edges for some speed (a point of the speed/accuracy
//                  trade, docs/RESULTS.md); same build quality as embree.
//   embree-high    default flags at RTC_BUILD_QUALITY_HIGH (spatial splits): a slower build for
//                  faster tracing; --embree-quality does not apply to it.
#pragma once

#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include "accel/accelerator.h"

namespace kdgrid {

/// One Embree configuration: its registered name, scene flags and build quality.
struct EmbreeConfig {
  std::string name = "embree";
  /// RTC_SCENE_FLAG_ROBUST on the scene; false = Embree's default flags.
  bool robust = false;
  /// "low", "medium" or "high" for every build; "" = BuildParams::embree_quality.
  std::string quality;
};

/// The configurations the factory registers, in the order tables list them (embree first).
const std::vector<EmbreeConfig>& embree_configs();
/// The registered configuration called `name`, or nullptr when no Embree configuration is.
const EmbreeConfig* embree_config(const std::string& name);

/// What Embree's library chose on this CPU, for reports. Embree 3 has no property naming its
/// ISA: the widest native ray packet (rtcGetDeviceProperty RTC_DEVICE_PROPERTY_NATIVE_RAY16,
/// RAY8, RAY4_SUPPORTED) tells which kernels its enabled ISA runs: 16 = AVX-512, 8 = AVX or
/// AVX2, 4 = SSE. A device restricted to one ISA (BuildParams::embree_isa, rtcNewDevice's
/// "isa=") runs that ISA's kernels, named as such. rtcIntersect1/rtcOccluded1 trace one ray at
/// a time with those kernels.
struct EmbreeIsa {
  std::string version;  ///< RTC_DEVICE_PROPERTY_VERSION as "3.13.5"
  /// "AVX-512", "AVX or AVX2", "SSE" or "unknown"; restricted: "AVX-512", "AVX2", "AVX", "SSE4.2"
  std::string isa;
  std::string config;     ///< the restriction ("avx2", ...; "" = none: Embree's own choice)
  int native_packet = 0;  ///< widest native ray packet: 16, 8, 4 (0 = none)
};
/// The names BuildParams::embree_isa takes ("sse4.2", "avx", "avx2", "avx512"), for messages.
const char* embree_isa_names();
/// Throws ParamError unless `isa` is "" or one of embree_isa_names() that this CPU runs.
void check_embree_isa(const std::string& isa);
/// Creates a device with the restriction `isa` ("" = none) once and asks it (cached per
/// restriction; "unknown" if no device can be created). Checks `isa` as check_embree_isa does.
const EmbreeIsa& embree_isa(const std::string& isa = "");

class EmbreeAccel final : public Accelerator {
 public:
  explicit EmbreeAccel(EmbreeConfig config = {});
  ~EmbreeAccel() override;
  EmbreeAccel(const EmbreeAccel&) = delete;
  EmbreeAccel& operator=(const EmbreeAccel&) = delete;

  std::string name() const override { return config_.name; }
  /// Whether the built scene has RTC_SCENE_FLAG_ROBUST, as Embree reports it
  /// (rtcGetSceneFlags); before a build, whether the configuration asks for it.
  bool robust() const;
  /// The build quality of the last build ("" before one), as BuildStats::extra "quality".
  const std::string& quality() const { return quality_; }
  BuildStats build(const Mesh& mesh, const BuildParams& params) override;

  bool intersect(const Ray& ray, Hit& hit) const override;
  bool occluded(const Ray& ray) const override;
  bool intersect_counted(const Ray& ray, Hit& hit, RayCounters&) const override {
    return intersect(ray, hit);
  }
  bool occluded_counted(const Ray& ray, RayCounters&) const override { return occluded(ray); }
  bool has_counters() const override { return false; }
  /// Embree's packet API: rtcIntersect16/8/4 (rtcOccluded likewise) at the widest native
  /// packet embree_isa() reports, with RTC_INTERSECT_CONTEXT_FLAG_COHERENT; invalid rays are
  /// masked off and miss. Without a native packet, the single-ray loop.
  void intersect_packet(const Ray* rays, int n, Hit* hits, bool* found) const override;
  void occluded_packet(const Ray* rays, int n, bool* occluded_out) const override;
  int packet_width() const override;
  Trace trace(const Ray& ray) const override;

  uint64_t memory_bytes() const override { return stats_.bytes; }
  const BuildStats& stats() const override { return stats_; }

 private:
  void release();
  template <int K>
  void intersect_k(const Ray* rays, int n, Hit* hits, bool* found) const;
  template <int K>
  void occluded_k(const Ray* rays, int n, bool* occluded_out) const;

  EmbreeConfig config_;
  std::string quality_;
  /// The ISA of the last build's device (before a build: Embree's own choice).
  EmbreeIsa isa_;
  struct State;  // Embree handles, kept out of this header
  std::unique_ptr<State> state_;
  std::vector<float> vertices_;  ///< xyz per vertex plus one float of padding
  const Mesh* mesh_ = nullptr;   ///< the built mesh (Embree shares its index buffer)
  BuildStats stats_;
};

}  // namespace kdgrid
