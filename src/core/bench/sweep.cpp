#include "bench/sweep.h"

#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <map>
#include <sstream>

#include <tbb/parallel_for.h>

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "bench/bench.h"
#include "bench/check.h"
#include "bench/raysets.h"
#include "image/image_io.h"
#include "math/rng.h"
#include "math/simd.h"
#include "render/renderer.h"
#include "scene/load.h"
#include "scene/procedural.h"
#include "util/error.h"
#include "util/format.h"
#include "util/paths.h"

namespace kdgrid {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

bool registered(const std::string& n) {
  const auto names = accelerator_names();
  return std::find(names.begin(), names.end(), n) != names.end();
}

/// What one build + primary-ray measurement gave.
struct Measured {
  std::string error;
  double build_seconds = 0;
  BuildStats stats;
  double mrays = 0, mrays_min = 0, mrays_max = 0;
  double steps = 0, leaves = 0, tests = 0;
  uint64_t hits = 0;
  /// Median of the per-repetition ratios to the reference timed just before each repetition
  /// (a pair sees the same machine load); < 0 without a reference.
  double ratio_to_ref = -1;
};

Measured measure_primary(const std::string& accel, const Mesh& mesh, const BuildParams& params,
                         const std::vector<Ray>& rays, int reps, const Accelerator* ref = nullptr,
                         std::unique_ptr<Accelerator>* keep = nullptr) {
  Measured m;
  try {
    auto a = make_accelerator(accel);
    const auto t0 = Clock::now();
    m.stats = a->build(mesh, params);
    m.build_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    const double n = double(std::max<size_t>(1, rays.size()));
    std::vector<Hit> hits;
    if (a->has_counters()) {
      const RayCounters c = count_rays(*a, rays, false);  // also warms the caches
      m.steps = double(c.steps) / n;
      m.leaves = double(c.leaves) / n;
      m.tests = double(c.tri_tests) / n;
    } else {
      trace_rays(*a, rays, false, &hits);
    }
    std::vector<double> v, ratios;
    std::vector<Hit> ref_hits;
    for (int r = 0; r < reps; ++r) {
      const double rs = ref ? trace_rays(*ref, rays, false, &ref_hits) : 0.0;
      const double s = trace_rays(*a, rays, false, &hits);
      v.push_back(s > 0 ? n * 1e-6 / s : 0.0);
      if (ref && s > 0) ratios.push_back(rs / s);
    }
    if (ref) m.ratio_to_ref = median(ratios);
    m.mrays = median(v);
    m.mrays_min = *std::min_element(v.begin(), v.end());
    m.mrays_max = *std::max_element(v.begin(), v.end());
    m.hits =
        uint64_t(std::count_if(hits.begin(), hits.end(), [](const Hit& h) { return h.valid(); }));
    if (keep) *keep = std::move(a);
  } catch (const std::exception& e) {
    m.error = e.what();
  }
  return m;
}

std::string extra_of(const BuildStats& s, const std::string& key) {
  for (const auto& [k, v] : s.extra)
    if (k == key) return v;
  return "";
}

/// Standard columns of a build + primary-ray row.
std::vector<std::pair<std::string, SweepValue>> measured_cells(const Measured& m, size_t tris) {
  if (!m.error.empty()) return {{"error", m.error}};
  std::vector<std::pair<std::string, SweepValue>> c = {
      {"build_s", m.build_seconds},
      {"bytes", double(m.stats.bytes)},
      {"bytes_per_triangle", double(m.stats.bytes) / double(std::max<size_t>(1, tris))},
      {"mrays", m.mrays},
      {"mrays_min", m.mrays_min},
      {"mrays_max", m.mrays_max},
      {"ratio_to_embree", m.ratio_to_ref >= 0 ? SweepValue(m.ratio_to_ref) : SweepValue{}},
      {"steps_per_ray", m.steps},
      {"leaves_per_ray", m.leaves},
      {"tests_per_ray", m.tests},
      {"nodes", double(m.stats.nodes)},
      {"leaves", double(m.stats.leaves)},
      {"references", double(m.stats.references)}};
  // The SAH cost of the built tree, when the structure reports one.
  std::string sah = extra_of(m.stats, "sah_cost");
  if (sah.empty()) sah = extra_of(m.stats, "SAH cost");  // the BVH's spelling
  char* end = nullptr;
  const double v = sah.empty() ? 0.0 : std::strtod(sah.c_str(), &end);
  c.emplace_back("sah_cost", !sah.empty() && end != sah.c_str() ? SweepValue(v) : SweepValue{});
  return c;
}

struct Setup {
  Scene scene;
  std::vector<Ray> rays;
  /// Embree, kept built: it is timed again before every repetition of every row.
  std::unique_ptr<Accelerator> embree;
};

Setup load_setup(const SweepOptions& o, SweepTable& t) {
  if (o.scene.empty())
    throw ParamError("sweep " + o.kind + " needs a scene file: kdgrid sweep " + o.kind +
                     " SCENE (e.g. $KDGRID_SCENES/bunny/bun_zipper.ply)");
  Setup s;
  s.scene = load_scene(o.scene);
  const Mesh& mesh = s.scene.mesh;
  const Camera cam = o.camera ? *o.camera : canonical_camera(mesh.bounds());
  s.rays = primary_rays(cam, o.width, o.height);
  t.notes.emplace_back("triangles", std::to_string(mesh.num_triangles()));
  t.notes.emplace_back("rays", std::to_string(s.rays.size()) + " primary rays (" +
                                   (o.camera ? "given camera" : "canonical camera") + ")");
  if (registered("embree")) {
    BuildParams p = o.params;
    const Measured e = measure_primary("embree", mesh, p, s.rays, o.reps, nullptr, &s.embree);
    if (e.error.empty()) {
      t.notes.emplace_back("embree_mrays", format_double("%.4g", e.mrays));
      if (o.progress)
        o.progress("  embree baseline: " + format_double("%.3g", e.mrays) + " Mrays/s");
    }
  }
  return s;
}

void say_row(const SweepOptions& o, const std::string& label, const Measured& m) {
  if (!o.progress) return;
  if (!m.error.empty()) {
    o.progress("  " + label + ": " + m.error);
    return;
  }
  o.progress("  " + label + ": build " + format_double("%.3f", m.build_seconds) + " s, " +
             format_double("%.1f", double(m.stats.bytes) / 1048576.0) + " MiB, " +
             format_double("%.3g", m.mrays) + " Mrays/s, " + format_double("%.1f", m.steps) +
             " steps, " + format_double("%.1f", m.tests) + " tests per ray");
}

/// Rays per ray family of kdgrid check judged per row of the cell-size sweep (each is tested
/// against every triangle in double precision).
constexpr int kSweepCheckRaysPerFamily = 8;
/// Rays leaving the scene's surfaces per row of the cell-size sweep, for its acne column.
constexpr int kSweepAcneRays = 2000;

/// judge_accelerator's counts, plus the closest-hit answers that AccuracyReference calls
/// leaks (slipped through a closed edge or vertex), on the case's own rays.
struct CheckAccuracy {
  uint64_t rays = 0, agree = 0, ambiguous = 0, disagree = 0, any_disagree = 0, leaks = 0;
};

CheckAccuracy judge_accuracy(const Accelerator& accel, const CheckCase& c) {
  const CheckResult r = judge_accelerator(accel, c);
  CheckAccuracy a{r.rays, r.agree, r.ambiguous, r.disagree, r.any_disagree, 0};
  const AccuracyReference ref(c.mesh);
  std::vector<uint8_t> leak(c.rays.size());
  tbb::parallel_for(size_t(0), c.rays.size(), [&](size_t i) {
    Hit h;
    const bool hit = accel.intersect(c.rays[i], h);
    leak[i] = ref.judge_closest(c.rays[i], hit, h) == AccuracyVerdict::Leak;
  });
  a.leaks = uint64_t(std::count(leak.begin(), leak.end(), uint8_t(1)));
  return a;
}

// ---- cellsize, lambda, kdcost --------------------------------------------------------------

void sweep_cellsize(const SweepOptions& o, SweepTable& t) {
  Setup s = load_setup(o, t);
  const Mesh& mesh = s.scene.mesh;
  BuildParams p = o.params;
  p.cell_size = 0.0f;
  std::unique_ptr<Accelerator> auto_accel;
  const Measured autom =
      measure_primary("hybrid", mesh, p, s.rays, o.reps, s.embree.get(), &auto_accel);
  if (!autom.error.empty()) throw Error("hybrid with the auto cell size: " + autom.error);
  const std::string auto_str = extra_of(autom.stats, "cell_size");
  const double auto_cell = std::strtod(auto_str.c_str(), nullptr);
  if (!(auto_cell > 0))
    throw Error("hybrid did not report its auto cell size in BuildStats::extra[\"cell_size\"]");
  t.notes.emplace_back("auto_cell_size", auto_str);
  t.notes.emplace_back("auto_rule", extra_of(autom.stats, "auto rule"));
  // Accuracy beside speed: each cell size's hybrid judged by check's double-precision
  // reference on the suite's ray families over this scene.
  const CheckCase check = make_check_case("sweep", mesh, kSweepCheckRaysPerFamily, 1);
  t.notes.emplace_back("check_rays", std::to_string(kSweepCheckRaysPerFamily) +
                                         " rays per family of kdgrid check's ray families");
  auto add = [&](const std::string& label, double mult, const Measured& m,
                 const Accelerator* accel) {
    auto cells =
        std::vector<std::pair<std::string, SweepValue>>{{"label", label},
                                                        {"multiplier", mult},
                                                        {"cell_size", mult * auto_cell},
                                                        {"grid", extra_of(m.stats, "grid")}};
    for (auto& c : measured_cells(m, mesh.num_triangles())) cells.push_back(c);
    if (accel) {
      const CheckAccuracy a = judge_accuracy(*accel, check);
      cells.insert(cells.end(),
                   {{"check_rays", double(a.rays)},
                    {"check_agree", double(a.agree)},
                    {"check_ambiguous", double(a.ambiguous)},
                    {"check_disagree", double(a.disagree)},
                    {"check_any_disagree", double(a.any_disagree)},
                    {"check_leaks", double(a.leaks)},
                    {"acne_rays", double(kSweepAcneRays)},
                    {"acne_self_hits", double(count_self_hits(*accel, mesh, kSweepAcneRays, 1))}});
    }
    t.add_row(cells);
    say_row(o, label, m);
  };
  add("auto", 1.0, autom, auto_accel.get());
  for (double mult : o.values) {
    BuildParams q = o.params;
    q.cell_size = float(mult * auto_cell);
    std::unique_ptr<Accelerator> accel;
    const Measured m = measure_primary("hybrid", mesh, q, s.rays, o.reps, s.embree.get(), &accel);
    add(format_double("%gx", mult), mult, m, accel.get());
  }
}

void sweep_param(const SweepOptions& o, SweepTable& t, const std::string& accel,
                 const std::string& column, const std::function<void(BuildParams&, double)>& set) {
  Setup s = load_setup(o, t);
  const Mesh& mesh = s.scene.mesh;
  for (double v : o.values) {
    BuildParams q = o.params;
    set(q, v);
    const Measured m = measure_primary(accel, mesh, q, s.rays, o.reps, s.embree.get());
    auto cells = std::vector<std::pair<std::string, SweepValue>>{{"label", format_double("%g", v)},
                                                                 {column, v}};
    for (auto& c : measured_cells(m, mesh.num_triangles())) cells.push_back(c);
    for (const auto& [k, x] : m.stats.extra)
      if (k == "resolution" || k == "grid") cells.emplace_back(k, x);
    t.add_row(cells);
    say_row(o, column + " " + format_double("%g", v), m);
  }
}

// ---- triangle ----------------------------------------------------------------------------------

/// End of a leak ray's segment, in units of (target - origin): far enough past the target
/// (1e-3 of the 2x-scene-diagonal approach) to absorb rounding of the hit's t, far short of
/// any other surface of the test meshes.
constexpr float kLeakRayTmax = 1.001f;

Mesh transformed(const Mesh& m, float scale, const Vec3& offset) {
  Mesh out = m;
  for (auto& p : out.positions) p = p * scale + offset;
  return out;
}

void sweep_triangle(const SweepOptions& o, SweepTable& t) {
  std::vector<std::string> accels = o.accels;
  if (accels.empty())
    for (const auto& n : default_bench_accels())
      if (!is_embree(n)) accels.push_back(n);
  t.notes.emplace_back("leak",
                       "a leak is a ray aimed from outside at a point on a shared edge "
                       "or vertex of a closed mesh that hits nothing");

  // Part 1: throughput on the scene's primary rays, per structure and test.
  if (!o.scene.empty()) {
    Setup s = load_setup(o, t);
    for (const auto& a : accels) {
      double wt = 0;
      for (TriangleTestKind k : {TriangleTestKind::Watertight, TriangleTestKind::Moller}) {
        BuildParams q = o.params;
        q.triangle_test = k;
        const Measured m = measure_primary(a, s.scene.mesh, q, s.rays, o.reps, s.embree.get());
        if (k == TriangleTestKind::Watertight) wt = m.mrays;
        auto cells = std::vector<std::pair<std::string, SweepValue>>{
            {"part", "throughput"},
            {"mesh", fs::path(o.scene).stem().string()},
            {"accel", a},
            {"test", to_string(k)},
            {"rays", double(s.rays.size())}};
        if (!m.error.empty()) {
          cells.emplace_back("error", m.error);
        } else {
          cells.emplace_back("mrays", m.mrays);
          cells.emplace_back("mrays_min", m.mrays_min);
          cells.emplace_back("mrays_max", m.mrays_max);
          cells.emplace_back("tests_per_ray", m.tests);
          cells.emplace_back("speedup_vs_watertight",
                             wt > 0 ? SweepValue(m.mrays / wt) : SweepValue{});
          cells.emplace_back("ratio_to_embree",
                             m.ratio_to_ref >= 0 ? SweepValue(m.ratio_to_ref) : SweepValue{});
        }
        t.add_row(cells);
        say_row(o, a + " " + to_string(k), m);
      }
    }
  }

  // Part 2: leaks on closed procedural meshes at several scales and far from the origin.
  struct Config {
    std::string name;
    float scale;
    Vec3 offset;
  };
  const std::vector<Config> configs = {{"1e-3", 1e-3f, Vec3(0.0f)},
                                       {"1", 1.0f, Vec3(0.0f)},
                                       {"1e3", 1e3f, Vec3(0.0f)},
                                       {"1 translated 1e4", 1.0f, Vec3(1e4f, 1e4f, 1e4f)}};
  const std::vector<std::pair<std::string, Mesh>> meshes = {{"sphere", make_icosphere(3)},
                                                            {"torus", make_torus(48, 24)}};
  std::vector<std::string> leak_accels = {"brute"};
  for (const auto& a : accels)
    if (a != "brute") leak_accels.push_back(a);
  for (const auto& [mname, base] : meshes) {
    for (const auto& c : configs) {
      const Mesh mesh = transformed(base, c.scale, c.offset);
      const std::vector<Ray> rays = edge_vertex_rays(mesh, std::max(1, o.leak_rays_per_target), 7);
      for (const auto& a : leak_accels) {
        for (TriangleTestKind k : {TriangleTestKind::Watertight, TriangleTestKind::Moller}) {
          auto cells = std::vector<std::pair<std::string, SweepValue>>{
              {"part", "leak"}, {"mesh", mname},        {"scale", c.name},
              {"accel", a},     {"test", to_string(k)}, {"rays", double(rays.size())}};
          try {
            BuildParams q = o.params;
            q.triangle_test = k;
            auto acc = make_accelerator(a);
            acc->build(mesh, q);
            std::vector<Hit> hits;
            trace_rays(*acc, rays, false, &hits);
            const auto leaks =
                std::count_if(hits.begin(), hits.end(), [](const Hit& h) { return !h.valid(); });
            cells.emplace_back("leaks", double(leaks));
            cells.emplace_back("leak_rate",
                               double(leaks) / double(std::max<size_t>(1, rays.size())));
            if (o.progress)
              o.progress("  leak " + mname + " scale " + c.name + " " + a + " " + to_string(k) +
                         ": " + std::to_string(leaks) + " of " + std::to_string(rays.size()));
          } catch (const std::exception& e) {
            cells.emplace_back("error", e.what());
          }
          t.add_row(cells);
        }
      }
    }
  }
}

// ---- scale -------------------------------------------------------------------------------------

void sweep_scale(const SweepOptions& o, SweepTable& t) {
  if (o.scene.empty())
    throw ParamError(
        "sweep scale needs a scene file: kdgrid sweep scale SCENE (e.g. "
        "$KDGRID_SCENES/bunny/bun_zipper.ply)");
  const std::vector<std::string> accels =
      o.accels.empty() ? std::vector<std::string>{"bvh", "hybrid"} : o.accels;
  const int spp = 1;
  t.notes.emplace_back("render", std::to_string(o.width) + "x" + std::to_string(o.height) + ", " +
                                     std::to_string(spp) +
                                     " spp, seed 1, the scene's camera and lights, scaled");
  t.notes.emplace_back("pixels_differing",
                       "fraction of pixels whose 8-bit sRGB value differs in any channel from "
                       "the same structure's render at scale 1");
  t.notes.emplace_back("mad_levels",
                       "mean absolute difference from that render over all channels, in 8-bit "
                       "levels (1 level = 1/255)");
  t.notes.emplace_back("mrays", "primary rays (the scene's camera) per second, in millions");
  t.notes.emplace_back("refused", "the scaled scene is outside the range of docs/LIMITS.md");
  t.notes.emplace_back("simd", std::string(kBuildIsa) + " build, " +
                                   std::to_string(kTraversalLanes) + "-lane traversal vectors");
  const Scene unit = load_scene(o.scene);
  std::map<std::string, std::vector<uint8_t>> reference;
  for (const auto& a : accels)
    reference[a] = render_scaled(unit, a, o.width, o.height, spp, o.params).srgb8;
  for (const double scale : o.values) {
    Scene scene;
    std::string refused;
    try {
      scene = load_scene(o.scene, scale);
    } catch (const LoadError& e) {
      refused = e.what();
    }
    for (const auto& a : accels) {
      auto cells = std::vector<std::pair<std::string, SweepValue>>{{"scale", scale}, {"accel", a}};
      if (!refused.empty()) {
        cells.emplace_back("status", "refused");
        cells.emplace_back("error", refused);
        t.add_row(cells);
        if (o.progress) o.progress("  " + format_double("%g", scale) + " " + a + ": refused");
        continue;
      }
      try {
        const ScaledRender r = render_scaled(scene, a, o.width, o.height, spp, o.params);
        const ImageDifference d = srgb8_difference(reference[a], r.srgb8);
        const std::vector<Ray> rays = primary_rays(*scene.camera, o.width, o.height);
        const Measured m = measure_primary(a, scene.mesh, o.params, rays, o.reps);
        cells.emplace_back("status", "rendered");
        cells.emplace_back("pixels_differing", d.pixels_differing);
        cells.emplace_back("mad_levels", d.mean_abs * 255.0);
        if (!m.error.empty()) {
          cells.emplace_back("error", m.error);
        } else {
          cells.emplace_back("mrays", m.mrays);
          cells.emplace_back("hit_fraction",
                             double(m.hits) / double(std::max<size_t>(1, rays.size())));
        }
        if (o.progress)
          o.progress("  " + format_double("%g", scale) + " " + a + ": " +
                     format_double("%.4f", d.pixels_differing) + " of pixels differ, mad " +
                     format_double("%.4f", d.mean_abs * 255.0) + " levels, " +
                     format_double("%.3g", m.mrays) + " Mrays/s");
      } catch (const std::exception& e) {
        cells.emplace_back("status", "error");
        cells.emplace_back("error", e.what());
      }
      t.add_row(cells);
    }
  }
}

// ---- spp ---------------------------------------------------------------------------------------

std::string find_cornell() {
  return find_asset("cornell.gltf");
}

/// The image as a display shows it: linear values clamped to [0, 1]. The emissive panel's
/// radiance is far above 1, so the plain RMSE is dominated by its jittered edges.
ImageRGB clamped(ImageRGB img) {
  for (float& v : img.rgb) v = std::clamp(v, 0.0f, 1.0f);
  return img;
}

void sweep_spp(const SweepOptions& o, SweepTable& t) {
  Scene scene;
  std::string source = o.scene.empty() ? find_cornell() : o.scene;
  if (source.empty()) {
    scene = generate_scene("cornell");
    scene.finalize();
    source = "procedural:cornell";
  } else {
    scene = load_scene(source);
  }
  t.scene = source;
  const std::string accel = o.accels.empty() ? (registered("bvh") ? "bvh" : "brute") : o.accels[0];
  auto acc = make_accelerator(accel);
  acc->build(scene.mesh, o.params);
  RenderSettings rs;
  rs.width = o.width;
  rs.height = o.height;
  if (o.camera) scene.camera = o.camera;

  // The reference uses another seed, so its samples are independent of the measured ones.
  rs.seed = 1000003;
  Renderer ref(scene, *acc, rs);
  for (int i = 0; i < o.spp_reference; ++i) ref.render_pass();
  ImageRGB ref_img{o.width, o.height, {}, {}};
  ref.resolve(ref_img.rgb);
  t.notes.emplace_back("accel", accel);
  t.notes.emplace_back("rmse",
                       "root-mean-square difference from the reference over all channels "
                       "of linear RGB; rmse_display clamps both images to [0, 1] first");
  t.notes.emplace_back("reference", std::to_string(o.spp_reference) + " spp, seed 1000003, " +
                                        format_double("%.2f", ref.seconds()) + " s");
  if (o.progress)
    o.progress("  reference: " + std::to_string(o.spp_reference) + " spp in " +
               format_double("%.1f", ref.seconds()) + " s");

  rs.seed = 1;
  Renderer r(scene, *acc, rs);
  std::vector<double> checkpoints = o.values;
  std::sort(checkpoints.begin(), checkpoints.end());
  size_t next = 0;
  const int max_spp = checkpoints.empty() ? 0 : int(checkpoints.back());
  ImageRGB img{o.width, o.height, {}, {}};
  for (int spp = 1; spp <= max_spp; ++spp) {
    r.render_pass();
    while (next < checkpoints.size() && int(checkpoints[next]) <= spp) {
      if (int(checkpoints[next]) == spp) {
        r.resolve(img.rgb);
        const double e = rmse(img, ref_img);
        const double e_display = rmse(clamped(img), clamped(ref_img));
        const double rays = double(r.counters().total());
        t.add_row({{"spp", double(spp)},
                   {"seconds", r.seconds()},
                   {"rmse", e},
                   {"rmse_display", e_display},
                   {"rays", rays},
                   {"mrays", r.seconds() > 0 ? rays * 1e-6 / r.seconds() : 0.0}});
        if (o.progress)
          o.progress("  " + std::to_string(spp) + " spp: " + format_double("%.2f", r.seconds()) +
                     " s, rmse " + format_double("%.5f", e) + ", display rmse " +
                     format_double("%.5f", e_display));
      }
      ++next;
    }
  }
}

}  // namespace

