#include "cli/common.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <sstream>

#include "accel/accelerator.h"
#include "accel/embree.h"
#include "render/camera.h"
#include "util/cancel.h"
#include "util/error.h"
#include "util/format.h"

namespace kdgrid::cli {

namespace {

/// A switch `names` that turns `knob` off. It sets the knob to false through a callback, so
/// --help lists its names without CLI11's "{false}" default-value syntax.
CLI::Option* add_off_switch(CLI::App* cmd, const std::string& names, bool& knob,
                            const std::string& help) {
  return cmd->add_flag_callback(
      names, [&knob] { knob = false; }, help);
}

}  // namespace

void AccelOptions::add_to(CLI::App* cmd, const std::string& default_accel) {
  accel = default_accel;
  const std::string g = "Acceleration structure";
  // Each flag is named after the BuildParams field it sets (accel/params.h documents them);
  // the second name of a renamed flag is its earlier name, still accepted.
  cmd->add_option("--accel", accel,
                  "Structure: brute, bvh, grid, kdtree, hybrid, irregular, embree (Embree's "
                  "default flags), embree-robust, embree-high")
      ->group(g)
      ->capture_default_str();
  cmd->add_option("--cell-size", cell_size,
                  "Hybrid basic cell size in scene units, or 'auto' (percentile rule)")
      ->group(g)
      ->capture_default_str();
  cmd->add_option("--cell-percentile", params.cell_percentile,
                  "Auto cell size: percentile of triangle extents that fit one cell (0-100]")
      ->group(g)
      ->capture_default_str();
  cmd->add_flag("--hybrid-dense-matrix,--dense-matrix", params.hybrid_dense_matrix,
                "Hybrid: dense cell matrix of the paper instead of bricked storage")
      ->group(g);
  cmd->add_option("--triangle-test", triangle_test, "watertight (default) or moller")
      ->group(g)
      ->capture_default_str();
  cmd->add_option("--grid-lambda", params.grid_lambda, "Uniform grid: cells per triangle")
      ->group(g)
      ->capture_default_str();
  cmd->add_option("--kd-intersection-cost,--kd-cost-ratio", params.kd_intersection_cost,
                  "kd-tree SAH: cost of a triangle test, in traversal steps")
      ->group(g)
      ->capture_default_str();
  cmd->add_option("--hybrid-intersection-cost,--hybrid-cost-ratio", params.hybrid_intersection_cost,
                  "Hybrid SAH (leaf termination): cost of a triangle test, in leaf steps")
      ->group(g)
      ->capture_default_str();
  cmd->add_option(
         "--hybrid-subtree-min,--hybrid-subtree", params.hybrid_subtree_min,
         "Hybrid: leaves with more triangles than this get a kd subtree built and walked as "
         "the kd-tree is (default 4); 0 = the paper's plain leaves")
      ->group(g)
      ->capture_default_str();
  cmd->add_option("--hybrid-max-build-seconds", params.hybrid_max_build_seconds,
                  "Hybrid: refuse an explicit --cell-size whose estimated extra build time exceeds "
                  "this (seconds), naming a size that fits; 0 = no limit")
      ->group(g)
      ->capture_default_str();
  add_off_switch(cmd, "--hybrid-no-expand-empty,--hybrid-no-expand", params.hybrid_expand_empty,
                 "Hybrid: step over the kd leaf boxes of the paper, without widening empty leaves "
                 "over the empty cells around them")
      ->group(g);
  add_off_switch(cmd, "--hybrid-no-flat-subtrees", params.hybrid_flat_subtrees,
                 "Hybrid: walk every leaf subtree by its kd nodes, instead of testing the leaves "
                 "of a subtree of 5 to 16 leaves against the ray all at once (AVX2 and AVX-512 "
                 "builds)")
      ->group(g);
  add_off_switch(cmd, "--hybrid-no-next-leaf-cache,--hybrid-no-guess",
                 params.hybrid_next_leaf_cache,
                 "Hybrid: look every next leaf up in the matrix, as the paper does, instead of "
                 "first checking the leaf this thread last reached across the same face")
      ->group(g);
  cmd->add_option("--bvh-max-leaf,--bvh-leaf", params.bvh_max_leaf, "BVH: max triangles per leaf")
      ->group(g)
      ->capture_default_str();
  cmd->add_option("--irregular-top-density,--irr-top-density", params.irregular_top_density,
                  "Irregular grid: top-level cells per triangle")
      ->group(g)
      ->capture_default_str();
  cmd->add_option("--irregular-sub-density,--irr-sub-density", params.irregular_sub_density,
                  "Irregular grid: second-level cells per reference")
      ->group(g)
      ->capture_default_str();
  cmd->add_option("--embree-quality", params.embree_quality,
                  "Embree build quality of embree and embree-robust: low, medium, high")
      ->group(g)
      ->capture_default_str();
  cmd->add_option("--embree-isa", embree_isa_,
                  "Restrict Embree's kernels to one ISA (rtcNewDevice \"isa=\"): sse4.2, avx, "
                  "avx2, avx512, or native (the widest Embree and the CPU support)")
      ->group(g)
      ->capture_default_str();
  cmd->add_option("--memory-budget-mb", budget_mb_,
                  "Refuse builds whose estimated peak exceeds this (MiB); 0 = half of the memory "
                  "available (the smallest of physical memory, the cgroup limit, ulimit -v)")
      ->group(g);
  cmd->add_option("--brute-work-limit", params.brute_work_limit,
                  "Brute force: refuse above this many primary-ray x triangle tests (0 = no "
                  "limit)")
      ->group(g)
      ->capture_default_str();
}

BuildParams AccelOptions::resolve() const {
  BuildParams p = params;
  p.cell_size = parse_cell_size(cell_size);
  p.triangle_test = parse_triangle_test(triangle_test);
  if (!(p.cell_percentile > 0.0f && p.cell_percentile <= 100.0f))
    throw ParamError("--cell-percentile " + std::to_string(p.cell_percentile) +
                     " is out of range: give a value in (0, 100]");
  if (!(p.grid_lambda > 0.0f) || !std::isfinite(p.grid_lambda))
    throw ParamError("--grid-lambda must be a positive number (cells per triangle), e.g. 4");
  if (!(p.kd_intersection_cost > 0.0f) || !std::isfinite(p.kd_intersection_cost))
    throw ParamError("--kd-intersection-cost must be a positive number, e.g. 1.5");
  if (p.bvh_max_leaf < 1 || p.bvh_max_leaf > 255)
    throw ParamError("--bvh-max-leaf must be between 1 and 255");
  if (!(p.irregular_top_density > 0.0f) || !(p.irregular_sub_density > 0.0f))
    throw ParamError("--irregular-top-density and --irregular-sub-density must be positive");
  if (budget_mb_ < 0) throw ParamError("--memory-budget-mb must be >= 0");
  p.embree_isa = embree_isa_ == "native" ? std::string() : embree_isa_;
  check_embree_isa(p.embree_isa);
  if (!(p.hybrid_max_build_seconds >= 0.0))
    throw ParamError("--hybrid-max-build-seconds must be >= 0 (0 = no limit), e.g. 10");
  if (!(p.brute_work_limit >= 0.0))
    throw ParamError("--brute-work-limit must be >= 0 (0 = no limit), e.g. 5e9");
  // MiB to bytes must not wrap: 2^44 MiB is 2^64 bytes.
  constexpr long kMaxBudgetMb = (long(1) << 44) - 1;
  if (budget_mb_ > kMaxBudgetMb)
    throw ParamError("--memory-budget-mb " + std::to_string(budget_mb_) +
                     " is too large: at most " + std::to_string(kMaxBudgetMb) +
                     " MiB (0 = half of the memory available)");
  if (budget_mb_ > 0) p.memory_budget = uint64_t(budget_mb_) << 20;
  return p;
}

std::string accel_flags(const std::string& accel, const BuildParams& p) {
  const BuildParams d;
  const auto num = [](double v) { return format_double("%.9g", v); };
  std::string s = " --accel " + accel;
  if (p.cell_size > 0) s += " --cell-size " + num(p.cell_size);
  if (p.cell_percentile != d.cell_percentile) s += " --cell-percentile " + num(p.cell_percentile);
  if (p.hybrid_dense_matrix) s += " --hybrid-dense-matrix";
  if (p.hybrid_subtree_min != d.hybrid_subtree_min)
    s += " --hybrid-subtree-min " + std::to_string(p.hybrid_subtree_min);
  if (!p.hybrid_expand_empty) s += " --hybrid-no-expand-empty";
  if (!p.hybrid_flat_subtrees) s += " --hybrid-no-flat-subtrees";
  if (!p.hybrid_next_leaf_cache) s += " --hybrid-no-next-leaf-cache";
  if (p.hybrid_intersection_cost != d.hybrid_intersection_cost)
    s += " --hybrid-intersection-cost " + num(p.hybrid_intersection_cost);
  if (p.hybrid_max_build_seconds != d.hybrid_max_build_seconds)
    s += " --hybrid-max-build-seconds " + num(p.hybrid_max_build_seconds);
  if (p.grid_lambda != d.grid_lambda) s += " --grid-lambda " + num(p.grid_lambda);
  if (p.kd_intersection_cost != d.kd_intersection_cost)
    s += " --kd-intersection-cost " + num(p.kd_intersection_cost);
  if (p.bvh_max_leaf != d.bvh_max_leaf) s += " --bvh-max-leaf " + std::to_string(p.bvh_max_leaf);
  if (p.irregular_top_density != d.irregular_top_density)
    s += " --irregular-top-density " + num(p.irregular_top_density);
  if (p.irregular_sub_density != d.irregular_sub_density)
    s += " --irregular-sub-density " + num(p.irregular_sub_density);
  if (p.embree_quality != d.embree_quality) s += " --embree-quality " + p.embree_quality;
  if (!p.embree_isa.empty()) s += " --embree-isa " + p.embree_isa;
  // The flag is in MiB; a budget set through it is a whole number of them.
  if (p.memory_budget != d.memory_budget)
    s += " --memory-budget-mb " + std::to_string((p.memory_budget + (1u << 20) - 1) >> 20);
  if (p.brute_work_limit != d.brute_work_limit)
    s += " --brute-work-limit " + num(p.brute_work_limit);
  if (p.triangle_test != d.triangle_test)
    s += std::string(" --triangle-test ") + to_string(p.triangle_test);
  return s;
}

void add_scene_argument(CLI::App* cmd, std::string& scene) {
  cmd->add_option("scene", scene, "Scene file (.gltf .glb .ply .obj)")->required();
}

void add_threads_option(CLI::App* cmd, int& threads) {
  cmd->add_option("--threads", threads,
                  "Threads for tracing and building; 0 = all hardware threads")
      ->capture_default_str();
}

void add_scale_option(CLI::App* cmd, double& scale) {
  cmd->add_option("--scale", scale,
                  "Multiply the scene's coordinates (its vertices, camera and light positions; "
                  "point and spot light intensities by S squared, so the picture stays the same) "
                  "by S when it loads, e.g. 1e-6. --eye and --target are in the scaled "
                  "coordinates. docs/LIMITS.md gives the scene sizes accepted")
      ->capture_default_str();
}

void CameraOptions::add_to(CLI::App* cmd) {
  const std::string g = "Camera (default: the scene's, else the canonical camera)";
  cmd->add_option("--eye", eye, "Camera position x,y,z")->group(g);
  cmd->add_option("--target", target, "Point looked at x,y,z")->group(g);
  fov_option_ =
      cmd->add_option("--fov", fov, "Vertical field of view in degrees, in (0, 180)")->group(g);
}

Camera CameraOptions::apply(const Camera& base) const {
  Camera c = base;
  if (!eye.empty()) c.eye = parse_vec3(eye, "--eye");
  if (!target.empty()) c.target = parse_vec3(target, "--target");
  if (fov_given()) {
    if (!(fov > 0.0f && fov < 180.0f))
      throw ParamError("--fov " + std::to_string(fov) +
                       " must be between 0 and 180 degrees (exclusive), e.g. --fov 45");
    c.fov_deg = fov;
  }
  if (!eye.empty() || !target.empty()) c.name = "command line";
  if (length(c.target - c.eye) == 0.0f) {
    if (!eye.empty() && !target.empty())
      throw ParamError("--eye and --target are the same point: the camera has no view direction");
    // Neither flag (or only one) made them equal: the scene's camera, or the canonical camera
    // of a scene without extent.
    throw ParamError(std::string("the camera's eye and target are the same point (") +
                     (eye.empty() && target.empty() ? "" : "with --eye or --target given, ") +
                     "from the scene's camera, or the scene has zero size: all its vertices at "
                     "one point); give both --eye X,Y,Z and --target X,Y,Z");
  }
  check_camera(c, any() ? "--eye/--target/--fov" : "the scene's camera");
  return c;
}

Vec3 parse_vec3(const std::string& s, const std::string& what) {
  Vec3 v;
  std::stringstream ss(s);
  std::string item;
  int i = 0;
  while (std::getline(ss, item, ',')) {
    char* end = nullptr;
    const float f = std::strtof(item.c_str(), &end);
    if (i >= 3 || end == item.c_str() || *end != '\0' || !std::isfinite(f))
      throw ParamError(what + " '" + s + "' is not three finite numbers x,y,z");
    v[i++] = f;
  }
  if (i != 3) throw ParamError(what + " '" + s + "' is not three finite numbers x,y,z");
  return v;
}

void parse_resolution(const std::string& s, int& width, int& height) {
  const auto x = s.find('x');
  char* end = nullptr;
  const long w = std::strtol(s.c_str(), &end, 10);
  long h = w;
  bool ok = end != s.c_str();
  if (ok && x != std::string::npos) {
    ok = end == s.c_str() + x;
    const char* hs = s.c_str() + x + 1;
    h = std::strtol(hs, &end, 10);
    ok = ok && end != hs && *end == '\0';
  } else {
    ok = ok && *end == '\0';
  }
  if (!ok || w < 1 || h < 1 || w > 16384 || h > 16384)
    throw ParamError("resolution '" + s +
                     "' must be W or WxH with 1 <= W, H <= 16384, e.g. 800x600");
  width = int(w);
  height = int(h);
}

Ray pixel_ray(const Camera& cam, const std::string& res, const std::string& pixel) {
  int w = 0, h = 0;
  parse_resolution(res, w, h);
  float px = 0, py = 0;
  if (std::sscanf(pixel.c_str(), "%f,%f", &px, &py) != 2 || !(px >= 0 && px < w) ||
      !(py >= 0 && py < h))
    throw ParamError("--pixel '" + pixel + "' must be X,Y inside the " + std::to_string(w) + "x" +
                     std::to_string(h) + " image (set the size with --res WxH)");
  const CameraFrame f = CameraFrame::make(cam, w, h);
  const bool integral = std::floor(px) == px && std::floor(py) == py;
  return f.ray(integral ? px + 0.5f : px, integral ? py + 0.5f : py);
}

float parse_cell_size(const std::string& s) {
  if (s == "auto") return 0.0f;
  char* end = nullptr;
  const float f = std::strtof(s.c_str(), &end);
  if (end == s.c_str() || *end != '\0' || !std::isfinite(f) || f <= 0.0f)
    throw ParamError("--cell-size '" + s +
                     "' must be 'auto' or a positive finite size in scene units, e.g. 0.01");
  return f;
}

std::vector<std::string> split_list(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

void require_accelerator_names(const std::vector<std::string>& names) {
  const std::vector<std::string> known = accelerator_names();
  for (const std::string& n : names) {
    if (std::find(known.begin(), known.end(), n) != known.end()) continue;
    std::string choices;
    for (const std::string& k : known) choices += (choices.empty() ? "" : ", ") + k;
    throw ParamError("unknown accelerator '" + n + "': choose one of " + choices);
  }
}

namespace {
// Set by SIGINT while build_interruptible runs (CancelToken::cancel is a lock-free store).
CancelToken g_build_interrupt;
extern "C" void on_build_sigint(int) {
  g_build_interrupt.cancel();
}
}  // namespace

std::unique_ptr<Accelerator> build_interruptible(const std::string& name, const Mesh& mesh,
                                                 const BuildParams& params) {
  BuildParams p = params;
  p.cancel = &g_build_interrupt;
  g_build_interrupt.reset();
  const auto t0 = std::chrono::steady_clock::now();
  auto old_handler = std::signal(SIGINT, on_build_sigint);
  struct Restore {
    decltype(old_handler) h;
    ~Restore() { std::signal(SIGINT, h == SIG_ERR ? SIG_DFL : h); }
  } restore{old_handler};
  try {
    return build_accelerator(name, mesh, p);
  } catch (const BuildCancelled&) {
    char secs[32];
    std::snprintf(secs, sizeof secs, "%.1f",
                  std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    throw BuildCancelled("interrupted (Ctrl-C) while building " + name + " over " +
                         std::to_string(mesh.num_triangles()) + " triangles, " + secs +
                         " s in; the build stopped and nothing was written");
  }
}

}  // namespace kdgrid::cli
