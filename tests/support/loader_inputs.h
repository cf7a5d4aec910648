// Scene files the loader tests write and read: a PLY with fan faces and skipped elements, a
// binary PLY of odd property order and types in either byte order, the test glTF (embedded
// buffer or GLB) and a one-triangle glTF beside its .bin, the files of tests/data/hostile, and
// the helpers that load them and check their messages.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <functional>
#include <initializer_list>
#include <string>
#include <vector>

#include "scene/load.h"
#include "test_util.h"

namespace kdgrid::test {

using TriangleTest = std::array<uint32_t, 3>;

inline void expect_near(const Vec3& a, const Vec3& b, float eps = 1e-5f) {
  EXPECT_NEAR(a.x, b.x, eps);
  EXPECT_NEAR(a.y, b.y, eps);
  EXPECT_NEAR(a.z, b.z, eps);
}

/// The message of loading the scene file at `path`, which must fail with LoadError.
inline std::string load_error_of(const std::string& path) {
  return load_error([&] { load_scene(path); });
}

/// Expects `msg` to contain each of `parts`.
inline void expect_message(const std::string& msg, std::initializer_list<const char*> parts) {
  for (const char* part : parts) EXPECT_CONTAINS(msg, part);
}

/// A file of tests/data/hostile.
inline std::string hostile(const std::string& name) {
  return source_path("tests/data/hostile/" + name);
}

// Seven vertices; a triangle, a quad and a pentagon, with elements the reader must skip
// before and after, comments and an obj_info line.
inline const char* const kAsciiPly =
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

/// The header of a PLY of 4 vertices and 2 faces; the tests append its body.
inline const char* const kTinyHeader =
    "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
    "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n";

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
inline const BinVertex kBinVerts[5] = {
    {0.5, 0, -1.25}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {-3.5, 2, 1e-3}};

/// A binary PLY with odd property order and types: coordinates as double and int16 among
/// other properties, a list in an element before the vertices, an unknown element holding a
/// 'vertex_indices' list, face lists of uchar count + uint index between other properties.
inline std::string binary_ply(bool big_endian) {
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

inline std::string base64(const std::string& in) {
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
inline std::string gltf_buffer() {
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
inline std::string gltf_json(const std::string& buffer, const std::string& accessor_extra = "") {
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

inline std::string embedded_buffer(const std::string& data) {
  return R"({"byteLength": )" + std::to_string(data.size()) +
         R"(, "uri": "data:application/octet-stream;base64,)" + base64(data) + R"("})";
}

/// GLB container: 12-byte header, JSON chunk, BIN chunk (both padded to 4 bytes).
inline std::string make_glb(std::string json, std::string bin) {
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

/// The test glTF as a GLB: its JSON chunk and its buffer as the BIN chunk.
inline std::string test_glb() {
  const std::string bin = gltf_buffer();
  return make_glb(gltf_json(R"({"byteLength": )" + std::to_string(bin.size()) + "}"), bin);
}

/// A glTF with one triangle in tri.bin (written beside it) and the given nodes.
inline std::string gltf_text(const std::string& nodes, const std::string& buffer_uri = "tri.bin",
                             const std::string& extra = "") {
  return R"({"asset":{"version":"2.0"},"buffers":[{"uri":")" + buffer_uri +
         R"(","byteLength":36}],"bufferViews":[{"buffer":0,"byteLength":36}],)"
         R"("accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",)"
         R"("min":[0,0,0],"max":[1,1,0]}],"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],)"
         R"("nodes":)" +
         nodes + R"(,"scenes":[{"nodes":[0]}],"scene":0)" + extra + "}";
}

inline std::string triangle_bin() {
  const float v[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
  return std::string(reinterpret_cast<const char*>(v), sizeof v);
}

/// What `f` writes to stderr (file descriptor 2) while it runs; `f` may throw.
inline std::string capture_stderr(const std::function<void()>& f) {
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

}  // namespace kdgrid::test
