// Progressive Whitted renderer. Each pass adds one jittered sample per pixel to a float
// accumulation film; tiles of a pass are spread over all cores with oneTBB. Deterministic for
// a given seed (each pixel's sample k uses a generator seeded by (seed, pixel, k)).
// A pass can be cancelled through an atomic flag; reset() restarts accumulation (the viewer
// calls it on every camera move).
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "accel/accelerator.h"
#include "image/image_io.h"  // tonemap_srgb8, the film's 8-bit encoding
#include "render/camera.h"
#include "render/offset.h"
#include "scene/scene.h"

namespace kdgrid {

enum class RenderMode {
  Shaded,     ///< Whitted shading
  HeatSteps,  ///< per-pixel traversal steps of the primary ray (counted traversal)
  HeatTests,  ///< per-pixel triangle tests of the primary ray
  /// Per-pixel nanoseconds of the primary ray's closest-hit query (Accelerator::intersect,
  /// timed with the steady clock around each call; its own cost, some 20 ns, included).
  HeatTime,
};

/// How RenderMode::Shaded lights a surface.
enum class Shading {
  Lights,    ///< the scene's lights, shadows, reflection and refraction (Whitted)
  EyeLight,  ///< a light at the eye: albedo times the cosine to the view ray; no scene light
  Normals,   ///< the surface's shading normal as a colour, (n + 1) / 2; no scene light
};

/// "lights", "eye" or "normals"; ParamError naming `what` for anything else.
Shading parse_shading(const std::string& s, const std::string& what);
const char* to_string(Shading s);

/// Where a secondary ray (shadow, reflection, refraction) starts on the surface it leaves.
enum class SecondaryOffset {
  Robust,   ///< offset_ray_origin: the hit point moved off the surface (scale invariant)
  Epsilon,  ///< the hit point itself, skipping hits nearer than kSecondaryEpsilon
  None,     ///< the hit point itself, tmin 0: the ray may hit the surface it leaves
};

/// The fixed distance SecondaryOffset::Epsilon skips, in scene units (the fixed epsilon of
/// `kdgrid check --acne`).
constexpr float kSecondaryEpsilon = 1e-4f;

/// "robust", "epsilon" or "none"; ParamError naming `what` for anything else.
SecondaryOffset parse_secondary_offset(const std::string& s, const std::string& what);
const char* to_string(SecondaryOffset o);

/// One in kLitProbeStride x kLitProbeStride pixels (x and y multiples of it) of an
/// EyeLight or Normals pass probes whether a scene light reaches its primary hit
/// (RenderCounters::probed, lit), so that the viewer can tell whether the scene's lights would
/// show anything without rendering with them.
constexpr int kLitProbeStride = 4;

/// Highest RenderSettings::max_depth (`--max-depth`) accepted. Shading recurses once per
/// bounce, so the limit bounds the stack (a few hundred bytes a level, well inside a worker
/// thread's stack); a Whitted path that has not faded below 1e-4 after 256 perfect
/// reflections is a hall of mirrors no image needs deeper. docs/LIMITS.md.
constexpr int kMaxRenderDepth = 256;

/// Most samples per pixel (render --spp, sweep spp's sample counts, the viewer's
/// --max-samples): each is a pass over the whole image, so 2^20 passes of even a 64x64 image
/// take hours, and the per-pixel sums stay far from float's 2^24 integer precision. Counts
/// past it are refused before any work. docs/LIMITS.md.
constexpr int kMaxSamplesPerPixel = 1 << 20;

/// Most reflection and refraction rays traced for one camera sample (its whole ray tree,
/// shadow rays not counted). Glass splits every path in two at each bounce, so a deep
/// --max-depth would otherwise trace up to 2^depth rays per sample; past the budget further
/// branches are not traced (their light is lost). Normal scenes stay far below it: a path
/// is also dropped once its weight (the product of the weights along it) is below 1e-4.
/// docs/LIMITS.md.
constexpr uint32_t kMaxSecondaryRaysPerSample = 1024;

/// Most primary rays of one packet (RenderSettings::packets): an 8x8 tile's, the packet size
/// `kdgrid bench` measures packets with (docs/HYBRID.md, "Packets").
constexpr int kRenderPacket = 64;

/// Most shadow rays of one occluded_packet call: the shadow rays of a packet's primary hits
/// (one per hit and light that can reach it) are traced in packets of this many.
constexpr int kShadowPacket = 256;

struct RenderSettings {
  int width = 640;      ///< pixels, >= 1
  int height = 480;     ///< pixels, >= 1
  int max_depth = 5;    ///< reflection/refraction bounces after the primary hit, 0..kMaxRenderDepth
  uint64_t seed = 1;    ///< sample pattern seed
  int tile_size = 16;   ///< pixels per tile edge (the unit of work of a thread)
  bool shadows = true;  ///< trace shadow rays to lights
  bool jitter = true;   ///< jitter samples inside the pixel (false: pixel centres)
  /// Trace each tile's primary rays together through Accelerator::intersect_packet, in packets
  /// of up to kRenderPacket rays (rows of the tile), instead of one intersect() per pixel, and
  /// their hits' shadow rays together through occluded_packet, up to kShadowPacket at a time.
  /// The packet answers are bitwise the single-ray ones, so the image is the same (with Embree,
  /// up to a pixel whose ray hits two triangles at exactly the same t or, with its default
  /// flags, grazes a shared edge: its packet kernels may pick the other triangle). On by
  /// default: Embree's packets and the hybrid's packet walk trace primary rays several times
  /// as fast as their single rays; the other structures' packet queries loop over their single
  /// rays (docs/HYBRID.md, "Packets").
  bool packets = true;
  RenderMode mode = RenderMode::Shaded;
  Shading shading = Shading::Lights;                 ///< how RenderMode::Shaded lights a surface
  SecondaryOffset offset = SecondaryOffset::Robust;  ///< where secondary rays start
};

/// The kind of a ray in a sample's Whitted ray tree (Renderer::trace_tree).
enum class RayKind : uint8_t { Primary, Shadow, Reflection, Refraction };
/// "primary", "shadow", "reflection", "refraction".
const char* to_string(RayKind k);

/// One ray of a sample's ray tree: the ray exactly as the renderer traced it, its traversal
/// step by step and the time the structure's fast query takes on it.
struct RayTreeNode {
  RayKind kind = RayKind::Primary;
  int parent = -1;     ///< the ray whose hit spawned this one (-1 for the primary)
  int depth = 0;       ///< bounces below the primary; a shadow ray has its surface's depth
  uint32_t light = 0;  ///< shadow rays: the light (index into Scene::lights) they test
  Ray ray;
  /// Closest-hit traversal (Accelerator::trace); for a shadow ray the any-hit traversal the
  /// renderer's occluded() query walks (Accelerator::trace_occluded, answer in trace.occluded).
  Trace trace;
  /// Seconds one fast query (intersect(), or occluded() for a shadow ray) takes on this ray:
  /// the mean of a timed loop of repetitions (kRayTreeTimingNanos at least).
  double seconds = 0;
};

/// A camera sample's whole ray tree, in the order the renderer traced the rays (depth first:
/// a surface's shadow rays, then its reflection ray and its subtree, then its refraction ray).
struct RayTree {
  std::vector<RayTreeNode> nodes;  ///< nodes[0] is the primary ray
  Vec3 radiance;                   ///< the sample's radiance, as render_pass() computes it
  bool timed = true;               ///< the nodes' seconds were measured
};

/// Least total time of the timed loop behind RayTreeNode::seconds, in nanoseconds: long
/// against the clock's resolution, short enough for a pick to stay interactive.
constexpr double kRayTreeTimingNanos = 20000.0;

/// Rays traced so far, by kind; updated after every pass. Reflection rays come from
/// reflective materials (Material::reflects()) and from the Fresnel reflection / total
/// internal reflection of refractive ones; a scene with neither traces none.
struct RenderCounters {
  uint64_t primary = 0, shadow = 0, reflection = 0, refraction = 0;
  /// Shaded passes only: primary hits checked for direct light (every hit with
  /// Shading::Lights, the probe pixels' with the others; kLitProbeStride), and those of them
  /// that a scene light reaches (unblocked) or that emit light. lit / probed near 0 means the
  /// scene's lights leave the view uniformly dark (ambient light only).
  uint64_t probed = 0, lit = 0;
  uint64_t total() const { return primary + shadow + reflection + refraction; }
};

class Renderer {
 public:
  /// scene and accel must outlive the renderer (the viewer swaps accel via set_accelerator).
  Renderer(const Scene& scene, const Accelerator& accel, const RenderSettings& settings);

