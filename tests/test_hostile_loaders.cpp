// Hostile scene files on the input side: geometry that a library would lose is kept (OBJ
// polygons of any size, byte-order marks), what kdgrid cannot show as meant is refused
// (required glTF extensions, negative colours, truncated textures, textures above the size
// limit, OBJ files above the memory budget), and every message names the file and stays short
// (tests/data/hostile holds the files; every file under tests/data is loaded here and each of
// its messages checked).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>

#include "cli_util.h"
#include "image/image_io.h"
#include "png_bytes.h"
#include "scene/load.h"
#include "temp_dir.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;
using test::load_error;
using test::TempDir;

std::string hostile(const std::string& name) {
  return test::source_path("tests/data/hostile/" + name);
}

std::string read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// What `f` writes to stderr (file descriptor 2) while it runs; `f` may throw.
std::string capture_stderr(const std::function<void()>& f) {
  std::fflush(stderr);
  FILE* tmp = std::tmpfile();
  const int saved = ::dup(2);
  ::dup2(::fileno(tmp), 2);
  std::exception_ptr thrown;
  try {
    f();
  } catch (...) {
    thrown = std::current_exception();
  }
  std::fflush(stderr);
  ::dup2(saved, 2);
  ::close(saved);
  std::string out;
  std::rewind(tmp);
  char buf[4096];
  for (size_t n; (n = std::fread(buf, 1, sizeof buf, tmp)) > 0;) out.append(buf, n);
  std::fclose(tmp);
  if (thrown) std::rethrow_exception(thrown);
  return out;
}

// ---------------------------------------------------------------------------------------
// Geometry kept

TEST(HostileLoaders, ObjPolygonsOfAnySizeKeepEveryTriangleInFanOrder) {
  // 300 corners: tinyobjloader's byte-sized corner count would read 44 and misread the rest.
  const Scene s = load_scene(hostile("polygon300.obj"));
  ASSERT_EQ(s.mesh.num_triangles(), 298u + 1u);
  for (uint32_t j = 2; j < 300; ++j) {
    const auto& t = s.mesh.triangles[j - 2];
    // (v0, v_{j-1}, v_j) of the file's corners; the corners share one vt and vn, so vertices
    // are made per distinct corner in first-use order, which is the polygon's own order here.
    ASSERT_EQ(s.mesh.positions[t[0]], s.mesh.positions[s.mesh.triangles[0][0]]);
    const float a = 2.0f * float(M_PI) * float(j) / 300.0f;
    EXPECT_NEAR(s.mesh.positions[t[2]].x, std::cos(a), 1e-5f) << "triangle " << j - 2;
    EXPECT_NEAR(s.mesh.positions[t[2]].y, std::sin(a), 1e-5f) << "triangle " << j - 2;
  }
  // The face after the polygon is read as written: (2,0,0) (3,0,0) (2,1,0).
  const auto& last = s.mesh.triangles.back();
  EXPECT_EQ(s.mesh.positions[last[0]], Vec3(2, 0, 0));
  EXPECT_EQ(s.mesh.positions[last[1]], Vec3(3, 0, 0));
  EXPECT_EQ(s.mesh.positions[last[2]], Vec3(2, 1, 0));

  // 600 corners (three pieces) on one line, plain indices.
  TempDir tmp;
  std::string text;
  for (int i = 0; i < 600; ++i) {
    const double a = 2 * M_PI * i / 600;
    text += "v " + std::to_string(std::cos(a)) + " " + std::to_string(std::sin(a)) + " 0\n";
  }
  text += "f";
  for (int i = 1; i <= 600; ++i) text += " " + std::to_string(i);
  text += "\nf 1 2 3\n";
  const Scene big = load_scene(tmp.write("big.obj", text));
  ASSERT_EQ(big.mesh.num_triangles(), 598u + 1u);
  for (uint32_t j = 2; j < 600; ++j) {
    const auto& t = big.mesh.triangles[j - 2];
    ASSERT_EQ(t[0], 0u);
    ASSERT_EQ(t[1], j - 1) << "triangle " << j - 2;
    ASSERT_EQ(t[2], j) << "triangle " << j - 2;
  }
  EXPECT_EQ(big.mesh.triangles.back()[2], 2u);
}

TEST(HostileLoaders, ByteOrderMarksAreSkipped) {
  // OBJ and MTL: the first line is read (3 vertices, the material 'red' found).
  std::string err;
  const std::string out = capture_stderr([&] {
    const Scene s = load_scene(hostile("bom.obj"));
    ASSERT_EQ(s.mesh.num_triangles(), 1u);
    ASSERT_FALSE(s.materials.empty());
    EXPECT_EQ(s.materials[0].name, "red");
    EXPECT_EQ(s.materials[0].base_color, Vec3(1, 0, 0));
  });
  EXPECT_EQ(out.find("not found"), std::string::npos) << out;
  EXPECT_EQ(load_scene(hostile("bom.ply")).mesh.num_triangles(), 1u);
  EXPECT_EQ(load_scene(hostile("bom.gltf")).mesh.num_triangles(), 1u);
}

