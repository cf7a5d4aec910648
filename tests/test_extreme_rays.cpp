// The extreme-ray families, written once and run for every structure the factory knows
// (accelerator_names() but brute force, the reference, and Embree's other configurations):
// axis-parallel rays, +0/-0 direction components, rays in the mesh's planes and in the structure's
// own split and cell planes, origins on boundaries, inside and outside, misses and invalid rays,
// rays grazing the box's edges, and scenes at scales 1e-6 and 1e6 and translated by 1e5. Each ray
// must agree with brute force; what is particular to one structure (step bounds, rays that miss
// without a step) is tested in that structure's file (test_grid.cpp, test_hybrid_agreement.cpp,
// test_irregular.cpp).
#include <gtest/gtest.h>

#include <functional>
#include <memory>
#include <string>
#include <tuple>
#include <vector>

#include "accel/accelerator.h"
#include "agreement.h"
#include "comparator_meshes.h"
#include "extreme_rays.h"
#include "test_util.h"

namespace kdgrid {
namespace {

using test::kExtremeCell;

/// Rays per random family: enough to meet every case of the generator many times, few enough
/// that the suite stays fast under the sanitizers.
constexpr int kRays = 500;

// Embree computes t with its own triangle test (not watertight), so t is compared within 1e-3
// and up to 1% of the well-posed rays may differ; on ill-posed rays (along shared edges, in the
// plane of coplanar triangles, starting on a triangle) only the sanity of its answer is checked.
constexpr double kEmbreeTol = 1e-3;

/// One build of the structure: the default, and for the hybrid and the irregular grid the
/// layouts whose walks differ.
struct Variant {
  std::string what;
  BuildParams params;
};

std::vector<Variant> variants(const std::string& name, const BuildParams& base) {
  std::vector<Variant> out = {{"", base}};
  if (name == "hybrid") {
    // Dense storage, a subtree in every leaf of more than 2 triangles, plain leaves, and the
    // paper's hybrid (plain leaves stepping over kd leaf boxes); and the automatic cell size.
    Variant dense = out[0], sub2 = out[0], plain = out[0], boxes = out[0], autocell = out[0];
    dense.params.hybrid_dense_matrix = true;
    sub2.params.hybrid_subtree_min = 2;
    plain.params.hybrid_subtree_min = 0;
    boxes.params.hybrid_subtree_min = 0;
    boxes.params.hybrid_expand_empty = false;
    autocell.params.cell_size = 0.0f;
    dense.what = " (dense)";
    sub2.what = " (subtrees over 2)";
    plain.what = " (plain leaves)";
    boxes.what = " (plain leaves, kd leaf boxes)";
    autocell.what = " (auto cell)";
    out.insert(out.end(), {dense, sub2, plain, boxes});
    if (base.cell_size > 0.0f) out.push_back(autocell);
  }
  if (name == "irregular") {
    Variant plain = out[0];
    plain.params.irregular_merge = plain.params.irregular_expand = false;
    plain.what = " (no merge/expand)";
    out.push_back(plain);
  }
  return out;
}

/// What a case checks beyond agreement.
struct Checks {
  /// The rays are well posed for any triangle test: Embree is held to 1% disagreement.
  bool embree_agrees = true;
  /// Counted and traced traversal match the fast path (structures whose trace is in t order).
  bool trace = false;
  /// t must equal brute force's exactly (structures sharing its triangle test).
  bool exact_t = false;
};

/// Checks of rays that are ill-posed for some triangle tests (Embree's may disagree).
const Checks kEmbreeMayDiffer = [] {
  Checks c;
  c.embree_agrees = false;
  return c;
}();

/// Build parameters with the cell size `size`, the rest the defaults.
BuildParams cell_of(float size) {
  BuildParams p;
  p.cell_size = size;
  return p;
}

/// Structures whose trace lists steps in order of t (test::check_counted_and_trace): not brute
/// force (one step) nor the BVH (nodes overlap; test_bvh.cpp checks its trace).
bool trace_in_t_order(const std::string& name) {
  return name != "brute" && name != "bvh" && !is_embree(name);
}

/// The rays whose trace order is checked: all of them, but for the trees (kd-tree, hybrid)
/// only those with no zero direction component, as a ray lying in a split plane visits both
/// children over one interval.
std::vector<Ray> trace_rays(const std::string& name, const std::vector<Ray>& rays) {
  if (name != "kdtree" && name != "hybrid") return rays;
  std::vector<Ray> off_plane;
  for (const Ray& r : rays)
    if (r.dir.x != 0 && r.dir.y != 0 && r.dir.z != 0) off_plane.push_back(r);
  return off_plane;
}

using RayMaker = std::function<std::vector<Ray>(const Accelerator&)>;

class ExtremeRayFamilies : public ::testing::TestWithParam<std::string> {
 protected:
  /// Builds the structure over `m` (each variant), makes the rays from the default build and
  /// checks them against brute force. Returns brute force's reference for further checks.
  test::BruteReference check(const std::string& label, const Mesh& m, const RayMaker& make,
                             const Checks& checks = {}, BuildParams base = {}) {
    SCOPED_TRACE(label);
    const std::string name = GetParam();
    base.threads = 2;
    const auto vs = variants(name, base);
    std::vector<Ray> rays;
    test::BruteReference ref;
    for (const Variant& v : vs) {
      auto acc = make_accelerator(name);
      acc->build(m, v.params);
      if (rays.empty()) {
        rays = make(*acc);
        ref = test::brute_answers(m, rays);
      }
      judge(m, *acc, rays, ref, label + v.what, checks);
      if (checks.trace && trace_in_t_order(name) && &v == &vs.front()) {
        EXPECT_EQ(test::check_counted_and_trace(*acc, trace_rays(name, rays)), 0) << label;
      }
    }
    return ref;
  }

