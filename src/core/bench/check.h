// The extreme-ray suite (`kdgrid check`): every structure against a double-precision brute
// force reference where floating point breaks first — scaled and far-off scenes,
// axis-parallel rays, signed zeros, rays lying in the structure's own split planes and cell
// faces, origins on surfaces and boundaries, grazing rays along edges, degenerate triangles,
// dense cells, coplanar scenes and NaN/inf rays.
//
// Each answer is judged against the reference with an explicit notion of ambiguity, so that
// only *unambiguous* disagreements count as failures:
//  - a miss is wrong iff some triangle is hit robustly (the ray passes through its interior,
//    shrunk by a relative margin) at a t safely inside (tmin, tmax);
//  - a hit on triangle p at t is wrong iff p is not even loosely hit (triangle grown by the
//    margin) near t, or some triangle is hit robustly at a t clearly smaller than t.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "accel/accelerator.h"
#include "accel/params.h"
#include "math/ray.h"
#include "scene/mesh.h"

namespace kdgrid {

/// A scene and its rays, each ray labelled with the family it belongs to.
struct CheckCase {
  std::string name;
  Mesh mesh;
  std::vector<Ray> rays;
  std::vector<uint8_t> family;  ///< index into check_ray_families(), per ray
};

/// Names of the ray families ("random", "axis-parallel", "signed-zero", ...).
const std::vector<std::string>& check_ray_families();

/// A scene of one's own with the suite's generic ray families (rays_per_family rays each).
CheckCase make_check_case(const std::string& name, Mesh mesh, int rays_per_family, uint64_t seed);

/// The scenes and rays of the suite. rays_per_family rays of each family per scene.
std::vector<CheckCase> make_check_cases(int rays_per_family, uint64_t seed);

struct CheckResult {
  std::string structure;
  std::string case_name;
  uint64_t rays = 0;
  uint64_t agree = 0;
  uint64_t ambiguous = 0;     ///< the reference itself cannot decide (edge, tie, near tmin)
  uint64_t disagree = 0;      ///< unambiguous disagreements: failures
  uint64_t any_disagree = 0;  ///< occluded() contradicting an unambiguous reference
  uint64_t max_steps = 0;     ///< largest per-ray traversal step count seen
  double seconds = 0;
  std::string error;                  ///< build or traversal exception, if any
  std::vector<std::string> examples;  ///< first few disagreements, printable
  std::vector<uint64_t> disagree_by_family;
};

/// Builds `structure` over the case's mesh (plus rays lying in its own split planes and cell
/// faces) and judges every ray. Never throws: errors are reported in CheckResult::error.
CheckResult run_check(const std::string& structure, const CheckCase& c, const BuildParams& params);

/// Judges an already built structure (over c.mesh, or over anything else: the suite's own
/// test judges a deliberately broken structure). Throws what the structure throws.
CheckResult judge_accelerator(const Accelerator& accel, const CheckCase& c);

/// The verdict on one answer against the double-precision reference.
enum class AccuracyVerdict : uint8_t {
  Agree,      ///< the answer is the reference's
  Ambiguous,  ///< the reference cannot decide (an edge or vertex hit, a tie, a grazing ray)
  Disagree,   ///< contradicts an unambiguous reference (judge_accelerator's failures)
  Leak,       ///< slipped through a shared edge or vertex of a closed part of the mesh
};
/// "agree", "ambiguous", "disagree", "leak".
const char* to_string(AccuracyVerdict v);

/// The reference of `kdgrid check` for judging answers one ray at a time (the viewer's
/// accuracy map), with the rules of judge_accelerator, plus leaks: where the ray crosses the
/// surface through a closed edge (two triangles, each hit within the reference's edge margin,
/// at the same t, facing the ray the same way, the edge used by exactly those two and each of
/// its ends closed) or through a closed vertex (every edge at it shared by two triangles), one
/// of them must be hit there; an
/// answer beyond that t, or none, has slipped through (what `kdgrid sweep triangle` counts as a
/// leak). judge_accelerator calls these answers ambiguous: it does not know the mesh's edges.
/// The cost is a double-precision test of every triangle per ray.
class AccuracyReference {
 public:
  /// `mesh` must outlive the reference.
  explicit AccuracyReference(const Mesh& mesh);
  /// A closest-hit answer (`hit`, and `h` when hit) of `r`.
  AccuracyVerdict judge_closest(const Ray& r, bool hit, const Hit& h) const;
  /// An any-hit (occlusion) answer of `r`.
  AccuracyVerdict judge_occluded(const Ray& r, bool occluded) const;

  const Mesh& mesh() const { return *mesh_; }
  /// The edge (a, b) is used by exactly two triangles.
  bool closed_edge(uint32_t a, uint32_t b) const;
  /// Every edge at vertex v is used by exactly two triangles.
  bool closed_vertex(uint32_t v) const { return closed_vertex_[v] != 0; }

 private:
  const Mesh* mesh_;
  double scale_;
  std::vector<std::pair<uint64_t, uint32_t>> edge_faces_;  ///< (edge key, faces), sorted
  std::vector<uint8_t> closed_vertex_;
};

/// Self-intersection study: rays leaving random points on random triangles (scales 1e-4 ..
/// 1e4, translated up to 1e5) away from the surface; counts rays that re-hit their own
/// triangle with the robust offset and with a fixed epsilon (tmin = eps) for comparison, and
/// times each policy (making the ray plus its closest-hit query) so that the acne rate sits
/// beside the speed it buys.
struct AcneResult {
  double scale = 1;
  double translation = 0;
  uint64_t rays = 0;
  uint64_t robust_self_hits = 0;
  uint64_t epsilon_self_hits = 0;
  float epsilon = 1e-4f;
  /// Seconds to make and trace this scale's rays, one thread, median of kAcneTimingReps
  /// passes, the two policies alternating so that a change in the machine's load hits both.
  double robust_seconds = 0;
  double epsilon_seconds = 0;
};
/// Timed passes per policy and scale in the acne study (the median is kept).
inline constexpr int kAcneTimingReps = 5;
/// The acne study's scene and structure, for reports.
inline constexpr const char* kAcneSceneDescription = "2000-triangle random soup, bvh";
std::vector<AcneResult> run_acne_study(int rays_per_scale, uint64_t seed, float epsilon = 1e-4f);
/// Surface acne of one structure: of `rays` rays leaving seeded random points of the mesh's
/// triangles (either side, offset by offset_ray_origin, random directions), how many re-hit
/// their own triangle first.
uint64_t count_self_hits(const Accelerator& accel, const Mesh& mesh, int rays, uint64_t seed);

}  // namespace kdgrid
