// Scene loaders: PLY (own reader), OBJ/MTL, glTF 2.0 on small files written here, on the
// shared scenes, on bad input (each must give a LoadError naming the file and the problem),
// and on seeded random mutations of a valid PLY (must throw or load, never crash or hang).
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "scene/load.h"
#include "temp_dir.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;
using test::load_error;
using test::TempDir;

using TriangleTest = std::array<uint32_t, 3>;

void expect_near(const Vec3& a, const Vec3& b, float eps = 1e-5f) {
  EXPECT_NEAR(a.x, b.x, eps);
  EXPECT_NEAR(a.y, b.y, eps);
  EXPECT_NEAR(a.z, b.z, eps);
}

// ------------------------------------------------------------------------------------------
// PLY, good files

// Seven vertices; a triangle, a quad and a pentagon, with elements the reader must skip
// before and after, comments and an obj_info line.
const char* kAsciiPly =
    "ply\n"
    "format ascii 1.0\n"
    "comment written by test_loaders\n"
    "obj_info nothing\n"
    "element material 2\n"
    "property uchar red\n"
    "property list uchar float weights\n"
    "element vertex 7\n"
    "property float x\n"
    "property float y\n"
    "property float z\n"
    "property float confidence\n"
    "element face 3\n"
    "property list uchar int vertex_indices\n"
    "element edge 2\n"
    "property int vertex1\n"
    "property int vertex2\n"
    "end_header\n"
    "255 3 0.5 0.25 1e-3\n"
    "12 0\n"
    "0 0 0 1\n"
    "1 0 0 1\n"
    "1 1 0 0.5\n"
    "0 1 0 0.5\n"
    "-1 2.5e0 +3 1\n"
    "0.5 -0.125 7 1\n"
    "2 2 2 1\n"
    "3 0 1 2 \n"
    "4 0 1 2 3\n"
    "5 6 5 4 3 2\n"
    "0 1\n"
    "1 2\n";

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

/// Binary writer for either byte order.
struct Bytes {
  std::string data;
  bool big_endian = false;
  template <class T>
  void put(T v) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    if (big_endian) std::reverse(b, b + sizeof(T));
    data.append(b, sizeof(T));
  }
};

struct BinVertex {
  double x;
  int16_t y;
  double z;
};
const BinVertex kBinVerts[5] = {{0.5, 0, -1.25}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {-3.5, 2, 1e-3}};