  /// Change the camera / accelerator / settings; each restarts accumulation. Not to be called
  /// while render_pass() runs on another thread.
  void set_camera(const Camera& cam);
  void set_accelerator(const Accelerator& accel);
  void set_settings(const RenderSettings& settings);
  void reset();

  /// Renders one sample per pixel over the whole image. Returns false (and leaves the film as
  /// it was before the pass) if *cancel became true during the pass.
  bool render_pass(const std::atomic<bool>* cancel = nullptr);

  int samples() const { return samples_; }
  const RenderSettings& settings() const { return settings_; }
  const Camera& camera() const { return camera_; }
  const RenderCounters& counters() const { return counters_; }
  double seconds() const { return seconds_; }  ///< wall time of all passes so far

  /// Averaged linear RGB (3 floats per pixel, row 0 at the top). In heat map modes the
  /// channels hold the raw per-pixel count in all three.
  void resolve(std::vector<float>& rgb) const;

  /// Radiance along one ray (used by render_pass; public for tests and the viewer's pick).
  /// Traces at most kMaxSecondaryRaysPerSample reflection/refraction rays below it.
  Vec3 radiance(const Ray& ray, int depth, RenderCounters& counters) const;

  /// The whole Whitted ray tree of one camera ray (primary, shadow, reflection and refraction
  /// rays down to settings().max_depth), traced by the same shading code as render_pass(), so
  /// its rays are bitwise the ones a render traces for that sample (the packet path's answers
  /// are bitwise the single-ray ones). Shaded mode's tree; for the viewer's pick and tests.
  /// timed = false leaves every RayTreeNode::seconds at 0 (no timing loops).
  RayTree trace_tree(const Ray& primary, bool timed = true) const;

