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
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include <nlohmann/json.hpp>

#include "accel/guards.h"
#include "accel/triangle.h"
#include "bench/rayfile.h"
#include "bench/raysets.h"
#include "scene/load.h"
#include "util/error.h"
#include "util/format.h"

namespace kdgrid {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

/// Rays per unit of parallel work: large enough that scheduling costs nothing next to the
/// traversals, small enough that 2..64 threads stay balanced on a 1 M-ray set.
constexpr size_t kChunk = 1024;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

std::string now_iso8601() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  localtime_r(&t, &tm);
  char buf[64];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%S%z", &tm);
  return buf;
}

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
        rays = shadow_rays(mesh, primary, primary_hits, canonical_light_position(mesh.bounds()));
      } else if (kind == RaySetKind::Diffuse) {
        need_primary();
        rays = diffuse_rays(mesh, primary, primary_hits, /*seed=*/1);
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

StructureFigures measure(const std::string& name, const Mesh& mesh, const SceneRays& sr,
                         const BenchOptions& o, int threads, const Reference* ref,
                         std::unique_ptr<Accelerator>* keep,
                         std::vector<std::vector<Hit>>* hits_out,
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
        if (paired) ref_reps.push_back(mrays_of(trace_rays(*ref->acc, rays, any, &ref_scratch, o.cpu_clock)));
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
        sf.agreement =
            hit_agreement(mesh, rays, hits, ref->hits[s], any, o.tie_tolerance, &sf.disagreements);
      } else if (!ref) {
        sf.ratio_to_reference = 1.0;  // this is the reference
        sf.reference_mrays = sf.mrays_median;
      }
      std::string line = "    " + sf.set + ": " + format_double("%.3g", sf.mrays_median) + " Mrays/s";
      if (ref && ref->ok) line += " (x" + format_double("%.2f", sf.ratio_to_reference) + " reference)";
      if (sf.counted)
        line += ", " + format_double("%.1f", sf.steps_per_ray) + " steps, " + format_double("%.1f", sf.tests_per_ray) +
                " tests per ray";
      if (sf.agreement >= 0) line += ", agreement " + format_double("%.6f", sf.agreement);
      say(line);
      if (hits_out) (*hits_out)[s] = std::move(hits);
      f.sets.push_back(std::move(sf));
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

// ---- helpers -----------------------------------------------------------------------------

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

uint64_t process_peak_rss_bytes() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return uint64_t(ru.ru_maxrss) * 1024;  // Linux reports kilobytes
}

bool reset_peak_rss() {
#ifdef __GLIBC__
  // Hand freed heap pages back to the kernel first; otherwise what the previous structure
  // freed stays resident and is counted against the next one.
  malloc_trim(0);
#endif
  // Writing 5 to clear_refs resets VmHWM to the current RSS (Linux >= 4.0).
  std::ofstream f("/proc/self/clear_refs");
  if (!f) return false;
  f << "5";
  f.flush();
  return bool(f);
}

namespace {
/// A "Vm...:  N kB" field of /proc/self/status in bytes, 0 if absent.
uint64_t proc_status_bytes(const char* field) {
  std::ifstream f("/proc/self/status");
  std::string line;
  const std::string key = std::string(field) + ":";
  while (std::getline(f, line)) {
    if (line.rfind(key, 0) == 0) {
      std::istringstream ss(line.substr(key.size()));
      uint64_t kb = 0;
      if (ss >> kb) return kb * 1024;
    }
  }
  return 0;
}
}  // namespace

uint64_t peak_rss_since_reset() {
  const uint64_t b = proc_status_bytes("VmHWM");
  return b ? b : process_peak_rss_bytes();
}

uint64_t current_rss_bytes() {
  return proc_status_bytes("VmRSS");
}

std::string cpu_model_name() {
  std::ifstream f("/proc/cpuinfo");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("model name", 0) == 0) {
      const auto c = line.find(':');
      if (c != std::string::npos) {
        std::string m = line.substr(c + 1);
        m.erase(0, m.find_first_not_of(" \t"));
        return m;
      }
    }
  }
  return "unknown";
}

namespace {
double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}
}  // namespace

