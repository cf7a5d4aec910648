// `kdgrid trace`: traces a .rays file with one structure and reports speed, per-ray
// traversal counts and build figures; or, with --pixel, prints the step-by-step traversal
// of one primary ray, and with --origin/--dir of any ray (the command lines the viewer prints
// for a picked pixel and for every ray of its ray tree).
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>

#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "accel/hybrid/hybrid.h"
#include "bench/rayfile.h"
#include "cli/commands.h"
#include "cli/common.h"
#include "render/camera.h"
#include "scene/load.h"
#include "util/atomic_file.h"
#include "util/error.h"
#include "util/paths.h"

namespace kdgrid::cli {

namespace {

struct TraceArgs {
  std::string scene, rays, hits, pixel, res = "1024x1024";
  std::string origin, dir, tmin = "0", tmax = "inf";
  int threads = 0;
  int repeat = 5;
  bool json = false;
  bool any = false;
  bool traversal_only = false;
  AccelOptions accel;
  CameraOptions camera;
  double scale = 1.0;
};

struct Counted {
  RayCounters c;
  uint64_t hits = 0;
  uint64_t from_cache = 0;  ///< the hybrid's next leaves taken from its next-leaf cache
};

void print_box(const Box3& b) {
  std::printf("(%.6g %.6g %.6g)-(%.6g %.6g %.6g)", b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z);
}

nlohmann::json build_json(const BuildStats& st, size_t tris) {
  nlohmann::json j;
  j["seconds"] = st.seconds;
  j["mtris_per_s"] = st.seconds > 0 ? double(tris) / st.seconds * 1e-6 : 0.0;
  j["nodes"] = st.nodes;
  j["leaves"] = st.leaves;
  j["empty_leaves"] = st.empty_leaves;
  j["references"] = st.references;
  j["max_depth"] = st.max_depth;
  j["sah_evaluations"] = st.sah_evaluations;
  j["bytes"] = st.bytes;
  j["bytes_per_triangle"] = tris ? double(st.bytes) / double(tris) : 0.0;
  for (const auto& [k, v] : st.bytes_by_part) j["bytes_by_part"][k] = v;
  for (const auto& [k, v] : st.extra) j["extra"][k] = v;
  return j;
}

/// Parses --tmin / --tmax: a number, "inf" allowed for --tmax.
float parse_ray_bound(const std::string& s, const char* what) {
  char* end = nullptr;
  const float f = std::strtof(s.c_str(), &end);
  if (end == s.c_str() || *end != '\0' || std::isnan(f) || f == -kInf)
    throw ParamError(std::string(what) + " '" + s + "' is not a number (inf is allowed)");
  return f;
}

/// Prints one ray's step-by-step traversal (the closest-hit one, or with --any the any-hit
/// one), after `header` (text only).
void print_ray_trace(const TraceArgs& a, const Ray& ray, const Accelerator& accel,
                     const std::string& header) {
  const Trace tr = a.any ? accel.trace_occluded(ray) : accel.trace(ray);
  if (a.json) {
    nlohmann::json j;
    j["ray"] = {
        {"org", {ray.org.x, ray.org.y, ray.org.z}},
        {"dir", {ray.dir.x, ray.dir.y, ray.dir.z}},
        {"tmin", ray.tmin},
        {"tmax", std::isfinite(ray.tmax) ? nlohmann::json(ray.tmax) : nlohmann::json("inf")}};
    j["query"] = a.any ? "any" : "closest";
    if (a.any) j["occluded"] = tr.occluded;
    for (const TraceStep& s : tr.steps) {
      nlohmann::json js;
      js["kind"] =
          s.kind == StepKind::Inner ? "inner" : (s.kind == StepKind::Leaf ? "leaf" : "cell");
      js["depth"] = s.depth;
      js["id"] = s.id;
      js["box"] = {{s.box.lo.x, s.box.lo.y, s.box.lo.z}, {s.box.hi.x, s.box.hi.y, s.box.hi.z}};
      js["t_in"] = s.t_in;
      js["t_out"] = s.t_out;
      js["tested"] = std::vector<uint32_t>(tr.tested.begin() + s.first_tested,
                                           tr.tested.begin() + s.first_tested + s.num_tested);
      j["steps"].push_back(js);
    }
    j["hit"] = tr.hit.valid() ? nlohmann::json{{"t", tr.hit.t}, {"prim", tr.hit.prim}}
                              : nlohmann::json(nullptr);
    j["counters"] = {{"steps", tr.counters.steps},
                     {"leaves", tr.counters.leaves},
                     {"tri_tests", tr.counters.tri_tests},
                     {"mailbox_skips", tr.counters.mailbox_skips},
                     {"lookups", tr.counters.lookups}};
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  std::printf("%s\n", header.c_str());
  std::printf("ray org (%.9g %.9g %.9g) dir (%.9g %.9g %.9g) t [%.9g, %.9g]\n", ray.org.x,
              ray.org.y, ray.org.z, ray.dir.x, ray.dir.y, ray.dir.z, ray.tmin, ray.tmax);
  for (size_t k = 0; k < tr.steps.size(); ++k) {
    const TraceStep& s = tr.steps[k];
    std::printf("%4zu %-5s depth %-3d id %-8llu box ", k,
                s.kind == StepKind::Inner ? "inner" : (s.kind == StepKind::Leaf ? "leaf" : "cell"),
                s.depth, (unsigned long long)s.id);
    print_box(s.box);
    std::printf(" t [%.6g, %.6g]", s.t_in, s.t_out);
    if (s.num_tested) {
      std::printf(" tested");
      for (uint32_t i = 0; i < s.num_tested; ++i) std::printf(" %u", tr.tested[s.first_tested + i]);
    }
    std::printf("\n");
  }
  if (a.any)
    std::printf("%s\n", tr.occluded ? "occluded" : "not occluded");
  else if (tr.hit.valid())
    std::printf("hit triangle %u at t %.9g (u %.4g v %.4g)\n", tr.hit.prim, tr.hit.t, tr.hit.u,
                tr.hit.v);
  else
    std::printf("miss\n");
  std::printf("steps %llu, leaves %llu, triangle tests %llu, mailbox skips %llu, lookups %llu\n",
              (unsigned long long)tr.counters.steps, (unsigned long long)tr.counters.leaves,
              (unsigned long long)tr.counters.tri_tests,
              (unsigned long long)tr.counters.mailbox_skips,
              (unsigned long long)tr.counters.lookups);
}

void trace_pixel(const TraceArgs& a, const Scene& scene, const Accelerator& accel) {
  int w = 0, h = 0;
  parse_resolution(a.res, w, h);
  const Camera cam = a.camera.apply(*scene.camera);
  char header[512];
  std::snprintf(header, sizeof header,
                "%s, pixel %s of %dx%d, camera --eye %g,%g,%g --target %g,%g,%g --fov %g",
                accel.name().c_str(), a.pixel.c_str(), w, h, cam.eye.x, cam.eye.y, cam.eye.z,
                cam.target.x, cam.target.y, cam.target.z, cam.fov_deg);
  print_ray_trace(a, pixel_ray(cam, a.res, a.pixel), accel, header);
}

/// The ray of --origin, --dir, --tmin and --tmax (checked before the scene is loaded).
Ray given_ray(const TraceArgs& a) {
  Ray r;
  r.org = parse_vec3(a.origin, "--origin");
  r.dir = parse_vec3(a.dir, "--dir");
  if (r.dir.x == 0 && r.dir.y == 0 && r.dir.z == 0)
    throw ParamError("--dir '" + a.dir + "' is the zero vector: give a direction");
  r.tmin = parse_ray_bound(a.tmin, "--tmin");
  r.tmax = parse_ray_bound(a.tmax, "--tmax");
  if (!std::isfinite(r.tmin) || r.tmin < 0 || !(r.tmax > r.tmin))
    throw ParamError("--tmin " + a.tmin + " and --tmax " + a.tmax +
                     " must satisfy 0 <= tmin < tmax (tmin finite)");
  return r;
}

void trace_file(const TraceArgs& a, const Scene& scene, const Accelerator& accel,
                const std::vector<Ray>& rays) {
  const size_t n = rays.size();
  std::vector<Hit> hits(n);
  const tbb::blocked_range<size_t> all(0, n, 256);

  // Fast path, timed: median of --repeat runs.
  std::vector<double> secs;
  for (int r = 0; r < std::max(1, a.repeat); ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    if (a.any) {
      tbb::parallel_for(all, [&](const tbb::blocked_range<size_t>& br) {
        for (size_t i = br.begin(); i < br.end(); ++i)
          hits[i].prim = accel.occluded(rays[i]) ? 0u : kInvalidPrim;
      });
    } else {
      tbb::parallel_for(all, [&](const tbb::blocked_range<size_t>& br) {
        for (size_t i = br.begin(); i < br.end(); ++i) {
          Hit h;
          accel.intersect(rays[i], h);
          hits[i] = h;
        }
      });
    }
    secs.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(secs.begin(), secs.end());
  const double median = secs[secs.size() / 2];
  const double mrays = median > 0 ? double(n) / median * 1e-6 : 0.0;

  // Counted pass (same traversal template with counters on), not timed.
  const Counted counted = tbb::parallel_reduce(
      all, Counted{},
      [&](const tbb::blocked_range<size_t>& br, Counted acc) {
        // The cached leaves taken are counted per thread: this chunk's runs on one.
        const uint64_t from_cache0 = GridKdHybrid::next_leaves_from_cache();
        for (size_t i = br.begin(); i < br.end(); ++i) {
          Hit h;
          const bool hit = a.any ? accel.occluded_counted(rays[i], acc.c)
                                 : accel.intersect_counted(rays[i], h, acc.c);
          acc.hits += hit;
        }
        acc.from_cache += GridKdHybrid::next_leaves_from_cache() - from_cache0;
        return acc;
      },
      [](Counted x, const Counted& y) {
        x.c += y.c;
        x.hits += y.hits;
        x.from_cache += y.from_cache;
        return x;
      });

  if (!a.hits.empty()) {
    if (a.any) {
      // Any-hit queries have no t: recompute closest hits so the file means the same thing.
      tbb::parallel_for(all, [&](const tbb::blocked_range<size_t>& br) {
        for (size_t i = br.begin(); i < br.end(); ++i) {
          Hit h;
          accel.intersect(rays[i], h);
          hits[i] = h;
        }
      });
    }
    write_hits(a.hits, hits);
  }

  const double per = n ? 1.0 / double(n) : 0.0;
  const BuildStats& st = accel.stats();
  const size_t tris = scene.mesh.num_triangles();
  const int threads =
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  // Thread time per ray (wall time x threads / rays: exact on one thread), and per step.
  const double thread_ns_per_ray = median * double(threads) * 1e9 * per;
  const double steps_per_ray = double(counted.c.steps) * per;
  const double ns_per_step = steps_per_ray > 0 ? thread_ns_per_ray / steps_per_ray : 0.0;
  if (a.json) {
    nlohmann::json j;
    j["scene"] = a.scene;
    j["triangles"] = tris;
    j["structure"] = accel.name();
    j["rays_file"] = a.rays;
    j["rays"] = n;
    j["query"] = a.any ? "any" : "closest";
    j["threads"] = threads;
    j["repetitions"] = secs.size();
    j["seconds_median"] = median;
    j["mrays_per_s"] = mrays;
    j["hit_fraction"] = double(counted.hits) * per;
    j["has_counters"] = accel.has_counters();
    j["traversal_only"] = a.traversal_only;
    if (a.traversal_only) {
      j["thread_ns_per_ray"] = thread_ns_per_ray;
      j["thread_ns_per_step"] = ns_per_step;
      j["thread_ns_per_lookup"] =
          counted.c.lookups > 0 ? thread_ns_per_ray / (double(counted.c.lookups) * per) : 0.0;
    }
    j["per_ray"] = {{"steps", double(counted.c.steps) * per},
                    {"leaves", double(counted.c.leaves) * per},
                    {"tri_tests", double(counted.c.tri_tests) * per},
                    {"mailbox_skips", double(counted.c.mailbox_skips) * per},
                    {"lookups", double(counted.c.lookups) * per},
                    {"next_leaves_from_cache", double(counted.from_cache) * per}};
    j["build"] = build_json(st, tris);
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  std::printf("scene        %s (%zu triangles)\n", a.scene.c_str(), tris);
  std::printf("structure    %s\n", accel.name().c_str());
  std::printf("rays         %zu from %s (%s hits)\n", n, a.rays.c_str(), a.any ? "any" : "closest");
  std::printf("speed        %.4g Mrays/s (median of %zu, %d threads, %.4f s)\n", mrays, secs.size(),
              threads, median);
  std::printf("hit fraction %.4f\n", double(counted.hits) * per);
  if (accel.has_counters())
    std::printf(
        "per ray      %.2f steps, %.2f leaves, %.2f triangle tests, %.2f mailbox skips, "
        "%.2f lookups\n",
        double(counted.c.steps) * per, double(counted.c.leaves) * per,
        double(counted.c.tri_tests) * per, double(counted.c.mailbox_skips) * per,
        double(counted.c.lookups) * per);
  else
    std::printf("per ray      (this structure cannot count its traversal)\n");
  if (accel.name() == "hybrid")
    std::printf(
        "leaf cache   %.2f of the lookups per ray answered by the next-leaf cache (counted "
        "pass)\n",
        double(counted.from_cache) * per);
  if (a.traversal_only) {
    std::printf(
        "traversal    alone (no triangle tested, every ray misses): %.1f ns per ray, %.2f ns "
        "per step",
        thread_ns_per_ray, ns_per_step);
    // Structures that step cell to cell (grids, the hybrid): the time per lookup, which
    // includes everything done in that cell or leaf (the hybrid's leaf subtrees).
    if (counted.c.lookups > 0)
      std::printf(", %.2f ns per lookup", thread_ns_per_ray / (double(counted.c.lookups) * per));
    std::printf(" (thread time)\n");
  }
  std::printf(
      "build        %.4f s, %.2f Mtris/s, %llu nodes, %llu leaves, depth %u, %llu refs, "
      "%llu SAH evaluations\n",
      st.seconds, st.seconds > 0 ? double(tris) / st.seconds * 1e-6 : 0.0,
      (unsigned long long)st.nodes, (unsigned long long)st.leaves, st.max_depth,
      (unsigned long long)st.references, (unsigned long long)st.sah_evaluations);
  std::printf("memory       %.2f MiB, %.1f bytes/triangle", double(st.bytes) / (1 << 20),
              tris ? double(st.bytes) / double(tris) : 0.0);
  for (const auto& [k, v] : st.bytes_by_part)
    std::printf(", %s %.2f MiB", k.c_str(), double(v) / (1 << 20));
  std::printf("\n");
  for (const auto& [k, v] : st.extra) std::printf("  %-10s %s\n", k.c_str(), v.c_str());
  if (!a.hits.empty()) std::printf("wrote hits to %s\n", a.hits.c_str());
}

}  // namespace

void add_trace_command(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "trace",
      "Trace a .rays file with one structure (speed, per-ray counts, build figures), or print "
      "the step-by-step traversal of one primary ray with --pixel X,Y, or of any ray with "
      "--origin X,Y,Z --dir X,Y,Z [--tmin T --tmax T] [--any]");
  auto a = std::make_shared<TraceArgs>();
  add_scene_argument(cmd, a->scene);
  auto* rays_opt = cmd->add_option("--rays", a->rays, "Ray file (.rays) to trace");
  cmd->add_option("--hits", a->hits, "Write the closest hits of the rays to this .hits file");
  cmd->add_flag("--any", a->any,
                "Any-hit (occluded) queries instead of closest hits: timed over --rays, or the "
                "any-hit traversal of the --origin ray or --pixel ray");
  cmd->add_flag("--traversal-only", a->traversal_only,
                "Time the traversal alone: no triangle is tested, so every ray misses and crosses "
                "the whole structure; reports ns per ray and per traversal step");
  add_threads_option(cmd, a->threads);
  cmd->add_option("--repeat", a->repeat, "Timed repetitions (the median is reported)")
      ->capture_default_str();
  cmd->add_flag("--json", a->json, "Print JSON instead of text");
  auto* pixel_opt = cmd->add_option(
      "--pixel", a->pixel,
      "Print the traversal of the primary ray through pixel X,Y (integers: the pixel centre) of "
      "the scene's camera, changed by the camera flags");
  cmd->add_option("--res", a->res, "Image size W or WxH for --pixel")->capture_default_str();
  auto* origin_opt = cmd->add_option(
      "--origin", a->origin,
      "Print the traversal of the ray from x,y,z along --dir (a secondary ray the viewer's ray "
      "tree shows, replayed); --any for a shadow ray's any-hit traversal");
  cmd->add_option("--dir", a->dir, "Direction x,y,z of the --origin ray");
  cmd->add_option("--tmin", a->tmin, "Start of the --origin ray's segment")->capture_default_str();
  cmd->add_option("--tmax", a->tmax, "End of the --origin ray's segment (inf allowed)")
      ->capture_default_str();
  rays_opt->excludes(pixel_opt);
  origin_opt->excludes(pixel_opt);
  origin_opt->excludes(rays_opt);
  a->accel.add_to(cmd, "bvh");
  a->camera.add_to(cmd);
  add_scale_option(cmd, a->scale);
  cmd->callback([a] {
    if (a->rays.empty() && a->pixel.empty() && a->origin.empty())
      throw ParamError(
          "trace needs --rays FILE.rays (write one with `kdgrid rays`), --pixel X,Y or "
          "--origin X,Y,Z --dir X,Y,Z");
    if (a->origin.empty() != a->dir.empty())
      throw ParamError("--origin and --dir give one ray together: give both");
    Ray one_ray;
    if (!a->origin.empty()) one_ray = given_ray(*a);
    check_threads(a->threads);
    if (a->repeat < 1) throw ParamError("--repeat must be >= 1");
    const BuildParams params = a->accel.resolve();
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism,
                           size_t(effective_threads(a->threads)));
    // Inputs and outputs are checked, and the rays read, before the scene is loaded and the
    // structure built: a bad path fails in milliseconds.
    const std::string scene_path = resolve_scene_path(a->scene);
    if (!a->hits.empty()) {
      if (a->rays.empty()) throw ParamError("--hits needs --rays FILE.rays: it writes their hits");
      check_output_path(a->hits, "--hits", {".hits"}, {scene_path, a->rays});
    }
    std::vector<Ray> rays;
    if (!a->rays.empty()) rays = read_rays(a->rays);
    const Scene scene = load_scene(scene_path, a->scale);
    BuildParams p = params;
    if (p.threads == 0) p.threads = a->threads;
    if (a->traversal_only) {
      if (!a->pixel.empty() || !a->origin.empty())
        throw ParamError(
            "--traversal-only times a .rays file: use it with --rays, not --pixel or --origin");
      if (!a->hits.empty()) throw ParamError("--traversal-only finds no hits: drop --hits");
      p.triangle_test = TriangleTestKind::None;
    }
    const auto accel = build_interruptible(a->accel.accel, scene.mesh, p);
    if (!a->pixel.empty())
      trace_pixel(*a, scene, *accel);
    else if (!a->origin.empty())
      print_ray_trace(*a, one_ray, *accel,
                      accel->name() + ", ray --origin " + a->origin + " --dir " + a->dir +
                          " --tmin " + a->tmin + " --tmax " + a->tmax +
                          (a->any ? " (any hit)" : " (closest hit)"));
    else
      trace_file(*a, scene, *accel, rays);
  });
}

}  // namespace kdgrid::cli
