// The extreme-ray suite's double-precision reference on degenerate and thin triangles: brute
// force with the float watertight test must never be judged an unambiguous disagreement, at
// `kdgrid check`'s default ray count (400 per family) and seed. A float test may see a sliver
// where exact arithmetic sees a zero-area triangle (its corners are sheared and scaled with
// rounding), and its t on a thin triangle seen obliquely is uncertain by its barycentrics'
// error times the triangle's depth span: the reference counts both as loose hits.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>

#include "accel/accelerator.h"
#include "bench/check.h"

namespace kdgrid {
namespace {

/// The case's rays of the named families only (no random rays, so judge_accelerator adds no
/// rays in the structure's planes).
CheckCase only_families(const CheckCase& c, const std::vector<std::string>& families) {
  CheckCase out;
  out.name = c.name;
  out.mesh = c.mesh;
  const auto& names = check_ray_families();
  for (size_t i = 0; i < c.rays.size(); ++i)
    if (std::find(families.begin(), families.end(), names[c.family[i]]) != families.end()) {
      out.rays.push_back(c.rays[i]);
      out.family.push_back(c.family[i]);
    }
  return out;
}

TEST(CheckReference, BruteForceAgreesOnDegenerateAndThinTrianglesAtTheDefaultRayCount) {
  const std::vector<CheckCase> cases = make_check_cases(400, 1);
  for (const CheckCase& c : cases) {
    if (c.name != "degenerate" && c.name != "thin-triangles") continue;
    SCOPED_TRACE(c.name);
    const CheckCase sub = only_families(c, {"on-surface", "grazing-edge", "edge-aimed"});
    ASSERT_GT(sub.rays.size(), 1000u);
    const auto brute = build_accelerator("brute", c.mesh, BuildParams{});
    const CheckResult r = judge_accelerator(*brute, sub);
    EXPECT_EQ(r.disagree, 0u) << (r.examples.empty() ? "" : r.examples.front());
    EXPECT_EQ(r.any_disagree, 0u);
    // The loose hits must not make everything ambiguous.
    EXPECT_GT(r.agree, r.rays / 4) << r.ambiguous << " ambiguous";
  }
}

}  // namespace
}  // namespace kdgrid