/// A binary PLY with odd property order and types: coordinates as double and int16 among
/// other properties, a list in an element before the vertices, an unknown element holding a
/// 'vertex_indices' list, face lists of uchar count + uint index between other properties.
std::string binary_ply(bool big_endian) {
  std::string h = "ply\nformat ";
  h += big_endian ? "binary_big_endian" : "binary_little_endian";
  h += " 1.0\n"
       "comment odd property order and types\n"
       "element material 2\n"
       "property uchar r\n"
       "property list uchar float weights\n"
       "element vertex 5\n"
       "property uchar red\n"
       "property double z\n"
       "property float confidence\n"
       "property double x\n"
       "property int16 y\n"
       "element tristrips 1\n"
       "property list int int vertex_indices\n"
       "element face 3\n"
       "property int flags\n"
       "property list uchar uint vertex_indices\n"
       "property float quality\n"
       "element trailer 1\n"
       "property list ushort char data\n"
       "end_header\n";
  Bytes b;
  b.big_endian = big_endian;
  b.data = h;
  b.put<uint8_t>(7);
  b.put<uint8_t>(2);
  b.put<float>(0.5f);
  b.put<float>(0.25f);
  b.put<uint8_t>(9);
  b.put<uint8_t>(0);
  for (const BinVertex& v : kBinVerts) {
    b.put<uint8_t>(200);
    b.put<double>(v.z);
    b.put<float>(0.75f);
    b.put<double>(v.x);
    b.put<int16_t>(v.y);
  }
  b.put<int32_t>(4);  // tristrips: 4 indices, not faces
  for (int32_t i : {0, 1, 2, 3}) b.put<int32_t>(i);
  const std::vector<std::vector<uint32_t>> faces = {{0, 1, 2, 3, 4}, {4, 3, 2, 1}, {0, 2, 4}};
  for (const auto& f : faces) {
    b.put<int32_t>(-1);
    b.put<uint8_t>(uint8_t(f.size()));
    for (uint32_t i : f) b.put<uint32_t>(i);
    b.put<float>(0.1f);
  }
  b.put<uint16_t>(3);
  b.put<int8_t>(1);
  b.put<int8_t>(2);
  b.put<int8_t>(3);
  return b.data;
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

// ------------------------------------------------------------------------------------------
// PLY, bad input: each error names the file and the problem.

std::string ply_error(const std::string& text, const std::string& name = "bad.ply") {
  return load_error([&] { parse_ply(text.data(), text.size(), name); });
}

TEST(PlyErrors, MissingFile) {
  TempDir tmp;
  const std::string p = tmp.file("nowhere.ply");
  const std::string msg = load_error([&] { load_scene(p); });
  EXPECT_CONTAINS(msg, "nowhere.ply");
  EXPECT_CONTAINS(msg, "no such file");
}

TEST(PlyErrors, UnknownExtension) {
  TempDir tmp;
  const std::string p = tmp.write("mesh.stl", "solid x\n");
  const std::string msg = load_error([&] { load_scene(p); });
  EXPECT_CONTAINS(msg, "mesh.stl");
  EXPECT_CONTAINS(msg, "unknown scene format");
}

TEST(PlyErrors, BadMagic) {
  const std::string msg = ply_error("plx\nformat ascii 1.0\nend_header\n", "magic.ply");
  EXPECT_CONTAINS(msg, "magic.ply");
  EXPECT_CONTAINS(msg, "not a PLY file");
}

TEST(PlyErrors, UnknownFormat) {
  const std::string msg =
      ply_error("ply\nformat binary_middle_endian 1.0\nend_header\n", "fmt.ply");
  EXPECT_CONTAINS(msg, "fmt.ply");
  EXPECT_CONTAINS(msg, "unknown format 'binary_middle_endian'");
}

TEST(PlyErrors, TruncatedHeader) {
  const std::string msg =
      ply_error("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n", "hdr.ply");
  EXPECT_CONTAINS(msg, "hdr.ply");
  EXPECT_CONTAINS(msg, "end_header");
}

TEST(PlyErrors, TruncatedAscii) {
  std::string text = kAsciiPly;
  text = text.substr(0, text.find("5 6 5 4"));  // cut before the pentagon (face 2)
  const std::string msg = ply_error(text, "cut.ply");
  EXPECT_CONTAINS(msg, "cut.ply");
  EXPECT_CONTAINS(msg, "face 2 of 3");
  EXPECT_CONTAINS(msg, "file ends early");
}

TEST(PlyErrors, TruncatedBinary) {
  std::string d = binary_ply(false);
  d.resize(d.size() - 10);  // the 5-byte trailer and half of the last face
  const std::string msg = ply_error(d, "cutbin.ply");
  EXPECT_CONTAINS(msg, "cutbin.ply");
  EXPECT_CONTAINS(msg, "face 2 of 3");
  EXPECT_CONTAINS(msg, "file ends early");
}

const char* kTinyHeader =
    "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
    "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n";

TEST(PlyErrors, MalformedNumber) {
  const std::string msg = ply_error(
      std::string(kTinyHeader) + "0 0 0\n1 0 0\n1 1z 0\n0 1 0\n3 0 1 2\n3 0 2 3\n", "num.ply");
  EXPECT_CONTAINS(msg, "num.ply");
  EXPECT_CONTAINS(msg, "vertex 2 of 4");
  EXPECT_CONTAINS(msg, "line 12");
  EXPECT_CONTAINS(msg, "malformed number '1z'");
}

TEST(PlyErrors, FaceIndexOutOfRange) {
  const std::string msg = ply_error(
      std::string(kTinyHeader) + "0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 7\n", "range.ply");
  EXPECT_CONTAINS(msg, "range.ply");
  EXPECT_CONTAINS(msg, "face 1 of 2");
  EXPECT_CONTAINS(msg, "references vertex 7 but the file has 4 vertices");
}

TEST(PlyErrors, NegativeFaceIndex) {
  const std::string msg = ply_error(
      std::string(kTinyHeader) + "0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 -1\n3 0 2 3\n", "neg.ply");
  EXPECT_CONTAINS(msg, "references vertex -1");
}

TEST(PlyErrors, FaceWithTwoVertices) {
  const std::string msg = ply_error(
      std::string(kTinyHeader) + "0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n2 0 2\n", "two.ply");
  EXPECT_CONTAINS(msg, "two.ply");
  EXPECT_CONTAINS(msg, "face 1 of 2");
  EXPECT_CONTAINS(msg, "at least 3");
}

TEST(PlyErrors, MissingCoordinate) {
  const std::string msg = ply_error(
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 "
      "0\n",
      "noz.ply");
  EXPECT_CONTAINS(msg, "noz.ply");
  EXPECT_CONTAINS(msg, "x, y, z");
}

TEST(PlyErrors, NanVertex) {
  TempDir tmp;
  const std::string p = tmp.write(
      "nan.ply", std::string(kTinyHeader) + "0 0 0\n1 nan 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n");
  const std::string msg = load_error([&] { load_scene(p); });
  EXPECT_CONTAINS(msg, "nan.ply");
  EXPECT_CONTAINS(msg, "vertex 1 has a NaN or infinite coordinate");
}

TEST(PlyErrors, InfVertex) {
  TempDir tmp;
  const std::string p = tmp.write(
      "inf.ply", std::string(kTinyHeader) + "0 0 0\n1 0 0\n1 1 -inf\n0 1 0\n3 0 1 2\n3 0 2 3\n");
  const std::string msg = load_error([&] { load_scene(p); });
  EXPECT_CONTAINS(msg, "inf.ply");
  EXPECT_CONTAINS(msg, "vertex 2 has a NaN or infinite coordinate");
}

TEST(PlyErrors, HugeFloatIsAnError) {
  const std::string msg = ply_error(
      std::string(kTinyHeader) + "0 0 0\n1 0 1e999\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n", "big.ply");
  EXPECT_CONTAINS(msg, "big.ply");
  EXPECT_CONTAINS(msg, "malformed number '1e999'");
}

TEST(PlyErrors, VerticesOnlyHasNoTriangles) {
  TempDir tmp;
  const std::string p = tmp.write("points.ply",
                                  "ply\nformat ascii 1.0\nelement vertex 3\nproperty float "
                                  "x\nproperty float y\nproperty float z\n"
                                  "end_header\n0 0 0\n1 0 0\n0 1 0\n");
  const std::string msg = load_error([&] { load_scene(p); });
  EXPECT_CONTAINS(msg, "points.ply");
  EXPECT_CONTAINS(msg, "no triangles");
}

TEST(PlyErrors, AbsurdCountsFailWithoutAllocating) {
  // More vertices than 32-bit indices allow: rejected from the header.
  std::string msg = ply_error(
      "ply\nformat binary_little_endian 1.0\nelement vertex 99999999999\nproperty float x\n"
      "property float y\nproperty float z\nend_header\n",
      "huge.ply");
  EXPECT_CONTAINS(msg, "huge.ply");
  EXPECT_CONTAINS(msg, "32-bit");
  // Counts that fit the index type but not the file: "ends early", quickly, with no
  // multi-gigabyte reservation (4e9 vertices * 12 bytes would be 48 GB).
  const auto t0 = std::chrono::steady_clock::now();
  msg = ply_error(
      "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n"
      "property float y\nproperty float z\nelement face 4000000000\n"
      "property list uint uint vertex_indices\nend_header\n\1\2\3\4",
      "lies.ply");
  EXPECT_CONTAINS(msg, "lies.ply");
  EXPECT_CONTAINS(msg, "file ends early");
  // An unknown element with 10^15 entries and a face list claiming 4e9 indices.
  msg = ply_error(
      "ply\nformat ascii 1.0\nelement junk 1000000000000000\nproperty list int int stuff\n"
      "element vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
      "2000000000 1 2\n",
      "junk.ply");
  EXPECT_CONTAINS(msg, "junk.ply");
  EXPECT_CONTAINS(msg, "file ends early");
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 5.0);
}