double trace_rays(const Accelerator& accel, const std::vector<Ray>& rays, bool any_hit,
                  std::vector<Hit>* out, bool cpu_clock) {
  if (out) out->resize(rays.size());
  Hit* dst = out ? out->data() : nullptr;
  std::atomic<int64_t> cpu_ns{0};
  const auto t0 = Clock::now();
  tbb::parallel_for(tbb::blocked_range<size_t>(0, rays.size(), kChunk),
                    [&](const tbb::blocked_range<size_t>& r) {
                      const double c0 = cpu_clock ? thread_cpu_seconds() : 0.0;
                      for (size_t i = r.begin(); i < r.end(); ++i) {
                        Hit h;
                        if (any_hit) {
                          if (accel.occluded(rays[i])) h = {0.0f, 0, 0, 0};
                        } else {
                          accel.intersect(rays[i], h);
                        }
                        if (dst) dst[i] = h;
                      }
                      if (cpu_clock)
                        cpu_ns.fetch_add(int64_t((thread_cpu_seconds() - c0) * 1e9), std::memory_order_relaxed);
                    });
  if (!cpu_clock) return seconds_since(t0);
  const size_t threads = tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  return double(cpu_ns.load()) * 1e-9 / double(std::max<size_t>(1, std::min(threads, rays.size() / kChunk + 1)));
}

RayCounters count_rays(const Accelerator& accel, const std::vector<Ray>& rays, bool any_hit) {
  return tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, rays.size(), kChunk), RayCounters{},
      [&](const tbb::blocked_range<size_t>& r, RayCounters c) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
          if (any_hit) {
            accel.occluded_counted(rays[i], c);
          } else {
            Hit h;
            accel.intersect_counted(rays[i], h, c);
          }
        }
        return c;
      },
      [](RayCounters a, const RayCounters& b) { return a += b; });
}

