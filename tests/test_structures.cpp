// The checks every acceleration structure must pass, written once and run for each name the
// factory knows (accelerator_names()): agreement with brute force on the procedural meshes,
// the Möller-Trumbore variant against brute-force Möller, counted and traced traversal against
// the fast path, and registration in the factory. The extreme-ray families are in
// test_extreme_rays.cpp; what is particular to one structure stays in its own test_<name>.cpp.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "accel/accelerator.h"
#include "comparator_meshes.h"
#include "test_util.h"

namespace kdgrid {
namespace {

using test::count_disagreements;

/// The names accepted by make_accelerator except those in `skip`.
std::vector<std::string> names_except(const std::vector<std::string>& skip) {
  std::vector<std::string> out;
  for (const auto& n : accelerator_names())
    if (std::find(skip.begin(), skip.end(), n) == skip.end()) out.push_back(n);
  return out;
}

/// kdgrid's own structures, checked bit for bit against brute force with the same triangle
/// test: brute force is the reference itself, and Embree's own triangle test (every one of its
/// configurations) is compared within a tolerance in test_embree.cpp.
std::vector<std::string> own_structures() {
  std::vector<std::string> out;
  for (const auto& n : names_except({"brute"}))
    if (!is_embree(n)) out.push_back(n);
  return out;
}

/// Instance names are the structure names ("Structures/grid", "Structures/embree_robust").
std::string structure_name(const ::testing::TestParamInfo<std::string>& info) {
  return test::test_name(info.param);
}

class Structures : public ::testing::TestWithParam<std::string> {};
class TracedStructures : public ::testing::TestWithParam<std::string> {};
class Factory : public ::testing::TestWithParam<std::string> {};

TEST_P(Structures, AgreesWithBruteForceOnProceduralMeshes) {
  for (const auto& [name, mesh] : test::test_meshes()) {
    SCOPED_TRACE(name);
    auto acc = make_accelerator(GetParam());
    const BuildStats st = acc->build(mesh, BuildParams{});
    EXPECT_GT(st.nodes, 1u);
    EXPECT_GT(st.references, 0u);
    const auto rays = test::random_rays(mesh, 20000, 17);
    int hits = 0;
    EXPECT_EQ(count_disagreements(mesh, *acc, rays, 5, &hits), 0);
    EXPECT_GT(hits, 2000) << "the ray set should hit the mesh often";
  }
}

TEST_P(Structures, MollerVariantAgreesWithBruteForceMoller) {
  auto acc = make_accelerator(GetParam());
  EXPECT_EQ(test::moller_mismatches(*acc), 0);
}

TEST_P(TracedStructures, CountedAndTracedTraversalMatchFastPath) {
  const Mesh mesh = test::random_soup(3000, 11);
  auto acc = make_accelerator(GetParam());
  acc->build(mesh, BuildParams{});
  const auto rays = test::random_rays(mesh, 5000, 3);
  EXPECT_EQ(test::check_counted_and_trace(*acc, rays), 0);
}

// The factory makes each name it lists, under that name, and the structure it makes builds
// and answers rays.
TEST_P(Factory, RegisteredInFactory) {
  auto acc = make_accelerator(GetParam());
  ASSERT_NE(acc, nullptr);
  EXPECT_EQ(acc->name(), GetParam());
  const Mesh mesh = test::sphere(16, 32);
  acc->build(mesh, BuildParams{});
  const Ray through{Vec3(-5, 0, 0), 0.0f, Vec3(1, 0, 0), kInf};
  Hit h;
  EXPECT_TRUE(acc->intersect(through, h));
  EXPECT_TRUE(acc->occluded(through));
  const Ray past{Vec3(-5, 3, 0), 0.0f, Vec3(1, 0, 0), kInf};
  EXPECT_FALSE(acc->intersect(past, h));
  EXPECT_FALSE(acc->occluded(past));
}

INSTANTIATE_TEST_SUITE_P(Structures, Structures, ::testing::ValuesIn(own_structures()),
                         structure_name);
INSTANTIATE_TEST_SUITE_P(Structures, TracedStructures,
                         ::testing::ValuesIn(names_except({"brute", "bvh"})), structure_name);
INSTANTIATE_TEST_SUITE_P(Structures, Factory, ::testing::ValuesIn(accelerator_names()),
                         structure_name);

}  // namespace
}  // namespace kdgrid
