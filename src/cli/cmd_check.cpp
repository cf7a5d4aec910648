// `kdgrid check`: the extreme-ray suite. Every structure against a double-precision brute
// force on scenes and rays where floating point breaks first; exits non-zero on any hang,
// crash or unambiguous disagreement.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <mutex>
#include <thread>

#include <tbb/global_control.h>
#include <nlohmann/json.hpp>

#include "accel/accelerator.h"
#include "bench/check.h"
#include "cli/commands.h"
#include "cli/common.h"
#include "util/atomic_file.h"
#include "util/error.h"

namespace kdgrid {

/// An acne study row in the JSON report: every field under its own name.
NLOHMANN_DEFINE_TYPE_NON_INTRUSIVE(AcneResult, scale, translation, rays, robust_self_hits,
                                   epsilon_self_hits, epsilon, robust_seconds, epsilon_seconds)

}  // namespace kdgrid

namespace kdgrid::cli {

namespace {

/// Aborts the process with a message if a unit of work runs past its deadline: a hang in a
/// traversal must fail CI with a name, not time it out silently.
class Watchdog {
 public:
  explicit Watchdog(double seconds) : seconds_(seconds), thread_([this] { run(); }) {}
  ~Watchdog() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }
  void arm(const std::string& what) {
    std::lock_guard<std::mutex> lock(mu_);
    what_ = what;
    deadline_ = std::chrono::steady_clock::now() +
                std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                    std::chrono::duration<double>(seconds_));
    armed_ = true;
  }
  void disarm() {
    std::lock_guard<std::mutex> lock(mu_);
    armed_ = false;
  }

 private:
  void run() {
    std::unique_lock<std::mutex> lock(mu_);
    while (!stop_) {
      cv_.wait_for(lock, std::chrono::milliseconds(200));
      if (armed_ && std::chrono::steady_clock::now() > deadline_) {
        std::fprintf(stderr, "kdgrid check: HANG: %s did not finish within %.0f s\n", what_.c_str(),
                     seconds_);
        std::fflush(stderr);
        std::_Exit(3);
      }
    }
  }
  double seconds_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false, armed_ = false;
  std::string what_;
  std::chrono::steady_clock::time_point deadline_;
  std::thread thread_;
};

}  // namespace

