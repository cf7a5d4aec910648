// Helpers shared by the test files: locating the shared scenes and the project's assets, whether
// a sanitizer runs, and the messages of failed loads.
#pragma once

#include <gtest/gtest.h>

#include <cctype>
#include <exception>
#include <filesystem>
#include <functional>
#include <string>

#include "util/error.h"
#include "util/paths.h"

/// Expects `haystack` (a message) to contain `needle`, printing both when it does not.
#define EXPECT_CONTAINS(haystack, needle)                          \
  EXPECT_NE(std::string(haystack).find(needle), std::string::npos) \
      << "message: \"" << (haystack) << "\"\nshould contain: \"" << (needle) << "\""

#if defined(__has_feature)
#define KDGRID_TEST_HAS_FEATURE(x) __has_feature(x)
#else
#define KDGRID_TEST_HAS_FEATURE(x) 0
#endif

namespace kdgrid::test {

/// Whether this build runs under AddressSanitizer (gcc defines __SANITIZE_ADDRESS__, clang has
/// the feature), and under any sanitizer (scripts/sanitize.sh), which runs the same code many
/// times slower, and unevenly.
#if defined(__SANITIZE_ADDRESS__) || KDGRID_TEST_HAS_FEATURE(address_sanitizer)
inline constexpr bool kAddressSanitizer = true;
#else
inline constexpr bool kAddressSanitizer = false;
#endif
#if defined(__SANITIZE_THREAD__) || KDGRID_TEST_HAS_FEATURE(thread_sanitizer)
inline constexpr bool kSanitizerBuild = true;
#else
inline constexpr bool kSanitizerBuild = kAddressSanitizer;
#endif

/// Absolute path of a file under the shared scenes directory ($KDGRID_SCENES or
/// ../shared/scenes beside the checkout), or "" if it is not there.
inline std::string shared_scene(const std::string& rel) {
  const std::string dir = scenes_dir(KDGRID_SOURCE_DIR);
  if (dir.empty()) return "";
  const auto p = std::filesystem::path(dir) / rel;
  return std::filesystem::exists(p) ? p.string() : "";
}

/// A GoogleTest parameter name for a structure name: letters, digits and '_' only, so
/// "embree-robust" becomes "embree_robust".
inline std::string test_name(std::string s) {
  for (char& c : s)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return s;
}

inline std::string source_path(const std::string& rel) {
  return (std::filesystem::path(KDGRID_SOURCE_DIR) / rel).string();
}

/// Runs `f`, which must throw LoadError; returns its message (empty, with a failure, otherwise).
inline std::string load_error(const std::function<void()>& f) {
  try {
    f();
  } catch (const LoadError& e) {
    return e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "expected LoadError, got another exception: " << e.what();
    return "";
  }
  ADD_FAILURE() << "expected LoadError, but loading succeeded";
  return "";
}

/// A cell size at which the hybrid's build of the full dragon (dragon/dragon_vrip.ply, with
/// --hybrid-max-build-seconds 0) runs long enough for a test to cancel, supersede or quit it
/// seconds after it starts: 6 s and 2.2 GB on an idle Zen 5. Builds of the bunny at any cell size
/// that fits take about a second there, too short to interrupt by a scripted key or signal.
inline constexpr const char* kLongDragonBuildCell = "7e-5";

}  // namespace kdgrid::test

/// Declares `var` as the path of shared scene `rel`, or skips the test saying what is missing.
#define KDGRID_REQUIRE_SCENE(var, rel)                                                        \
  const std::string var = ::kdgrid::test::shared_scene(rel);                                  \
  if (var.empty())                                                                            \
  GTEST_SKIP() << "shared scene '" << (rel) << "' not found: set KDGRID_SCENES or place the " \
               << "scenes in ../shared/scenes beside the checkout"
