// PLY files the loader must refuse with a LoadError that names the file and the problem (bad
// magic, formats, truncation, malformed numbers, indices out of range, non-finite coordinates,
// absurd counts, missing end_header, NUL bytes), line endings it must still read, and seeded
// random mutations of valid files (each loads or throws LoadError, never crashes or hangs).
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "loader_inputs.h"
#include "scene/load.h"
#include "temp_dir.h"
#include "test_util.h"
#include "util/error.h"

namespace kdgrid {
namespace {

using namespace test;

std::string ply_error(const std::string& text, const std::string& name = "bad.ply") {
  return load_error([&] { parse_ply(text.data(), text.size(), name); });
}

/// A PLY of kTinyHeader and its body (four vertices, then faces (0 1 2) and (0 2 3)) with the
/// body's first occurrence of `from` replaced by `to`.
std::string tiny_ply(const std::string& from, const std::string& to) {
  std::string body = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n";
  body.replace(body.find(from), from.size(), to);
  return std::string(kTinyHeader) + body;
}

TEST(PlyErrors, MissingFile) {
  TempDir tmp;
  expect_message(load_error_of(tmp.file("nowhere.ply")), {"nowhere.ply", "no such file"});
}

TEST(PlyErrors, UnknownExtension) {
  TempDir tmp;
  expect_message(load_error_of(tmp.write("mesh.stl", "solid x\n")),
                 {"mesh.stl", "unknown scene format"});
}

TEST(PlyErrors, BadMagic) {
  expect_message(ply_error("plx\nformat ascii 1.0\nend_header\n", "magic.ply"),
                 {"magic.ply", "not a PLY file"});
}

TEST(PlyErrors, UnknownFormat) {
  expect_message(ply_error("ply\nformat binary_middle_endian 1.0\nend_header\n", "fmt.ply"),
                 {"fmt.ply", "unknown format 'binary_middle_endian'"});
}

TEST(PlyErrors, TruncatedHeader) {
  expect_message(
      ply_error("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n", "hdr.ply"),
      {"hdr.ply", "end_header"});
}

TEST(PlyErrors, TruncatedAscii) {
  std::string text = kAsciiPly;
  text = text.substr(0, text.find("5 6 5 4"));  // cut before the pentagon (face 2)
  expect_message(ply_error(text, "cut.ply"), {"cut.ply", "face 2 of 3", "file ends early"});
}

TEST(PlyErrors, TruncatedBinary) {
  std::string d = binary_ply(false);
  d.resize(d.size() - 10);  // the 5-byte trailer and half of the last face
  expect_message(ply_error(d, "cutbin.ply"), {"cutbin.ply", "face 2 of 3", "file ends early"});
}

TEST(PlyErrors, MalformedNumber) {
  expect_message(ply_error(tiny_ply("1 1 0", "1 1z 0"), "num.ply"),
                 {"num.ply", "vertex 2 of 4", "line 12", "malformed number '1z'"});
}

TEST(PlyErrors, FaceIndexOutOfRange) {
  expect_message(ply_error(tiny_ply("0 2 3", "0 2 7"), "range.ply"),
                 {"range.ply", "face 1 of 2", "references vertex 7 but the file has 4 vertices"});
}

TEST(PlyErrors, NegativeFaceIndex) {
  expect_message(ply_error(tiny_ply("0 1 2", "0 1 -1"), "neg.ply"), {"references vertex -1"});
}

TEST(PlyErrors, FaceWithTwoVertices) {
  expect_message(ply_error(tiny_ply("3 0 2 3", "2 0 2"), "two.ply"),
                 {"two.ply", "face 1 of 2", "at least 3"});
}

TEST(PlyErrors, MissingCoordinate) {
  expect_message(ply_error("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                           "property float y\nend_header\n0 0\n",
                           "noz.ply"),
                 {"noz.ply", "x, y, z"});
}

TEST(PlyErrors, NanVertex) {
  TempDir tmp;
  expect_message(load_error_of(tmp.write("nan.ply", tiny_ply("1 0 0", "1 nan 0"))),
                 {"nan.ply", "vertex 1 has a NaN or infinite coordinate"});
}

TEST(PlyErrors, InfVertex) {
  TempDir tmp;
  expect_message(load_error_of(tmp.write("inf.ply", tiny_ply("1 1 0", "1 1 -inf"))),
                 {"inf.ply", "vertex 2 has a NaN or infinite coordinate"});
}

TEST(PlyErrors, HugeFloatIsAnError) {
  expect_message(ply_error(tiny_ply("1 0 0", "1 0 1e999"), "big.ply"),
                 {"big.ply", "malformed number '1e999'"});
}

TEST(PlyErrors, VerticesOnlyHasNoTriangles) {
  TempDir tmp;
  const std::string p = tmp.write("points.ply",
                                  "ply\nformat ascii 1.0\nelement vertex 3\nproperty float "
                                  "x\nproperty float y\nproperty float z\n"
                                  "end_header\n0 0 0\n1 0 0\n0 1 0\n");
  expect_message(load_error_of(p), {"points.ply", "no triangles"});
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

TEST(HostileFiles, PlyLineEndingsNulBytesAndMissingEndHeader) {
  TempDir tmp;
  const std::string body =
      "ply|format ascii 1.0|element vertex 3|property float x|property float y|property float z|"
      "element face 1|property list uchar int vertex_indices|end_header|0 0 0|1 0 0|0 1 0|3 0 1 2|";
  for (const std::string eol : {"\r", "\r\n"}) {
    std::string text;
    for (char c : body) text += c == '|' ? eol : std::string(1, c);
    const std::string p = tmp.write("cr.ply", text);
    EXPECT_EQ(load_scene(p).mesh.num_triangles(), 1u) << (eol == "\r" ? "CR" : "CRLF");
  }
  const std::string noend =
      tmp.write("noend.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n0\n");
  EXPECT_CONTAINS(load_error_of(noend), "no 'end_header' line came before it");
  static const char kNulPly[] =
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty fl\0at x\nend_header\n0\n";
  const std::string nul = tmp.write("nul.ply", std::string(kNulPly, sizeof kNulPly - 1));
  const std::string e = load_error_of(nul);
  EXPECT_CONTAINS(e, "fl\\x00at");
  EXPECT_EQ(e.size(), std::strlen(e.c_str())) << "a NUL byte cuts the message";
}

}  // namespace
}  // namespace kdgrid
