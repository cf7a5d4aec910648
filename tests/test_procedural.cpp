// Procedural scenes (scene/procedural.h) and the scene writers (scene/write.h).
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <map>
#include <set>

#include "scene/load.h"
#include "scene/procedural.h"
#include "scene/write.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;

std::string temp_file(const std::string& name) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  return (fs::temp_directory_path() /
          ("kdgrid_" + std::string(info->name()) + "_" + std::to_string(::getpid()) + "_" + name))
      .string();
}

/// Every undirected edge is used by exactly two triangles, in opposite directions (closed
/// and consistently oriented). Returns a description of the first failure, or "".
std::string check_closed(const Mesh& m) {
  std::map<std::pair<uint32_t, uint32_t>, int> directed;
  for (const auto& t : m.triangles)
    for (int k = 0; k < 3; ++k) ++directed[{t[k], t[(k + 1) % 3]}];
  for (const auto& [e, n] : directed) {
    if (n != 1)
      return "edge " + std::to_string(e.first) + "-" + std::to_string(e.second) + " used " +
             std::to_string(n) + " times in one direction";
    if (!directed.count({e.second, e.first}))
      return "edge " + std::to_string(e.first) + "-" + std::to_string(e.second) +
             " has no opposite triangle (open boundary)";
  }
  return "";
}

/// Signed volume enclosed by a closed mesh (positive when triangles wind outwards).
double signed_volume(const Mesh& m) {
  double v = 0;
  for (size_t i = 0; i < m.num_triangles(); ++i) {
    const auto c = m.corners(i);
    v += dot(Vec3d(c[0]), cross(Vec3d(c[1]), Vec3d(c[2]))) / 6.0;
  }
  return v;
}

TEST(Procedural, EveryGeneratorMakesAValidMesh) {
  for (const auto& g : procedural_generators()) {
    SCOPED_TRACE(g.name);
    ProceduralParams p;
    if (g.name != "cornell" && g.name != "sphere") p.count = 300;
    Scene s = generate_scene(g.name, p);
    EXPECT_NO_THROW(s.mesh.validate(g.name));
    EXPECT_GT(s.mesh.num_triangles(), 0u);
    EXPECT_FALSE(g.description.empty());
    // Non-degenerate triangles only (every generator is meant to produce real surfaces).
    for (size_t i = 0; i < s.mesh.num_triangles(); ++i)
      ASSERT_GT(length(s.mesh.geometric_normal(i)), 0.0f) << "triangle " << i;
    EXPECT_NO_THROW(s.finalize());
  }
}

TEST(Procedural, RandomGeneratorsFollowTheSeed) {
  for (const char* name : {"thin-triangles", "coplanar-quads", "duplicates", "soup"}) {
    SCOPED_TRACE(name);
    ProceduralParams p;
    p.count = 100;
    p.seed = 7;
    const Scene a = generate_scene(name, p), b = generate_scene(name, p);
    EXPECT_EQ(a.mesh.positions.size(), b.mesh.positions.size());
    EXPECT_TRUE(
        std::equal(a.mesh.positions.begin(), a.mesh.positions.end(), b.mesh.positions.begin()));
    p.seed = 8;
    const Scene c = generate_scene(name, p);
    EXPECT_FALSE(
        a.mesh.positions.size() == c.mesh.positions.size() &&
        std::equal(a.mesh.positions.begin(), a.mesh.positions.end(), c.mesh.positions.begin()));
  }
  ProceduralParams p;
  p.count = 1234;
  EXPECT_EQ(generate_scene("soup", p).mesh.num_triangles(), 1234u);
  EXPECT_EQ(generate_scene("thin-triangles", p).mesh.num_triangles(), 1234u);
  EXPECT_EQ(generate_scene("coplanar-quads", p).mesh.num_triangles(), 2468u);
}

TEST(Procedural, SphereAndTorusAreClosedAndOutward) {
  for (int level = 0; level <= 4; ++level) {
    SCOPED_TRACE("sphere level " + std::to_string(level));
    const Mesh m = make_icosphere(level);
    EXPECT_EQ(m.num_triangles(), 20u << (2 * level));
    EXPECT_EQ(check_closed(m), "");
    // The inscribed polyhedron's volume approaches 4/3 pi from below.
    const double v = signed_volume(m);
    EXPECT_GT(v, 0.0);
    EXPECT_LT(v, 4.18879);
    if (level >= 3) {
      EXPECT_GT(v, 4.18879 * 0.97);
    }
  }
  for (int count : {100, 5000, 20000}) {
    SCOPED_TRACE("torus " + std::to_string(count));
    ProceduralParams p;
    p.count = count;
    const Mesh m = generate_scene("torus", p).mesh;
    EXPECT_NEAR(double(m.num_triangles()), count, count * 0.1);
    EXPECT_EQ(check_closed(m), "");
    const double exact = 2.0 * 3.14159265 * 3.14159265 * 1.0 * 0.35 * 0.35;
    const double v = signed_volume(m);
    EXPECT_GT(v, 0.0);
    if (count >= 5000) {
      EXPECT_NEAR(v, exact, exact * 0.02);
    }
  }
  EXPECT_NE(check_closed(make_box({0, 0, 0}, {1, 2, 3})), "")
      << "faces do not share vertices, so the check must see open edges";
}

