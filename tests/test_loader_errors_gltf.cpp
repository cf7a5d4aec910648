// glTF and GLB files the loader must refuse with a message that names the file, the field and
// the rule (truncated or broken GLB headers, malformed JSON, accessors past their buffer, sparse
// accessors, URIs outside the scene's folder, instance explosions and deep node chains, lights
// and colours out of range, required extensions it does not read, huge images), and its
// warnings capped at ten.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <string>

#include "cli_util.h"
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

std::string le32s(uint32_t v) {
  return {char(v), char(v >> 8), char(v >> 16), char(v >> 24)};
}

TEST(GltfErrors, TruncatedGlb) {
  TempDir tmp;
  const std::string bin = gltf_buffer();
  std::string glb =
      make_glb(gltf_json(R"({"byteLength": )" + std::to_string(bin.size()) + "}"), bin);
  for (size_t keep : {size_t(10), glb.size() / 2, glb.size() - 40}) {
    const std::string p = tmp.write("cut.glb", glb.substr(0, keep));
    const std::string msg = load_error_of(p);
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
  const std::string msg = load_error_of(p);
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
  const std::string msg = load_error_of(p);
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
  const std::string msg = load_error_of(p);
  EXPECT_CONTAINS(msg, "sparse.gltf");
  EXPECT_CONTAINS(msg, "sparse");
}

TEST(HostileFiles, BrokenGlbHeadersNameTheField) {
  TempDir tmp;
  std::string json = R"({"asset":{"version":"2.0"}})";
  while (json.size() % 4) json += ' ';
  auto glb = [&](uint32_t version, int32_t length_delta, const std::string& type) {
    const std::string chunk = le32s(uint32_t(json.size())) + type + json;
    return "glTF" + le32s(version) + le32s(uint32_t(12 + chunk.size() + length_delta)) + chunk;
  };
  auto err = [&](const std::string& bytes) {
    const std::string p = tmp.write("x.glb", bytes);
    return load_error_of(p);
  };
  EXPECT_CONTAINS(err(glb(1, 0, "JSON")), "header version (bytes 4-7) is 1");
  EXPECT_CONTAINS(err(glb(2, 8, "JSON")), "truncated .glb: its header length (bytes 8-11)");
  EXPECT_CONTAINS(err(glb(2, -4, "JSON")), "bytes follow the end");
  EXPECT_CONTAINS(err(glb(2, 0, "JSOX")), "type (bytes 16-19) is 'JSOX', not 'JSON'");
  EXPECT_CONTAINS(err("glTF" + le32s(2) + le32s(20) + le32s(999) + "JSON"),
                  "length (bytes 12-15) is 999");
  EXPECT_CONTAINS(err(json), "not the magic 'glTF' (this is JSON: rename it to .gltf)");
}

TEST(HostileFiles, GltfUriOutsideTheSceneFolderIsNotRead) {
  TempDir tmp;
  fs::create_directories(tmp.file("scene"));
  tmp.write("outside.bin", triangle_bin());
  tmp.write("scene/tri.bin", triangle_bin());
  const std::string ok = tmp.write("scene/ok.gltf", gltf_text(R"([{"mesh":0}])"));
  EXPECT_EQ(load_scene(ok).mesh.num_triangles(), 1u);
  const std::string up = tmp.write("scene/up.gltf", gltf_text(R"([{"mesh":0}])", "../outside.bin"));
  EXPECT_CONTAINS(load_error_of(up), "outside the scene's folder");
  const std::string passwd =
      tmp.write("scene/pw.gltf", gltf_text(R"([{"mesh":0}])", "../../../../../../../etc/passwd"));
  const std::string e = load_error_of(passwd);
  EXPECT_CONTAINS(e, "outside the scene's folder");
  EXPECT_EQ(e.find("but got"), std::string::npos) << "the error reveals the file's size: " << e;
}

TEST(HostileFiles, GltfInstanceExplosionAndDeepChainsAreRefused) {
  TempDir tmp;
  tmp.write("tri.bin", triangle_bin());
  // 41 nodes, each listing the next one twice: 2^41 instances of the last node's mesh.
  std::string nodes = "[";
  for (int i = 0; i < 40; ++i)
    nodes += R"({"children":[)" + std::to_string(i + 1) + "," + std::to_string(i + 1) + "]},";
  nodes += R"({"mesh":0}])";
  const std::string boom = tmp.write("boom.gltf", gltf_text(nodes));
  const auto t0 = std::chrono::steady_clock::now();
  std::string e = load_error_of(boom);
  EXPECT_CONTAINS(e, "node instances");
  EXPECT_CONTAINS(e, "above the limit of 1048576");
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 5.0);
  // 24 levels of nodes listing the next one twice and no mesh at all: 2^24 - 1 instances, each
  // a matrix product; loading them took 11.6 s under AddressSanitizer (a fuzzer timeout).
  nodes = "[";
  for (int i = 0; i < 23; ++i)
    nodes += R"({"children":[)" + std::to_string(i + 1) + "," + std::to_string(i + 1) + "]},";
  nodes += R"({}])";
  const std::string empty_tree = tmp.write("empty_tree.gltf", gltf_text(nodes));
  EXPECT_CONTAINS(load_error_of(empty_tree), "expands to 1.678e+07 node instances");
  // A chain of 1100 nodes: too deep, which is not a cycle.
  nodes = "[";
  for (int i = 0; i < 1100; ++i) nodes += R"({"children":[)" + std::to_string(i + 1) + "]},";
  nodes += R"({"mesh":0}])";
  const std::string deep = tmp.write("deep.gltf", gltf_text(nodes));
  e = load_error_of(deep);
  EXPECT_CONTAINS(e, "more than 1000 levels deep");
  EXPECT_EQ(e.find("own ancestor"), std::string::npos) << e;
}

