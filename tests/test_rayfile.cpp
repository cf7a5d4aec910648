// .rays/.hits files (docs/RAYSETS.md) and the benchmark ray sets.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>

#include <unistd.h>

#include "accel/bvh.h"
#include "agreement.h"
#include "bench/rayfile.h"
#include "bench/raysets.h"
#include "render/camera.h"
#include "util/error.h"

namespace kdgrid {
namespace {

namespace fs = std::filesystem;

fs::path temp_file(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("kdgrid_rayfile_test_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  return dir / name;
}

bool bits_equal(float a, float b) {
  return std::memcmp(&a, &b, 4) == 0;
}

std::string load_error_of(const std::vector<uint8_t>& bytes, const std::string& name) {
  try {
    parse_rays(bytes.data(), bytes.size(), name);
  } catch (const LoadError& e) {
    return e.what();
  }
  return "";
}

TEST(RayFile, RoundTripKeepsEveryBit) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<Ray> rays = random_rays(Box3({-1, -2, -3}, {4, 5, 6}), 1000, 3);
  rays.push_back({{nan, 1, 2}, 0.0f, {0, -0.0f, 1}, kInf});  // NaN rays are valid content
  rays.push_back({{1e30f, -1e-30f, 0}, 0.5f, {-0.0f, 0.0f, -1}, 3.0f});
  const fs::path f = temp_file("a.rays");
  write_rays(f.string(), rays);
  EXPECT_EQ(fs::file_size(f), 16 + 32 * rays.size());
  const auto back = read_rays(f.string());
  ASSERT_EQ(back.size(), rays.size());
  for (size_t i = 0; i < rays.size(); ++i)
    for (int k = 0; k < 3; ++k) {
      EXPECT_TRUE(bits_equal(back[i].org[k], rays[i].org[k]));
      EXPECT_TRUE(bits_equal(back[i].dir[k], rays[i].dir[k]));
      EXPECT_TRUE(bits_equal(back[i].tmin, rays[i].tmin));
      EXPECT_TRUE(bits_equal(back[i].tmax, rays[i].tmax));
    }
  // The header is exactly what docs/RAYSETS.md specifies.
  const auto bytes = serialize_rays(rays);
  EXPECT_EQ(std::memcmp(bytes.data(), "RAYS", 4), 0);
  uint32_t version;
  uint64_t n;
  std::memcpy(&version, bytes.data() + 4, 4);
  std::memcpy(&n, bytes.data() + 8, 8);
  EXPECT_EQ(version, 1u);
  EXPECT_EQ(n, rays.size());
  float first[8];
  std::memcpy(first, bytes.data() + 16, 32);
  EXPECT_EQ(first[0], rays[0].org.x);
  EXPECT_EQ(first[3], rays[0].tmin);
  EXPECT_EQ(first[4], rays[0].dir.x);
  EXPECT_EQ(first[7], rays[0].tmax);
  fs::remove(f);
}

TEST(RayFile, HitsRoundTripAndMissEncoding) {
  std::vector<Hit> hits = {{1.5f, 7, 0.1f, 0.2f}, {}, {0.0f, 0, 0, 0}, {kInf, 12, 0, 0}};
  const auto bytes = serialize_hits(hits);
  ASSERT_EQ(bytes.size(), 32u);
  float t;
  uint32_t prim;
  std::memcpy(&t, bytes.data() + 8, 4);
  std::memcpy(&prim, bytes.data() + 12, 4);
  EXPECT_EQ(t, kInf);
  EXPECT_EQ(prim, 0xFFFFFFFFu);
  const fs::path f = temp_file("a.hits");
  write_hits(f.string(), hits);
  const auto back = read_hits(f.string(), 4);
  ASSERT_EQ(back.size(), 4u);
  EXPECT_EQ(back[0].t, 1.5f);
  EXPECT_EQ(back[0].prim, 7u);
  EXPECT_FALSE(back[1].valid());
  EXPECT_EQ(back[1].t, kInf);
  EXPECT_EQ(back[2].prim, 0u);
  EXPECT_THROW(read_hits(f.string(), 5), LoadError);
  fs::remove(f);
}

TEST(RayFile, RejectsMalformedFilesNamingThem) {
  const auto good = serialize_rays(random_rays(Box3({0, 0, 0}, {1, 1, 1}), 10, 1));
  ASSERT_EQ(load_error_of(good, "x.rays"), "");

  auto truncated = good;
  truncated.resize(truncated.size() - 5);
  std::string e = load_error_of(truncated, "trunc.rays");
  EXPECT_NE(e.find("trunc.rays"), std::string::npos) << e;
  EXPECT_NE(e.find("truncated"), std::string::npos) << e;

  auto trailing = good;
  trailing.push_back(0);
  e = load_error_of(trailing, "trail.rays");
  EXPECT_NE(e.find("trail.rays"), std::string::npos) << e;
  EXPECT_NE(e.find("trailing"), std::string::npos) << e;

  auto magic = good;
  magic[0] = 'X';
  e = load_error_of(magic, "magic.rays");
  EXPECT_NE(e.find("magic"), std::string::npos) << e;

  auto version = good;
  version[4] = 2;
  e = load_error_of(version, "v2.rays");
  EXPECT_NE(e.find("version 2"), std::string::npos) << e;

  auto huge = good;
  const uint64_t n = uint64_t(1) << 60;  // n * 32 would overflow 64 bits
  std::memcpy(huge.data() + 8, &n, 8);
  e = load_error_of(huge, "huge.rays");
  EXPECT_NE(e.find("corrupt"), std::string::npos) << e;

  auto fewer = good;  // N says 11 rays, the file holds 10
  const uint64_t eleven = 11;
  std::memcpy(fewer.data() + 8, &eleven, 8);
  EXPECT_NE(load_error_of(fewer, "n.rays"), "");

  EXPECT_NE(load_error_of({}, "empty.rays"), "");
  EXPECT_NE(load_error_of({'R', 'A', 'Y'}, "short.rays"), "");

  // A file on disk reports its path; a missing one says so.
  const fs::path f = temp_file("bad.rays");
  {
    std::ofstream out(f, std::ios::binary);
    out.write(reinterpret_cast<const char*>(truncated.data()), std::streamsize(truncated.size()));
  }
  try {
    read_rays(f.string());
    ADD_FAILURE() << "truncated file accepted";
  } catch (const LoadError& err) {
    EXPECT_NE(std::string(err.what()).find(f.string()), std::string::npos);
  }
  EXPECT_THROW(read_rays((f.parent_path() / "missing.rays").string()), LoadError);
  EXPECT_THROW(parse_hits("abc", 3, "odd.hits"), LoadError);
  fs::remove(f);
}

TEST(RaySets, PrimaryRaysFollowTheCanonicalCamera) {
  const Mesh mesh = test::subdivided_sphere(1, 3.0f, {1, 0, 0});
  const Camera cam = canonical_camera(mesh.bounds());
  const auto rays = primary_rays(cam, 32, 16);
  ASSERT_EQ(rays.size(), 32u * 16u);
  const CameraFrame f = CameraFrame::make(cam, 32, 16);
  // Row by row, pixel centres.
  for (int j : {0, 7, 15})
    for (int i : {0, 13, 31}) {
      const Ray expect = f.ray(i + 0.5f, j + 0.5f);
      const Ray& got = rays[size_t(j) * 32 + i];
      EXPECT_EQ(got.org, expect.org);
      EXPECT_EQ(got.dir, expect.dir);
      EXPECT_EQ(got.tmin, 0.0f);
      EXPECT_EQ(got.tmax, kInf);
    }
  // Row 0 is at the top: its rays point more upwards than the last row's.
  EXPECT_GT(rays.front().dir.y, rays.back().dir.y);
  EXPECT_LT(rays.front().dir.x, rays[31].dir.x + 1.0f);
  EXPECT_THROW(primary_rays(cam, 0, 5), ParamError);
}

// Shadow rays from a sphere: points whose outward normal faces the light reach it unoccluded
// (the offset escapes the surface); points facing away are blocked by the sphere itself.
TEST(RaySets, ShadowRaysLeaveTheSurfaceAndStopAtTheLight) {
  const Mesh mesh = test::subdivided_sphere(5, 100.0f, {1000, -50, 20});  // off-origin, large
  Bvh bvh;
  bvh.build(mesh, BuildParams{});
  const Box3 b = mesh.bounds();
  const Vec3 light = canonical_light_position(b);
  const auto primary = primary_rays(canonical_camera(b), 96, 96);
  const auto hits = trace_hits(bvh, primary);
  const auto shadow = shadow_rays(mesh, primary, hits, light);
  size_t nhits = 0;
  for (const Hit& h : hits) nhits += h.valid();
  ASSERT_EQ(shadow.size(), nhits);
  ASSERT_GT(nhits, 1000u);
  size_t lit = 0, blocked = 0, checked = 0;
  for (const Ray& r : shadow) {
    EXPECT_EQ(r.tmax, 1.0f);
    EXPECT_LT(length(r.org + r.dir - light), 1e-3f * length(r.dir));
    const Vec3 n = normalize(r.org - Vec3(1000, -50, 20));
    const float c = dot(n, normalize(r.dir));
    const bool occ = bvh.occluded(r);
    if (c > 0.05f) {
      EXPECT_FALSE(occ) << "self-intersection: " << test::describe(r);
      ++lit;
      ++checked;
    } else if (c < -0.05f) {
      EXPECT_TRUE(occ) << test::describe(r);
      ++blocked;
      ++checked;
    }
  }
  EXPECT_GT(lit, 100u);
  EXPECT_GT(checked, nhits / 2);
  (void)blocked;
}

TEST(RaySets, DiffuseRaysAreSeededAndInTheCameraHemisphere) {
  const Mesh mesh = test::subdivided_sphere(3);
  Bvh bvh;
  bvh.build(mesh, BuildParams{});
  const auto primary = primary_rays(canonical_camera(mesh.bounds()), 48, 48);
  const auto hits = trace_hits(bvh, primary);
  const auto a = diffuse_rays(mesh, primary, hits, 7);
  const auto b = diffuse_rays(mesh, primary, hits, 7);
  const auto c = diffuse_rays(mesh, primary, hits, 8);
  ASSERT_EQ(a.size(), b.size());
  ASSERT_GT(a.size(), 100u);
  size_t differ = 0, escaped = 0;
  double mean_cos = 0;
  for (size_t i = 0, k = 0; i < primary.size(); ++i) {
    if (!hits[i].valid()) continue;
    EXPECT_EQ(a[k].dir, b[k].dir);
    differ += !(a[k].dir == c[k].dir);
    Vec3 n = normalize(mesh.geometric_normal(hits[i].prim));
    if (dot(n, primary[i].dir) > 0) n = -n;
    const float cs = dot(n, a[k].dir);
    EXPECT_GE(cs, -1e-6f);
    mean_cos += cs;
    escaped += !bvh.occluded(a[k]);  // a convex outside surface: every bounce escapes
    ++k;
  }
  EXPECT_GT(differ, a.size() * 9 / 10);
  EXPECT_EQ(escaped, a.size());
  // Cosine-distributed: E[cos] = 2/3.
  EXPECT_NEAR(mean_cos / a.size(), 2.0 / 3.0, 0.03);
}

TEST(RaySets, RandomRaysAreDeterministicAndVaried) {
  const Box3 box({-1, 0, 2}, {3, 1, 2});  // flat in z
  const auto a = random_rays(box, 4000, 42);
  const auto b = random_rays(box, 4000, 42);
  const auto c = random_rays(box, 4000, 43);
  ASSERT_EQ(a.size(), 4000u);
  size_t finite_tmax = 0, positive_tmin = 0, zero_components = 0, same = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].org, b[i].org);
    EXPECT_EQ(a[i].dir, b[i].dir);
    same += a[i].dir == c[i].dir;
    EXPECT_TRUE(ray_is_valid(a[i])) << test::describe(a[i]);
    finite_tmax += std::isfinite(a[i].tmax);
    positive_tmin += a[i].tmin > 0;
    zero_components += a[i].dir.x == 0 || a[i].dir.y == 0 || a[i].dir.z == 0;
  }
  EXPECT_LT(same, 100u);
  EXPECT_GT(finite_tmax, 300u);
  EXPECT_GT(positive_tmin, 300u);
  EXPECT_GT(zero_components, 300u);
  EXPECT_EQ(parse_ray_set("shadow"), RaySetKind::Shadow);
  EXPECT_THROW(parse_ray_set("bogus"), ParamError);
}

}  // namespace
}  // namespace kdgrid