TEST(Procedural, ClosedCheckCatchesHoles) {
  Mesh m = make_icosphere(1);
  m.triangles.pop_back();
  EXPECT_NE(check_closed(m), "");
  Mesh flipped = make_icosphere(1);
  std::swap(flipped.triangles[0][0], flipped.triangles[0][1]);
  EXPECT_NE(check_closed(flipped), "");
}

TEST(Procedural, CornellHasWhatTheRendererNeeds) {
  const Scene s = generate_scene("cornell");
  EXPECT_TRUE(s.has_reflective_material());
  EXPECT_TRUE(s.has_refractive_material());
  ASSERT_TRUE(s.camera.has_value());
  ASSERT_EQ(s.lights.size(), 1u);
  bool emissive = false;
  for (const auto& m : s.materials) emissive |= max_component(m.emission) > 0.0f;
  EXPECT_TRUE(emissive);
  // The light hangs inside the box, below the ceiling.
  const Box3 b = s.mesh.bounds();
  EXPECT_TRUE(b.contains(s.lights[0].position));
  EXPECT_LT(s.lights[0].position.y, b.hi.y);
  // The camera looks into the box from outside the open side.
  EXPECT_GT(s.camera->eye.z, b.hi.z);
}

TEST(Procedural, TeapotInStadiumScales) {
  const Scene s = generate_scene("teapot-in-stadium");
  Box3 small, big;
  for (size_t i = 0; i < s.mesh.num_triangles(); ++i)
    (s.mesh.material_of(i) == 1 ? small : big).grow(s.mesh.triangle_bounds(i));
  EXPECT_GE(max_component(big.extent()) / max_component(small.extent()), 1000.0f);
  EXPECT_NEAR(double(s.mesh.num_triangles()), 20012.0, 2000.0);
  EXPECT_TRUE(big.contains(small.lo) && big.contains(small.hi));
}

TEST(Procedural, CoplanarQuadsLieExactlyInTheirPlanes) {
  ProceduralParams p;
  p.count = 400;
  const Mesh m = generate_scene("coplanar-quads", p).mesh;
  int integer_quads = 0;
  for (size_t i = 0; i < m.num_triangles(); ++i) {
    const auto c = m.corners(i);
    const bool in_plane = (c[0].z == 0 && c[1].z == 0 && c[2].z == 0) ||
                          (c[0].z == 3 && c[1].z == 3 && c[2].z == 3) ||
                          (c[0].x == 0 && c[1].x == 0 && c[2].x == 0) ||
                          (c[0].y == 1.5f && c[1].y == 1.5f && c[2].y == 1.5f);
    ASSERT_TRUE(in_plane) << "triangle " << i;
    bool integer = true;
    for (const Vec3& q : c)
      for (int a = 0; a < 3; ++a) integer &= q[a] == std::floor(q[a]) || q[a] == 1.5f;
    integer_quads += integer;
  }
  EXPECT_GT(integer_quads, 300);
}

TEST(Procedural, DuplicatesHasExactAndNearDuplicates) {
  ProceduralParams p;
  p.count = 100;
  const Mesh m = generate_scene("duplicates", p).mesh;
  int exact = 0, near = 0;
  for (size_t i = 1; i < m.num_triangles(); ++i) {
    if (m.triangles[i] == m.triangles[i - 1]) ++exact;
    const auto a = m.corners(i), b = m.corners(i - 1);
    if (m.triangles[i] != m.triangles[i - 1] && length(a[0] - b[0]) < 1e-5f) ++near;
  }
  EXPECT_EQ(exact, 100);
  EXPECT_EQ(near, 25);
}

TEST(Procedural, BadParametersAreRejected) {
  EXPECT_THROW(generate_scene("teapot"), ParamError);
  ProceduralParams p;
  p.count = -1;
  EXPECT_THROW(generate_scene("soup", p), ParamError);
  p.count = 0;
  p.level = 9;
  EXPECT_THROW(generate_scene("sphere", p), ParamError);
  try {
    generate_scene("nope");
  } catch (const ParamError& e) {
    EXPECT_NE(std::string(e.what()).find("cornell"), std::string::npos) << "lists valid names";
  }
}

// ---- writers -----------------------------------------------------------------------------

void expect_same_triangles(const Mesh& a, const Mesh& b) {
  ASSERT_EQ(a.num_triangles(), b.num_triangles());
  for (size_t i = 0; i < a.num_triangles(); ++i) {
    const auto ca = a.corners(i), cb = b.corners(i);
    for (int k = 0; k < 3; ++k) ASSERT_EQ(ca[k], cb[k]) << "triangle " << i << " corner " << k;
  }
}

