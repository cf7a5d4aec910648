// Differential agreement: every registered structure (except brute force, the reference)
// against brute force on real and procedural meshes, with >= 100,000 seeded rays per scene
// across the random, primary (camera), shadow and diffuse sets. New structures are picked up
// from accelerator_names() automatically.
#include <gtest/gtest.h>

#include <functional>
#include <map>
#include <memory>
#include <mutex>

#include "agreement.h"
#include "bench/raysets.h"
#include "scene/load.h"
#include "test_util.h"

namespace kdgrid {
namespace {

/// Rays per scene across all sets (the random set tops the camera-derived sets up to this).
constexpr size_t kRaysPerScene = 100000;
/// Camera resolution of the primary set; shadow and diffuse come from its hits.
constexpr int kCameraWidth = 240, kCameraHeight = 160;
/// Random rays are never fewer than this, whatever the camera sets hold.
constexpr size_t kMinRandomRays = 30000;

struct RaySet {
  std::string name;
  std::vector<Ray> rays;
  std::vector<Hit> reference;
};

struct Workload {
  Mesh mesh;
  std::vector<RaySet> sets;
  size_t total_rays() const {
    size_t n = 0;
    for (const auto& s : sets) n += s.rays.size();
    return n;
  }
};

struct SceneCase {
  std::string name;
  std::string shared_file;     ///< shared scene path, or empty for a procedural mesh
  std::function<Mesh()> make;  ///< procedural generator
};

const std::vector<SceneCase>& scene_cases() {
  static const std::vector<SceneCase> cases = {
      {"bunny", "bunny/bun_zipper.ply", nullptr},
      {"dragon", "dragon/dragon_vrip_res2.ply", nullptr},
      {"soup", "", [] { return test::triangle_soup(10000, 11); }},
      {"sphere", "", [] { return test::subdivided_sphere(5); }},
      {"coplanar_quads", "", [] { return test::coplanar_quads(48); }},
      {"thin", "", [] { return test::thin_triangles(5000, 12); }},
      {"duplicates", "", [] { return test::duplicated_triangles(4000, 13); }},
  };
  return cases;
}

/// Builds (once per process) the mesh, ray sets and brute references of a scene. Returns
/// null with `skip` set when a shared scene is missing.
const Workload* workload(const SceneCase& sc, std::string& skip) {
  static std::mutex mu;
  static std::map<std::string, std::unique_ptr<Workload>> cache;
  std::lock_guard<std::mutex> lock(mu);
  auto it = cache.find(sc.name);
  if (it != cache.end()) return it->second.get();

  auto w = std::make_unique<Workload>();
  if (!sc.shared_file.empty()) {
    const std::string path = test::shared_scene(sc.shared_file);
    if (path.empty()) {
      skip = "shared scene '" + sc.shared_file +
             "' not found: set KDGRID_SCENES or place the scenes in ../shared/scenes";
      return nullptr;
    }
    w->mesh = load_scene(path).mesh;
  } else {
    w->mesh = sc.make();
    w->mesh.validate(sc.name);
  }
  const Mesh& mesh = w->mesh;
  const Box3 bounds = mesh.bounds();

  RaySet primary{
      "primary", primary_rays(canonical_camera(bounds), kCameraWidth, kCameraHeight), {}};
  // The reference's own primary hits seed the secondary sets, so no structure under test
  // influences the rays it is tested on.
  primary.reference = test::brute_reference(mesh, primary.rays);
  RaySet shadow{
      "shadow",
      shadow_rays(mesh, primary.rays, primary.reference, canonical_light_position(bounds)),
      {}};
  RaySet diffuse{"diffuse", diffuse_rays(mesh, primary.rays, primary.reference, 7), {}};
  shadow.reference = test::brute_reference(mesh, shadow.rays);
  diffuse.reference = test::brute_reference(mesh, diffuse.rays);
  const size_t camera_rays = primary.rays.size() + shadow.rays.size() + diffuse.rays.size();
  const size_t random_count =
      std::max(kMinRandomRays, camera_rays < kRaysPerScene ? kRaysPerScene - camera_rays : 0);
  RaySet random{"random", random_rays(bounds, random_count, 5), {}};
  random.reference = test::brute_reference(mesh, random.rays);
  w->sets.push_back(std::move(random));
  w->sets.push_back(std::move(primary));
  w->sets.push_back(std::move(shadow));
  w->sets.push_back(std::move(diffuse));
  return (cache[sc.name] = std::move(w)).get();
}

std::vector<std::string> structures_under_test() {
  std::vector<std::string> out;
  for (const auto& n : accelerator_names())
    if (n != "brute") out.push_back(n);
  return out;
}

using Param = std::tuple<std::string, size_t>;  // structure, scene case index

class Agreement : public ::testing::TestWithParam<Param> {
 protected:
  const SceneCase& scene() const { return scene_cases()[std::get<1>(GetParam())]; }
  const std::string& structure() const { return std::get<0>(GetParam()); }
};

TEST_P(Agreement, MatchesBruteForce) {
  std::string skip;
  const Workload* w = workload(scene(), skip);
  if (!w) GTEST_SKIP() << skip;
  ASSERT_GE(w->total_rays(), kRaysPerScene);
  auto accel = make_accelerator(structure());
  accel->build(w->mesh, BuildParams{});
  size_t hits = 0;
  for (const RaySet& set : w->sets) {
    const test::AgreementRule rule = test::rule_for(structure(), set.name);
    const auto rep = test::compare_with_reference(*accel, w->mesh, set.rays, set.reference, rule,
                                                  set.name + " rays of " + scene().name);
    EXPECT_TRUE(rep.ok()) << rep.summary();
    for (const Hit& h : set.reference) hits += h.valid();
  }
  // A workload that never hits anything would agree vacuously. Thin slivers are hit by few
  // rays (about 3% here), so the threshold is 1% of the rays: still thousands of hits per scene.
  EXPECT_GT(hits, w->total_rays() / 100);
}

TEST_P(Agreement, InstrumentedTraversalMatchesFastPath) {
  std::string skip;
  const Workload* w = workload(scene(), skip);
  if (!w) GTEST_SKIP() << skip;
  auto accel = make_accelerator(structure());
  accel->build(w->mesh, BuildParams{});
  for (const RaySet& set : w->sets) {
    std::vector<std::string> examples;
    const size_t bad = test::compare_instrumented(*accel, set.rays, 37, examples);
    std::string ex;
    for (const auto& e : examples) ex += "\n  " + e;
    EXPECT_EQ(bad, 0u) << structure() << ": counted/traced traversal disagrees with the fast "
                       << "path on " << set.name << " rays of " << scene().name << ex;
  }
}

std::vector<size_t> scene_indices() {
  std::vector<size_t> v(scene_cases().size());
  for (size_t i = 0; i < v.size(); ++i) v[i] = i;
  return v;
}

INSTANTIATE_TEST_SUITE_P(AllStructures, Agreement,
                         ::testing::Combine(::testing::ValuesIn(structures_under_test()),
                                            ::testing::ValuesIn(scene_indices())),
                         [](const ::testing::TestParamInfo<Param>& p) {
                           return test::test_name(std::get<0>(p.param)) + "_" +
                                  scene_cases()[std::get<1>(p.param)].name;
                         });

// The harness itself must be able to fail: a structure that drops every other triangle is
// caught, and the reference cache returns what brute force computes.
class DropHalf final : public AcceleratorBase<DropHalf> {
 public:
  std::string name() const override { return "drop-half"; }
  BuildStats build(const Mesh& mesh, const BuildParams& p) override {
    mesh_ = &mesh;
    triangle_test_ = p.triangle_test;
    return stats_;
  }
  template <class TriangleTest, class Probe, bool kAny>
  bool traverse(const Ray& ray, Hit* hit, Probe&) const {
    const auto rd = TriangleTest::prepare(ray);
    float tmax = ray.tmax;
    bool found = false;
    for (uint32_t i = 0; i < mesh_->num_triangles(); i += 2) {
      const auto c = mesh_->corners(i);
      float t, u, v;
      if (TriangleTest::intersect(rd, c[0], c[1], c[2], ray.tmin, tmax, t, u, v)) {
        if constexpr (kAny) return true;
        tmax = t;
        *hit = {t, i, u, v};
        found = true;
      }
    }
    return found;
  }

