// Speed-vs-accuracy sweeps behind `kdgrid sweep KIND SCENE`: one knob varied over a range,
// everything else fixed, each row measured on the same primary rays. Results are a table
// (columns + rows) written as CSV and JSON for scripts/plot.
//
//   cellsize  hybrid basic cell size as multiples of the auto size (plus the auto row); each
//             row also judged by kdgrid check's reference on its ray families over the scene
//             (check_agree / check_ambiguous / check_disagree / check_leaks), and for acne:
//             rays leaving random surface points that re-hit their own triangle
//             (acne_rays / acne_self_hits)
//   lambda    uniform grid density, cells per triangle
//   kdcost    kd-tree SAH cost ratio, triangle test / traversal step
//   triangle  watertight vs Möller-Trumbore: Mrays/s on primary rays per structure, and the
//             leak rate of rays aimed exactly at shared edges and vertices of closed meshes
//             (procedural sphere and torus at scales 1e-3, 1, 1e3 and translated by 1e4)
//   scale     the scene scaled by each value (default 10^-20 .. 10^16): per structure
//             (default bvh and hybrid), its render's difference from the scale-1 render, the
//             primary rays' speed and hit fraction; scales outside docs/LIMITS.md's range are
//             rows marked refused
//   spp       progressive render: samples per pixel vs RMSE against a high-spp reference vs
//             time (default scene assets/cornell.gltf)
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "accel/params.h"
#include "math/ray.h"
#include "scene/mesh.h"
#include "scene/scene.h"

namespace kdgrid {

struct SweepOptions {
  std::string kind;
  /// Scene file. Empty for spp means assets/cornell.gltf (else the procedural cornell box);
  /// the other kinds need one.
  std::string scene;
  /// Camera of the primary rays; empty = the canonical camera of docs/RAYSETS.md.
  std::optional<Camera> camera;
  /// Values of the swept knob; empty = the kind's defaults (see sweep_default_values()).
  std::vector<double> values;
  /// triangle: structures timed and leak-tested (default: every registered one except brute
  /// and embree, whose triangle test is its own). spp: the first is the renderer's structure.
  std::vector<std::string> accels;
  /// Tracing threads; 0 = all hardware threads.
  int threads = 0;
  /// Timed repetitions of the primary set per row (median reported).
  int reps = 3;
  /// Primary rays (canonical camera), and the image size of the spp sweep; 0 x 0 = the
  /// kind's default: 512 x 512 rays, 200 x 200 pixels for spp (its 256-spp reference is the
  /// costly part).
  int width = 0, height = 0;
  BuildParams params;
  /// spp: largest sample count measured (powers of two from 1), and the reference's count.
  int spp_max = 64;
  int spp_reference = 256;
  /// triangle: rays per edge point / vertex of the leak meshes (directions differ).
  int leak_rays_per_target = 4;
  std::function<void(const std::string&)> progress;
};

/// One table cell: empty, a number or text.
using SweepValue = std::variant<std::monostate, double, std::string>;

struct SweepTable {
  std::string kind, scene, date, machine;
  int threads = 0, reps = 0, width = 0, height = 0;
  std::vector<std::pair<std::string, std::string>> notes;  ///< what the columns mean, baselines
  std::vector<std::string> columns;
  std::vector<std::vector<SweepValue>> rows;

  /// Appends a row given as (column, value) pairs; unknown columns are added at the end.
  void add_row(const std::vector<std::pair<std::string, SweepValue>>& cells);
};

/// "cellsize", "lambda", "kdcost", "triangle", "spp".
std::vector<std::string> sweep_kinds();
/// The default values of a kind (multipliers for cellsize, lambdas, cost ratios, spp counts).
std::vector<double> sweep_default_values(const std::string& kind);

/// Runs a sweep. Throws ParamError for an unknown kind or bad options and LoadError for a
/// scene that cannot be read; a row whose build fails (e.g. over the memory budget) gets its
/// message in the "error" column and the sweep goes on.
SweepTable run_sweep(const SweepOptions& options);

std::string sweep_to_csv(const SweepTable& t);
std::string sweep_to_json(const SweepTable& t);

// ---- building blocks, public for the tests ----------------------------------------------

/// A scene loaded at a scale (load_scene's `scale`) and rendered with one structure.
struct ScaledRender {
  std::vector<uint8_t> srgb8;  ///< the PNG's pixels: tone-mapped 8-bit sRGB, 3 bytes each
  double seconds = 0;          ///< rendering time, build excluded
  uint64_t rays = 0;           ///< rays traced, all kinds
};
/// Renders `spp` passes of width x height of a loaded scene (load_scene(path, scale)) with
/// `accel` from the scene's camera, seed 1.
ScaledRender render_scaled(const Scene& scene, const std::string& accel, int width, int height,
                           int spp, const BuildParams& params);

/// Rays aimed exactly at the shared edges (at 1/4, 1/2, 3/4 of each edge used by two
/// triangles) and vertices of a closed mesh, `per_target` rays per point, each from a point
/// outside (two scene diagonals away), on the side all adjacent faces face: t = 1 at the
/// target and tmax = 1.001, so the segment ends just inside the mesh. A watertight test must
/// hit every one of them; a ray that hits nothing has leaked through the edge or vertex.
std::vector<Ray> edge_vertex_rays(const Mesh& mesh, int per_target, uint64_t seed);

}  // namespace kdgrid