// ---------------------------------------------------------------------------------------
// Refusals and warnings

TEST(HostileLoaders, TruncatedJpegTextureWarnsAsATruncatedPngDoes) {
  Scene s;
  const std::string out = capture_stderr([&] { s = load_scene(hostile("truncated_texture.obj")); });
  EXPECT_CONTAINS(out, "truncated.jpg");
  EXPECT_CONTAINS(out, "the file is truncated or corrupt");
  EXPECT_CONTAINS(out, "rendering it untextured");
  EXPECT_TRUE(s.textures.empty());
  // The whole JPEG still loads.
  TempDir tmp;
  fs::copy_file(hostile("gradient.jpg"), tmp.file("truncated.jpg"));
  fs::copy_file(hostile("truncated_texture.mtl"), tmp.file("truncated_texture.mtl"));
  fs::copy_file(hostile("truncated_texture.obj"), tmp.file("t.obj"));
  const std::string ok_out = capture_stderr([&] { s = load_scene(tmp.file("t.obj")); });
  EXPECT_EQ(ok_out, "");
  ASSERT_EQ(s.textures.size(), 1u);
  EXPECT_EQ(s.textures[0].width, 64);
}

TEST(HostileLoaders, RequiredGltfExtensionsKdgridDoesNotReadAreRefused) {
  const std::string e = load_error([] { load_scene(hostile("requires_basisu.gltf")); });
  EXPECT_CONTAINS(e, "requires_basisu.gltf: requires the glTF extension 'KHR_texture_basisu'");
  EXPECT_CONTAINS(e, "re-export the file without it");
  TempDir tmp;
  std::string text = read_all(hostile("requires_basisu.gltf"));
  const std::string basisu = "KHR_texture_basisu";
  for (size_t at; (at = text.find(basisu)) != std::string::npos;)
    text.replace(at, basisu.size(), "EXT_made_up");
  EXPECT_CONTAINS(load_error([&] { load_scene(tmp.write("x.gltf", text)); }), "'EXT_made_up'");
  // Used but not required: ignored, as glTF allows.
  EXPECT_EQ(load_scene(hostile("uses_unknown.gltf")).mesh.num_triangles(), 1u);
}

TEST(HostileLoaders, NegativeGltfMaterialColoursAreRefusedNamingTheField) {
  std::string e = load_error([] { load_scene(hostile("negative_base_color.gltf")); });
  EXPECT_CONTAINS(e, "material 0 'dark' has pbrMetallicRoughness.baseColorFactor[0] -1");
  EXPECT_CONTAINS(e, ">= 0");
  e = load_error([] { load_scene(hostile("negative_emissive.gltf")); });
  EXPECT_CONTAINS(e, "material 0 'glow' has emissiveFactor[1] -5");
}

TEST(HostileLoaders, GltfMessagesStateTheRuleAndBlameTheRightPart) {
  std::string e = load_error([] { load_scene(hostile("stride256.gltf")); });
  EXPECT_CONTAINS(e, "byteStride 256");
  EXPECT_CONTAINS(e, "multiple of 4 from 4 to 252");
  e = load_error([] { load_scene(hostile("json_length_short.glb")); });
  EXPECT_CONTAINS(e, "the JSON chunk length is wrong");
  EXPECT_EQ(e.find("BIN"), std::string::npos) << e;
  // A data: URI of 8000 bad characters is not echoed whole.
  e = load_error([] { load_scene(hostile("bad_base64.gltf")); });
  EXPECT_CONTAINS(e, "bad_base64.gltf: cannot parse glTF");
  EXPECT_LT(e.size(), 1024u) << e;
}

TEST(HostileLoaders, GltfWarningsAreCappedAtTen) {
  // 30 images that are neither PNG nor JPEG, each used by a material: one warning each.
  std::string images, textures, materials;
  for (int i = 0; i < 30; ++i) {
    const std::string sep = i ? "," : "";
    images += sep + R"({"uri":"data:image/png;base64,AAAA"})";
    textures += sep + R"({"source":)" + std::to_string(i) + "}";
    materials += sep + R"({"pbrMetallicRoughness":{"baseColorTexture":{"index":)" +
                 std::to_string(i) + "}}}";
  }
  std::string text = read_all(hostile("uses_unknown.gltf"));
  text.insert(text.rfind('}'), R"(,"images":[)" + images + R"(],"textures":[)" + textures +
                                   R"(],"materials":[)" + materials + "]");
  TempDir tmp;
  const std::string p = tmp.write("many.gltf", text);
  const std::string out = capture_stderr([&] { load_scene(p); });
  size_t lines = 0;
  for (char c : out) lines += c == '\n';
  EXPECT_LE(lines, 12u) << out;
  EXPECT_CONTAINS(out, "further warnings suppressed");
}