 private:
  const Mesh* mesh_ = nullptr;
};

TEST(AgreementHarness, DetectsAWrongStructure) {
  const Mesh mesh = test::triangle_soup(500, 3);
  const auto rays = random_rays(mesh.bounds(), 4000, 9);
  const auto ref = test::brute_reference(mesh, rays);
  DropHalf bad;
  bad.build(mesh, BuildParams{});
  const auto rep = test::compare_with_reference(bad, mesh, rays, ref, {}, "random");
  EXPECT_FALSE(rep.ok());
  EXPECT_GT(rep.miss_mismatch + rep.prim_mismatch + rep.t_mismatch, 0u);
  EXPECT_FALSE(rep.examples.empty());
  // Allowing 100% disagreement accepts it: the fraction rule is what decides.
  test::AgreementRule lax;
  lax.min_fraction = 0.0;
  EXPECT_TRUE(test::compare_with_reference(bad, mesh, rays, ref, lax, "random").ok());
}

TEST(AgreementHarness, CachedReferenceEqualsFreshBruteForce) {
  const Mesh mesh = test::subdivided_sphere(2);
  const auto rays = random_rays(mesh.bounds(), 3000, 21);
  const auto a = test::brute_reference(mesh, rays);  // computes (and caches if configured)
  const auto b = test::brute_reference(mesh, rays);  // may come from the cache
  BruteForce brute;
  brute.build(mesh, BuildParams{});
  ASSERT_EQ(a.size(), rays.size());
  ASSERT_EQ(b.size(), rays.size());
  size_t hits = 0;
  for (size_t i = 0; i < rays.size(); ++i) {
    Hit h;
    const bool hit = brute.intersect(rays[i], h);
    EXPECT_EQ(a[i].valid(), hit);
    EXPECT_EQ(b[i].valid(), hit);
    if (hit) {
      EXPECT_EQ(a[i].t, h.t);
      EXPECT_EQ(b[i].t, h.t);
      EXPECT_EQ(b[i].prim, h.prim);
      ++hits;
    }
  }
  EXPECT_GT(hits, 100u);
  // A different ray list must not share the cache entry.
  auto rays2 = rays;
  rays2[0].org.x += 1.0f;
  EXPECT_NE(test::reference_key(mesh, rays, TriangleTestKind::Watertight),
            test::reference_key(mesh, rays2, TriangleTestKind::Watertight));
  EXPECT_NE(test::reference_key(mesh, rays, TriangleTestKind::Watertight),
            test::reference_key(mesh, rays, TriangleTestKind::Moller));
}

/// Reports one fixed hit for every ray.
class ReportsPrim final : public AcceleratorBase<ReportsPrim> {
 public:
  ReportsPrim(uint32_t p, float t) : p_(p), t_(t) {}
  std::string name() const override { return "fixed"; }
  BuildStats build(const Mesh&, const BuildParams&) override { return stats_; }
  template <class TriangleTest, class Probe, bool kAny>
  bool traverse(const Ray&, Hit* h, Probe&) const {
    if constexpr (!kAny) *h = {t_, p_, 0, 0};
    return true;
  }