void add_check_command(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "check", "Extreme-ray suite: every structure vs a double-precision brute force");
  struct Opts {
    std::string accel;
    int rays = 400;
    uint64_t seed = 1;
    int threads = 0;
    double timeout = 300;
    std::string json;
    bool acne = false;
    int acne_rays = 20000;
    std::string triangle_test = "watertight";
  };
  auto o = std::make_shared<Opts>();
  cmd->add_option("--accel", o->accel, "Comma-separated structures (default: all but brute)");
  cmd->add_option("--rays", o->rays, "Rays per family per scene")->capture_default_str();
  cmd->add_option("--seed", o->seed, "Seed of scenes and rays")->capture_default_str();
  add_threads_option(cmd, o->threads);
  cmd->add_option("--timeout", o->timeout, "Seconds one structure may take on one scene")
      ->capture_default_str();
  cmd->add_option("--json", o->json, "Write results as JSON");
  cmd->add_option("--triangle-test", o->triangle_test, "watertight or moller")
      ->capture_default_str();
  cmd->add_flag("--acne", o->acne, "Also run the self-intersection (acne) study");
  cmd->add_option("--acne-rays", o->acne_rays, "Rays per scale in the acne study")
      ->capture_default_str();
  cmd->callback([o] {
    if (o->rays < 1 || o->rays > 1000000)
      throw ParamError("--rays " + std::to_string(o->rays) + " must be between 1 and 1000000");
    if (!(o->timeout > 0)) throw ParamError("--timeout must be a positive number of seconds");
    check_threads(o->threads);
    if (o->acne_rays < 1 || o->acne_rays > 10000000)
      throw ParamError("--acne-rays " + std::to_string(o->acne_rays) +
                       " must be between 1 and 10000000 (rays per scale of the acne study)");
    if (!o->json.empty()) check_output_path(o->json, "--json", {".json"});
    std::vector<std::string> accels = split_list(o->accel);
    if (accels.empty())
      for (const auto& n : accelerator_names())
        if (n != "brute") accels.push_back(n);
    for (const auto& a : accels) make_accelerator(a);  // validate names before the long run
    BuildParams params;
    params.triangle_test = parse_triangle_test(o->triangle_test);
    tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                                effective_threads(o->threads));
    Watchdog watchdog(o->timeout);
    const auto cases = make_check_cases(o->rays, o->seed);
    nlohmann::json out = nlohmann::json::array();
    uint64_t failures = 0;
    std::printf("%-13s %-22s %8s %8s %9s %8s %8s %7s %7s\n", "structure", "scene", "rays", "agree",
                "ambiguous", "DISAGREE", "any-dis", "steps", "sec");
    for (const auto& c : cases) {
      for (const auto& a : accels) {
        watchdog.arm(a + " on " + c.name);
        const CheckResult r = run_check(a, c, params);
        watchdog.disarm();
        std::printf("%-13s %-22s %8llu %8llu %9llu %8llu %8llu %7llu %7.2f%s\n", a.c_str(),
                    c.name.c_str(), (unsigned long long)r.rays, (unsigned long long)r.agree,
                    (unsigned long long)r.ambiguous, (unsigned long long)r.disagree,
                    (unsigned long long)r.any_disagree, (unsigned long long)r.max_steps, r.seconds,
                    r.error.empty() ? "" : "  ERROR");
        if (!r.error.empty()) std::printf("    error: %s\n", r.error.c_str());
        for (const auto& e : r.examples) std::printf("    %s\n", e.c_str());
        std::fflush(stdout);
        // Embree is the external reference: its non-watertight test may accept slivers the
        // double-precision reference rejects; reported, but only a crash counts against it.
        const bool exact = !is_embree(a);
        const bool failed = !r.error.empty() || (exact && (r.disagree > 0 || r.any_disagree > 0));
        failures += failed;
        nlohmann::json j = {{"structure", a},
                            {"scene", c.name},
                            {"rays", r.rays},
                            {"agree", r.agree},
                            {"ambiguous", r.ambiguous},
                            {"disagree", r.disagree},
                            {"any_disagree", r.any_disagree},
                            {"max_steps", r.max_steps},
                            {"seconds", r.seconds},
                            {"error", r.error},
                            {"examples", r.examples}};
        for (size_t f = 0; f < r.disagree_by_family.size(); ++f)
          j["disagree_by_family"][check_ray_families()[f]] = r.disagree_by_family[f];
        out.push_back(j);
      }
    }
    nlohmann::json acne = nlohmann::json::array();
    if (o->acne) {
      std::printf(
          "\nself-intersection: rays leaving a surface that re-hit their own triangle,\n"
          "and the speed of those rays with each policy (%s, 1 thread, median of %d)\n",
          kAcneSceneDescription, kAcneTimingReps);
      const auto results = run_acne_study(o->acne_rays, o->seed);
      const float eps = results.empty() ? 1e-4f : results.front().epsilon;
      char eps_head[32];
      std::snprintf(eps_head, sizeof eps_head, "fixed eps %g", eps);
      std::printf("%10s %12s %8s %14s %16s %14s %16s\n", "scale", "translation", "rays",
                  "robust offset", eps_head, "robust Mrays/s", "eps Mrays/s");
      auto mrays = [](uint64_t n, double s) { return s > 0 ? double(n) / s * 1e-6 : 0.0; };
      uint64_t rays = 0, robust_hits = 0, eps_hits = 0;
      double robust_s = 0, eps_s = 0;
      for (const auto& r : results) {
        std::printf("%10g %12g %8llu %14llu %16llu %14.2f %16.2f\n", r.scale, r.translation,
                    (unsigned long long)r.rays, (unsigned long long)r.robust_self_hits,
                    (unsigned long long)r.epsilon_self_hits, mrays(r.rays, r.robust_seconds),
                    mrays(r.rays, r.epsilon_seconds));
        acne.push_back(r);
        if (r.robust_self_hits > 0) ++failures;
        rays += r.rays;
        robust_hits += r.robust_self_hits;
        eps_hits += r.epsilon_self_hits;
        robust_s += r.robust_seconds;
        eps_s += r.epsilon_seconds;
      }
      std::printf("%10s %12s %8llu %14llu %16llu %14.2f %16.2f\n", "all", "",
                  (unsigned long long)rays, (unsigned long long)robust_hits,
                  (unsigned long long)eps_hits, mrays(rays, robust_s), mrays(rays, eps_s));
    }
    if (!o->json.empty()) {
      const nlohmann::json meta = {{"rays_per_family", o->rays},
                                   {"seed", o->seed},
                                   {"threads", effective_threads(o->threads)},
                                   {"triangle_test", o->triangle_test},
                                   {"acne_rays_per_scale", o->acne ? o->acne_rays : 0},
                                   {"acne_scene", kAcneSceneDescription},
                                   {"acne_threads", 1},
                                   {"acne_timing_reps", kAcneTimingReps}};
      write_file_atomically(
          o->json, nlohmann::json{{"meta", meta}, {"check", out}, {"acne", acne}}.dump(2) + "\n");
    }
    if (failures) {
      std::printf("\ncheck: %llu failing structure x scene results (see above)\n",
                  (unsigned long long)failures);
      throw Error("the extreme-ray suite found unambiguous disagreements, errors or acne");
    }
    std::printf("\ncheck: no hangs, crashes or unambiguous disagreements\n");
  });
}

}  // namespace kdgrid::cli