  test::BruteReference check(const std::string& label, const Mesh& m, const std::vector<Ray>& rays,
                             const Checks& checks = {}, const BuildParams& base = {}) {
    return check(
        label, m, [&](const Accelerator&) { return rays; }, checks, base);
  }

 private:
  static void judge(const Mesh& m, const Accelerator& acc, const std::vector<Ray>& rays,
                    const test::BruteReference& ref, const std::string& label,
                    const Checks& checks) {
    if (!is_embree(acc.name())) {
      EXPECT_EQ(
          test::count_disagreements(m, acc, rays, ref, 5, nullptr, checks.exact_t ? 0.0 : 1e-5), 0)
          << label;
      return;
    }
    Hit h;
    for (const Ray& r : rays)
      if (acc.intersect(r, h)) {
        EXPECT_TRUE(h.t >= r.tmin && h.t < r.tmax && h.prim < m.num_triangles()) << label;
      }
    if (checks.embree_agrees) {
      const int bad = test::count_disagreements(m, acc, rays, ref, 0, nullptr, kEmbreeTol);
      EXPECT_LE(bad, int(rays.size() / 100)) << label << ": " << bad << " of " << rays.size();
    }
  }
};

TEST_P(ExtremeRayFamilies, AxisParallel) {
  const BuildParams cell = cell_of(kExtremeCell);
  check("lattice scene", test::extreme_scene(), test::axis_parallel_rays(-0.5f, 2.5f, kRays, 1), {},
        cell);
  const Checks on_lines = kEmbreeMayDiffer;  // a quarter start on the lines of the grid quads
  for (const auto& [name, mesh] : {test::NamedMesh{"grid quads", test::grid_quads()},
                                   test::NamedMesh{"soup", test::random_soup(2000, 3, 0.2f)},
                                   test::NamedMesh{"sphere", test::octahedron_sphere(4)}})
    check(name + " from outside", mesh, test::axis_parallel_rays_from_outside(kRays, 21), on_lines);
  const Mesh quads = test::integer_quads(8);
  check("integer quads, +0/-0 components", quads, test::signed_zero_axis_rays(600, 3, false));
  check("integer quads, along edges", quads, test::signed_zero_axis_rays(600, 3, true),
        kEmbreeMayDiffer);
}

TEST_P(ExtremeRayFamilies, SignedZeroComponents) {
  const BuildParams cell = cell_of(kExtremeCell);
  check("lattice scene", test::extreme_scene(), test::zero_component_rays(-0.5f, 2.5f, kRays, 2, 6),
        {}, cell);
  // +0 and -0 in the same components give the same answer.
  const Mesh soup = test::random_soup(2000, 5, 0.2f);
  const auto rays = test::zero_component_rays(-1.2f, 1.2f, kRays, 22, 5);
  check("soup", soup, rays);
  auto acc = build_accelerator(GetParam(), soup, BuildParams{});
  for (const Ray& r : rays) {
    Ray flipped = r;
    for (int a = 0; a < 3; ++a)
      if (flipped.dir[a] == 0.0f) flipped.dir[a] = -flipped.dir[a];
    Hit h1, h2;
    ASSERT_EQ(acc->intersect(r, h1), acc->intersect(flipped, h2));
    EXPECT_EQ(h1.prim, h2.prim);
  }
  // Rays from inside, outside and on the sphere's box, and along the lines of coplanar quads.
  Checks traced = kEmbreeMayDiffer;  // rays from the box faces and along its edges
  traced.trace = true;
  check("sphere", test::sphere(16, 32), test::signed_zero_rays(), traced);
  Checks exact = kEmbreeMayDiffer;
  exact.exact_t = true;
  const auto ref =
      check("coplanar quad lines", test::coplanar_quads(8), test::coplanar_quad_line_rays(), exact);
  int hits = 0;
  for (const Hit& h : ref.hits) hits += h.valid();
  EXPECT_GT(hits, int(ref.hits.size() / 4));
}

TEST_P(ExtremeRayFamilies, RaysInMeshPlanes) {
  const BuildParams cell = cell_of(kExtremeCell);
  Checks in_plane = kEmbreeMayDiffer;
  check("lattice scene", test::extreme_scene(),
        test::rays_in_lattice_planes(kExtremeCell, -1, 9, -0.5f, 2.5f, kRays, 3), in_plane, cell);
  for (const auto& [name, mesh] : {test::NamedMesh{"grid quads", test::grid_quads()},
                                   test::NamedMesh{"sphere", test::octahedron_sphere(4)}})
    check(name, mesh, test::rays_in_lattice_planes(0.5f, -2, 2, -1.2f, 1.2f, kRays, 23), in_plane);
}

TEST_P(ExtremeRayFamilies, RaysInStructurePlanes) {
  Checks in_plane = kEmbreeMayDiffer;
  const BuildParams cell = cell_of(kExtremeCell);
  for (const auto& [name, mesh, base] :
       {std::tuple{std::string("lattice scene"), test::extreme_scene(), cell},
        std::tuple{std::string("grid quads"), test::grid_quads(), BuildParams{}},
        std::tuple{std::string("sphere"), test::octahedron_sphere(4), BuildParams{}}}) {
    const Mesh& m = mesh;
    check(
        name, m,
        [&](const Accelerator& acc) {
          return test::rays_in_planes(test::structure_planes(acc, m, 200), kRays, 4);
        },
        in_plane, base);
  }
  // The integer quads at every extreme scale, with the grid's cells and the hybrid's cells on
  // the planes of the quads (8 per axis) and the kd-tree splitting on them (test_grid.cpp and
  // test_kdtree.cpp check that they do).
  Checks traced = in_plane;
  traced.trace = true;
  for (const test::ScaleCase& c : test::extreme_scale_cases()) {
    const Mesh m = test::transformed(test::integer_quads(8), c.scale, c.offset);
    BuildParams p;
    p.grid_lambda = 512.0f / float(m.num_triangles());
    p.cell_size = c.scale;
    check(
        std::string("integer quads, ") + c.name, m,
        [&](const Accelerator& acc) {
          auto planes = test::axis_positions(test::structure_planes(acc, m, 60));
          for (int a = 0; a < 3; ++a)
            for (int k = 0; k <= 8; ++k) planes.push_back({a, float(k) * c.scale + c.offset[a]});
          return test::extreme_rays(m, planes, 23, 40);
        },
        traced, p);
  }
}

TEST_P(ExtremeRayFamilies, ProceduralMeshes) {
  Checks in_plane = kEmbreeMayDiffer;
  for (const auto& [name, mesh] : test::test_meshes()) {
    const Mesh& m = mesh;
    check(
        name, m,
        [&](const Accelerator& acc) {
          return test::extreme_rays(m, test::axis_positions(test::structure_planes(acc, m, 20)), 29,
                                    8);
        },
        in_plane);
  }
}

TEST_P(ExtremeRayFamilies, OriginsOnBoundaries) {
  const BuildParams cell = cell_of(kExtremeCell);
  Checks on_boundary = kEmbreeMayDiffer;
  check("lattice points", test::extreme_scene(),
        test::rays_from_lattice_points(kExtremeCell, -1, 9, kRays, 5), on_boundary, cell);
  const Mesh sphere = test::octahedron_sphere(4);
  check(
      "sphere", sphere,
      [&](const Accelerator& acc) {
        return test::rays_from_structure_boundaries(test::structure_planes(acc, sphere, 200),
                                                    sphere, kRays, 24);
      },
      on_boundary);
}

TEST_P(ExtremeRayFamilies, OriginsInsideAndOutside) {
  const BuildParams cell = cell_of(kExtremeCell);
  check("lattice scene", test::extreme_scene(),
        test::rays_inside_and_outside(Vec3(1.0f), 0.01f, 1.99f, kRays, 6), {}, cell);
}

TEST_P(ExtremeRayFamilies, MissesAndInvalidRays) {
  const BuildParams cell = cell_of(kExtremeCell);
  int hits = 0;
  for (const Hit& h :
       check("beside the box", test::extreme_scene(), test::rays_beside_the_box(kRays, 7), {}, cell)
           .hits)
    hits += h.valid();
  const Mesh sphere = test::octahedron_sphere(4);
  for (const Hit& h :
       check("around the sphere", sphere, test::rays_missing_the_sphere(kRays / 3, 25)).hits)
    hits += h.valid();
  EXPECT_EQ(hits, 0) << "these rays all miss";
  const auto ref = check("invalid", sphere, test::invalid_rays());
  // Only the last, valid, ray hits (the sphere at t = 4).
  for (size_t i = 0; i + 1 < ref.hits.size(); ++i) EXPECT_FALSE(ref.hits[i].valid()) << i;
  EXPECT_NEAR(ref.hits.back().t, 4.0f, 1e-2f);
}

// The structures clip rays to their box in float before the exact clip: a box widened too
// little rejects rays that touch the scene box in a single point or segment. A box of 12
// triangles is its own scene box; origins 50 units away at offsets up to 1e5, and 1e4 and 1e6
// away, where the rounding of a float pre-clip grows with the origin's coordinates.
TEST_P(ExtremeRayFamilies, GrazingBoxEdgesAndCorners) {
  struct Case {
    float offset, distance;
  };
  for (const Case cs : {Case{0.0f, 50.0f}, Case{1e3f, 50.0f}, Case{1e5f, 50.0f}, Case{0.0f, 1e4f},
                        Case{0.0f, 1e6f}}) {
    const Vec3 lo(cs.offset, cs.offset * 0.5f, -cs.offset), hi = lo + Vec3(1.0f, 2.0f, 0.5f);
    const std::string what = "box at offset " + std::to_string(cs.offset) + ", origins " +
                             std::to_string(cs.distance) + " away";
    Checks edges = kEmbreeMayDiffer;
    const auto ref =
        check(what, test::box_mesh(lo, hi),
              test::rays_at_box_edges(lo, hi, cs.distance, cs.offset, kRays, 11), edges);
    int hits = 0;
    for (const Hit& h : ref.hits) hits += h.valid();
    EXPECT_GT(hits, kRays / 6) << what;
  }
}

TEST_P(ExtremeRayFamilies, ExtremeScales) {
  // The lattice scene scaled and moved, with rays in its transformed lattice planes.
  const Mesh base = test::extreme_scene();
  const auto in_planes = test::rays_in_lattice_planes(kExtremeCell, 0, 8, 0.0f, 2.0f, kRays / 4, 8);
  const struct {
    float scale;
    Vec3 offset;
    const char* what;
  } scene_cases[] = {{1e-6f, Vec3(0.0f), "scale 1e-6"},
                     {1e6f, Vec3(0.0f), "scale 1e6"},
                     {50.0f, Vec3(1e5f, -1e5f, 1e5f), "scale 50, translated 1e5"}};
  for (const auto& c : scene_cases) {
    const Mesh m = test::transformed(base, c.scale, c.offset);
    auto rays = test::random_rays(m, kRays, 99);
    const auto planar = test::transformed_rays(in_planes, c.scale, c.offset);
    rays.insert(rays.end(), planar.begin(), planar.end());
    const BuildParams cell = cell_of(kExtremeCell * c.scale);
    Checks in_plane = kEmbreeMayDiffer;
    check(std::string("lattice scene, ") + c.what, m, rays, in_plane, cell);
  }
  // A soup scaled by 1e-6 and 1e6, moved by 1e5, and scaled by 1e3 and moved by 1e5.
  const Mesh soup = test::random_soup(1500, 6, 0.2f);
  const auto soup_rays = test::random_rays(soup, kRays, 26);
  const struct {
    float scale;
    Vec3 offset;
  } cases[] = {{1e-6f, Vec3(0.0f)},
               {1e6f, Vec3(0.0f)},
               {1.0f, Vec3(1e5f, -1e5f, 1e5f)},
               {1e3f, Vec3(1e5f, 0.0f, 0.0f)}};
  for (const auto& c : cases)
    check("soup, scale " + std::to_string(c.scale) + " offset " + std::to_string(c.offset.x),
          test::transformed(soup, c.scale, c.offset),
          test::transformed_rays(soup_rays, c.scale, c.offset));
}

/// Instance names are the structure names ("AllStructures/ExtremeRayFamilies.Misses/grid").
/// Every structure but brute force (the reference itself) and Embree's other configurations
/// (embree-robust, embree-high: its kernels over other build flags, which `embree` holds to
/// here and the agreement suite holds each to).
std::vector<std::string> structures_under_test() {
  std::vector<std::string> out;
  for (const std::string& n : accelerator_names())
    if (n != "brute" && (!is_embree(n) || n == "embree")) out.push_back(n);
  return out;
}

INSTANTIATE_TEST_SUITE_P(AllStructures, ExtremeRayFamilies,
                         ::testing::ValuesIn(structures_under_test()),
                         [](const auto& test_info) { return test::test_name(test_info.param); });

}  // namespace
}  // namespace kdgrid
