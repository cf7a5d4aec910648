// `kdgrid bench`: every structure side by side on the same rays, against Embree
// (docs/RAYSETS.md). Progress goes to stderr, the Markdown tables to stdout, and --json/--md
// write the reports. A failed scene or structure is reported and the others still run; the
// exit code is non-zero at the end if anything failed.
#include <algorithm>
#include <cstdio>
#include <filesystem>

#include "bench/bench.h"
#include "bench/suite.h"
#include "cli/commands.h"
#include "cli/common.h"
#include "util/atomic_file.h"
#include "util/error.h"

namespace kdgrid::cli {

namespace {

void write_text(const std::string& path, const std::string& text) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path p(path);
  if (p.has_parent_path()) fs::create_directories(p.parent_path(), ec);
  write_file_atomically(path, text);
}

struct BenchArgs {
  std::vector<std::string> suites;
  std::vector<std::string> scenes;
  std::string only;
  std::string sets = "primary,shadow,diffuse";
  int threads = 0;
  int reps = 5;
  std::string res = "1024";
  std::string json, md, rays_dir, reference;
  bool quiet = false;
  bool no_interleave = false, render = false;
  std::string clock = "wall";
  int packet_tile = 8;
  AccelOptions accel;
};

}  // namespace

void add_bench_command(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "bench", "Benchmark every structure on the same rays against Embree (docs/RAYSETS.md)");
  auto a = std::make_shared<BenchArgs>();
  cmd->add_option("scenes", a->scenes, "Scene files to run instead of a suite (canonical camera)");
  cmd->add_option("--suite", a->suites,
                  "Suite JSON (repeatable); default $KDGRID_SCENES/suite.json, "
                  "../shared/scenes/suite.json, else assets/suite.json");
  a->accel.add_to(cmd, "");
  cmd->get_option("--accel")->description(
      "Comma-separated structures; default: every registered one except brute");
  cmd->add_option("--only", a->only,
                  "Run only these scenes of the suite, by name (comma-separated), e.g. sponza");
  cmd->add_option("--sets", a->sets, "Ray sets: primary, shadow, diffuse (comma-separated)")
      ->capture_default_str();
  add_threads_option(cmd, a->threads);
  cmd->add_option("--reps", a->reps, "Timed repetitions per set; the median is reported")
      ->capture_default_str();
  cmd->add_option("--res", a->res, "Primary rays: W or WxH pixels (docs/RAYSETS.md: 1024)")
      ->capture_default_str();
  cmd->add_option("--json", a->json, "Write the results as JSON here");
  cmd->add_option("--md", a->md, "Write the results as Markdown tables here");
  cmd->add_option("--rays-dir", a->rays_dir,
                  "Read DIR/<scene>.<set>.rays when present, else write the generated sets there");
  cmd->add_option("--reference", a->reference,
                  "Structure the ratios and agreement refer to (default embree)");
  cmd->add_flag("--quiet,-q", a->quiet, "No progress on stderr, no tables on stdout");
  cmd->add_option(
         "--clock", a->clock,
         "wall, or cpu: time tracing by the threads' CPU time (divided by the thread count), "
         "so that other processes on a shared machine do not count")
      ->check(CLI::IsMember({"wall", "cpu"}))
      ->capture_default_str();
  cmd->add_option("--packet-tile", a->packet_tile,
                  "Packet column: primary rays also traced through each structure's packet "
                  "query in tiles of this many pixels square (shadow rays in runs of its square), "
                  "beside Embree's rtcIntersect16/8; 0 = none")
      ->capture_default_str();
  cmd->add_flag("--render", a->render,
                "Render column: the whole Whitted render (one pass of pixel centres at --res: "
                "primary, shadow, reflection and refraction rays, packets where the renderer "
                "uses them) through each structure, each pass timed just after the reference's");
  cmd->add_flag("--no-interleave", a->no_interleave,
                "Time the reference once per scene instead of before every repetition "
                "(halves the tracing time; ratios then suffer from changing machine load)");
  cmd->callback([a] {
    BenchOptions o;
    o.accels = split_list(a->accel.accel);
    o.sets = split_list(a->sets);
    o.threads = a->threads;
    o.reps = a->reps;
    parse_resolution(a->res, o.width, o.height);
    o.rays_dir = a->rays_dir;
    o.reference = a->reference;
    o.interleave_reference = !a->no_interleave;
    o.cpu_clock = a->clock == "cpu";
    o.packet_tile = a->packet_tile;
    o.render = a->render;
    o.params = a->accel.resolve();
    if (!a->quiet)
      o.progress = [](const std::string& s) { std::fprintf(stderr, "%s\n", s.c_str()); };

    // Gather the scenes: explicit files, else the given suites, else the default suite. A
    // suite that cannot be parsed counts as a failed scene so the others still run.
    Suite suite;
    std::vector<std::string> suite_errors;
    for (const auto& f : a->scenes)
      for (auto& s : single_scene_suite(f).scenes) suite.scenes.push_back(s);
    std::vector<std::string> files = a->suites;
    if (files.empty() && a->scenes.empty()) {
      const std::string def = default_suite_path();
      if (def.empty())
        throw LoadError(
            "no suite given and no default found: pass --suite FILE.json or scene "
            "files, or set KDGRID_SCENES to a folder with suite.json");
      files.push_back(def);
    }
    for (const auto& f : files) {
      try {
        Suite s = load_suite(f);
        suite.path += (suite.path.empty() ? "" : ",") + f;
        for (auto& e : s.scenes) suite.scenes.push_back(e);
      } catch (const Error& e) {
        SuiteScene bad;
        bad.name = std::filesystem::path(f).stem().string();
        bad.file = f;
        bad.error = e.what();
        suite.scenes.push_back(bad);
        suite_errors.push_back(e.what());
      }
    }
    if (!a->only.empty()) {
      // Keep the named scenes, in the suite's order; a name the suite lacks is an error that
      // lists the names it has.
      const std::vector<std::string> wanted = split_list(a->only);
      std::string names;
      for (const auto& s : suite.scenes) names += (names.empty() ? "" : ", ") + s.name;
      if (names.empty()) names = "none";
      if (wanted.empty())
        throw ParamError(
            "--only '" + a->only +
            "' names no scene; give suite scene names, e.g. --only sponza (the suite's: " + names +
            ")");
      for (const auto& w : wanted)
        if (std::none_of(suite.scenes.begin(), suite.scenes.end(),
                         [&](const SuiteScene& s) { return s.name == w; }))
          throw ParamError("--only " + a->only + ": the suite has no scene named '" + w +
                           "'; its scenes: " + names);
      std::erase_if(suite.scenes, [&](const SuiteScene& s) {
        return std::find(wanted.begin(), wanted.end(), s.name) == wanted.end();
      });
    }
    if (o.progress) {
      for (const auto& e : suite_errors) o.progress("suite error: " + e);
      o.progress("bench: " + std::to_string(suite.scenes.size()) + " scene(s), suite " +
                 (suite.path.empty() ? std::string("(command line)") : suite.path));
    }

    // Outputs are checked before the benchmark runs, not after it.
    for (const auto& [path, option, ext] :
         {std::tuple{a->json, "--json", ".json"}, std::tuple{a->md, "--md", ".md"}}) {
      if (path.empty()) continue;
      std::error_code ec;
      if (std::filesystem::path(path).has_parent_path())
        std::filesystem::create_directories(std::filesystem::path(path).parent_path(), ec);
      check_output_path(path, option, {ext});
    }
    const BenchReport rep = run_bench(suite, o);
    if (!a->json.empty()) write_text(a->json, bench_to_json(rep));
    if (!a->md.empty()) write_text(a->md, bench_to_markdown(rep));
    if (!a->quiet) std::printf("%s", bench_to_markdown(rep).c_str());
    if (rep.any_failed()) {
      int n = 0;
      std::string first;
      for (const auto& s : rep.scenes) {
        if (!s.error.empty() && n++ == 0) first = s.name + ": " + s.error;
        for (const auto& x : s.structures)
          if (!x.error.empty() && n++ == 0) first = s.name + ": " + x.error;
      }
      throw Error(std::to_string(n) +
                  " scene(s)/structure(s) failed (reports written); first: " + first);
    }
  });
}

}  // namespace kdgrid::cli