double hit_agreement(const Mesh& mesh, const std::vector<Ray>& rays, const std::vector<Hit>& hits,
                     const std::vector<Hit>& ref, bool any_hit, double tie_tolerance,
                     uint64_t* disagreements) {
  if (hits.size() != ref.size() || hits.size() != rays.size())
    throw Error("hit_agreement: " + std::to_string(hits.size()) + " hits, " +
                std::to_string(ref.size()) + " reference hits and " + std::to_string(rays.size()) +
                " rays: the sets differ");
  const uint64_t bad = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, rays.size(), kChunk), uint64_t(0),
      [&](const tbb::blocked_range<size_t>& r, uint64_t n) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
          const Hit& a = hits[i];
          const Hit& b = ref[i];
          if (a.valid() != b.valid()) {
            ++n;
            continue;
          }
          if (any_hit || !a.valid() || a.prim == b.prim) continue;
          // Different triangles: a tie if this triangle, intersected on its own, lies at the
          // reference's t (both sides of a shared edge, coplanar duplicates).
          float t = a.t;
          if (a.prim < mesh.num_triangles()) {
            const auto c = mesh.corners(a.prim);
            const auto rd = WatertightTest::prepare(rays[i]);
            float tt, u, v;
            if (WatertightTest::intersect(rd, c[0], c[1], c[2], rays[i].tmin, kInf, tt, u, v))
              t = tt;
          }
          const double diff = std::fabs(double(t) - double(b.t));
          if (!(diff <= tie_tolerance * std::max(std::fabs(double(t)), std::fabs(double(b.t)))))
            ++n;
        }
        return n;
      },
      [](uint64_t x, uint64_t y) { return x + y; });
  if (disagreements) *disagreements = bad;
  return rays.empty() ? 1.0 : 1.0 - double(bad) / double(rays.size());
}

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
  if (o.threads < 0) throw ParamError("--threads must be >= 0 (0 = all hardware threads)");
  if (o.width < 1 || o.height < 1 || o.width > 16384 || o.height > 16384)
    throw ParamError("--res must be between 1 and 16384 pixels per side");
  if (o.sets.empty()) throw ParamError("--sets is empty: give primary, shadow and/or diffuse");
  for (const auto& s : o.sets) parse_ray_set(s);  // ParamError naming the valid sets
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
  rep.hardware_threads = int(std::thread::hardware_concurrency());
  rep.threads = threads;
  rep.reps = o.reps;
  rep.clock = o.cpu_clock ? "cpu" : "wall";
  rep.width = o.width;
  rep.height = o.height;
  rep.sets = o.sets;
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
      StructureFigures rf =
          measure(ref_name, mesh, sr, o, threads, nullptr, &ref_acc, &ref_hits, say);
      ref.ok = rf.error.empty();
      ref.acc = ref_acc.get();
      if (ref.ok) {
        ref.hits = std::move(ref_hits);
        for (const auto& x : rf.sets) ref.mrays.push_back(x.mrays_median);
      }
      sf.structures.push_back(std::move(rf));
      for (const auto& a : accels) {
        if (a == ref_name) continue;
        sf.structures.push_back(measure(a, mesh, sr, o, threads, &ref, nullptr, nullptr, say));
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

// ---- reports -----------------------------------------------------------------------------

std::string bench_to_json(const BenchReport& r) {
  using nlohmann::json;
  json j;
  j["meta"] = {{"suite", r.suite},
               {"date", r.date},
               {"machine", r.machine},
               {"hardware_threads", r.hardware_threads},
               {"threads", r.threads},
               {"reps", r.reps},
               {"clock", r.clock},
               {"width", r.width},
               {"height", r.height},
               {"sets", r.sets},
               {"seconds", r.seconds},
               {"bytes_note",
                "bytes = BuildStats::bytes: the structure only, excluding the mesh (positions "
                "and indices) that every structure shares; bytes_by_part breaks it down"},
               {"peak_rss_note",
                "peak_rss_bytes: VmHWM reset (after malloc_trim) before the build, so it covers "
                "this structure's build and traces plus what was already resident "
                "(rss_before_bytes: mesh, ray sets, reference hits); rss_growth_bytes = the "
                "difference, what building and tracing this structure added at its peak; "
                "process_peak_rss_bytes: getrusage ru_maxrss, the process's lifetime peak"}};
  j["scenes"] = json::array();
  j["builds"] = json::array();
  j["results"] = json::array();
  j["errors"] = json::array();
  for (const auto& s : r.scenes) {
    json js = {{"scene", s.name},      {"file", s.file},           {"triangles", s.triangles},
               {"camera", s.camera},   {"reference", s.reference}, {"load_seconds", s.load_seconds},
               {"ok", s.error.empty()}};
    for (const auto& [n, c] : s.set_sizes) js["rays"][n] = c;
    for (const auto& [n, src] : s.set_sources) js["ray_sources"][n] = src;
    if (!s.error.empty()) {
      js["error"] = s.error;
      j["errors"].push_back({{"scene", s.name}, {"error", s.error}});
    }
    j["scenes"].push_back(js);
    for (const auto& a : s.structures) {
      json b = {{"scene", s.name},
                {"accel", a.accel},
                {"triangles", s.triangles},
                {"ok", a.error.empty()},
                {"build_seconds", a.build_seconds},
                {"build_mtris_per_s", a.build_mtris_per_s},
                {"bytes", a.bytes},
                {"bytes_per_triangle", a.bytes_per_triangle},
                {"peak_rss_bytes", a.peak_rss_bytes},
                {"rss_before_bytes", a.rss_before_bytes},
                {"rss_growth_bytes",
                 a.peak_rss_bytes > a.rss_before_bytes ? a.peak_rss_bytes - a.rss_before_bytes : 0},
                {"process_peak_rss_bytes", a.process_peak_rss_bytes},
                {"nodes", a.stats.nodes},
                {"leaves", a.stats.leaves},
                {"empty_leaves", a.stats.empty_leaves},
                {"references", a.stats.references},
                {"max_depth", a.stats.max_depth},
                {"sah_evaluations", a.stats.sah_evaluations},
                {"builder_seconds", a.stats.seconds}};
      b["bytes_by_part"] = json::object();
      for (const auto& [k, v] : a.stats.bytes_by_part) b["bytes_by_part"][k] = v;
      b["extra"] = json::object();
      for (const auto& [k, v] : a.stats.extra) b["extra"][k] = v;
      if (!a.error.empty()) {
        b["error"] = a.error;
        j["errors"].push_back({{"scene", s.name}, {"accel", a.accel}, {"error", a.error}});
      }
      j["builds"].push_back(b);
      for (const auto& x : a.sets) {
        json e = {{"scene", s.name},
                  {"accel", a.accel},
                  {"set", x.set},
                  {"reference", s.reference},
                  {"rays", x.rays},
                  {"hits", x.hits},
                  {"threads", r.threads},
                  {"reps", x.mrays_reps.size()},
                  {"mrays", x.mrays_median},
                  {"mrays_min", x.mrays_min},
                  {"mrays_max", x.mrays_max},
                  {"mrays_reps", x.mrays_reps},
                  {"ratio_to_reference", x.ratio_to_reference},
                  {"reference_mrays", x.reference_mrays},
                  {"ratio_method", x.paired ? "median of per-repetition ratios, reference "
                                              "timed just before each repetition"
                                            : "median / reference's median"},
                  {"counted", x.counted},
                  {"steps_per_ray", x.steps_per_ray},
                  {"leaves_per_ray", x.leaves_per_ray},
                  {"tests_per_ray", x.tests_per_ray},
                  {"lookups_per_ray", x.lookups_per_ray},
                  {"mailbox_skips_per_ray", x.mailbox_skips_per_ray},
                  {"agreement", x.agreement >= 0 ? json(x.agreement) : json(nullptr)},
                  {"disagreements", x.disagreements}};
        j["results"].push_back(e);
      }
    }
  }
  return j.dump(2) + "\n";
}

namespace {

std::string mib(uint64_t b) {
  return format_double("%.1f", double(b) / (1024.0 * 1024.0));
}

const SetFigures* find_set(const StructureFigures& a, const std::string& set) {
  for (const auto& x : a.sets)
    if (x.set == set) return &x;
  return nullptr;
}

}  // namespace

std::string bench_to_markdown(const BenchReport& r) {
  std::ostringstream md;
  md << "Machine: " << r.machine << ", " << r.threads << " thread(s) of " << r.hardware_threads
     << "; " << r.width << "x" << r.height << " primary rays; median of " << r.reps
     << " repetitions" << (r.clock == "cpu" ? " timed by the tracing threads' CPU clocks" : "")
     << "; " << r.date << "; whole run " << format_double("%.0f", r.seconds) << " s.\n\n";

  // Headline: ratio to the reference on each set, one row per scene x structure.
  md << "### Throughput relative to the reference (higher is better)\n\n";
  md << "| scene | structure |";
  for (const auto& s : r.sets) md << " " << s << " Mrays/s | " << s << " ratio |";
  md << "\n|---|---|";
  for (size_t i = 0; i < r.sets.size(); ++i) md << "---:|---:|";
  md << "\n";
  for (const auto& s : r.scenes) {
    if (!s.error.empty()) {
      md << "| " << s.name << " | **failed** |";
      for (size_t i = 0; i < r.sets.size(); ++i) md << " | |";
      md << "\n";
      continue;
    }
    for (const auto& a : s.structures) {
      md << "| " << s.name << " | " << a.accel << (a.accel == s.reference ? " (ref)" : "") << " |";
      for (const auto& set : r.sets) {
        const SetFigures* x = find_set(a, set);
        if (!x) {
          md << " - | - |";
          continue;
        }
        md << " " << format_double("%.3g", x->mrays_median) << " (" << format_double("%.3g", x->mrays_min) << "-"
           << format_double("%.3g", x->mrays_max) << ") | " << format_double("%.2f", x->ratio_to_reference) << " |";
      }
      md << "\n";
    }
  }

  md << "\n### Per ray: traversal steps, leaves visited, triangle tests; agreement with the "
        "reference\n\n";
  md << "| scene | structure | set | rays | steps | leaves | tests | agreement |\n";
  md << "|---|---|---|---:|---:|---:|---:|---:|\n";
  for (const auto& s : r.scenes) {
    for (const auto& a : s.structures) {
      for (const auto& x : a.sets) {
        md << "| " << s.name << " | " << a.accel << " | " << x.set << " | " << x.rays << " | ";
        if (x.counted)
          md << format_double("%.1f", x.steps_per_ray) << " | " << format_double("%.1f", x.leaves_per_ray) << " | "
             << format_double("%.1f", x.tests_per_ray) << " | ";
        else
          md << "n/a | n/a | n/a | ";
        md << (x.agreement >= 0 ? format_double("%.6f", x.agreement) : std::string("reference")) << " |\n";
      }
    }
  }

  md << "\n### Build and memory\n\n";
  md << "Bytes are the structure's own (BuildStats::bytes), excluding the shared mesh. Peak "
        "RSS is the process's resident high-water mark while that structure was built and "
        "traced (it includes the mesh and the ray sets); growth is that peak minus the "
        "resident memory just before the build.\n\n";
  md << "| scene | triangles | structure | build s | build Mtris/s | MiB | bytes/triangle | "
        "peak RSS MiB (growth) | parts |\n";
  md << "|---|---:|---|---:|---:|---:|---:|---:|---|\n";
  for (const auto& s : r.scenes) {
    for (const auto& a : s.structures) {
      std::string parts;
      for (const auto& [k, v] : a.stats.bytes_by_part)
        parts += (parts.empty() ? "" : ", ") + k + " " + mib(v);
      md << "| " << s.name << " | " << s.triangles << " | " << a.accel << " | "
         << (a.error.empty() ? format_double("%.3f", a.build_seconds) : std::string("failed")) << " | "
         << format_double("%.2f", a.build_mtris_per_s) << " | " << mib(a.bytes) << " | "
         << format_double("%.1f", a.bytes_per_triangle) << " | " << mib(a.peak_rss_bytes) << " ("
         << mib(a.peak_rss_bytes > a.rss_before_bytes ? a.peak_rss_bytes - a.rss_before_bytes : 0)
         << ") | " << parts << " |\n";
    }
  }

  bool errors = false;
  for (const auto& s : r.scenes) {
    if (!s.error.empty() || std::any_of(s.structures.begin(), s.structures.end(),
                                        [](const auto& a) { return !a.error.empty(); })) {
      if (!errors) md << "\n### Errors\n\n";
      errors = true;
      if (!s.error.empty()) md << "- " << s.name << ": " << s.error << "\n";
      for (const auto& a : s.structures)
        if (!a.error.empty()) md << "- " << s.name << ": " << a.error << "\n";
    }
  }
  return md.str();
}

}  // namespace kdgrid
