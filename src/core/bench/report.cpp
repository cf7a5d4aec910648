// The benchmark's reports: JSON (every figure) and Markdown (the tables of docs/RESULTS.md).
#include <cstdio>
#include <sstream>

#include <nlohmann/json.hpp>

#include "bench/bench.h"
#include "util/format.h"

namespace kdgrid {

using nlohmann::json;

namespace {

/// One entry of "renders" (BenchOptions::render).
json render_json(const SceneFigures& s, const StructureFigures& a) {
  const RenderFigures& x = a.render;
  return {{"scene", s.name},
          {"accel", a.accel},
          {"reference", s.reference},
          {"rays",
           {{"primary", x.primary},
            {"shadow", x.shadow},
            {"reflection", x.reflection},
            {"refraction", x.refraction},
            {"total", x.rays()}}},
          {"seconds", x.seconds_median},
          {"seconds_reps", x.seconds_reps},
          {"mrays", x.mrays_median},
          {"ratio_to_reference", x.ratio_to_reference},
          {"reference_seconds", x.reference_seconds},
          {"pixels_differ", x.pixels_differ >= 0 ? json(x.pixels_differ) : json(nullptr)}};
}

}  // namespace

std::string bench_to_json(const BenchReport& r) {
  json j;
  j["meta"] = {
      {"suite", r.suite},
      {"date", r.date},
      {"machine", r.machine},
      {"simd",
       {{"kdgrid",
         {{"isa", r.kdgrid_isa},
          {"lanes", r.kdgrid_lanes},
          {"leaf_lanes", r.kdgrid_leaf_lanes},
          {"how",
           "the ISA the build targets (-march=native unless KDGRID_NATIVE=OFF); every "
           "structure traces one ray at a time outside the packet column, the hybrid's walk in "
           "vectors of this "
           "many lanes (three axes and padding), its leaves' triangles leaf_lanes at a "
           "time"}}},
        {"embree",
         {{"version", r.embree.version},
          {"isa", r.embree.isa},
          {"restricted_to", r.embree.config.empty() ? "native" : r.embree.config},
          {"native_packet", r.embree.native_packet},
          {"how",
           "rtcGetDeviceProperty RTC_DEVICE_PROPERTY_NATIVE_RAY16/8/4_SUPPORTED: the "
           "widest ray packet Embree's enabled ISA runs natively (16 = AVX-512, 8 = AVX "
           "or AVX2, 4 = SSE), or the ISA --embree-isa restricts it to (rtcNewDevice "
           "\"isa=\"; restricted_to); rtcIntersect1/rtcOccluded1 trace one ray at a time "
           "with those kernels"}}}}},
      {"hardware_threads", r.hardware_threads},
      {"threads", r.threads},
      {"reps", r.reps},
      {"clock", r.clock},
      {"width", r.width},
      {"height", r.height},
      {"sets", r.sets},
      {"packet_tile", r.packet_tile},
      {"packet_note",
       "results[].packet: primary rays in tiles of packet_tile x packet_tile pixels, one "
       "packet a tile (shadow rays in runs of packet_tile^2), through each structure's "
       "packet query (packet_width: the rays its walk holds at once, 1 = a loop over "
       "single rays; Embree: rtcIntersect/rtcOccluded at its native packet with "
       "RTC_INTERSECT_CONTEXT_FLAG_COHERENT); ratio_to_reference pairs it with the "
       "reference's packet query per repetition, speedup_over_single_loop with the "
       "structure's own single-ray loop on the same packets; mismatches: rays whose "
       "packet answer is not bitwise the single-ray one (mismatched_ties: same t)"},
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
  j["renders"] = json::array();
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
      if (a.render.measured) j["renders"].push_back(render_json(s, a));
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
                  {"disagreements", x.disagreements},
                  {"disagreements_on_surface", x.disagreements_on_surface}};
        if (x.packet_rays > 0)
          e["packet"] = {{"rays_per_packet", x.packet_rays},
                         {"packet_width", x.packet_width},
                         {"mrays", x.packet_mrays_median},
                         {"mrays_reps", x.packet_mrays_reps},
                         {"ratio_to_reference", x.packet_ratio_to_reference},
                         {"reference_mrays", x.packet_reference_mrays},
                         {"single_loop_mrays", x.packet_single_mrays},
                         {"speedup_over_single_loop", x.packet_speedup},
                         {"mismatches", x.packet_mismatches},
                         {"mismatched_ties", x.packet_ties}};
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

/// The structure's name, with the scene flags and build quality for Embree's configurations
/// (from BuildStats::extra), so every table row says which Embree it is.
std::string structure_label(const StructureFigures& a) {
  std::string flags, quality;
  for (const auto& [k, v] : a.stats.extra) {
    if (k == "flags") flags = v;
    if (k == "quality") quality = v;
  }
  if (!is_embree(a.accel) || flags.empty()) return a.accel;
  return a.accel + " (" + flags + " flags, " + quality + " quality)";
}

std::string simd_line(const BenchReport& r) {
  return "SIMD: kdgrid built for " + r.kdgrid_isa +
         " (one ray at a time outside the packet tables, the hybrid's walk in " +
         std::to_string(r.kdgrid_lanes) + "-lane vectors, its leaves' triangles " +
         std::to_string(r.kdgrid_leaf_lanes) + " at a time); Embree " + r.embree.version +
         " with its " + r.embree.isa + " kernels" +
         (r.embree.config.empty() ? ""
                                  : " (restricted with --embree-isa " + r.embree.config + ")") +
         " (native ray packets of " + std::to_string(r.embree.native_packet) +
         "; rtcIntersect1/rtcOccluded1 one ray at a time).";
}

const SetFigures* find_set(const StructureFigures& a, const std::string& set) {
  for (const auto& x : a.sets)
    if (x.set == set) return &x;
  return nullptr;
}

/// The render column's table, when it was run.
void render_markdown(const BenchReport& r, std::ostringstream& md) {
  bool any = false;
  for (const auto& s : r.scenes)
    for (const auto& a : s.structures) any = any || a.render.measured;
  if (!any) return;
  md << "\n### The whole render: one Whitted pass (primary, shadow, reflection and refraction "
        "rays; packets where the renderer uses them) of "
     << r.width << "x" << r.height
     << " pixel centres, each pass timed just after the reference's\n\n"
     << "| scene | structure | rays a pass | pass s | Mrays/s | ratio to reference | pixels "
        "differ |\n|---|---|---:|---:|---:|---:|---:|\n";
  for (const auto& s : r.scenes)
    for (const auto& a : s.structures) {
      if (!a.render.measured) continue;
      const RenderFigures& x = a.render;
      md << "| " << s.name << " | " << structure_label(a)
         << (a.accel == s.reference ? " (ref)" : "") << " | " << x.rays() << " | "
         << format_double("%.3f", x.seconds_median) << " | "
         << format_double("%.3g", x.mrays_median) << " | "
         << format_double("%.2f", x.ratio_to_reference) << " | " << x.pixels_differ << " |\n";
    }
}

}  // namespace

std::string bench_to_markdown(const BenchReport& r) {
  std::ostringstream md;
  md << "Machine: " << r.machine << ", " << r.threads << " thread(s) of " << r.hardware_threads
     << "; " << r.width << "x" << r.height << " primary rays; median of " << r.reps
     << " repetitions" << (r.clock == "cpu" ? " timed by the tracing threads' CPU clocks" : "")
     << "; " << r.date << "; whole run " << format_double("%.0f", r.seconds) << " s.\n"
     << simd_line(r) << "\n\n";

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
      md << "| " << s.name << " | " << structure_label(a)
         << (a.accel == s.reference ? " (ref)" : "") << " |";
      for (const auto& set : r.sets) {
        const SetFigures* x = find_set(a, set);
        if (!x) {
          md << " - | - |";
          continue;
        }
        md << " " << format_double("%.3g", x->mrays_median) << " ("
           << format_double("%.3g", x->mrays_min) << "-" << format_double("%.3g", x->mrays_max)
           << ") | " << format_double("%.2f", x->ratio_to_reference) << " |";
      }
      md << "\n";
    }
  }

  bool packets = false;
  for (const auto& s : r.scenes)
    for (const auto& a : s.structures)
      for (const auto& x : a.sets) packets = packets || x.packet_rays > 0;
  if (packets) {
    md << "\n### Packets: " << r.packet_tile << "x" << r.packet_tile
       << " tiles of primary rays (shadow rays in runs of " << r.packet_tile * r.packet_tile
       << "), each structure's packet query against the reference's\n\n"
       << "Packet width: the rays a structure's packet walk holds at once (1: its packet "
          "query loops over single rays). Embree: rtcIntersect"
       << r.embree.native_packet << "/rtcOccluded" << r.embree.native_packet
       << " with the coherent context flag. Speedup: over the same structure's single-ray loop on "
          "the same packets, timed after it in each repetition (median of the ratios). Differ: "
          "rays whose packet answer is not bitwise the single-ray one (ties: the same t, "
          "another triangle).\n\n";
    md << "| scene | structure | set | packet width | packet Mrays/s | ratio to reference "
          "packets | speedup over its single rays | differ (ties) |\n";
    md << "|---|---|---|---:|---:|---:|---:|---:|\n";
    for (const auto& s : r.scenes)
      for (const auto& a : s.structures)
        for (const auto& x : a.sets) {
          if (x.packet_rays == 0) continue;
          md << "| " << s.name << " | " << structure_label(a)
             << (a.accel == s.reference ? " (ref)" : "") << " | " << x.set << " | "
             << x.packet_width << " | " << format_double("%.3g", x.packet_mrays_median) << " | "
             << format_double("%.2f", x.packet_ratio_to_reference) << " | "
             << format_double("%.2f", x.packet_speedup) << " | " << x.packet_mismatches << " ("
             << x.packet_ties << ") |\n";
        }
  }

  render_markdown(r, md);

  md << "\n### Per ray: traversal steps, leaves visited, triangle tests; agreement with the "
        "reference\n\n";
  md << "| scene | structure | set | rays | steps | leaves | tests | agreement |\n";
  md << "|---|---|---|---:|---:|---:|---:|---:|\n";
  for (const auto& s : r.scenes) {
    for (const auto& a : s.structures) {
      for (const auto& x : a.sets) {
        md << "| " << s.name << " | " << structure_label(a) << " | " << x.set << " | " << x.rays
           << " | ";
        if (x.counted)
          md << format_double("%.1f", x.steps_per_ray) << " | "
             << format_double("%.1f", x.leaves_per_ray) << " | "
             << format_double("%.1f", x.tests_per_ray) << " | ";
        else
          md << "n/a | n/a | n/a | ";
        md << (x.agreement >= 0 ? format_double("%.6f", x.agreement) : std::string("reference"))
           << " |\n";
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
      md << "| " << s.name << " | " << s.triangles << " | " << structure_label(a) << " | "
         << (a.error.empty() ? format_double("%.3f", a.build_seconds) : std::string("failed"))
         << " | " << format_double("%.2f", a.build_mtris_per_s) << " | " << mib(a.bytes) << " | "
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