// Seeded random mutations (byte flips, insertions, truncations, garbage) of valid ascii and
// binary PLY buffers: each must load or throw LoadError, never crash, hang or throw
// anything else; what loads must be index-consistent.
TEST(PlyFuzz, RandomMutationsThrowOrLoad) {
  const std::vector<std::string> seeds = {kAsciiPly, binary_ply(false), binary_ply(true)};
  std::mt19937 rng(20240607);
  int loaded = 0, rejected = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (int iter = 0; iter < 3000; ++iter) {
    std::string d = seeds[size_t(iter) % seeds.size()];
    const int kind = int(rng() % 5);
    const int edits = 1 + int(rng() % 4);
    for (int e = 0; e < edits && !d.empty(); ++e) {
      const size_t pos = rng() % d.size();
      switch (kind) {
        case 0:
          d[pos] = char(rng() & 0xff);
          break;  // byte flip
        case 1:
          d.resize(pos);
          break;  // truncation
        case 2:
          d.insert(pos, 1, " 0123456789-+.eE\nxyz"[rng() % 20]);
          break;  // ascii noise
        case 3:
          d.erase(pos, 1 + rng() % 8);
          break;    // deletion
        default: {  // garbage tail
          d.resize(pos);
          for (int k = int(rng() % 64); k > 0; --k) d += char(rng() & 0xff);
        }
      }
    }
    if (iter % 50 == 0) {  // pure garbage, sometimes with a valid magic line
      d = iter % 100 == 0 ? "ply\n" : "";
      for (int k = int(rng() % 300); k > 0; --k) d += char(rng() & 0xff);
    }
    try {
      const Scene s = parse_ply(d.data(), d.size(), "fuzz.ply");
      for (const auto& t : s.mesh.triangles)
        for (uint32_t v : t) ASSERT_LT(v, s.mesh.num_vertices()) << "mutation " << iter;
      ++loaded;
    } catch (const LoadError& e) {
      ASSERT_NE(std::string(e.what()).find("fuzz.ply"), std::string::npos) << e.what();
      ++rejected;
    }
  }
  const double sec = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("[ fuzz     ] 3000 mutations: %d loaded, %d rejected with LoadError, %.3f s\n",
              loaded, rejected, sec);
  EXPECT_GT(rejected, 0);
}

