// The benchmark runner behind `kdgrid bench` (docs/RAYSETS.md "Figures"): every structure side
// by side on the same rays, in one run, with every throughput also given as a ratio to the
// reference (Embree's rtcIntersect1/rtcOccluded1) measured on the same rays in the same run.
//
// Per scene: load, choose the camera, make the ray sets once (or read them from .rays files),
// run the reference first, then each structure: build, time each set `reps` times (fast path:
// intersect() for primary/diffuse, occluded() for shadow, tbb::parallel_for over chunks with
// the thread count fixed by tbb::global_control), one extra counted pass for the per-ray
// steps/leaves/tests, and hit agreement with the reference.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "accel/accelerator.h"
#include "accel/embree.h"
#include "accel/params.h"
#include "bench/probes.h"
#include "bench/suite.h"

namespace kdgrid {

/// Largest BenchOptions::packet_tile: 16 x 16 = 256 rays a packet.
constexpr int kMaxPacketTile = 16;

struct BenchOptions {
  /// Structures to measure, in table order; empty = every registered structure except brute
  /// (O(N) per ray: only on request). The reference is always run first and reported too.
  std::vector<std::string> accels;
  /// Ray sets (docs/RAYSETS.md): "primary", "shadow", "diffuse".
  std::vector<std::string> sets = {"primary", "shadow", "diffuse"};
  /// Worker threads for tracing (and parallel builders); 0 = all hardware threads.
  int threads = 0;
  /// Timed repetitions of each set; the median is reported (docs/RAYSETS.md asks for >= 5).
  int reps = 5;
  /// Primary image size: one ray per pixel. docs/RAYSETS.md's canonical size is 1024 x 1024.
  int width = 1024, height = 1024;
  /// If set, ray sets are read from DIR/<scene>.<set>.rays when that file exists, and written
  /// there when it does not, so other tools can trace exactly the same rays.
  std::string rays_dir;
  /// Reference structure for ratios and agreement; "" = embree if registered, else bvh.
  std::string reference;
  /// Build knobs shared by all structures.
  BuildParams params;
  /// Time the reference again just before each repetition of every structure and take the
  /// ratio per pair: a shared machine's load changes between structures, and a pair sees the
  /// same load. Doubles the tracing time; false = reference timed once per scene.
  bool interleave_reference = true;
  /// Time tracing with the threads' CPU clocks instead of the wall clock (trace_rays), for
  /// shared, loaded machines; the report says which clock was used.
  bool cpu_clock = false;
  /// The packet column: primary rays are traced again through every structure's packet query
  /// (Accelerator::intersect_packet) in tiles of packet_tile x packet_tile pixels, one packet a
  /// tile, and shadow rays (made in image order from the primary hits) in runs of packet_tile^2,
  /// with the reference's packet query (Embree: rtcIntersect16/8 with the coherent flag)
  /// timed beside each repetition. 8 = 64-ray packets, the renderer's; 0 = no packet column;
  /// at most kMaxPacketTile. Single-ray figures stay the headline.
  int packet_tile = 8;
  /// The render column: the whole Whitted render of the scene (Renderer, one pass of one
  /// sample per pixel at the bench's image size from the bench's camera: primary, shadow,
  /// reflection and refraction rays, packets where the renderer uses them) through every
  /// structure, `reps` passes each, the reference's pass timed just before each of them.
  bool render = false;
  /// Relative tolerance on t under which two different triangles count as the same hit.
  double tie_tolerance = 1e-5;
  /// Receives one line per step of a long run (stderr in the CLI); may be empty.
  std::function<void(const std::string&)> progress;
};

/// Figures of one structure on one ray set.
struct SetFigures {
  std::string set;
  uint64_t rays = 0;
  uint64_t hits = 0;               ///< rays that hit (shadow: rays found occluded)
  std::vector<double> mrays_reps;  ///< Mrays/s of each timed repetition
  double mrays_median = 0, mrays_min = 0, mrays_max = 0;
  /// Throughput relative to the reference (0 if none). Paired (the default): the median of
  /// the per-repetition ratios, the reference timed on the same set just before each of this
  /// structure's repetitions. Otherwise mrays_median / the reference's own median.
  double ratio_to_reference = 0;
  double reference_mrays = 0;  ///< the reference's median Mrays/s behind the ratio
  bool paired = false;
  bool counted = false;  ///< false for structures without counters (Embree)
  double steps_per_ray = 0, leaves_per_ray = 0, tests_per_ray = 0;
  double lookups_per_ray = 0, mailbox_skips_per_ray = 0;
  /// Fraction of rays whose answer matches the reference: same triangle, both miss, or a tie
  /// (this structure's triangle, intersected on its own, has the reference's t within
  /// tie_tolerance relative). Shadow rays: same occluded answer. -1 when not compared.
  double agreement = -1;
  uint64_t disagreements = 0;
  /// Of the disagreements, rays that start on a triangle one of the answers hit: rounding
  /// decides those (docs/RAYSETS.md, "Rays that start on a surface"), the rest are errors.
  uint64_t disagreements_on_surface = 0;
  /// The packet column (BenchOptions::packet_tile), for primary and shadow sets; packet_rays 0
  /// where it was not run. Rays are traced in tile order, each side through its own packet query.
  int packet_rays = 0;   ///< rays per packet (the last packet of a set may hold fewer)
  int packet_width = 0;  ///< Accelerator::packet_width(): 1 = the loop over single rays
  std::vector<double> packet_mrays_reps;
  double packet_mrays_median = 0;
  /// To the reference's packet query on the same packets, paired per repetition as
  /// ratio_to_reference is.
  double packet_ratio_to_reference = 0;
  double packet_reference_mrays = 0;
  /// Rays whose packet answer is not bitwise this structure's single-ray answer: 0 but for
  /// Embree, whose packet kernels may take the other triangle of an exact tie and, with its
  /// default (not robust) flags, round its edge tests differently from its single-ray kernels.
  uint64_t packet_mismatches = 0;
  /// Of those, the ties: the same t bitwise, another triangle.
  uint64_t packet_ties = 0;
  /// The packet query over the structure's own single-ray loop on the same packets
  /// (Accelerator's default intersect_packet), timed right after it in each repetition: the
  /// median of the per-repetition ratios (1 within the noise without a packet walk).
  double packet_speedup = 0;
  double packet_single_mrays = 0;  ///< the single-ray loop's median Mrays/s behind it
};

/// The render column (BenchOptions::render) of one structure on one scene.
struct RenderFigures {
  bool measured = false;
  /// Rays of one pass by kind (the same for every structure but where answers differ).
  uint64_t primary = 0, shadow = 0, reflection = 0, refraction = 0;
  std::vector<double> seconds_reps;  ///< wall time of each timed pass
  double seconds_median = 0;
  double mrays_median = 0;  ///< every ray of a pass over the median pass time
  /// The median of the per-pass ratios of the reference's pass time to this one's (> 1:
  /// faster than the reference), each reference pass timed just before; 1 for the reference.
  double ratio_to_reference = 0;
  double reference_seconds = 0;  ///< the reference's median pass time behind the ratio
  /// Pixels whose 8-bit sRGB colour (as written to PNG) differs in any channel from the
  /// reference render's (srgb8_difference, as `kdgrid sweep scale` compares): another triangle
  /// of a tie or an edge, not the last bits of a barycentric; -1 when not compared.
  int64_t pixels_differ = -1;
  uint64_t rays() const { return primary + shadow + reflection + refraction; }
};

/// Figures of one structure on one scene.
struct StructureFigures {
  std::string accel;
  std::string error;         ///< non-empty if the build or a trace threw
  double build_seconds = 0;  ///< wall time of build(), as measured here
  double build_mtris_per_s = 0;
  uint64_t bytes = 0;  ///< BuildStats::bytes: the structure, excluding the Mesh
  double bytes_per_triangle = 0;
  BuildStats stats;  ///< everything build() reported (bytes_by_part, extra, ...)
  /// Peak resident memory while this structure was built and traced (VmHWM reset before the
  /// build; includes the mesh, the ray sets and the reference), and the process's lifetime
  /// peak (getrusage ru_maxrss), both in bytes.
  uint64_t peak_rss_bytes = 0;
  uint64_t process_peak_rss_bytes = 0;
  /// Resident memory just before the build (after the reset): the mesh, the ray sets and
  /// the reference's hits. peak_rss_bytes - rss_before_bytes is this structure's growth.
  uint64_t rss_before_bytes = 0;
  std::vector<SetFigures> sets;
  RenderFigures render;
};

struct SceneFigures {
  std::string name, file;
  std::string error;  ///< non-empty if the scene could not be loaded/run
  uint64_t triangles = 0;
  double load_seconds = 0;
  std::string camera;     ///< "canonical" or "eye ... target ... fov ..."
  std::string reference;  ///< structure the ratios and agreement refer to
  std::vector<std::pair<std::string, uint64_t>> set_sizes;
  std::vector<std::pair<std::string, std::string>> set_sources;  ///< "generated" or a .rays file
  std::vector<StructureFigures> structures;
};

struct BenchReport {
  std::string suite;    ///< suite file
  std::string date;     ///< ISO 8601 local time of the start
  std::string machine;  ///< CPU model name (lscpu / /proc/cpuinfo)
  /// SIMD of each side: kdgrid's from the build (math/simd.h: the ISA it targets, the lanes
  /// of its traversal vectors; accel/triangle_wide.h: the triangles a hybrid leaf tests at
  /// once), Embree's as its library chose it on this CPU or as BenchOptions::params restricts it
  /// (embree_isa()).
  std::string kdgrid_isa;
  int kdgrid_lanes = 0;
  int kdgrid_leaf_lanes = 0;
  EmbreeIsa embree;
  int hardware_threads = 0;
  int threads = 0, reps = 0, width = 0, height = 0;
  int packet_tile = 0;         ///< BenchOptions::packet_tile
  std::string clock = "wall";  ///< "wall" or "cpu" (BenchOptions::cpu_clock)
  std::vector<std::string> sets;
  double seconds = 0;  ///< wall time of the whole run
  std::vector<SceneFigures> scenes;

  /// True if any scene or structure failed (the CLI then exits non-zero).
  bool any_failed() const;
};

/// Runs the whole suite. Scene and structure failures are recorded, never thrown, so one bad
/// scene does not stop the others. Throws ParamError for bad options (unknown set, reps < 1).
BenchReport run_bench(const Suite& suite, const BenchOptions& options);

/// The report as JSON: {"meta": {...}, "scenes": [...], "builds": [one per scene x
/// structure], "results": [one per scene x structure x set], "errors": [...]}.
std::string bench_to_json(const BenchReport& report);
/// The report as Markdown tables (throughput and ratios, per-ray counts, build and memory).
std::string bench_to_markdown(const BenchReport& report);

/// Default structure list: accelerator_names() without brute.
std::vector<std::string> default_bench_accels();

}  // namespace kdgrid
