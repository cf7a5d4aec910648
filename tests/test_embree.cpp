// Embree 3 reference: its configurations (default flags, robust, high quality) and the ISA it
// reports, agreement with brute force (>= 99.99%: Embree's own triangle test is not kdgrid's),
// build qualities, ray interval semantics, memory reporting.
#include <gtest/gtest.h>

#include <map>
#include <random>

#include "accel/embree.h"
#include "comparator_meshes.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

// Embree computes t with its own triangle test: at grazing angles it differs from kdgrid's
// watertight test by up to ~2e-4 relative (both are float), so t is compared within 1e-3.
constexpr double kTol = 1e-3;

// Allowed fraction of disagreeing rays: 1e-4 (99.99% agreement) on well-conditioned meshes.
// Three procedural meshes are ill-conditioned for ANY float triangle test, so two correct
// tests legitimately differ there:
//  - slivers: 1e-3-wide triangles hit at grazing angles; t is ill-conditioned (kdgrid's
//    watertight t is off by up to 1e-2 there, Embree's is closer to the true t = 1);
//  - quads_at_1e5: rays aimed at points rounded to a 1/128 grid at 1e5, i.e. on shared edges,
//    where Embree and kdgrid pick different neighbours, and where Embree's default flags (no
//    RTC_SCENE_FLAG_ROBUST) let more rays slip between neighbours: 99 of 20000 rays against
//    robust mode's 26 (measured), so the default flags are allowed 1% there;
//  - cluster_in_box: triangles of 1e-6..5e-4 seen from 1000 away, below the float spacing
//    (6e-5) of the origin's coordinates: both answers are rounding noise.
double allowed_fraction(const std::string& mesh, bool robust) {
  if (mesh == "slivers") return 5e-4;
  if (mesh == "quads_at_1e5") return robust ? 5e-3 : 1e-2;
  if (mesh == "cluster_in_box") return 0.2;
  return 1e-4;
}

std::string extra(const BuildStats& st, const std::string& key) {
  for (const auto& [k, v] : st.extra)
    if (k == key) return v;
  return "";
}

// Every configuration is held to the allowances above, the default flags to their own on the
// edge-aimed quads. One test per configuration, so ctest runs them side by side.
class EmbreeConfigs : public ::testing::TestWithParam<size_t> {};  // index in embree_configs()

TEST_P(EmbreeConfigs, AgreesWithBruteForceOnProceduralMeshes) {
  const EmbreeConfig& config = embree_configs().at(GetParam());
  for (const auto& [name, mesh] : test::test_meshes()) {
    SCOPED_TRACE(config.name + " on " + name);
    EmbreeAccel e(config);
    const BuildStats st = e.build(mesh, BuildParams{});
    EXPECT_GT(st.bytes, 0u);
    const auto rays = test::random_rays(mesh, 20000, 17);
    int hits = 0;
    const int bad = test::count_disagreements(mesh, e, rays, 0, &hits, kTol);
    std::printf("%s vs brute on %s: %d of %zu rays disagree\n", config.name.c_str(), name.c_str(),
                bad, rays.size());
    EXPECT_LE(double(bad), allowed_fraction(name, config.robust) * double(rays.size()))
        << bad << " of " << rays.size() << " rays disagree";
    EXPECT_GT(hits, 2000);
  }
}

INSTANTIATE_TEST_SUITE_P(Embree, EmbreeConfigs,
                         ::testing::Range(size_t(0), embree_configs().size()),
                         [](const ::testing::TestParamInfo<size_t>& p) {
                           return test::test_name(embree_configs().at(p.param).name);
                         });

// The benchmark's reference is Embree as a user runs it: `embree` is built with the default
// scene flags at medium quality (Embree's defaults); the robust and high-quality
// configurations are what their names say. The flags are read back from Embree's scene.
TEST(Embree, DefaultIsDefaultFlagsAtMediumQualityAndVariantsAreRobustOrHigh) {
  const Mesh mesh = test::sphere(10, 20);
  struct Want {
    const char* name;
    bool robust;
    const char* quality;
  };
  for (const Want& w : {Want{"embree", false, "medium"}, Want{"embree-robust", true, "medium"},
                        Want{"embree-high", false, "high"}}) {
    SCOPED_TRACE(w.name);
    auto acc = make_accelerator(w.name);
    auto* e = dynamic_cast<EmbreeAccel*>(acc.get());
    ASSERT_NE(e, nullptr);
    EXPECT_EQ(e->name(), w.name);
    const BuildStats st = e->build(mesh, BuildParams{});
    EXPECT_EQ(e->robust(), w.robust);
    EXPECT_EQ(e->quality(), w.quality);
    EXPECT_EQ(extra(st, "flags"), w.robust ? "robust" : "default");
    EXPECT_EQ(extra(st, "quality"), w.quality);
    EXPECT_EQ(extra(st, "isa"), embree_isa().isa);
  }
  // --embree-quality applies to embree and embree-robust; embree-high stays high.
  BuildParams low;
  low.embree_quality = "low";
  for (const char* n : {"embree", "embree-robust"}) {
    auto acc = build_accelerator(n, mesh, low);
    EXPECT_EQ(extra(acc->stats(), "quality"), "low") << n;
  }
  auto high = build_accelerator("embree-high", mesh, low);
  EXPECT_EQ(extra(high->stats(), "quality"), "high");
  for (const std::string n : {"embree", "embree-robust", "embree-high"}) EXPECT_TRUE(is_embree(n));
  for (const std::string n : {"bvh", "hybrid", "brute", "embree-fast"}) EXPECT_FALSE(is_embree(n));
}