// ---- public ------------------------------------------------------------------------------------

ScaledRender render_scaled(const Scene& scene, const std::string& accel, int width, int height,
                           int spp, const BuildParams& params) {
  const auto acc = build_accelerator(accel, scene.mesh, params);
  RenderSettings rs;
  rs.width = width;
  rs.height = height;
  rs.seed = 1;
  Renderer r(scene, *acc, rs);
  for (int i = 0; i < spp; ++i) r.render_pass();
  std::vector<float> rgb;
  r.resolve(rgb);
  ScaledRender out;
  tonemap_srgb8(rgb, out.srgb8);
  out.seconds = r.seconds();
  out.rays = r.counters().total();
  return out;
}

void SweepTable::add_row(const std::vector<std::pair<std::string, SweepValue>>& cells) {
  std::vector<SweepValue> row(columns.size());
  for (const auto& [k, v] : cells) {
    auto it = std::find(columns.begin(), columns.end(), k);
    size_t i = size_t(it - columns.begin());
    if (it == columns.end()) {
      columns.push_back(k);
      for (auto& r : rows) r.emplace_back();
      row.emplace_back();
      i = columns.size() - 1;
    }
    row[i] = v;
  }
  rows.push_back(std::move(row));
}

std::vector<std::string> sweep_kinds() {
  return {"cellsize", "lambda", "kdcost", "triangle", "scale", "spp"};
}