 private:
  /// radiance() for a ray whose contribution to the pixel is `path_weight` times its
  /// radiance; `budget` is the number of secondary rays the sample may still trace.
  /// With `tree` (trace_tree), every ray is recorded into it, its parent being node `parent`.
  Vec3 shade(const Ray& ray, int depth, const Vec3& path_weight, uint32_t& budget,
             RenderCounters& counters, RayTree* tree = nullptr, int parent = -1,
             RayKind kind = RayKind::Primary) const;
  /// shade() once the ray's closest hit is known (`found`, `hit` as intersect() gives them);
  /// `node` is the ray's node in `tree` when one is recorded.
  Vec3 shade_hit(const Ray& ray, bool found, const Hit& hit, int depth, const Vec3& path_weight,
                 uint32_t& budget, RenderCounters& counters, RayTree* tree = nullptr,
                 int node = -1) const;
  /// Traces `ray` step by step into a new node of `tree` and times its fast query; returns
  /// the node's index.
  int record_ray(RayTree& tree, const Ray& ray, RayKind kind, int parent, int depth) const;

  /// What shading needs of the surface a ray hit: its point, normals and material terms.
  struct Surface {
    const Material* m;
    Vec3 p, d, ng, n;  ///< hit point, unit ray direction, geometric and shading normals
    Vec3 albedo, diffuse, spec, shadow_org;
    float shadow_skip;  ///< the distance from shadow_org a shadow ray skips (SecondaryOffset)
    std::array<Vec3, 3> corners;  ///< the hit triangle's, for offset_ray_origin
    float exponent, transmission;
    bool front;  ///< the ray entered through the outside (ng was not flipped)
  };
  /// The light one light sends to a surface point if nothing is in its way.
  struct LightTerm {
    Vec3 wi, irradiance;
    float cos_l;
  };
  Surface surface_at(const Ray& ray, const Hit& hit) const;
  /// The colour of a primary hit without scene lights (Shading::EyeLight, Normals); at the
  /// probe pixels (`probe`) also counts whether a scene light reaches it.
  Vec3 shade_unlit_mode(const Ray& ray, bool found, const Hit& hit, bool probe,
                        RenderCounters& counters) const;
  /// Whether some scene light reaches `s` (a shadow ray per light until one is unblocked).
  bool any_light_reaches(const Surface& s, RenderCounters& counters) const;
  /// False when `light` cannot light `s` whatever lies between them (behind the surface,
  /// outside a spot's cone, at the point itself).
  bool light_term(const Surface& s, const Light& light, LightTerm& t) const;
  /// The shadow ray that decides whether `light` reaches `s`.
  static Ray shadow_ray(const Surface& s, const Light& light, const LightTerm& t);
  /// A reflection or refraction ray leaving `s` in direction `dir` (unit) on the side `side`
  /// of the surface faces, started as RenderSettings::offset says.
  Ray leaving_ray(const Surface& s, const Vec3& side, const Vec3& dir) const;
  /// The light's reflected radiance, added to `result`.
  static void add_light(const Surface& s, const LightTerm& t, Vec3& result);
  /// Emission and ambient light: the start of a surface's radiance, before its lights.
  static Vec3 unlit(const Surface& s);
  /// The surface's reflection and refraction rays, traced and added to `result` (its lights
  /// already in it); returns the radiance.
  Vec3 finish_hit(const Surface& s, Vec3 result, int depth, const Vec3& path_weight,
                  uint32_t& budget, RenderCounters& counters, RayTree* tree = nullptr,
                  int node = -1) const;
  /// The shaded radiance of n primary rays of one packet (their hits as intersect_packet gave
  /// them), their shadow rays traced through occluded_packet; bitwise shade_hit's answers.
  void shade_packet(const Ray* rays, const Hit* hits, const bool* found, int n, Vec3* out,
                    RenderCounters& counters) const;
  /// One tile of a pass (x0..x1, y0..y1): its samples added to `film` (the pass's scratch).
  void render_tile(int x0, int y0, int x1, int y1, uint64_t sample, float* film,
                   RenderCounters& c) const;

  const Scene* scene_;
  const Accelerator* accel_;
  RenderSettings settings_;
  Camera camera_;
  CameraFrame frame_;
  std::vector<float> accum_;  // RGB sums
  int samples_ = 0;
  RenderCounters counters_;
  double seconds_ = 0;
  bool need_reflection_ = false, need_refraction_ = false;
};

}  // namespace kdgrid
