#include "bench/bench.h"

#include <malloc.h>
#include <sys/resource.h>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include <nlohmann/json.hpp>

#include "accel/guards.h"
#include "accel/triangle.h"
#include "accel/triangle_wide.h"
#include "bench/bench_render.h"
#include "bench/rayfile.h"
#include "bench/raysets.h"
#include "math/simd.h"
#include "scene/load.h"
#include "util/error.h"
#include "util/format.h"

namespace kdgrid {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

bool is_any_hit(const std::string& set) {
  return set == "shadow";
}

std::string describe_camera(const std::optional<Camera>& c) {
  if (!c) return "canonical";
  std::ostringstream s;
  s << "eye " << c->eye.x << "," << c->eye.y << "," << c->eye.z << " target " << c->target.x << ","
    << c->target.y << "," << c->target.z << " fov " << c->fov_deg;
  return s.str();
}

/// The ray sets of one scene, shared by every structure.
struct SceneRays {
  std::vector<std::string> names;
  std::vector<std::vector<Ray>> rays;
  std::vector<std::string> sources;
};

std::string rays_file(const std::string& dir, const std::string& scene, const std::string& set) {
  return (fs::path(dir) / (scene + "." + set + ".rays")).string();
}

/// Makes (or reads) every set the options ask for. `ref` is a built structure used for the
/// primary hits that shadow and diffuse rays start from.
SceneRays make_scene_rays(const SceneFigures& sf, const Mesh& mesh, const Camera& cam,
                          const Accelerator& ref, const BenchOptions& o) {
  SceneRays out;
  std::vector<Ray> primary;
  std::vector<Hit> primary_hits;
  auto need_primary = [&] {
    if (!primary.empty()) return;
    const std::string f = o.rays_dir.empty() ? "" : rays_file(o.rays_dir, sf.name, "primary");
    std::error_code ec;
    if (!f.empty() && fs::exists(f, ec))
      primary = read_rays(f);
    else
      primary = primary_rays(cam, o.width, o.height);
    primary_hits = trace_hits(ref, primary);
  };
  for (const std::string& set : o.sets) {
    const std::string f = o.rays_dir.empty() ? "" : rays_file(o.rays_dir, sf.name, set);
    std::error_code ec;
    std::vector<Ray> rays;
    std::string source = "generated";
    if (!f.empty() && fs::exists(f, ec)) {
      rays = read_rays(f);
      source = f;
    } else {
      const RaySetKind kind = parse_ray_set(set);
      if (kind == RaySetKind::Primary) {
        need_primary();
        rays = primary;
      } else if (kind == RaySetKind::Shadow) {
        need_primary();
        rays =
            shadow_rays(mesh, primary, primary_hits, canonical_light_position(mesh.bounds()), &ref);
      } else if (kind == RaySetKind::Diffuse) {
        need_primary();
        rays = diffuse_rays(mesh, primary, primary_hits, /*seed=*/1, &ref);
      } else {
        rays = random_rays(mesh.bounds(), size_t(o.width) * size_t(o.height), /*seed=*/1);
      }
      if (!f.empty()) {
        fs::create_directories(o.rays_dir, ec);
        write_rays(f, rays);
        source = "generated, written to " + f;
      }
    }
    out.names.push_back(set);
    out.rays.push_back(std::move(rays));
    out.sources.push_back(source);
  }
  return out;
}

/// What the reference measured on each set, for ratios and agreement.
struct Reference {
  bool ok = false;
  const Accelerator* acc = nullptr;    // kept built for interleaved timing
  std::vector<double> mrays;           // per set
  std::vector<std::vector<Hit>> hits;  // per set
};

/// The packet column of one set (BenchOptions::packet_tile): the rays in tile order (primary
/// rays of the bench's image; others as they come), timed through acc's packet query, paired
/// with the reference's when `ref` is given (`is_reference`: acc is the reference itself), and
/// checked bitwise against acc's single-ray answers `single` (image order).
void measure_packets(const Accelerator& acc, const std::string& set, const std::vector<Ray>& rays,
                     const std::vector<Hit>& single, const BenchOptions& o, const Reference* ref,
                     bool is_reference, SetFigures& sf) {
  const bool any = is_any_hit(set);
  const int tile = o.packet_tile;
  std::vector<uint32_t> order;
  if (set == "primary" && rays.size() == size_t(o.width) * size_t(o.height))
    order = tile_order(o.width, o.height, tile);
  else
    for (uint32_t i = 0; i < rays.size(); ++i) order.push_back(i);
  std::vector<Ray> tiled(rays.size());
  for (size_t i = 0; i < order.size(); ++i) tiled[i] = rays[order[i]];
  sf.packet_rays = tile * tile;
  sf.packet_width = acc.packet_width();
  auto mrays_of = [&](double sec) { return sec > 0 ? double(rays.size()) / sec * 1e-6 : 0.0; };
  std::vector<Hit> hits, ref_scratch;
  trace_packets(acc, tiled, sf.packet_rays, any, &hits);  // warms caches, gives the hits
  std::vector<double> ratios, ref_reps, single_reps, speedups;
  for (int r = 0; r < o.reps; ++r) {
    if (ref)
      ref_reps.push_back(mrays_of(
          trace_packets(*ref->acc, tiled, sf.packet_rays, any, &ref_scratch, o.cpu_clock)));
    sf.packet_mrays_reps.push_back(
        mrays_of(trace_packets(acc, tiled, sf.packet_rays, any, &hits, o.cpu_clock)));
    single_reps.push_back(
        mrays_of(trace_packets(acc, tiled, sf.packet_rays, any, &ref_scratch, o.cpu_clock, true)));
    if (ref && ref_reps.back() > 0) ratios.push_back(sf.packet_mrays_reps.back() / ref_reps.back());
    if (single_reps.back() > 0)
      speedups.push_back(sf.packet_mrays_reps.back() / single_reps.back());
  }
  sf.packet_mrays_median = median(sf.packet_mrays_reps);
  sf.packet_single_mrays = median(single_reps);
  sf.packet_speedup = median(speedups);
  if (ref) {
    sf.packet_ratio_to_reference = median(ratios);
    sf.packet_reference_mrays = median(ref_reps);
  } else if (is_reference) {
    sf.packet_ratio_to_reference = 1.0;
    sf.packet_reference_mrays = sf.packet_mrays_median;
  }
  sf.packet_mismatches = 0;
  for (size_t i = 0; i < order.size(); ++i) {
    const Hit& a = hits[i];
    const Hit& b = single[order[i]];
    const bool same = any ? a.valid() == b.valid()
                          : a.prim == b.prim && std::memcmp(&a.t, &b.t, sizeof a.t) == 0 &&
                                std::memcmp(&a.u, &b.u, sizeof a.u) == 0 &&
                                std::memcmp(&a.v, &b.v, sizeof a.v) == 0;
    sf.packet_mismatches += !same;
    sf.packet_ties += !same && !any && a.prim != b.prim && std::memcmp(&a.t, &b.t, sizeof a.t) == 0;
  }
}

/// The progress line of a render column.
std::string render_line(const RenderFigures& r, bool against_reference) {
  std::string line = "    render: " + format_double("%.3f", r.seconds_median) + " s a pass of " +
                     std::to_string(r.rays()) + " rays, " + format_double("%.3g", r.mrays_median) +
                     " Mrays/s";
  if (against_reference)
    line += " (x" + format_double("%.2f", r.ratio_to_reference) + " reference), " +
            std::to_string(r.pixels_differ) + " pixels of its PNG differ from the reference's";
  return line;
}

StructureFigures measure(const std::string& name, const Mesh& mesh, const SceneRays& sr,
                         const BenchOptions& o, int threads, const Reference* ref,
                         std::unique_ptr<Accelerator>* keep,
                         std::vector<std::vector<Hit>>* hits_out, const RenderJob* render,
                         const std::function<void(const std::string&)>& say) {
  StructureFigures f;
  f.accel = name;
  try {
    reset_peak_rss();
    f.rss_before_bytes = current_rss_bytes();
    auto acc = make_accelerator(name);
    BuildParams p = o.params;
    p.threads = threads;
    uint64_t all_rays = 0;
    for (const auto& rays : sr.rays) all_rays += rays.size();
    check_brute_force_work(name, all_rays, mesh.num_triangles(), p);
    const auto t0 = Clock::now();
    f.stats = acc->build(mesh, p);
    f.build_seconds = seconds_since(t0);
    f.build_mtris_per_s =
        f.build_seconds > 0 ? double(mesh.num_triangles()) / f.build_seconds * 1e-6 : 0;
    f.bytes = f.stats.bytes;
    f.bytes_per_triangle = double(f.bytes) / double(std::max<size_t>(1, mesh.num_triangles()));
    say("  " + name + ": built in " + format_double("%.3f", f.build_seconds) + " s, " +
        format_double("%.1f", f.bytes_per_triangle) + " bytes/triangle");
    if (hits_out) hits_out->assign(sr.names.size(), {});
    for (size_t s = 0; s < sr.names.size(); ++s) {
      const auto& rays = sr.rays[s];
      const bool any = is_any_hit(sr.names[s]);
      SetFigures sf;
      sf.set = sr.names[s];
      sf.rays = rays.size();
      // The counted pass also warms caches and the hit buffer before the timed passes.
      sf.counted = acc->has_counters();
      std::vector<Hit> hits(rays.size());
      if (sf.counted) {
        const RayCounters c = count_rays(*acc, rays, any);
        const double n = double(std::max<size_t>(1, rays.size()));
        sf.steps_per_ray = double(c.steps) / n;
        sf.leaves_per_ray = double(c.leaves) / n;
        sf.tests_per_ray = double(c.tri_tests) / n;
        sf.lookups_per_ray = double(c.lookups) / n;
        sf.mailbox_skips_per_ray = double(c.mailbox_skips) / n;
      } else {
        trace_rays(*acc, rays, any, &hits);
      }
      // With interleaving, each repetition times the reference and then this structure, so
      // a change in machine load hits both of a pair and their ratio stays meaningful.
      const bool paired = o.interleave_reference && ref && ref->ok && ref->acc;
      std::vector<Hit> ref_scratch(paired ? rays.size() : 0);
      std::vector<double> ratios, ref_reps;
      auto mrays_of = [&](double sec) { return sec > 0 ? double(rays.size()) / sec * 1e-6 : 0.0; };
      for (int r = 0; r < o.reps; ++r) {
        if (paired)
          ref_reps.push_back(mrays_of(trace_rays(*ref->acc, rays, any, &ref_scratch, o.cpu_clock)));
        sf.mrays_reps.push_back(mrays_of(trace_rays(*acc, rays, any, &hits, o.cpu_clock)));
        if (paired && ref_reps.back() > 0) ratios.push_back(sf.mrays_reps.back() / ref_reps.back());
      }
      sf.mrays_median = median(sf.mrays_reps);
      sf.mrays_min = *std::min_element(sf.mrays_reps.begin(), sf.mrays_reps.end());
      sf.mrays_max = *std::max_element(sf.mrays_reps.begin(), sf.mrays_reps.end());
      sf.hits =
          uint64_t(std::count_if(hits.begin(), hits.end(), [](const Hit& h) { return h.valid(); }));
      if (ref && ref->ok) {
        sf.paired = paired;
        sf.reference_mrays = paired ? median(ref_reps) : ref->mrays[s];
        if (paired)
          sf.ratio_to_reference = median(ratios);
        else if (ref->mrays[s] > 0)
          sf.ratio_to_reference = sf.mrays_median / ref->mrays[s];
        sf.agreement = hit_agreement(mesh, rays, hits, ref->hits[s], any, o.tie_tolerance,
                                     &sf.disagreements, &sf.disagreements_on_surface);
      } else if (!ref) {
        sf.ratio_to_reference = 1.0;  // this is the reference
        sf.reference_mrays = sf.mrays_median;
      }
      std::string line =
          "    " + sf.set + ": " + format_double("%.3g", sf.mrays_median) + " Mrays/s";
      if (ref && ref->ok)
        line += " (x" + format_double("%.2f", sf.ratio_to_reference) + " reference)";
      if (sf.counted)
        line += ", " + format_double("%.1f", sf.steps_per_ray) + " steps, " +
                format_double("%.1f", sf.tests_per_ray) + " tests per ray";
      if (sf.agreement >= 0) {
        line += ", agreement " + format_double("%.6f", sf.agreement);
        if (sf.disagreements_on_surface > 0)
          line += " (" + std::to_string(sf.disagreements_on_surface) + " of its " +
                  std::to_string(sf.disagreements) +
                  " differences start on a surface: rounding decides them)";
      }
      say(line);
      if (o.packet_tile > 0 && (sr.names[s] == "primary" || sr.names[s] == "shadow")) {
        measure_packets(*acc, sr.names[s], rays, hits, o,
                        ref && ref->ok && ref->acc ? ref : nullptr, !ref, sf);
        line = "    " + sf.set + " packets of " + std::to_string(sf.packet_rays) + ": " +
               format_double("%.3g", sf.packet_mrays_median) + " Mrays/s";
        if (ref && ref->ok)
          line +=
              " (x" + format_double("%.2f", sf.packet_ratio_to_reference) + " reference packets)";
        line += ", x" + format_double("%.2f", sf.packet_speedup) + " its single-ray loop, " +
                std::to_string(sf.packet_mismatches) + " differ from single rays (" +
                std::to_string(sf.packet_ties) + " ties)";
        say(line);
      }
      if (hits_out) (*hits_out)[s] = std::move(hits);
      f.sets.push_back(std::move(sf));
    }
    if (render) {
      f.render = measure_render(*acc, *render, o);
      say(render_line(f.render, render->reference != nullptr));
    }
    f.peak_rss_bytes = peak_rss_since_reset();
    f.process_peak_rss_bytes = process_peak_rss_bytes();
    if (keep) *keep = std::move(acc);
  } catch (const std::exception& e) {
    f.error = name + ": " + e.what();
    f.peak_rss_bytes = peak_rss_since_reset();
    f.process_peak_rss_bytes = process_peak_rss_bytes();
    say("  " + f.error);
  }
  return f;
}

}  // namespace

