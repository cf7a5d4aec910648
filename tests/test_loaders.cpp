// Scene loaders on good input: PLY (own reader; ascii and binary in either byte order), OBJ/MTL
// and glTF 2.0 (embedded buffer and GLB) on small files written here, the shared scenes, and
// `kdgrid info`. Bad input, format by format: test_loader_errors*.cpp.
#include <gtest/gtest.h>

#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "cli_util.h"
#include "loader_inputs.h"
#include "scene/load.h"
#include "temp_dir.h"
#include "test_util.h"

namespace kdgrid {
namespace {

using namespace test;

// ---------------------------------------------------------------------------------------
// PLY

TEST(PlyLoader, AsciiFanTriangulationInFileOrder) {
  const Scene s = parse_ply(kAsciiPly, std::strlen(kAsciiPly), "fan.ply");
  ASSERT_EQ(s.mesh.num_vertices(), 7u);
  // triangle -> 1, quad -> 2, pentagon -> 3 triangles (v0, v_{i-1}, v_i), in file order.
  const std::vector<TriangleTest> want = {{0, 1, 2}, {0, 1, 2}, {0, 2, 3},
                                          {6, 5, 4}, {6, 4, 3}, {6, 3, 2}};
  ASSERT_EQ(s.mesh.triangles.size(), want.size());
  for (size_t i = 0; i < want.size(); ++i)
    EXPECT_EQ(s.mesh.triangles[i], want[i]) << "triangle " << i;
  expect_near(s.mesh.positions[4], {-1, 2.5f, 3});
  expect_near(s.mesh.positions[5], {0.5f, -0.125f, 7});
  EXPECT_TRUE(s.mesh.normals.empty());
  EXPECT_TRUE(s.mesh.uvs.empty());
}

TEST(PlyLoader, AsciiWithCrlfLineEnds) {
  std::string text = kAsciiPly;
  std::string crlf;
  for (char c : text) {
    if (c == '\n') crlf += '\r';
    crlf += c;
  }
  const Scene s = parse_ply(crlf.data(), crlf.size(), "crlf.ply");
  EXPECT_EQ(s.mesh.num_triangles(), 6u);
  expect_near(s.mesh.positions[6], {2, 2, 2});
}

TEST(PlyLoader, AsciiNormalsUvsAndVertexIndexName) {
  const std::string text =
      "ply\nformat ascii 1.0\n"
      "element vertex 3\n"
      "property float32 nx\nproperty float32 ny\nproperty float32 nz\n"
      "property float32 texture_u\nproperty float32 texture_v\n"
      "property float32 x\nproperty float32 y\nproperty float32 z\n"
      "element face 1\nproperty list uint8 int32 vertex_index\n"
      "end_header\n"
      "0 0 1 0 0 0 0 0\n"
      "0 0 1 1 0 1 0 0\n"
      "0 1 0 0.5 1 0 1 0\n"
      "3 0 1 2\n";
  const Scene s = parse_ply(text.data(), text.size(), "attrs.ply");
  ASSERT_EQ(s.mesh.normals.size(), 3u);
  ASSERT_EQ(s.mesh.uvs.size(), 3u);
  expect_near(s.mesh.positions[1], {1, 0, 0});
  expect_near(s.mesh.normals[2], {0, 1, 0});
  EXPECT_FLOAT_EQ(s.mesh.uvs[2][0], 0.5f);
  EXPECT_FLOAT_EQ(s.mesh.uvs[2][1], 1.0f);
}

void check_binary_scene(const Scene& s) {
  ASSERT_EQ(s.mesh.num_vertices(), 5u);
  for (size_t i = 0; i < 5; ++i)
    expect_near(s.mesh.positions[i],
                {float(kBinVerts[i].x), float(kBinVerts[i].y), float(kBinVerts[i].z)});
  const std::vector<TriangleTest> want = {{0, 1, 2}, {0, 2, 3}, {0, 3, 4},
                                          {4, 3, 2}, {4, 2, 1}, {0, 2, 4}};
  ASSERT_EQ(s.mesh.triangles.size(), want.size());
  for (size_t i = 0; i < want.size(); ++i)
    EXPECT_EQ(s.mesh.triangles[i], want[i]) << "triangle " << i;
}

TEST(PlyLoader, BinaryLittleEndianOddOrderAndTypes) {
  const std::string d = binary_ply(false);
  check_binary_scene(parse_ply(d.data(), d.size(), "le.ply"));
}

TEST(PlyLoader, BinaryBigEndianOddOrderAndTypes) {
  const std::string d = binary_ply(true);
  check_binary_scene(parse_ply(d.data(), d.size(), "be.ply"));
}

TEST(PlyLoader, LoadSceneFromFileFinalizes) {
  TempDir tmp;
  const std::string p = tmp.write("le.ply", binary_ply(false));
  const Scene s = load_scene(p);
  EXPECT_EQ(s.mesh.num_triangles(), 6u);
  EXPECT_EQ(s.source, p);
  EXPECT_FALSE(s.materials.empty());
  EXPECT_TRUE(s.camera.has_value());
}

// ---------------------------------------------------------------------------------------
// OBJ + MTL

TEST(ObjLoader, MaterialsTexturesAndFanOrder) {
  TempDir tmp;
  // 2x1 RGB texture as binary PPM (OpenImageIO reads it): red, blue.
  tmp.write("tex.ppm", std::string("P6\n2 1\n255\n") + std::string("\xff\x00\x00\x00\x00\xff", 6));
  tmp.write("scene.mtl",
            "newmtl mirror\nKd 0.1 0.2 0.3\nKs 0.9 0.8 0.7\nNs 250\nillum 3\n"
            "newmtl glass\nKd 1 1 1\nNi 1.33\nd 0.25\nillum 7\n"
            "newmtl lamp\nKd 0 0 0\nKe 5 4 3\n"
            "newmtl textured\nKd 1 1 1\nmap_Kd tex.ppm\n"
            "newmtl lost\nKd 1 1 1\nmap_Kd does_not_exist.png\n");
  const std::string p = tmp.write("scene.obj",
                                  "mtllib scene.mtl\n"
                                  "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 2 0\n"
                                  "vt 0 0\nvt 1 0\nvt 1 1\n"
                                  "vn 0 0 1\nvn 0 0 -1\n"
                                  "usemtl mirror\n"
                                  "f 1 2 3 4\n"  // quad -> (0,1,2) (0,2,3)
                                  "usemtl glass\n"
                                  "f 5 4 3 2 1\n"  // pentagon -> 3 triangles
                                  "usemtl lamp\n"
                                  "f 1/1/1 2/2/1 3/3/2\n"  // differing indices per corner
                                  "usemtl textured\n"
                                  "f -5 -4 -3\n"  // relative indices
                                  "usemtl lost\n"
                                  "f 1 3 4\n");
  const Scene s = load_scene(p);
  ASSERT_EQ(s.mesh.num_triangles(), 2u + 3u + 1u + 1u + 1u);
  // Fan order, by corner positions (the loader may re-index vertices).
  const std::vector<std::array<Vec3, 3>> want = {{{{0, 0, 0}, {1, 0, 0}, {1, 1, 0}}},
                                                 {{{0, 0, 0}, {1, 1, 0}, {0, 1, 0}}},
                                                 {{{0.5f, 2, 0}, {0, 1, 0}, {1, 1, 0}}},
                                                 {{{0.5f, 2, 0}, {1, 1, 0}, {1, 0, 0}}},
                                                 {{{0.5f, 2, 0}, {1, 0, 0}, {0, 0, 0}}}};
  for (size_t i = 0; i < want.size(); ++i) {
    const auto c = s.mesh.corners(i);
    for (int k = 0; k < 3; ++k) expect_near(c[size_t(k)], want[i][size_t(k)]);
  }
  // Per-face materials.
  auto mat = [&](size_t tri) -> const Material& { return s.materials[s.mesh.material_of(tri)]; };
  EXPECT_EQ(mat(0).name, "mirror");
  EXPECT_EQ(mat(1).name, "mirror");
  EXPECT_EQ(mat(2).name, "glass");
  EXPECT_EQ(mat(5).name, "lamp");
  EXPECT_EQ(mat(6).name, "textured");
  EXPECT_EQ(mat(7).name, "lost");
  // MTL mapping.
  expect_near(mat(0).base_color, {0.1f, 0.2f, 0.3f});
  expect_near(mat(0).specular, {0.9f, 0.8f, 0.7f});
  expect_near(mat(0).mirror, {0.9f, 0.8f, 0.7f});
  EXPECT_FLOAT_EQ(mat(0).shininess, 250.0f);
  EXPECT_FALSE(mat(0).refracts());
  EXPECT_NEAR(mat(2).transmission, 0.75f, 1e-6f);
  EXPECT_NEAR(mat(2).ior, 1.33f, 1e-6f);
  expect_near(mat(5).emission, {5, 4, 3});
  // Texture read through OpenImageIO; the missing one only warns.
  ASSERT_GE(mat(6).base_color_texture, 0);
  const Texture& t = s.textures[size_t(mat(6).base_color_texture)];
  EXPECT_EQ(t.width, 2);
  EXPECT_EQ(t.height, 1);
  ASSERT_EQ(t.pixels.size(), 6u);
  EXPECT_EQ(t.pixels[0], 255);
  EXPECT_EQ(t.pixels[5], 255);
  EXPECT_EQ(mat(7).base_color_texture, -1);
  // Mixed attributes: normals are not on every corner, so none are kept; uvs fill with 0.
  EXPECT_TRUE(s.mesh.normals.empty());
  ASSERT_EQ(s.mesh.uvs.size(), s.mesh.num_vertices());
  const auto& lamp = s.mesh.triangles[5];
  EXPECT_FLOAT_EQ(s.mesh.uvs[lamp[2]][0], 1.0f);
  EXPECT_FLOAT_EQ(s.mesh.uvs[lamp[2]][1], 1.0f);
}

TEST(ObjLoader, PerCornerNormalsAreDeindexed) {
  TempDir tmp;
  const std::string p = tmp.write("n.obj",
                                  "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nvn 0 1 0\n"
                                  "f 1//1 2//1 3//1\nf 2//2 4//2 3//2\n");
  const Scene s = load_scene(p);
  ASSERT_EQ(s.mesh.num_triangles(), 2u);
  ASSERT_EQ(s.mesh.normals.size(), s.mesh.num_vertices());
  // Vertices 2 and 3 (0-based 1, 2) appear with two different normals: each triangle keeps its own.
  for (uint32_t v : s.mesh.triangles[0]) expect_near(s.mesh.normals[v], {0, 0, 1});
  for (uint32_t v : s.mesh.triangles[1]) expect_near(s.mesh.normals[v], {0, 1, 0});
  expect_near(s.mesh.corners(1)[0], {1, 0, 0});
  expect_near(s.mesh.corners(1)[1], {1, 1, 0});
}

TEST(ObjLoader, MissingMtlWarnsAndUsesGrey) {
  TempDir tmp;
  const std::string p =
      tmp.write("nomtl.obj", "mtllib gone.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl brick\nf 1 2 3\n");
  const Scene s = load_scene(p);
  EXPECT_EQ(s.mesh.num_triangles(), 1u);
  ASSERT_EQ(s.materials.size(), 1u);
  EXPECT_EQ(s.materials[s.mesh.material_of(0)].name, "default grey diffuse");
}

// ---------------------------------------------------------------------------------------
// glTF

void check_test_gltf(const Scene& s) {
  // 3 instances of mesh 0, each 2 indexed + 2 strip triangles; the points primitive is skipped.
  ASSERT_EQ(s.mesh.num_triangles(), 12u);
  // Instance 1: translate(10,0,0) * scale 2.
  const auto c0 = s.mesh.corners(0);
  expect_near(c0[0], {10, 0, 0});
  expect_near(c0[1], {12, 0, 0});
  expect_near(c0[2], {12, 2, 0});
  expect_near(s.mesh.corners(1)[2], {10, 2, 0});
  // Strip of 4 vertices: (0,1,2), (1,3,2).
  const auto c3 = s.mesh.corners(3);
  expect_near(c3[0], {12, 0, 0});
  expect_near(c3[1], {10, 2, 0});
  expect_near(c3[2], {12, 2, 0});
  // Instance 2: 90 degrees about z then z -= 3: (1,0,0) -> (0,1,-3).
  expect_near(s.mesh.corners(4)[1], {0, 1, -3});
  // Normals: rotated by the matrix, and by the inverse transpose under scale (1,2,1).
  ASSERT_EQ(s.mesh.normals.size(), s.mesh.num_vertices());
  expect_near(s.mesh.normals[s.mesh.triangles[0][0]], {0, 0, 1});
  expect_near(s.mesh.normals[s.mesh.triangles[5][2]], {-0.8f, 0.6f, 0});
  const float k = 1.0f / std::sqrt(0.36f + 0.16f);
  expect_near(s.mesh.normals[s.mesh.triangles[9][2]], {0.6f * k, 0.4f * k, 0});
  // uvs: normalized u16.
  ASSERT_EQ(s.mesh.uvs.size(), s.mesh.num_vertices());
  EXPECT_NEAR(s.mesh.uvs[s.mesh.triangles[0][1]][0], 1.0f, 1e-6f);
  EXPECT_NEAR(s.mesh.uvs[s.mesh.triangles[1][2]][1], 32768.0f / 65535.0f, 1e-6f);
  // Materials.
  const Material& m0 = s.materials[s.mesh.material_of(0)];
  EXPECT_EQ(m0.name, "emissive");
  expect_near(m0.base_color, {0.5f, 0.25f, 1});
  EXPECT_NEAR(m0.metallic, 0.3f, 1e-6f);
  EXPECT_NEAR(m0.roughness, 0.7f, 1e-6f);
  expect_near(m0.emission, {4, 2, 0});
  const Material& m1 = s.materials[s.mesh.material_of(2)];
  EXPECT_EQ(m1.name, "water");
  EXPECT_NEAR(m1.transmission, 0.9f, 1e-6f);
  EXPECT_NEAR(m1.ior, 1.33f, 1e-6f);
  // Camera from node 2.
  ASSERT_TRUE(s.camera.has_value());
  EXPECT_EQ(s.camera->name, "testcam");
  expect_near(s.camera->eye, {0, 0, 5});
  expect_near(s.camera->target, {0, 0, 4});
  expect_near(s.camera->up, {0, 1, 0});
  EXPECT_NEAR(s.camera->fov_deg, 0.5f * 180.0f / 3.14159265f, 1e-4f);
  // Lights.
  ASSERT_EQ(s.lights.size(), 2u);
  EXPECT_EQ(s.lights[0].type, LightType::Point);
  EXPECT_EQ(s.lights[0].name, "bulb");
  expect_near(s.lights[0].position, {0, 3, 0});
  expect_near(s.lights[0].color, {1, 0.5f, 0.25f});
  EXPECT_FLOAT_EQ(s.lights[0].intensity, 20.0f);
  EXPECT_EQ(s.lights[1].type, LightType::Spot);
  expect_near(s.lights[1].direction, {0, -1, 0});
  EXPECT_FLOAT_EQ(s.lights[1].inner_cone, 0.2f);
  EXPECT_FLOAT_EQ(s.lights[1].outer_cone, 0.5f);
}

TEST(GltfLoader, EmbeddedBufferSceneGraph) {
  TempDir tmp;
  const std::string p = tmp.write("test.gltf", gltf_json(embedded_buffer(gltf_buffer())));
  check_test_gltf(load_scene(p));
}

TEST(GltfLoader, BinaryGlb) {
  TempDir tmp;
  const std::string bin = gltf_buffer();
  const std::string p =
      tmp.write("test.glb",
                make_glb(gltf_json(R"({"byteLength": )" + std::to_string(bin.size()) + "}"), bin));
  check_test_gltf(load_scene(p));
}

// A texture whose image file is missing only warns; a TRIANGLE_FAN primitive is converted
// as (v0, v_i, v_i+1).
TEST(GltfLoader, MissingImageAndTriangleFan) {
  TempDir tmp;
  std::string json = gltf_json(embedded_buffer(gltf_buffer()));
  auto replace = [&](const std::string& from, const std::string& to) {
    const size_t at = json.find(from);
    ASSERT_NE(at, std::string::npos) << from;
    json.replace(at, from.size(), to);
  };
  replace(R"("metallicFactor": 0.3)", R"("metallicFactor": 0.3, "baseColorTexture": {"index": 0})");
  replace(R"("scene": 0,)",
          R"("scene": 0, "images": [{"uri": "missing.png"}], "textures": [{"source": 0}],)");
  replace(R"("mode": 0)", R"("mode": 6)");
  const Scene s = load_scene(tmp.write("fan.gltf", json));
  ASSERT_EQ(s.mesh.num_triangles(), 18u);  // 3 instances of 2 + 2 + 2
  EXPECT_TRUE(s.textures.empty());
  EXPECT_EQ(s.materials[s.mesh.material_of(0)].base_color_texture, -1);
  // Instance 1's fan: triangles 4 and 5 = (0,1,2), (0,2,3) of the quad scaled by 2 at x=10.
  expect_near(s.mesh.corners(4)[1], {12, 0, 0});
  expect_near(s.mesh.corners(5)[0], {10, 0, 0});
  expect_near(s.mesh.corners(5)[1], {12, 2, 0});
  expect_near(s.mesh.corners(5)[2], {10, 2, 0});
}

// ---------------------------------------------------------------------------------------
// Shared scenes

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

Scene timed_load(const std::string& path, const char* label) {
  const auto t0 = std::chrono::steady_clock::now();
  Scene s = load_scene(path);
  std::printf("[ load     ] %-26s %9zu triangles %9zu vertices in %.3f s\n", label,
              s.mesh.num_triangles(), s.mesh.num_vertices(), seconds_since(t0));
  return s;
}

/// Loads shared scene `rel` (or skips the test) and checks its triangle and vertex counts.
void expect_scene_size(const char* rel, const char* label, size_t triangles, size_t vertices) {
  KDGRID_REQUIRE_SCENE(p, rel);
  const Scene s = timed_load(p, label);
  EXPECT_EQ(s.mesh.num_triangles(), triangles);
  EXPECT_EQ(s.mesh.num_vertices(), vertices);
}

TEST(SharedScenes, Bunny) {
  expect_scene_size("bunny/bun_zipper.ply", "bunny", 69451u, 35947u);
}

TEST(SharedScenes, DragonRes2) {
  expect_scene_size("dragon/dragon_vrip_res2.ply", "dragon res2", 202520u, 100250u);
}

TEST(SharedScenes, DragonFull) {
  expect_scene_size("dragon/dragon_vrip.ply", "dragon full", 871414u, 437645u);
}

TEST(SharedScenes, Sponza) {
  KDGRID_REQUIRE_SCENE(p, "sponza_dabrovic/sponza.obj");
  const Scene s = timed_load(p, "sponza");
  EXPECT_EQ(s.mesh.num_triangles(), 66454u);
  EXPECT_FALSE(s.materials.empty());
}

TEST(SharedScenes, BoxTextured) {
  KDGRID_REQUIRE_SCENE(p, "gltf/BoxTextured/BoxTextured.glb");
  const Scene s = timed_load(p, "BoxTextured.glb");
  EXPECT_EQ(s.mesh.num_triangles(), 12u);
  ASSERT_EQ(s.textures.size(), 1u);
  EXPECT_GT(s.textures[0].width, 0);
  EXPECT_EQ(
      s.textures[0].pixels.size(),
      size_t(s.textures[0].width) * size_t(s.textures[0].height) * size_t(s.textures[0].channels));
  EXPECT_GE(s.materials[s.mesh.material_of(0)].base_color_texture, 0);
  EXPECT_EQ(s.mesh.uvs.size(), s.mesh.num_vertices());
}

TEST(SharedScenes, CamerasGetsItsCamera) {
  KDGRID_REQUIRE_SCENE(p, "gltf/Cameras/Cameras.gltf");
  const Scene s = timed_load(p, "Cameras.gltf");
  EXPECT_EQ(s.mesh.num_triangles(), 2u);
  ASSERT_TRUE(s.camera.has_value());
  EXPECT_NE(s.camera->name, "canonical");
  expect_near(s.camera->eye, {0.5f, 0.5f, 3.0f});
  EXPECT_NEAR(s.camera->fov_deg, 0.7f * 180.0f / 3.14159265f, 1e-3f);
}

TEST(SharedScenes, CornellBoxHasEmissiveMaterial) {
  KDGRID_REQUIRE_SCENE(p, "gltf/CornellBox/cornell-box.glb");
  const Scene s = timed_load(p, "cornell-box.glb");
  EXPECT_EQ(s.mesh.num_triangles(), 1040u);
  size_t emissive_tris = 0;
  for (size_t i = 0; i < s.mesh.num_triangles(); ++i)
    if (max_component(s.materials[s.mesh.material_of(i)].emission) > 0.0f) ++emissive_tris;
  EXPECT_GT(emissive_tris, 0u);
}

// ---------------------------------------------------------------------------------------
// CLI: `kdgrid info`

TEST(CliInfo, MissingFileFailsNamingIt) {
  TempDir tmp;
  const CliStreams r = run_cli_streams("info \"" + tmp.file("no_such_scene.ply") + "\"", tmp);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_CONTAINS(r.err, "no_such_scene.ply");
}

TEST(CliInfo, BadFileFailsWithLoaderMessage) {
  TempDir tmp;
  const std::string p = tmp.write(
      "range.ply", std::string(kTinyHeader) + "0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 7\n");
  const CliStreams r = run_cli_streams("info \"" + p + "\"", tmp);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_CONTAINS(r.err, "range.ply");
  EXPECT_CONTAINS(r.err, "references vertex 7");
}

TEST(CliInfo, GoodFileSucceeds) {
  TempDir tmp;
  const std::string p = tmp.write("fan.ply", kAsciiPly);
  const CliStreams r = run_cli_streams("info \"" + p + "\"", tmp);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_CONTAINS(r.out, "triangles   6");
  const CliStreams j = run_cli_streams("info --json \"" + p + "\"", tmp);
  EXPECT_EQ(j.exit_code, 0) << j.err;
  EXPECT_CONTAINS(j.out, "\"triangles\": 6");
}

}  // namespace
}  // namespace kdgrid