std::vector<double> sweep_default_values(const std::string& kind) {
  if (kind == "cellsize")
    return {0.25, 0.35, 0.5, 0.7, 1.4, 2.0, 2.8, 4.0, 5.6, 8.0};  // 1x = auto row
  if (kind == "lambda") return {0.5, 1, 2, 4, 8, 16};
  if (kind == "kdcost") return {0.5, 0.75, 1, 1.5, 2, 3, 4, 6, 8};
  if (kind == "spp") return {1, 2, 4, 8, 16, 32, 64};
  if (kind == "scale") {
    std::vector<double> v;
    for (int k = -20; k <= 16; ++k) v.push_back(std::pow(10.0, k));
    return v;
  }
  return {};
}

SweepTable run_sweep(const SweepOptions& in) {
  SweepOptions o = in;
  const auto kinds = sweep_kinds();
  if (std::find(kinds.begin(), kinds.end(), o.kind) == kinds.end())
    throw ParamError("unknown sweep '" + o.kind +
                     "': choose cellsize, lambda, kdcost, triangle, scale or spp");
  if (o.reps < 1) throw ParamError("--reps must be at least 1");
  check_threads(o.threads);
  if (o.width == 0 && o.height == 0)
    o.width = o.height = o.kind == "spp" ? 200 : o.kind == "scale" ? 128 : 512;
  if (o.width < 1 || o.height < 1 || o.width > 16384 || o.height > 16384)
    throw ParamError("--res must be between 1 and 16384 pixels per side");
  const std::string most_spp = std::to_string(kMaxSamplesPerPixel);
  if (o.kind == "spp" && (o.spp_max < 1 || o.spp_max > kMaxSamplesPerPixel))
    throw ParamError("--spp-max " + std::to_string(o.spp_max) + " must be between 1 and " +
                     most_spp + " samples per pixel");
  if (o.kind == "spp" && (o.spp_reference < 1 || o.spp_reference > kMaxSamplesPerPixel))
    throw ParamError("--spp-reference " + std::to_string(o.spp_reference) +
                     " must be between 1 and " + most_spp + " samples per pixel");
  if (o.values.empty()) {
    o.values = sweep_default_values(o.kind);
    if (o.kind == "spp") {
      o.values.clear();
      for (int s = 1; s <= o.spp_max; s *= 2) o.values.push_back(s);
    }
  }
  for (double v : o.values)
    if (!(v > 0) || !std::isfinite(v))
      throw ParamError("sweep value " + format_double("%g", v) +
                       " must be a positive finite number");
  if (o.kind == "spp")
    for (double v : o.values)
      if (v != std::floor(v) || v > kMaxSamplesPerPixel)
        throw ParamError("--values: " + format_double("%g", v) +
                         " is not a sample count: give whole numbers from 1 to " + most_spp);
  for (const auto& a : o.accels) make_accelerator(a);
  const int threads = effective_threads(o.threads);
  o.params.threads = threads;
  tbb::global_control gc(tbb::global_control::max_allowed_parallelism, size_t(threads));

  SweepTable t;
  t.kind = o.kind;
  t.scene = o.scene;
  t.date = now_iso8601();
  t.machine = cpu_model_name();
  t.threads = threads;
  t.reps = o.reps;
  t.width = o.width;
  t.height = o.height;
  if (o.progress) o.progress("sweep " + o.kind + (o.scene.empty() ? "" : " on " + o.scene));
  if (o.kind == "cellsize") {
    sweep_cellsize(o, t);
  } else if (o.kind == "lambda") {
    sweep_param(o, t, "grid", "lambda", [](BuildParams& p, double v) { p.grid_lambda = float(v); });
  } else if (o.kind == "kdcost") {
    t.notes.emplace_back("kdcost", "kd_intersection_cost / kd_traversal_cost, traversal cost 1");
    sweep_param(o, t, "kdtree", "cost_ratio", [](BuildParams& p, double v) {
      p.kd_traversal_cost = 1.0f;
      p.kd_intersection_cost = float(v);
    });
  } else if (o.kind == "triangle") {
    sweep_triangle(o, t);
  } else if (o.kind == "scale") {
    sweep_scale(o, t);
  } else {
    sweep_spp(o, t);
  }
  return t;
}

