// The wide watertight test (accel/triangle_wide.h) against the scalar one, bit for bit: lane by
// lane on random and adversarial triangle groups, then through the hybrid's leaves, whose
// WatertightTest walk uses the wide test and whose WatertightScalar walk tests lane by lane.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "accel/brute.h"
#include "accel/hybrid/hybrid.h"
#include "accel/kdtree.h"
#include "accel/triangle_wide.h"
#include "comparator_meshes.h"
#include "scene/load.h"
#include "test_util.h"

namespace kdgrid {
namespace {

bool same_bits(float a, float b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

struct Tri {
  Vec3 v[3];
};

/// The scalar loop the wide test stands for: the lanes in `lanes`, in order, each tested against
/// the closest hit so far (strict t < best).
template <int W>
int scalar_reference(const Ray& r, const std::vector<Tri>& tris, uint32_t lanes, float& t, float& u,
                     float& v) {
  const auto rd = WatertightTest::prepare(r);
  float best = r.tmax;
  int lane = -1;
  for (int i = 0; i < W; ++i) {
    if (!(lanes >> i & 1u)) continue;
    float ts, us, vs;
    if (WatertightTest::intersect(rd, tris[i].v[0], tris[i].v[1], tris[i].v[2], r.tmin, best, ts,
                                  us, vs)) {
      best = ts;
      lane = i;
      u = us;
      v = vs;
    }
  }
  t = best;
  return lane;
}

/// Groups of W triangles made to reach every path of the scalar test: random triangles, fans
/// and strips sharing edges and corners (rays through them make edge functions exactly zero:
/// the double-precision lanes), duplicates and coplanar copies (ties: the lowest lane wins),
/// degenerate triangles (det 0), coordinates near 1e13 whose depth overflows float (the
/// double depth), and rays with finite tmax.
template <int W>
struct Cases {
  std::mt19937 rng{7};
  std::uniform_real_distribution<float> u01{0.0f, 1.0f};
  float uni(float lo, float hi) { return lo + (hi - lo) * u01(rng); }
  Vec3 point(float s) { return {uni(-s, s), uni(-s, s), uni(-s, s)}; }
  /// On integer coordinates: rays through shared corners and edges give exact zeros.
  Vec3 lattice(int n) {
    std::uniform_int_distribution<int> k(-n, n);
    return Vec3(float(k(rng)), float(k(rng)), float(k(rng)));
  }

  std::vector<Tri> group(int kind) {
    std::vector<Tri> g(W);
    const float scale = kind == 4 ? 1e13f : 1.0f;
    const Vec3 hub = kind == 1 ? lattice(2) : point(scale);
    for (int i = 0; i < W; ++i) {
      Tri& t = g[size_t(i)];
      switch (kind) {
        case 0:  // random
        case 4:  // huge coordinates
          for (Vec3& p : t.v) p = point(scale);
          break;
        case 1:  // a fan around a lattice point, on lattice points
          t.v[0] = hub;
          t.v[1] = lattice(2);
          t.v[2] = lattice(2);
          break;
        case 2:  // duplicates and coplanar copies of a few triangles
          if (i < 2) {
            for (Vec3& p : t.v) p = point(1);
          } else {
            t = g[size_t(rng() % uint32_t(i))];
            if (rng() % 2) std::swap(t.v[0], t.v[1]);  // the same plane, the other winding
          }
          break;
        default:  // degenerate: collinear or repeated corners, mixed with random ones
          t.v[0] = point(1);
          t.v[1] = rng() % 2 ? t.v[0] : point(1);
          t.v[2] = t.v[0] + (t.v[1] - t.v[0]) * uni(-1, 2);
          if (i % 3 == 0)
            for (Vec3& p : t.v) p = point(1);
          break;
      }
    }
    return g;
  }

  Ray ray(int kind, const std::vector<Tri>& g) {
    Ray r;
    const float scale = kind == 4 ? 1e13f : 1.0f;
    const Tri& t = g[rng() % uint32_t(W)];
    Vec3 target;
    switch (rng() % 4) {
      case 0:  // a corner
        target = t.v[rng() % 3];
        break;
      case 1:  // an edge's midpoint
        target = (t.v[0] + t.v[1]) * 0.5f;
        break;
      default: {  // inside
        float a = u01(rng), b = u01(rng);
        if (a + b > 1) a = 1 - a, b = 1 - b;
        target = t.v[0] * (1 - a - b) + t.v[1] * a + t.v[2] * b;
      }
    }
    r.org = kind == 1 ? lattice(6) : target + point(3 * scale);
    if (kind == 1 && rng() % 2) {
      // Axis-parallel through a lattice point: the edge functions of the fan are exact.
      r.org = target;
      const int a = int(rng() % 3);
      r.org[a] += 5.0f;
    }
    r.dir = target - r.org;
    if (r.dir == Vec3(0.0f)) r.dir = Vec3(0, 0, 1);
    // Huge coordinates with a unit direction: the depth's numerator, of the order of the cube of
    // the coordinates over the direction, overflows float.
    if (kind == 4) r.dir = normalize(r.dir);
    r.tmin = rng() % 8 == 0 ? 0.5f : 0.0f;
    r.tmax = rng() % 4 == 0 ? uni(0.5f, 1.5f) : kInf;
    return r;
  }
};

template <int W>
void check_lanes_match_scalar() {
  Cases<W> c;
  int hits = 0, mismatches = 0;
  for (int n = 0; n < 40000; ++n) {
    const int kind = n % 5;
    const std::vector<Tri> tris = c.group(kind);
    WideTriangles<W> g;
    for (int i = 0; i < W; ++i)
      g.set(i, tris[size_t(i)].v[0], tris[size_t(i)].v[1], tris[size_t(i)].v[2]);
    for (int k = 0; k < 4; ++k) {
      const Ray r = c.ray(kind, tris);
      const uint32_t lanes = k == 0 ? (1u << W) - 1 : uint32_t(c.rng()) & ((1u << W) - 1);
      float ts = 0, us = 0, vs = 0, tw = 0, uw = 0, vw = 0;
      const int ls = scalar_reference<W>(r, tris, lanes, ts, us, vs);
      const int lw = WatertightWide<W>::intersect(WatertightTest::prepare(r), g, lanes, r.tmin,
                                                  r.tmax, tw, uw, vw);
      hits += ls >= 0;
      const bool same =
          ls == lw && (ls < 0 || (same_bits(ts, tw) && same_bits(us, uw) && same_bits(vs, vw)));
      if (!same && ++mismatches <= 5)
        ADD_FAILURE() << "W " << W << " group " << n << " kind " << kind << " lanes " << lanes
                      << ": scalar lane " << ls << " t " << ts << " u " << us << " v " << vs
                      << "; wide lane " << lw << " t " << tw << " u " << uw << " v " << vw;
    }
  }
  EXPECT_EQ(mismatches, 0);
  EXPECT_GT(hits, 40000);  // most rays are aimed at a triangle of their group
}

TEST(WideTriangle, FourLanesMatchScalarBitForBit) {
  check_lanes_match_scalar<4>();
}

#if defined(__AVX__)
TEST(WideTriangle, EightLanesMatchScalarBitForBit) {
  check_lanes_match_scalar<8>();
}
#endif

#if defined(__AVX512F__)
TEST(WideTriangle, SixteenLanesMatchScalarBitForBit) {
  check_lanes_match_scalar<16>();
}
#endif

// Ties: a group of one triangle repeated in every lane reports lane 0, the scalar loop's first.
TEST(WideTriangle, EqualDepthsGoToTheLowestLane) {
  constexpr int W = kWideLanes > 1 ? kWideLanes : 4;
  WideTriangles<W> g;
  for (int i = 0; i < W; ++i) g.set(i, Vec3(-1, -1, 2), Vec3(1, -1, 2), Vec3(0, 1, 2));
  const Ray r{Vec3(0, 0, 0), 0.0f, Vec3(0, 0, 1), kInf};
  float t, u, v;
  EXPECT_EQ(WatertightWide<W>::intersect(WatertightTest::prepare(r), g, (1u << W) - 1, r.tmin,
                                         r.tmax, t, u, v),
            0);
  EXPECT_EQ(
      WatertightWide<W>::intersect(WatertightTest::prepare(r), g, 0b110u, r.tmin, r.tmax, t, u, v),
      1);
}

// ---- the hybrid's leaves ---------------------------------------------------------------

/// Rays whose closest hit (triangle, t, u, v: bit for bit), any-hit answer or steps differ
/// between the wide walk (WatertightTest) and the scalar one (WatertightScalar), or whose wide
/// walk skipped a test through the mailbox or tested fewer triangles than the scalar one (it
/// tests every lane, repeats included).
int wide_scalar_differences(const GridKdHybrid& h, const std::vector<Ray>& rays,
                            const std::string& label) {
  int bad = 0;
  for (size_t i = 0; i < rays.size(); ++i) {
    const Ray& r = rays[i];
    Hit hw, hs;
    CountProbe cw, cs;
    const bool fw = h.traverse<WatertightTest, CountProbe, false>(r, &hw, cw);
    const bool fs = h.traverse<WatertightScalar, CountProbe, false>(r, &hs, cs);
    NoProbe n;
    const bool aw = h.traverse<WatertightTest, NoProbe, true>(r, nullptr, n),
               as = h.traverse<WatertightScalar, NoProbe, true>(r, nullptr, n);
    bool same = fw == fs && aw == as && aw == fw && cw.c.tri_tests >= cs.c.tri_tests &&
                cw.c.mailbox_skips == 0 && cw.c.steps == cs.c.steps;
    if (same && fw)
      same = hw.prim == hs.prim && same_bits(hw.t, hs.t) && same_bits(hw.u, hs.u) &&
             same_bits(hw.v, hs.v);
    if (!same && ++bad <= 5)
      ADD_FAILURE() << label << " ray " << i << ": wide " << fw << " prim " << hw.prim << " t "
                    << hw.t << " any " << aw << "; scalar " << fs << " prim " << hs.prim << " t "
                    << hs.t << " any " << as;
  }
  return bad;
}

// The group width follows the build's target (16 lanes with AVX-512, 8 with AVX, 4 with SSE)
// unless KDGRID_WIDE_LANES sets it, and the hybrid builds its leaves in groups of that width.
TEST(WideLeaves, GroupWidthFollowsTheTargetAndTheBuildUsesIt) {
#if defined(KDGRID_WIDE_LANES)
  EXPECT_EQ(kWideLanes, KDGRID_WIDE_LANES);
#elif defined(__AVX512F__)
  EXPECT_EQ(kWideLanes, 16);
#elif defined(__AVX__)
  EXPECT_EQ(kWideLanes, 8);
#elif defined(__SSE2__)
  EXPECT_EQ(kWideLanes, 4);
#endif
  if (kWideLanes == 1) GTEST_SKIP() << "this build's groups have one lane";
  const auto meshes = test::test_meshes();
  GridKdHybrid h;
  const BuildStats st = h.build(meshes.front().mesh, BuildParams{});
  std::string groups;
  for (const auto& [key, value] : st.extra)
    if (key == "triangle groups") groups = value;
  const std::string width =
      std::string(hybrid::kSharedCorners ? " groups of up to " : " groups of ") +
      std::to_string(kWideLanes) + " lanes ";
  EXPECT_NE(groups.find(width), std::string::npos) << groups;
}

TEST(WideLeaves, HybridHitsMatchScalarBitForBit) {
  if (kWideLanes == 1) GTEST_SKIP() << "this build's groups have one lane: no wide test";
  for (const auto& nm : test::test_meshes()) {
    for (const uint32_t subtree_min : {0u, 4u}) {
      BuildParams p;
      p.hybrid_subtree_min = subtree_min;
      GridKdHybrid h;
      h.build(nm.mesh, p);
      std::vector<Ray> rays = test::random_rays(nm.mesh, 3000, 3);
      for (const Ray& r : test::signed_zero_rays()) rays.push_back(r);
      const std::string label = nm.name + " subtree_min " + std::to_string(subtree_min);
      EXPECT_EQ(wide_scalar_differences(h, rays, label), 0) << label;
    }
  }
}

/// The lanes and distinct corners a group holds on average, from the build's "triangle groups"
/// figure (a shared-corner build: "... (L lanes and C distinct corners a group)").
std::pair<double, double> lanes_and_corners(const BuildStats& st) {
  for (const auto& [key, value] : st.extra) {
    const size_t at = value.rfind('(');
    double lanes = 0, corners = 0;
    if (key == "triangle groups" && at != std::string::npos &&
        std::sscanf(value.c_str() + at, "(%lf lanes and %lf distinct corners", &lanes, &corners) ==
            2)
      return {lanes, corners};
  }
  return {0, 0};
}

// Shared-corner groups (records.h): a group stores each distinct corner once and its lanes
// index them. A mesh's connected triangles share corners (a sphere: about one new corner a
// lane); a triangle soup brings three a lane, so its groups end at kMaxGroupCorners (32 with
// groups of 16: 10 lanes; 16 with groups of 8: 5 lanes). Either
// way every hit is the one brute force finds from the mesh (t bit for bit, and the triangle
// where no other lies at the same t).
TEST(WideLeaves, SharedCornerGroupsStoreEachCornerOnce) {
  if (!hybrid::kSharedCorners)
    GTEST_SKIP() << "this build stores groups by lane (shared corners need groups of 16 with "
                    "AVX-512 BW and VL, or of 8 with AVX2)";
  struct Case {
    const char* name;
    Mesh mesh;
  };
  const Case cases[] = {{"soup", test::random_soup(6000, 5)}, {"sphere", test::sphere(60, 120)}};
  for (const Case& c : cases) {
    BuildParams p;
    p.hybrid_subtree_min = 0;  // plain leaves, so that many hold more than one group
    GridKdHybrid h;
    const auto [lanes, corners] = lanes_and_corners(h.build(c.mesh, p));
    if (std::string(c.name) == "soup") {
      EXPECT_GT(lanes, 1.0) << c.name;
      // kMaxGroupCorners at most, three new ones a lane (the figure is rounded to one decimal).
      EXPECT_LE(lanes, double(hybrid::kMaxGroupCorners / 3) + 0.05) << c.name;
      // Both figures are rounded to one decimal: 3 x 0.05 + 0.05 apart at most.
      EXPECT_NEAR(corners, 3 * lanes, 0.2 + 1e-9) << c.name;
    } else {
      EXPECT_GT(lanes, 4.0) << c.name;
      EXPECT_LT(corners, 1.6 * lanes) << c.name;  // shared: well under three a lane
    }
    BruteForce brute;
    brute.build(c.mesh, p);
    int bad = 0;
    for (const Ray& r : test::random_rays(c.mesh, 4000, 17)) {
      Hit hh, hb;
      const bool fh = h.intersect(r, hh), fb = brute.intersect(r, hb);
      bool same = fh == fb;
      if (same && fh)
        same = same_bits(hh.t, hb.t) &&
               (hh.prim != hb.prim || (same_bits(hh.u, hb.u) && same_bits(hh.v, hb.v)));
      if (!same && ++bad <= 5)
        ADD_FAILURE() << c.name << ": hybrid " << fh << " prim " << hh.prim << " t " << hh.t
                      << "; brute force " << fb << " prim " << hb.prim << " t " << hb.t;
    }
    EXPECT_EQ(bad, 0) << c.name;
  }
}

// The build's memory account (check_flatten_memory) counts the group plan's record of each group
// as the references over kFullGroupLanesAtLeast, plus one group a leaf: a group that is not its
// leaf's last holds at least that many lanes. A triangle soup (three new corners a lane) fills
// shared-corner groups least, a sphere most; plain leaves and leaf subtrees; and one cell, whose
// one leaf holds the whole soup, where the references' term is the whole bound.
TEST(WideLeaves, GroupsAreAtMostWhatTheMemoryAccountCounts) {
  const Mesh soup = test::random_soup(6000, 5), ball = test::sphere(60, 120);
  struct Case {
    const char* name;
    const Mesh* mesh;
    int subtree_min;
    float cell;
  };
  const Case cases[] = {{"soup, plain leaves", &soup, 0, 0.0f},
                        {"soup, leaf subtrees", &soup, 4, 0.0f},
                        {"soup in one cell", &soup, 0, 4.0f},
                        {"sphere, plain leaves", &ball, 0, 0.0f},
                        {"sphere, leaf subtrees", &ball, 4, 0.0f}};
  for (const Case& c : cases) {
    BuildParams p;
    p.hybrid_subtree_min = c.subtree_min;
    p.cell_size = c.cell;
    GridKdHybrid h;
    const BuildStats st = h.build(*c.mesh, p);
    double groups = -1;
    for (const auto& [key, value] : st.extra) {
      if (key == "triangle groups") groups = std::atof(value.c_str());
    }
    ASSERT_GT(groups, 0) << c.name;
    EXPECT_LE(groups, double(st.references) / hybrid::kFullGroupLanesAtLeast + double(st.leaves))
        << c.name << ": " << st.references << " references, " << st.leaves << " leaves";
    if (c.cell > 0) {
      EXPECT_EQ(st.leaves, 1u) << c.name;
      if (hybrid::kSharedCorners) {  // the bound's worst case is reached
        EXPECT_GT(groups, double(st.references) / hybrid::kFullGroupLanesAtLeast - 1) << c.name;
      }
    }
  }
}

// Groups of 8 choose each lane among the leaf's next 32 triangles for the fewest new corners
// (TreeFlattener::plan_groups), so a group holds a connected patch whatever order the mesh lists
// its triangles in. A unit sphere whose triangles are shuffled, in plain leaves on cells 0.1
// wide, whose lists keep the mesh's order: 6.6 lanes and 9.6 corners a group (1.45 a lane),
// against 6.2 and 12.0 (1.94) when each group takes the list's next triangles. Hits stay brute
// force's.
TEST(WideLeaves, GroupsOfEightHoldConnectedPatchesOfAShuffledMesh) {
  if (!hybrid::kSharedCorners || kWideLanes != 8)
    GTEST_SKIP() << "this build does not store shared-corner groups of 8 (AVX2 builds do)";
  Mesh mesh = test::sphere(60, 120);
  std::mt19937 rng(11);
  std::shuffle(mesh.triangles.begin(), mesh.triangles.end(), rng);
  BuildParams p;
  p.hybrid_subtree_min = 0;
  p.cell_size = 0.1f;
  GridKdHybrid h;
  const auto [lanes, corners] = lanes_and_corners(h.build(mesh, p));
  std::printf("shuffled sphere: %.1f lanes and %.1f corners a group\n", lanes, corners);
  EXPECT_GT(lanes, 6.0);
  EXPECT_LT(corners, 1.7 * lanes);
  BruteForce brute;
  brute.build(mesh, BuildParams{});
  int bad = 0;
  for (const Ray& r : test::random_rays(mesh, 3000, 5)) {
    Hit hh, hb;
    const bool fh = h.intersect(r, hh), fb = brute.intersect(r, hb);
    bad += fh != fb || (fh && !same_bits(hh.t, hb.t));
  }
  EXPECT_EQ(bad, 0);
}

/// The share of references whose shared-corner groups store 16-bit triangle ids, from the
/// build's "triangle groups" figure ("...; 16-bit triangle ids for P% of references)"); -1
/// where it has none.
double narrow_id_percent(const BuildStats& st) {
  for (const auto& [key, value] : st.extra) {
    const size_t at = value.rfind("ids for ");
    double percent = 0;
    if (key == "triangle groups" && at != std::string::npos &&
        std::sscanf(value.c_str() + at, "ids for %lf%%", &percent) == 1)
      return percent;
  }
  return -1;
}

// A shared-corner group of 4 or more lanes stores their mesh indices as 16-bit differences from
// the smallest where they lie within 65535 of it (records.h, kNarrowIds), else whole. A sphere
// of 134,680 triangles in ring order: a group's neighbours have near indices, so nearly every
// reference's group is narrow; the same triangles shuffled: a group's indices spread over the
// whole mesh, so most are whole. Either way each hit names the triangle it lies on, at the t the
// kd-tree finds.
TEST(WideLeaves, SharedCornerGroupsNameTheirTrianglesByNarrowOrWholeIds) {
  if (!hybrid::kSharedCorners)
    GTEST_SKIP() << "this build stores groups by lane (its triangle ids are always whole)";
  const Mesh ordered = test::sphere(260, 260);
  ASSERT_GT(ordered.num_triangles(), 2u * 65536u);
  Mesh shuffled = ordered;
  std::mt19937 rng(3);
  std::shuffle(shuffled.triangles.begin(), shuffled.triangles.end(), rng);
  const std::vector<Ray> rays = test::random_rays(ordered, 3000, 21);
  for (const Mesh* m : {&ordered, static_cast<const Mesh*>(&shuffled)}) {
    const bool is_ordered = m == &ordered;
    const char* name = is_ordered ? "ordered" : "shuffled";
    GridKdHybrid h;
    const double narrow = narrow_id_percent(h.build(*m, BuildParams{}));
    std::printf("%s: 16-bit triangle ids for %.1f%% of references\n", name, narrow);
    if (is_ordered)
      EXPECT_GT(narrow, 90.0) << name;
    else
      EXPECT_LT(narrow, 50.0) << name;  // 13% with groups of 8, 35% with groups of 16
    EXPECT_GE(narrow, 0.0) << name;
    KdTree kd;
    kd.build(*m, BuildParams{});
    int bad = 0, hits = 0;
    for (const Ray& r : rays) {
      Hit hh, hk;
      const bool fh = h.intersect(r, hh), fk = kd.intersect(r, hk);
      bool good = fh == fk && (!fh || same_bits(hh.t, hk.t));
      if (good && fh) {
        ++hits;
        // The hit point from the named triangle's corners and (u, v) is the ray's at t.
        const auto c = m->corners(hh.prim);
        const Vec3 on = c[0] * (1.0f - hh.u - hh.v) + c[1] * hh.u + c[2] * hh.v;
        good = length(on - r.at(hh.t)) < 1e-4f;
      }
      if (!good && ++bad <= 5)
        ADD_FAILURE() << name << ": hybrid " << fh << " prim " << hh.prim << " t " << hh.t
                      << "; kd-tree " << fk << " prim " << hk.prim << " t " << hk.t;
    }
    EXPECT_EQ(bad, 0) << name;
    EXPECT_GT(hits, 500) << name;
  }
}

TEST(WideLeaves, HybridHitsMatchScalarBitForBitOnTheBunny) {
  if (kWideLanes == 1) GTEST_SKIP() << "this build's groups have one lane: no wide test";
  const std::string path = test::shared_scene("bunny/bun_zipper.ply");
  if (path.empty()) GTEST_SKIP() << "bunny/bun_zipper.ply is not in the shared scenes";
  const Scene scene = load_scene(path);
  GridKdHybrid h;
  h.build(scene.mesh, BuildParams{});
  EXPECT_EQ(wide_scalar_differences(h, test::random_rays(scene.mesh, 20000, 11), "bunny"), 0);
}

}  // namespace
}  // namespace kdgrid
