// Options shared by several subcommands: accelerator choice and build knobs, camera flags.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "accel/accelerator.h"
#include "accel/params.h"
#include "math/ray.h"
#include "math/vec.h"
#include "scene/scene.h"

namespace kdgrid::cli {

/// --accel and every build knob, parsed into BuildParams.
struct AccelOptions {
  std::string accel = "bvh";
  std::string cell_size = "auto";
  std::string triangle_test = "watertight";
  BuildParams params;
  long budget_mb_ = 0;
  std::string embree_isa_ = "native";  ///< --embree-isa ("native": BuildParams::embree_isa "")

  /// Adds the options to `cmd` (in an "Acceleration structure" group).
  void add_to(CLI::App* cmd, const std::string& default_accel = "bvh");
  /// BuildParams with cell size / triangle test parsed and validated (ParamError on bad input).
  BuildParams resolve() const;
};

/// " --accel NAME" and the AccelOptions flags of every knob of `p` that differs from
/// BuildParams' defaults, each under its primary name, so a printed command line (the viewer's
/// pick) builds the very same structure. Floats are written so they read back unchanged.
std::string accel_flags(const std::string& accel, const BuildParams& p);

/// The required positional scene file argument of every subcommand that loads one.
void add_scene_argument(CLI::App* cmd, std::string& scene);
/// --threads N: worker threads for tracing and building (tbb::global_control); 0 = all.
void add_threads_option(CLI::App* cmd, int& threads);

/// --scale S: the scene's coordinates multiplied by S when it loads (load_scene's scale).
void add_scale_option(CLI::App* cmd, double& scale);

/// --eye x,y,z --target x,y,z --fov DEG overriding the scene's camera.
struct CameraOptions {
  std::string eye, target;
  float fov = 0.0f;  ///< degrees; used only when --fov was given (fov_given())
  void add_to(CLI::App* cmd);
  /// True if --fov was on the command line (any value, 0 included, which apply() refuses).
  bool fov_given() const { return fov_option_ && fov_option_->count() > 0; }
  /// True if any of --eye, --target, --fov was given.
  bool any() const { return !eye.empty() || !target.empty() || fov_given(); }
  /// The scene's camera with the given flags applied. Throws ParamError on malformed values
  /// and on a camera check_camera refuses (coordinates out of range, fov outside (0, 180)).
  Camera apply(const Camera& base) const;

 private:
  CLI::Option* fov_option_ = nullptr;
};

/// Splits a comma-separated list ("kdtree,hybrid"), dropping empty items.
std::vector<std::string> split_list(const std::string& s);
/// ParamError naming the unknown entry and the choices if a name in `names` is not a
/// registered structure (checked before a scene is loaded, so a typo fails at once).
void require_accelerator_names(const std::vector<std::string>& names);
/// Parses "x,y,z" (ParamError naming `what` on failure).
Vec3 parse_vec3(const std::string& s, const std::string& what);
/// Parses "W" or "WxH" (ParamError on failure or out of 1..16384).
void parse_resolution(const std::string& s, int& width, int& height);
/// The primary ray through pixel `pixel` ("X,Y") of a `res` ("W" or "WxH") image of `cam`:
/// integer coordinates mean the pixel's centre, as in the primary ray set. ParamError when
/// the pixel lies outside the image.
Ray pixel_ray(const Camera& cam, const std::string& res, const std::string& pixel);
/// Parses a cell size: "auto" -> 0, else a finite positive number.
float parse_cell_size(const std::string& s);

/// build_accelerator() that Ctrl-C (SIGINT) cancels: while it builds, SIGINT sets the build's
/// cancel token (BuildParams::cancel) instead of killing the process, and the builder stops
/// within about 100 ms with BuildCancelled, which main() reports with exit code 130. The
/// previous SIGINT handler is back in place when it returns or throws.
std::unique_ptr<Accelerator> build_interruptible(const std::string& name, const Mesh& mesh,
                                                 const BuildParams& params);

}  // namespace kdgrid::cli