std::string sweep_to_csv(const SweepTable& t) {
  auto quote = [](const std::string& s) {
    if (s.find_first_of(",\"\n") == std::string::npos) return s;
    std::string q = "\"";
    for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
    return q + "\"";
  };
  std::ostringstream out;
  for (size_t i = 0; i < t.columns.size(); ++i) out << (i ? "," : "") << quote(t.columns[i]);
  out << "\n";
  for (const auto& r : t.rows) {
    for (size_t i = 0; i < t.columns.size(); ++i) {
      if (i) out << ",";
      if (i >= r.size()) continue;
      if (const auto* d = std::get_if<double>(&r[i]))
        out << format_double("%.9g", *d);
      else if (const auto* s = std::get_if<std::string>(&r[i]))
        out << quote(*s);
    }
    out << "\n";
  }
  return out.str();
}

std::string sweep_to_json(const SweepTable& t) {
  using nlohmann::json;
  json j;
  j["meta"] = {{"kind", t.kind},       {"scene", t.scene},     {"date", t.date},
               {"machine", t.machine}, {"threads", t.threads}, {"reps", t.reps},
               {"width", t.width},     {"height", t.height}};
  for (const auto& [k, v] : t.notes) j["meta"]["notes"][k] = v;
  j["columns"] = t.columns;
  j["rows"] = json::array();
  for (const auto& r : t.rows) {
    json o = json::object();
    for (size_t i = 0; i < t.columns.size() && i < r.size(); ++i) {
      if (const auto* d = std::get_if<double>(&r[i]))
        o[t.columns[i]] = *d;
      else if (const auto* s = std::get_if<std::string>(&r[i]))
        o[t.columns[i]] = *s;
    }
    j["rows"].push_back(o);
  }
  return j.dump(2) + "\n";
}