// ------------------------------------------------------------------------------------------
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

TEST(ObjErrors, IndexOutOfRange) {
  TempDir tmp;
  const std::string p = tmp.write("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
  const std::string msg = load_error([&] { load_scene(p); });
  EXPECT_CONTAINS(msg, "range.obj");
  EXPECT_CONTAINS(msg, "references vertex 9 but the file has 3 vertices");
}

TEST(ObjErrors, NoFaces) {
  TempDir tmp;
  const std::string p = tmp.write("pts.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
  const std::string msg = load_error([&] { load_scene(p); });
  EXPECT_CONTAINS(msg, "pts.obj");
  EXPECT_CONTAINS(msg, "no triangles");
}

// ------------------------------------------------------------------------------------------
// glTF

std::string base64(const std::string& in) {
  static const char* kAlphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    const uint32_t v = (uint8_t(in[i]) << 16) | (uint8_t(in[i + 1]) << 8) | uint8_t(in[i + 2]);
    for (int k = 18; k >= 0; k -= 6) out += kAlphabet[(v >> k) & 63];
  }
  if (i + 1 == in.size()) {
    const uint32_t v = uint8_t(in[i]) << 16;
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += "==";
  } else if (i + 2 == in.size()) {
    const uint32_t v = (uint8_t(in[i]) << 16) | (uint8_t(in[i + 1]) << 8);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += '=';
  }
  return out;
}

/// The binary buffer of the test glTF: a unit quad with interleaved position + normal
/// (stride 24), u8 indices, normalized u16 uvs. 120 bytes.
std::string gltf_buffer() {
  Bytes b;
  const float pos[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  const float nrm[4][3] = {{0, 0, 1}, {0, 0, 1}, {0, 0, 1}, {0.6f, 0.8f, 0}};
  for (int i = 0; i < 4; ++i) {
    for (float f : pos[i]) b.put<float>(f);
    for (float f : nrm[i]) b.put<float>(f);
  }
  for (uint8_t i : {0, 1, 2, 0, 2, 3}) b.put<uint8_t>(i);
  b.put<uint16_t>(0);  // pad to 104
  const uint16_t uv[4][2] = {{0, 0}, {65535, 0}, {65535, 65535}, {0, 32768}};
  for (const auto& t : uv) {
    b.put<uint16_t>(t[0]);
    b.put<uint16_t>(t[1]);
  }
  return b.data;
}

/// JSON of the test glTF; `buffer` is the buffers[0] object. Nodes: 0 (translate 10,0,0)
/// -> child 1 (mesh, scale 2); 2 camera at z=5; 3 point light at y=3; 4 mesh under a matrix
/// (90 degrees about z, then z -= 3); 5 mesh under scale (1,2,1); 6 spot light pointing down.
/// Mesh 0: indexed triangles (material 0), a non-indexed strip (material 1), points (skipped).
std::string gltf_json(const std::string& buffer, const std::string& accessor_extra = "") {
  return R"({
  "asset": {"version": "2.0", "generator": "kdgrid test"},
  "extensionsUsed": ["KHR_lights_punctual", "KHR_materials_emissive_strength",
                     "KHR_materials_transmission", "KHR_materials_ior"],
  "scene": 0,
  "scenes": [{"nodes": [0, 2, 3, 4, 5, 6]}, {"nodes": [1]}],
  "nodes": [
    {"translation": [10, 0, 0], "children": [1]},
    {"mesh": 0, "scale": [2, 2, 2]},
    {"camera": 0, "translation": [0, 0, 5]},
    {"translation": [0, 3, 0], "extensions": {"KHR_lights_punctual": {"light": 0}}},
    {"mesh": 0, "matrix": [0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 1, 0, 0, 0, -3, 1]},
    {"mesh": 0, "scale": [1, 2, 1]},
    {"rotation": [-0.70710678, 0, 0, 0.70710678],
     "extensions": {"KHR_lights_punctual": {"light": 1}}}
  ],
  "cameras": [{"type": "perspective", "name": "testcam",
               "perspective": {"yfov": 0.5, "znear": 0.1, "aspectRatio": 1.5}}],
  "extensions": {"KHR_lights_punctual": {"lights": [
    {"type": "point", "color": [1, 0.5, 0.25], "intensity": 20, "name": "bulb"},
    {"type": "spot", "intensity": 7, "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.5}}
  ]}},
  "materials": [
    {"name": "emissive", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.25, 1, 1],
      "metallicFactor": 0.3, "roughnessFactor": 0.7},
     "emissiveFactor": [1, 0.5, 0],
     "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4}}},
    {"name": "water", "extensions": {"KHR_materials_transmission": {"transmissionFactor": 0.9},
                                      "KHR_materials_ior": {"ior": 1.33}}}
  ],
  "meshes": [{"primitives": [
    {"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 3}, "indices": 2, "material": 0},
    {"attributes": {"POSITION": 0}, "mode": 5, "material": 1},
    {"attributes": {"POSITION": 0}, "mode": 0}
  ]}],
  "buffers": [)" +
         buffer + R"(],
  "bufferViews": [
    {"buffer": 0, "byteOffset": 0, "byteLength": 96, "byteStride": 24},
    {"buffer": 0, "byteOffset": 96, "byteLength": 6},
    {"buffer": 0, "byteOffset": 104, "byteLength": 16}
  ],
  "accessors": [
    {"bufferView": 0, "byteOffset": 0, "componentType": 5126, "count": 4, "type": "VEC3",
     "min": [0, 0, 0], "max": [1, 1, 0])" +
         accessor_extra + R"(},
    {"bufferView": 0, "byteOffset": 12, "componentType": 5126, "count": 4, "type": "VEC3"},
    {"bufferView": 1, "componentType": 5121, "count": 6, "type": "SCALAR"},
    {"bufferView": 2, "componentType": 5123, "normalized": true, "count": 4, "type": "VEC2"}
  ]
})";
}

std::string embedded_buffer(const std::string& data) {
  return R"({"byteLength": )" + std::to_string(data.size()) +
         R"(, "uri": "data:application/octet-stream;base64,)" + base64(data) + R"("})";
}

/// GLB container: 12-byte header, JSON chunk, BIN chunk (both padded to 4 bytes).
std::string make_glb(std::string json, std::string bin) {
  while (json.size() % 4) json += ' ';
  while (bin.size() % 4) bin += '\0';
  Bytes b;
  b.data = "glTF";
  b.put<uint32_t>(2);
  b.put<uint32_t>(uint32_t(12 + 8 + json.size() + 8 + bin.size()));
  b.put<uint32_t>(uint32_t(json.size()));
  b.data += "JSON";
  b.data += json;
  b.put<uint32_t>(uint32_t(bin.size()));
  b.data += std::string("BIN\0", 4);
  b.data += bin;
  return b.data;
}

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

TEST(GltfErrors, TruncatedGlb) {
  TempDir tmp;
  const std::string bin = gltf_buffer();
  std::string glb =
      make_glb(gltf_json(R"({"byteLength": )" + std::to_string(bin.size()) + "}"), bin);
  for (size_t keep : {size_t(10), glb.size() / 2, glb.size() - 40}) {
    const std::string p = tmp.write("cut.glb", glb.substr(0, keep));
    const std::string msg = load_error([&] { load_scene(p); });
    EXPECT_CONTAINS(msg, "cut.glb");
    // Past the 12-byte header the message can say how much is missing.
    if (keep >= 12) {
      EXPECT_CONTAINS(msg, "truncated .glb");
    }
  }
}

TEST(GltfErrors, MalformedJson) {
  TempDir tmp;
  const std::string p =
      tmp.write("broken.gltf", R"({"asset": {"version": "2.0"}, "nodes": [ {"mesh": 0 )");
  const std::string msg = load_error([&] { load_scene(p); });
  EXPECT_CONTAINS(msg, "broken.gltf");
  EXPECT_CONTAINS(msg, "cannot parse glTF");
}

TEST(GltfErrors, AccessorPastEndOfBuffer) {
  TempDir tmp;
  std::string data = gltf_buffer();
  // Declare 5 positions in a view that holds 4 (stride 24): reading them would overrun.
  std::string json = gltf_json(embedded_buffer(data));
  const std::string needle = R"("componentType": 5126, "count": 4, "type": "VEC3",
     "min")";
  ASSERT_NE(json.find(needle), std::string::npos);
  json.replace(json.find(needle), needle.size(),
               R"("componentType": 5126, "count": 5, "type": "VEC3",
     "min")");
  const std::string p = tmp.write("overrun.gltf", json);
  const std::string msg = load_error([&] { load_scene(p); });
  EXPECT_CONTAINS(msg, "overrun.gltf");
  EXPECT_CONTAINS(msg, "reads past the end of buffer view 0");
}