 private:
  uint32_t p_;
  float t_;
};

// Ties: on the duplicated-triangle mesh the reported triangle may differ from brute force's
// but must be accepted only because its own t equals the reference t.
TEST(AgreementHarness, AcceptsTiesOnlyAtTheSameT) {
  Mesh mesh;
  mesh.positions = {{-1, -1, 0}, {1, -1, 0}, {0, 1, 0}, {-1, -1, 1}, {1, -1, 1}, {0, 1, 1}};
  mesh.triangles = {{0, 1, 2}, {0, 1, 2}, {3, 4, 5}};
  std::vector<Ray> rays = {{{0, 0, -1}, 0.0f, {0, 0, 1}, kInf}};
  std::vector<Hit> ref = {{1.0f, 0, 0, 0}};
  // A structure that reports the duplicate (prim 1) at the same t is a tie.
  const auto tie = test::compare_with_reference(ReportsPrim(1, 1.0f), mesh, rays, ref, {}, "t");
  EXPECT_TRUE(tie.ok()) << tie.summary();
  EXPECT_EQ(tie.ties, 1u);
  // Prim 2 lies at t = 2; reporting it with the reference's t is a lie the harness catches.
  const auto lie = test::compare_with_reference(ReportsPrim(2, 1.0f), mesh, rays, ref, {}, "t");
  EXPECT_FALSE(lie.ok());
  EXPECT_EQ(lie.prim_mismatch, 1u);
}

// Hits at a ray's start: a structure that skips them (here DropHalf, which has no triangle 0)
// disagrees, unless the rule leaves such rays unjudged; a hit it skips further along the ray
// is still a disagreement under that rule. Embree's configurations get the rule by robustness.
TEST(AgreementHarness, StartHitsAreUnjudgedOnlyWhenTheRuleSaysSo) {
  // DropHalf tests triangles 0, 2, ... only: triangle 0 is degenerate, so it misses everything,
  // and the reference's hits are on triangle 1.
  Mesh mesh;
  mesh.positions = {{-1, -1, 0}, {1, -1, 0}, {0, 1, 0}};
  mesh.triangles = {{0, 0, 0}, {0, 1, 2}};
  DropHalf skips;
  skips.build(mesh, BuildParams{});
  const std::vector<Ray> at_start = {{{0, 0, 0}, 0.0f, {0, 0, 1}, kInf}};
  const std::vector<Ray> further = {{{0, 0, -1}, 0.0f, {0, 0, 1}, kInf}};
  const std::vector<Hit> ref_start = {{0.0f, 1, 0, 0}}, ref_further = {{1.0f, 1, 0, 0}};
  test::AgreementRule strict, lenient;
  lenient.start_hits_ambiguous = true;
  EXPECT_FALSE(test::compare_with_reference(skips, mesh, at_start, ref_start, strict, "s").ok());
  const auto start = test::compare_with_reference(skips, mesh, at_start, ref_start, lenient, "s");
  EXPECT_TRUE(start.ok()) << start.summary();
  EXPECT_EQ(start.start_hits, 1u);
  const auto far = test::compare_with_reference(skips, mesh, further, ref_further, lenient, "f");
  EXPECT_FALSE(far.ok());
  EXPECT_EQ(far.start_hits, 0u);
  EXPECT_TRUE(test::rule_for("embree", "shadow").start_hits_ambiguous);
  EXPECT_TRUE(test::rule_for("embree-high", "shadow").start_hits_ambiguous);
  EXPECT_FALSE(test::rule_for("embree-robust", "shadow").start_hits_ambiguous);
  EXPECT_FALSE(test::rule_for("hybrid", "shadow").start_hits_ambiguous);
}

}  // namespace
}  // namespace kdgrid