TEST(HostileLoaders, ObjWarningsHaveLineNumbersAndReadWell) {
  const std::string out = capture_stderr(
      [] { EXPECT_EQ(load_scene(hostile("degenerate_face.obj")).mesh.num_triangles(), 1u); });
  EXPECT_CONTAINS(out, "degenerate_face.obj: warning: line 4: face with 2 vertices skipped");
  EXPECT_CONTAINS(out, "line 5: usemtl 'nowhere': no material of that name");
  EXPECT_EQ(out.find("Degenerated"), std::string::npos) << out;
  EXPECT_EQ(out.find("warning: .\n"), std::string::npos) << out;
}

TEST(HostileLoaders, TexturesAboveTheSideLimitAreRefusedAndInfoDecodesNoPixels) {
  TempDir tmp;
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n";
  const std::string mtl_a = "newmtl a\nKd 1 1 1\nmap_Kd tex.png\n";
  tmp.write("t.mtl", mtl_a);
  tmp.write("u.mtl", mtl_a + "newmtl b\nKd 1 1 1\nmap_Kd big.png\n");
  const std::string obj = tmp.write("a.obj", "mtllib t.mtl\n" + tri + "usemtl a\nf 1/1 2/1 3/1\n");
  // 16385 x 4: a few hundred kilobytes to decode, yet wider than kMaxTextureSide.
  tmp.write("tex.png", test::png_header_only(kMaxTextureSide + 1, 4));
  std::string out = capture_stderr([&] { EXPECT_TRUE(load_scene(obj).textures.empty()); });
  EXPECT_CONTAINS(out, "16385x4 pixels: above the limit of 16384 a side");
  // A header with no pixel data: a load that decodes warns that it cannot; one that does not
  // (kdgrid info) reads the header only and keeps the texture's size.
  tmp.write("tex.png", test::png_header_only(64, 64));
  out = capture_stderr([&] { EXPECT_TRUE(load_scene(obj).textures.empty()); });
  EXPECT_CONTAINS(out, "cannot decode the pixels");
  LoadOptions headers;
  headers.decode_textures = false;
  Scene s;
  EXPECT_EQ(capture_stderr([&] { s = load_scene(obj, headers); }), "");
  ASSERT_EQ(s.textures.size(), 1u);
  EXPECT_EQ(s.textures[0].width, 64);
  // `kdgrid info`: no pixels decoded, 40000 x 40000 (100 s and 6 GB to decode) refused.
  tmp.write("big.png", test::png_header_only(40000, 40000));
  const std::string both = tmp.write(
      "b.obj", "mtllib u.mtl\n" + tri + "usemtl a\nf 1/1 2/1 3/1\nusemtl b\nf 1/1 2/1 3/1\n");
  const test::CliResult r = test::run_cli("info --json \"" + both + "\"");
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_CONTAINS(r.output, "\"textures\": 1");
  EXPECT_CONTAINS(r.output, "40000x40000 pixels");
  EXPECT_EQ(r.output.find("cannot decode"), std::string::npos) << r.output;
}

TEST(HostileLoaders, ObjAboveTheMemoryBudgetIsRefusedBeforeParsing) {
  TempDir tmp;
  std::string text;
  for (int i = 0; i < 1000; ++i) text += "v " + std::to_string(i) + " 0 0\n";
  for (int i = 1; i + 2 <= 1000; ++i)
    text +=
        "f " + std::to_string(i) + " " + std::to_string(i + 1) + " " + std::to_string(i + 2) + "\n";
  const std::string p = tmp.write("many.obj", text);
  EXPECT_EQ(load_scene(p).mesh.num_triangles(), 998u);
  LoadOptions small;
  small.memory_budget = 64 << 10;
  const std::string e = load_error([&] { load_scene(p, small); });
  EXPECT_CONTAINS(e, "many.obj: loading it would take about");
  EXPECT_CONTAINS(e, "(1000 vertices, 998 faces), above the memory budget of 64 KiB");
}

// ---------------------------------------------------------------------------------------
// Every input in tests/data: every message it causes is one short line.

TEST(HostileLoaders, NoMessageOverOneKilobyteForAnyFileInTestData) {
  size_t files = 0;
  for (const auto& entry : fs::recursive_directory_iterator(test::source_path("tests/data"))) {
    if (!entry.is_regular_file()) continue;
    const std::string path = entry.path().string();
    std::string ext = entry.path().extension().string();
    for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
    std::string error;
    const std::string out = capture_stderr([&] {
      try {
        if (ext == ".obj" || ext == ".ply" || ext == ".gltf" || ext == ".glb")
          load_scene(path);
        else if (ext != ".mtl" && ext != ".bin")
          read_image(path);
      } catch (const Error& e) {
        error = e.what();
      }
    });
    ++files;
    EXPECT_LE(error.size(), 1024u) << path << ": " << error.substr(0, 2000);
    std::istringstream lines(out);
    for (std::string line; std::getline(lines, line);)
      EXPECT_LE(line.size(), 1024u) << path << ": " << line.substr(0, 2000);
  }
  EXPECT_GE(files, 10u);
}

}  // namespace
}  // namespace kdgrid