TEST(GltfErrors, SparseAccessorIsRejectedClearly) {
  TempDir tmp;
  const std::string p = tmp.write(
      "sparse.gltf",
      gltf_json(embedded_buffer(gltf_buffer()),
                R"(, "sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5121},
                    "values": {"bufferView": 2}})"));
  const std::string msg = load_error([&] { load_scene(p); });
  EXPECT_CONTAINS(msg, "sparse.gltf");
  EXPECT_CONTAINS(msg, "sparse");
}

// ------------------------------------------------------------------------------------------
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

TEST(SharedScenes, Bunny) {
  KDGRID_REQUIRE_SCENE(p, "bunny/bun_zipper.ply");
  const Scene s = timed_load(p, "bunny");
  EXPECT_EQ(s.mesh.num_triangles(), 69451u);
  EXPECT_EQ(s.mesh.num_vertices(), 35947u);
}

TEST(SharedScenes, DragonRes2) {
  KDGRID_REQUIRE_SCENE(p, "dragon/dragon_vrip_res2.ply");
  const Scene s = timed_load(p, "dragon res2");
  EXPECT_EQ(s.mesh.num_triangles(), 202520u);
  EXPECT_EQ(s.mesh.num_vertices(), 100250u);
}

TEST(SharedScenes, DragonFull) {
  KDGRID_REQUIRE_SCENE(p, "dragon/dragon_vrip.ply");
  const Scene s = timed_load(p, "dragon full");
  EXPECT_EQ(s.mesh.num_triangles(), 871414u);
  EXPECT_EQ(s.mesh.num_vertices(), 437645u);
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

// ------------------------------------------------------------------------------------------
// CLI: `kdgrid info`

struct CliResult {
  int exit_code = -1;
  std::string out, err;
};

std::string read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

CliResult run_cli(const std::string& args, const TempDir& tmp) {
  const std::string out = tmp.file("stdout.txt"), err = tmp.file("stderr.txt");
  const std::string cmd =
      std::string("\"") + KDGRID_CLI_PATH + "\" " + args + " >\"" + out + "\" 2>\"" + err + "\"";
  const int status = std::system(cmd.c_str());
  CliResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = read_all(out);
  r.err = read_all(err);
  return r;
}

TEST(CliInfo, MissingFileFailsNamingIt) {
  TempDir tmp;
  const CliResult r = run_cli("info \"" + tmp.file("no_such_scene.ply") + "\"", tmp);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_CONTAINS(r.err, "no_such_scene.ply");
}

TEST(CliInfo, BadFileFailsWithLoaderMessage) {
  TempDir tmp;
  const std::string p = tmp.write(
      "range.ply", std::string(kTinyHeader) + "0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 7\n");
  const CliResult r = run_cli("info \"" + p + "\"", tmp);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_CONTAINS(r.err, "range.ply");
  EXPECT_CONTAINS(r.err, "references vertex 7");
}

TEST(CliInfo, GoodFileSucceeds) {
  TempDir tmp;
  const std::string p = tmp.write("fan.ply", kAsciiPly);
  const CliResult r = run_cli("info \"" + p + "\"", tmp);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_CONTAINS(r.out, "triangles   6");
  const CliResult j = run_cli("info --json \"" + p + "\"", tmp);
  EXPECT_EQ(j.exit_code, 0) << j.err;
  EXPECT_CONTAINS(j.out, "\"triangles\": 6");
}

}  // namespace
}  // namespace kdgrid