TEST(Writers, GltfRoundTripKeepsTrianglesMaterialsCameraLights) {
  Scene s = generate_scene("cornell");
  Light spot;
  spot.type = LightType::Spot;
  spot.position = {0.5f, 1.5f, 0.5f};
  spot.direction = normalize(Vec3(0.2f, -1.0f, -0.1f));
  spot.inner_cone = 0.3f;
  spot.outer_cone = 0.6f;
  spot.intensity = 3.0f;
  spot.name = "spot";
  s.lights.push_back(spot);
  const std::string path = temp_file("cornell.gltf");
  write_gltf(s, path);
  EXPECT_LT(fs::file_size(path), 300u * 1024u);
  const Scene r = load_gltf(path);
  fs::remove(path);
  expect_same_triangles(s.mesh, r.mesh);
  ASSERT_EQ(r.mesh.normals.size(), r.mesh.positions.size());
  // Materials by triangle: same colours, metal, glass and emission.
  ASSERT_EQ(r.materials.size(), s.materials.size());
  for (size_t i = 0; i < s.mesh.num_triangles(); ++i) {
    const Material& a = s.materials[s.mesh.material_of(i)];
    const Material& b = r.materials[r.mesh.material_of(i)];
    ASSERT_EQ(a.name, b.name) << "triangle " << i;
    EXPECT_NEAR(a.base_color.x, b.base_color.x, 1e-6f);
    EXPECT_EQ(a.metallic, b.metallic);
    EXPECT_EQ(a.transmission, b.transmission);
    EXPECT_NEAR(a.ior, b.ior, 1e-6f);
    EXPECT_NEAR(a.emission.x, b.emission.x, 1e-5f);
    EXPECT_NEAR(a.emission.z, b.emission.z, 1e-5f);
  }
  ASSERT_TRUE(r.camera.has_value());
  EXPECT_NEAR(length(r.camera->eye - s.camera->eye), 0.0f, 1e-5f);
  EXPECT_NEAR(r.camera->fov_deg, s.camera->fov_deg, 1e-3f);
  const Vec3 fwd_a = normalize(s.camera->target - s.camera->eye);
  const Vec3 fwd_b = normalize(r.camera->target - r.camera->eye);
  EXPECT_GT(dot(fwd_a, fwd_b), 0.99999f);
  ASSERT_EQ(r.lights.size(), 2u);
  EXPECT_EQ(r.lights[0].type, LightType::Point);
  EXPECT_NEAR(length(r.lights[0].position - s.lights[0].position), 0.0f, 1e-5f);
  EXPECT_NEAR(r.lights[0].intensity, s.lights[0].intensity, 1e-4f);
  EXPECT_EQ(r.lights[1].type, LightType::Spot);
  EXPECT_GT(dot(normalize(r.lights[1].direction), spot.direction), 0.99999f);
  EXPECT_NEAR(r.lights[1].outer_cone, spot.outer_cone, 1e-5f);
  EXPECT_NEAR(r.lights[1].inner_cone, spot.inner_cone, 1e-5f);
}

TEST(Writers, PlyAndObjRoundTripKeepTriangleOrder) {
  ProceduralParams p;
  p.count = 500;
  for (const char* name : {"soup", "torus"}) {
    SCOPED_TRACE(name);
    const Scene s = generate_scene(name, p);
    const std::string ply = temp_file(std::string(name) + ".ply");
    const std::string obj = temp_file(std::string(name) + ".obj");
    write_scene(s, ply);
    write_scene(s, obj);
    const Scene a = load_ply(ply), b = load_obj(obj);
    fs::remove(ply);
    fs::remove(obj);
    expect_same_triangles(s.mesh, a.mesh);
    expect_same_triangles(s.mesh, b.mesh);
  }
  EXPECT_THROW(write_scene(generate_scene("soup", p), temp_file("x.stl")), ParamError);
  EXPECT_THROW(write_scene(generate_scene("soup", p), "/no/such/dir/x.ply"), Error);
}

TEST(Writers, CommittedCornellAssetIsCurrent) {
  // assets/cornell.gltf is `kdgrid gen cornell -o assets/cornell.gltf`: it must load and
  // match the generator (regenerate it when the generator changes).
  const Scene asset = load_scene(test::source_path("assets/cornell.gltf"));
  const Scene gen = generate_scene("cornell");
  expect_same_triangles(gen.mesh, asset.mesh);
  EXPECT_LT(fs::file_size(test::source_path("assets/cornell.gltf")), 300u * 1024u);
}

TEST(GenCli, WritesFilesAndRejectsBadInput) {
  const std::string out = temp_file("sphere.ply");
  const std::string cli = KDGRID_CLI_PATH;
  EXPECT_EQ(std::system((cli + " gen sphere --level 2 -o " + out + " > /dev/null").c_str()), 0);
  EXPECT_EQ(load_ply(out).mesh.num_triangles(), 320u);
  fs::remove(out);
  EXPECT_NE(std::system((cli + " gen sphere -o " + temp_file("x.stl") + " 2> /dev/null").c_str()),
            0);
  EXPECT_NE(std::system((cli + " gen bogus -o " + temp_file("x.ply") + " 2> /dev/null").c_str()),
            0);
  EXPECT_NE(std::system(
                (cli + " gen soup --count -5 -o " + temp_file("x.ply") + " 2> /dev/null").c_str()),
            0);
}

}  // namespace
}  // namespace kdgrid
