// OBJ and MTL files the loader must refuse or warn about, naming the file, the line and the
// rule (indices out of range or past the first vertex, non-numbers, no faces, files above the
// memory budget, material libraries and textures that are devices, truncated or oversized
// textures), and polygons of any size it must keep whole.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>

#include "cli_util.h"
#include "image/image_io.h"
#include "loader_inputs.h"
#include "png_bytes.h"
#include "scene/load.h"
#include "temp_dir.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;
using namespace test;

TEST(ObjErrors, IndexOutOfRange) {
  TempDir tmp;
  expect_message(load_error_of(tmp.write("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")),
                 {"range.obj", "references vertex 9 but the file has 3 vertices"});
}

TEST(ObjErrors, NoFaces) {
  TempDir tmp;
  expect_message(load_error_of(tmp.write("pts.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n")),
                 {"pts.obj", "no triangles"});
}

TEST(HostileFiles, ObjNonNumbersAndHugeIndicesAreRefusedWithTheLine) {
  TempDir tmp;
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  auto err = [&](const std::string& text) { return load_error_of(tmp.write("x.obj", text)); };
  std::string e = err("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  EXPECT_CONTAINS(e, "line 1");
  EXPECT_CONTAINS(e, "'nan' is not a finite number");
  EXPECT_CONTAINS(err("v 0 0 0\nv abc def ghi\nv 0 1 0\nf 1 2 3\n"), "line 2: vertex");
  EXPECT_CONTAINS(err(tri + "vn 0 0 inf\nf 1//1 2//1 3//1\n"), "'inf' is not a finite number");
  e = err(tri + "f 1 2 99999999999999999999\n");
  EXPECT_CONTAINS(e, "line 4");
  EXPECT_CONTAINS(e, "'99999999999999999999' is not a whole number");
  e = err(tri + "v 1 1 0\nf -1 -2 -5\n");
  EXPECT_CONTAINS(e, "line 5");
  EXPECT_CONTAINS(e, "index -5 counts back past the first vertex: only 4 are defined");
  EXPECT_CONTAINS(err(tri + "f 1 2 0\n"), "index 0");
  e = err(tri + "\nf 1 2 7\n");
  EXPECT_CONTAINS(e, "line 5: face references vertex 7 but the file has 3 vertices");
  // Valid relative indices still load.
  const std::string ok = tmp.write("ok.obj", tri + "f -3 -2 -1\n");
  EXPECT_EQ(load_scene(ok).mesh.num_triangles(), 1u);
}

TEST(HostileLoaders, ObjWarningsHaveLineNumbersAndReadWell) {
  const std::string out = capture_stderr(
      [] { EXPECT_EQ(load_scene(hostile("degenerate_face.obj")).mesh.num_triangles(), 1u); });
  EXPECT_CONTAINS(out, "degenerate_face.obj: warning: line 4: face with 2 vertices skipped");
  EXPECT_CONTAINS(out, "line 5: usemtl 'nowhere': no material of that name");
  EXPECT_EQ(out.find("Degenerated"), std::string::npos) << out;
  EXPECT_EQ(out.find("warning: .\n"), std::string::npos) << out;
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
  for (int i = 1; i <= 600; ++i) {
    text += ' ';  // not " " + std::to_string(i): gcc 12 warns of overlapping copies there
    text += std::to_string(i);
  }
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

// ---------------------------------------------------------------------------------------
// Material libraries and textures

TEST(HostileFiles, ObjMaterialLibraryAndTextureOnDevicesAreWarnings) {
  TempDir tmp;
  fs::create_symlink("/dev/zero", tmp.file("zero.mtl"));
  fs::create_symlink("/dev/zero", tmp.file("zero.png"));
  tmp.write("t.mtl", "newmtl a\nKd 1 1 1\nmap_Kd zero.png\n");
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  const std::string a = tmp.write("a.obj", "mtllib zero.mtl\n" + tri + "f 1 2 3\n");
  const std::string b = tmp.write("b.obj", "mtllib t.mtl\n" + tri + "usemtl a\nf 1 2 3\n");
  CliStreams r = run_cli_streams("info \"" + a + "\"", tmp, "ulimit -t 10; ulimit -v 4000000;");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_CONTAINS(r.err, "zero.mtl (material library): is not a regular file");
  r = run_cli_streams("info \"" + b + "\"", tmp, "ulimit -t 10; ulimit -v 4000000;");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_CONTAINS(r.err, "zero.png (texture): is not a regular file");
}

TEST(HostileFiles, HugeTextureIsRefusedFromItsHeaderBeforeDecoding) {
  if (kAddressSanitizer)
    GTEST_SKIP()
        << "its memory budget comes from ulimit -v, under which AddressSanitizer cannot start";
  TempDir tmp;
  tmp.write("big.png", png_header_only(40000, 40000));
  tmp.write("t.mtl", "newmtl a\nKd 1 1 1\nmap_Kd big.png\n");
  const std::string obj = tmp.write(
      "a.obj", "mtllib t.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nusemtl a\nf 1/1 2/1 3/1\n");
  // Under a 4 GB address-space limit the budget is 2 GB: 40000^2 pixels need 11 GB.
  const CliStreams r = run_cli_streams("info \"" + obj + "\"", tmp, "ulimit -v 4000000;");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_CONTAINS(r.err, "40000x40000 pixels would take");
  EXPECT_CONTAINS(r.err, "above the memory budget");
}

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

}  // namespace
}  // namespace kdgrid