TEST(HostileFiles, GltfLightIntensityOutOfRangeIsRefused) {
  TempDir tmp;
  tmp.write("tri.bin", triangle_bin());
  for (const std::string value : {"1e300", "-2"}) {
    const std::string extra =
        R"(,"extensionsUsed":["KHR_lights_punctual"],"extensions":{"KHR_lights_punctual":)"
        R"({"lights":[{"type":"point","name":"lamp","intensity":)" +
        value + "}]}}";
    const std::string p = tmp.write(
        "light.gltf",
        gltf_text(
            R"([{"mesh":0,"children":[1]},{"extensions":{"KHR_lights_punctual":{"light":0}}}])",
            "tri.bin", extra));
    const std::string e = load_error_of(p);
    EXPECT_CONTAINS(e, "light 0 'lamp' has intensity");
    EXPECT_CONTAINS(e, "between 0 and 3.4e38");
  }
}

TEST(HostileFiles, GltfHugeImageIsRefusedFromItsHeader) {
  if (kAddressSanitizer)
    GTEST_SKIP()
        << "its memory budget comes from ulimit -v, under which AddressSanitizer cannot start";
  TempDir tmp;
  tmp.write("tri.bin", triangle_bin());
  tmp.write("big.png", png_header_only(20000, 20000));
  const std::string extra =
      R"(,"images":[{"uri":"big.png"}],"textures":[{"source":0}],)"
      R"("materials":[{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}])";
  std::string text = gltf_text(R"([{"mesh":0}])", "tri.bin", extra);
  const std::string p = tmp.write("tex.gltf", text);
  // Under a 4 GB address-space limit the budget is 2 GB: 20000^2 pixels need 2.8 GB.
  const CliStreams r = run_cli_streams("info \"" + p + "\"", tmp, "ulimit -v 4000000;");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_CONTAINS(r.err, "20000x20000 pixels would take");
  EXPECT_EQ(r.err.find("Unknown image format"), std::string::npos) << r.err;
}

TEST(HostileLoaders, RequiredGltfExtensionsKdgridDoesNotReadAreRefused) {
  const std::string e = load_error_of(hostile("requires_basisu.gltf"));
  EXPECT_CONTAINS(e, "requires_basisu.gltf: requires the glTF extension 'KHR_texture_basisu'");
  EXPECT_CONTAINS(e, "re-export the file without it");
  TempDir tmp;
  std::string text = read_file_bytes(hostile("requires_basisu.gltf"));
  const std::string basisu = "KHR_texture_basisu";
  for (size_t at; (at = text.find(basisu)) != std::string::npos;)
    text.replace(at, basisu.size(), "EXT_made_up");
  EXPECT_CONTAINS(load_error_of(tmp.write("x.gltf", text)), "'EXT_made_up'");
  // Used but not required: ignored, as glTF allows.
  EXPECT_EQ(load_scene(hostile("uses_unknown.gltf")).mesh.num_triangles(), 1u);
}

TEST(HostileLoaders, NegativeGltfMaterialColoursAreRefusedNamingTheField) {
  expect_message(load_error_of(hostile("negative_base_color.gltf")),
                 {"material 0 'dark' has pbrMetallicRoughness.baseColorFactor[0] -1", ">= 0"});
  EXPECT_CONTAINS(load_error_of(hostile("negative_emissive.gltf")),
                  "material 0 'glow' has emissiveFactor[1] -5");
}

TEST(HostileLoaders, GltfMessagesStateTheRuleAndBlameTheRightPart) {
  expect_message(load_error_of(hostile("stride256.gltf")),
                 {"byteStride 256", "multiple of 4 from 4 to 252"});
  std::string e = load_error_of(hostile("json_length_short.glb"));
  EXPECT_CONTAINS(e, "the JSON chunk length is wrong");
  EXPECT_EQ(e.find("BIN"), std::string::npos) << e;
  // A data: URI of 8000 bad characters is not echoed whole.
  e = load_error_of(hostile("bad_base64.gltf"));
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
  std::string text = read_file_bytes(hostile("uses_unknown.gltf"));
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

}  // namespace
}  // namespace kdgrid
