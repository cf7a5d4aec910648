#include "bench/rayfile.h"

#include <bit>
#include <cstring>

#include "util/atomic_file.h"
#include "util/error.h"
#include "util/input_file.h"

namespace kdgrid {

// The formats are little-endian and records are copied with memcpy; a big-endian port would
// need byte swaps here.
static_assert(std::endian::native == std::endian::little, "rayfile.cpp assumes little-endian");

std::vector<Ray> parse_rays(const void* data, size_t size, const std::string& name) {
  const auto* p = static_cast<const uint8_t*>(data);
  if (size < kRayFileHeaderBytes)
    throw LoadError(name + ": only " + std::to_string(size) +
                    " bytes, shorter than the 16-byte .rays header: not a ray file");
  if (std::memcmp(p, "RAYS", 4) != 0)
    throw LoadError(name +
                    ": does not start with the magic 'RAYS': not a .rays file "
                    "(see docs/RAYSETS.md for the format)");
  uint32_t version;
  uint64_t n;
  std::memcpy(&version, p + 4, 4);
  std::memcpy(&n, p + 8, 8);
  if (version != kRayFileVersion)
    throw LoadError(name + ": .rays version " + std::to_string(version) +
                    " is not supported; this kdgrid reads version " +
                    std::to_string(kRayFileVersion));
  if (n > kMaxRaysInFile)
    throw LoadError(name + ": header claims " + std::to_string(n) +
                    " rays, more than the supported maximum " + std::to_string(kMaxRaysInFile) +
                    ": the header is corrupt");
  const uint64_t expected = kRayFileHeaderBytes + n * kRayRecordBytes;
  if (size != expected)
    throw LoadError(
        name + ": header says " + std::to_string(n) + " rays (" + std::to_string(expected) +
        " bytes) but the file has " + std::to_string(size) +
        " bytes: " + (size < expected ? "the file is truncated" : "trailing bytes after the rays") +
        "; regenerate it with `kdgrid rays`");
  std::vector<Ray> rays(n);
  const uint8_t* q = p + kRayFileHeaderBytes;
  for (uint64_t i = 0; i < n; ++i, q += kRayRecordBytes) {
    float f[8];
    std::memcpy(f, q, sizeof f);
    rays[i].org = {f[0], f[1], f[2]};
    rays[i].tmin = f[3];
    rays[i].dir = {f[4], f[5], f[6]};
    rays[i].tmax = f[7];
  }
  return rays;
}

std::vector<Ray> read_rays(const std::string& path) {
  const std::string data = read_input_file(path);
  return parse_rays(data.data(), data.size(), path);
}

std::vector<uint8_t> serialize_rays(const std::vector<Ray>& rays) {
  std::vector<uint8_t> out(kRayFileHeaderBytes + rays.size() * kRayRecordBytes);
  std::memcpy(out.data(), "RAYS", 4);
  const uint32_t version = kRayFileVersion;
  const uint64_t n = rays.size();
  std::memcpy(out.data() + 4, &version, 4);
  std::memcpy(out.data() + 8, &n, 8);
  uint8_t* q = out.data() + kRayFileHeaderBytes;
  for (const Ray& r : rays) {
    const float f[8] = {r.org.x, r.org.y, r.org.z, r.tmin, r.dir.x, r.dir.y, r.dir.z, r.tmax};
    std::memcpy(q, f, sizeof f);
    q += kRayRecordBytes;
  }
  return out;
}

void write_rays(const std::string& path, const std::vector<Ray>& rays) {
  const auto bytes = serialize_rays(rays);
  write_file_atomically(path, {reinterpret_cast<const char*>(bytes.data()), bytes.size()});
}

std::vector<Hit> parse_hits(const void* data, size_t size, const std::string& name,
                            int64_t expected_count) {
  if (size % kHitRecordBytes != 0)
    throw LoadError(name + ": " + std::to_string(size) +
                    " bytes is not a whole number of 8-byte hit records: the file is truncated "
                    "or not a .hits file");
  const uint64_t n = size / kHitRecordBytes;
  if (expected_count >= 0 && n != uint64_t(expected_count))
    throw LoadError(name + ": holds " + std::to_string(n) + " hits but the ray file has " +
                    std::to_string(expected_count) + " rays: the files do not belong together");
  std::vector<Hit> hits(n);
  const auto* q = static_cast<const uint8_t*>(data);
  for (uint64_t i = 0; i < n; ++i, q += kHitRecordBytes) {
    std::memcpy(&hits[i].t, q, 4);
    std::memcpy(&hits[i].prim, q + 4, 4);
    if (hits[i].prim == kInvalidPrim) hits[i].t = kInf;
  }
  return hits;
}

std::vector<Hit> read_hits(const std::string& path, int64_t expected_count) {
  const std::string data = read_input_file(path);
  return parse_hits(data.data(), data.size(), path, expected_count);
}

std::vector<uint8_t> serialize_hits(const std::vector<Hit>& hits) {
  std::vector<uint8_t> out(hits.size() * kHitRecordBytes);
  uint8_t* q = out.data();
  for (const Hit& h : hits) {
    const float t = h.valid() ? h.t : kInf;
    const uint32_t prim = h.valid() ? h.prim : kInvalidPrim;
    std::memcpy(q, &t, 4);
    std::memcpy(q + 4, &prim, 4);
    q += kHitRecordBytes;
  }
  return out;
}

void write_hits(const std::string& path, const std::vector<Hit>& hits) {
  const auto bytes = serialize_hits(hits);
  write_file_atomically(path, {reinterpret_cast<const char*>(bytes.data()), bytes.size()});
}

}  // namespace kdgrid