// What Embree reports about the kernels it chose on this CPU (bench reports and tables).
TEST(Embree, ReportsTheIsaItChose) {
  const EmbreeIsa& isa = embree_isa();
  EXPECT_EQ(isa.version.rfind("3.", 0), 0u) << isa.version;
  const std::map<int, std::string> by_packet = {{16, "AVX-512"}, {8, "AVX or AVX2"}, {4, "SSE"}};
  ASSERT_EQ(by_packet.count(isa.native_packet), 1u) << isa.native_packet;
  EXPECT_EQ(isa.isa, by_packet.at(isa.native_packet));
#if defined(__AVX512F__) && defined(__AVX512VL__) && defined(__AVX512BW__) && \
    defined(__AVX512DQ__) && defined(__AVX512CD__)
  // This build runs only where the CPU has AVX-512 (SKX), and Debian's libembree3 has
  // AVX-512 kernels (its targets: SSE2, SSE4.2, AVX, AVX2, AVX512): Embree must use them.
  EXPECT_EQ(isa.native_packet, 16);
#endif
}

// Extreme rays (axis-parallel with +0/-0 components, rays along edges and in planes):
// ExtremeRayFamilies.*/embree*.

TEST(Embree, AllQualitiesBuildAndBadQualityIsRejected) {
  const Mesh mesh = test::sphere(30, 60);
  const auto rays = test::random_rays(mesh, 3000, 2);
  for (const char* q : {"low", "medium", "high"}) {
    SCOPED_TRACE(q);
    BuildParams p;
    p.embree_quality = q;
    EmbreeAccel e;
    e.build(mesh, p);
    EXPECT_LE(test::count_disagreements(mesh, e, rays, 0, nullptr, kTol), 1);
  }
  BuildParams bad;
  bad.embree_quality = "ultra";
  EmbreeAccel e;
  try {
    e.build(mesh, bad);
    FAIL() << "expected ParamError";
  } catch (const ParamError& err) {
    EXPECT_NE(std::string(err.what()).find("ultra"), std::string::npos);
  }
}

// [tmin, tmax) as kdgrid defines it, mapped onto Embree's [tnear, tfar].
TEST(Embree, RayIntervalSemantics) {
  Mesh m;
  test::add_tri(m, Vec3(-1, -1, 2), Vec3(1, -1, 2), Vec3(0, 1, 2));
  EmbreeAccel e;
  e.build(m, BuildParams{});
  Hit h;
  const Ray r{Vec3(0, 0, 0), 0.0f, Vec3(0, 0, 1), kInf};
  ASSERT_TRUE(e.intersect(r, h));
  EXPECT_FLOAT_EQ(h.t, 2.0f);
  EXPECT_EQ(h.prim, 0u);
  // Barycentrics: the hit point is (1-u-v) v0 + u v1 + v v2.
  const auto c = m.corners(0);
  const Vec3 p = c[0] * (1 - h.u - h.v) + c[1] * h.u + c[2] * h.v;
  EXPECT_NEAR(p.x, 0.0f, 1e-5f);
  EXPECT_NEAR(p.y, 0.0f, 1e-5f);
  Ray seg = r;
  seg.tmax = 2.0f;  // tmax is exclusive
  EXPECT_FALSE(e.intersect(seg, h));
  EXPECT_FALSE(e.occluded(seg));
  seg.tmax = 2.001f;
  EXPECT_TRUE(e.occluded(seg));
  Ray late = r;
  late.tmin = 2.5f;
  EXPECT_FALSE(e.intersect(late, h));
  // A negative tmin reaches behind the origin.
  Ray back{Vec3(0, 0, 3), -2.0f, Vec3(0, 0, 1), kInf};
  ASSERT_TRUE(e.intersect(back, h));
  EXPECT_NEAR(h.t, -1.0f, 1e-5f);
  // Invalid rays miss.
  Ray nan_ray = r;
  nan_ray.dir.x = std::nanf("");
  EXPECT_FALSE(e.intersect(nan_ray, h));
  EXPECT_FALSE(e.occluded(nan_ray));
}

TEST(Embree, CountersAreZeroAndTraceHoldsTheHit) {
  const Mesh mesh = test::sphere(20, 40);
  EmbreeAccel e;
  e.build(mesh, BuildParams{});
  EXPECT_FALSE(e.has_counters());
  const auto rays = test::random_rays(mesh, 500, 4);
  EXPECT_EQ(test::check_counted_and_trace(e, rays), 0);
  RayCounters c;
  Hit h;
  for (const Ray& r : rays) e.intersect_counted(r, h, c);
  EXPECT_EQ(c, RayCounters{});
  const Trace t = e.trace(rays[0]);
  EXPECT_TRUE(t.steps.empty());
}

TEST(Embree, ReportsMemoryAndRebuilds) {
  const Mesh small = test::sphere(10, 20), big = test::sphere(100, 200);
  EmbreeAccel e;
  const uint64_t b_small = e.build(small, BuildParams{}).bytes;
  const BuildStats sb = e.build(big, BuildParams{});
  EXPECT_GT(sb.bytes, b_small);
  EXPECT_GT(sb.bytes_by_part.at(0).second, 0u);  // Embree's own allocations were seen
  EXPECT_EQ(e.memory_bytes(), sb.bytes);
  EXPECT_EQ(
      test::count_disagreements(big, e, test::random_rays(big, 2000, 6), 0, nullptr, kTol) <= 1,
      true);
}

}  // namespace
}  // namespace kdgrid