std::vector<Ray> edge_vertex_rays(const Mesh& mesh, int per_target, uint64_t seed) {
  // Adjacency: faces around each edge and each vertex, and the unit face normals.
  const size_t nt = mesh.num_triangles();
  std::vector<Vec3> fn(nt);
  for (size_t i = 0; i < nt; ++i) fn[i] = normalize(mesh.geometric_normal(i));
  std::map<std::pair<uint32_t, uint32_t>, std::vector<uint32_t>> edges;
  std::vector<std::vector<uint32_t>> vfaces(mesh.num_vertices());
  for (uint32_t i = 0; i < nt; ++i) {
    const auto& t = mesh.triangles[i];
    for (int k = 0; k < 3; ++k) {
      const uint32_t a = t[k], b = t[(k + 1) % 3];
      edges[{std::min(a, b), std::max(a, b)}].push_back(i);
      vfaces[a].push_back(i);
    }
  }
  const Box3 bounds = mesh.bounds();
  const float dist = 2.0f * length(bounds.extent()) + 1e-30f;
  SplitMix64 rng{seed};  // the leak rays' directions
  std::vector<Ray> rays;
  // A direction d whose origin target + d * dist lies on the outer side of every adjacent
  // face (dot(d, n) > 0.2 for each), so the ray crosses into the closed volume at the target.
  auto add = [&](const Vec3& target, const std::vector<uint32_t>& faces) {
    Vec3 avg(0.0f);
    for (uint32_t f : faces) avg += fn[f];
    avg = normalize(avg);
    for (int k = 0; k < per_target; ++k) {
      Vec3 d = avg;
      for (int attempt = 0; attempt < 32; ++attempt) {
        const Vec3 r(rng.uniform() * 2 - 1, rng.uniform() * 2 - 1, rng.uniform() * 2 - 1);
        const Vec3 cand = normalize(avg + r * 0.6f);
        if (std::all_of(faces.begin(), faces.end(),
                        [&](uint32_t f) { return dot(cand, fn[f]) > 0.2f; })) {
          d = cand;
          break;
        }
      }
      const Vec3 org = target + d * dist;
      // The segment ends just past the target: with tmax = inf a ray slipping through the
      // edge would be caught by the far side of the closed mesh and the leak go unseen.
      rays.push_back({org, 0.0f, target - org, kLeakRayTmax});
    }
  };
  for (const auto& [e, faces] : edges) {
    if (faces.size() != 2) continue;  // boundary or non-manifold edge: not "shared"
    const Vec3 a = mesh.positions[e.first], b = mesh.positions[e.second];
    for (float s : {0.25f, 0.5f, 0.75f}) add(a + (b - a) * s, faces);
  }
  for (size_t v = 0; v < vfaces.size(); ++v)
    if (vfaces[v].size() >= 3) add(mesh.positions[v], vfaces[v]);
  return rays;
}

}  // namespace kdgrid