std::vector<std::string> default_bench_accels() {
  std::vector<std::string> v;
  for (const auto& n : accelerator_names())
    if (n != "brute") v.push_back(n);
  return v;
}

bool BenchReport::any_failed() const {
  for (const auto& s : scenes) {
    if (!s.error.empty()) return true;
    for (const auto& a : s.structures)
      if (!a.error.empty()) return true;
  }
  return false;
}

// ---- the runner --------------------------------------------------------------------------

BenchReport run_bench(const Suite& suite, const BenchOptions& o) {
  if (o.reps < 1) throw ParamError("--reps " + std::to_string(o.reps) + " must be at least 1");
  check_threads(o.threads);
  if (o.width < 1 || o.height < 1 || o.width > 16384 || o.height > 16384)
    throw ParamError("--res must be between 1 and 16384 pixels per side");
  if (o.sets.empty()) throw ParamError("--sets is empty: give primary, shadow and/or diffuse");
  if (o.packet_tile < 0 || o.packet_tile > kMaxPacketTile)
    throw ParamError("--packet-tile " + std::to_string(o.packet_tile) +
                     " must be between 0 (no "
                     "packet column) and " +
                     std::to_string(kMaxPacketTile) + " pixels");
  for (const auto& s : o.sets) parse_ray_set(s);  // ParamError naming the valid sets
  check_suite_names(suite);                       // names become ray file names in --rays-dir
  const auto names = accelerator_names();
  auto registered = [&](const std::string& n) {
    return std::find(names.begin(), names.end(), n) != names.end();
  };
  std::vector<std::string> accels = o.accels.empty() ? default_bench_accels() : o.accels;
  for (const auto& a : accels) make_accelerator(a);  // ParamError naming the valid choices
  std::string ref_name = o.reference;
  if (ref_name.empty())
    ref_name = registered("embree") ? "embree" : (registered("bvh") ? "bvh" : "brute");
  make_accelerator(ref_name);

  const int threads = effective_threads(o.threads);
  tbb::global_control gc(tbb::global_control::max_allowed_parallelism, size_t(threads));
  auto say = [&](const std::string& s) {
    if (o.progress) o.progress(s);
  };

  BenchReport rep;
  rep.suite = suite.path;
  rep.date = now_iso8601();
  rep.machine = cpu_model_name();
  rep.kdgrid_isa = kBuildIsa;
  rep.kdgrid_lanes = kTraversalLanes;
  rep.kdgrid_leaf_lanes = kWideLanes;
  rep.embree = embree_isa(o.params.embree_isa);
  rep.hardware_threads = int(std::thread::hardware_concurrency());
  rep.threads = threads;
  rep.reps = o.reps;
  rep.clock = o.cpu_clock ? "cpu" : "wall";
  rep.width = o.width;
  rep.height = o.height;
  rep.sets = o.sets;
  rep.packet_tile = o.packet_tile;
  const auto t_all = Clock::now();

  for (size_t si = 0; si < suite.scenes.size(); ++si) {
    const SuiteScene& entry = suite.scenes[si];
    SceneFigures sf;
    sf.name = entry.name;
    sf.file = entry.file;
    sf.camera = describe_camera(entry.camera);
    sf.reference = ref_name;
    const std::string tag = "[" + std::to_string(si + 1) + "/" +
                            std::to_string(suite.scenes.size()) + "] " + entry.name;
    if (!entry.error.empty()) {
      sf.error = entry.error;
      say(tag + ": skipped: " + sf.error);
      rep.scenes.push_back(std::move(sf));
      continue;
    }
    try {
      const auto t0 = Clock::now();
      const Scene scene = load_scene(entry.file);
      sf.load_seconds = seconds_since(t0);
      const Mesh& mesh = scene.mesh;
      sf.triangles = mesh.num_triangles();
      say(tag + ": " + std::to_string(sf.triangles) + " triangles, loaded in " +
          format_double("%.2f", sf.load_seconds) + " s");
      const Camera cam = entry.camera ? *entry.camera : canonical_camera(mesh.bounds());

      // The reference is built first: it makes the primary hits the secondary sets start
      // from, then is timed like every other structure on the shared sets.
      std::unique_ptr<Accelerator> ref_acc;
      Reference ref;
      SceneRays sr;
      {
        reset_peak_rss();
        auto acc = make_accelerator(ref_name);
        BuildParams p = o.params;
        p.threads = threads;
        acc->build(mesh, p);
        sr = make_scene_rays(sf, mesh, cam, *acc, o);
      }
      for (size_t s = 0; s < sr.names.size(); ++s) {
        sf.set_sizes.emplace_back(sr.names[s], sr.rays[s].size());
        sf.set_sources.emplace_back(sr.names[s], sr.sources[s]);
      }
      std::string sizes;
      for (const auto& [n, c] : sf.set_sizes) sizes += " " + n + " " + std::to_string(c);
      say("  rays:" + sizes);

      std::vector<std::vector<Hit>> ref_hits;
      std::vector<uint8_t> ref_image;
      RenderJob job;
      job.scene = &scene;
      job.camera = cam;
      job.reference_image = &ref_image;
      StructureFigures rf = measure(ref_name, mesh, sr, o, threads, nullptr, &ref_acc, &ref_hits,
                                    o.render ? &job : nullptr, say);
      ref.ok = rf.error.empty();
      ref.acc = ref_acc.get();
      if (ref.ok) {
        ref.hits = std::move(ref_hits);
        for (const auto& x : rf.sets) ref.mrays.push_back(x.mrays_median);
      }
      sf.structures.push_back(std::move(rf));
      job.reference = ref.ok ? ref.acc : nullptr;
      for (const auto& a : accels) {
        if (a == ref_name) continue;
        sf.structures.push_back(measure(a, mesh, sr, o, threads, &ref, nullptr, nullptr,
                                        o.render && ref.ok ? &job : nullptr, say));
      }
    } catch (const std::exception& e) {
      sf.error = e.what();
      say(tag + ": failed: " + sf.error);
    }
    rep.scenes.push_back(std::move(sf));
  }
  rep.seconds = seconds_since(t_all);
  return rep;
}

}  // namespace kdgrid
