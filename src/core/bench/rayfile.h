// `.rays` and `.hits` files (docs/RAYSETS.md): little-endian binary, so the same rays can be
// traced by kdgrid, Embree or any other tool and the hits compared record by record.
//
//   .rays: magic "RAYS", uint32 version 1, uint64 N, then N x {ox oy oz tmin dx dy dz tmax}
//          as float32.
//   .hits: N x {float32 t, uint32 prim}; a miss is t = +inf, prim = 0xFFFFFFFF.
//
// Readers reject anything that does not match exactly (wrong magic, version, a size that
// disagrees with N) with a LoadError naming the file. Rays with NaN are kept: they are
// valid file content, and every accelerator treats them as misses.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "math/ray.h"

namespace kdgrid {

constexpr uint32_t kRayFileVersion = 1;
constexpr size_t kRayFileHeaderBytes = 16;
constexpr size_t kRayRecordBytes = 32;
constexpr size_t kHitRecordBytes = 8;
/// Upper bound on N accepted by the readers (2^32 rays = 128 GiB of file): anything larger is
/// a corrupt header, not a ray set.
constexpr uint64_t kMaxRaysInFile = uint64_t(1) << 32;

/// Parses a whole `.rays` file held in memory; `name` appears in error messages.
std::vector<Ray> parse_rays(const void* data, size_t size, const std::string& name);
std::vector<Ray> read_rays(const std::string& path);
/// Writes a `.rays` file (Error if it cannot be written).
void write_rays(const std::string& path, const std::vector<Ray>& rays);
/// The bytes of a `.rays` file, as write_rays would write them.
std::vector<uint8_t> serialize_rays(const std::vector<Ray>& rays);

/// Parses a whole `.hits` file held in memory. Barycentrics are not stored: u = v = 0.
/// If expected_count >= 0, a different record count is an error naming both counts.
std::vector<Hit> parse_hits(const void* data, size_t size, const std::string& name,
                            int64_t expected_count = -1);
std::vector<Hit> read_hits(const std::string& path, int64_t expected_count = -1);
/// Writes a `.hits` file; invalid hits are written as misses (t = +inf, prim = 0xFFFFFFFF).
void write_hits(const std::string& path, const std::vector<Hit>& hits);
std::vector<uint8_t> serialize_hits(const std::vector<Hit>& hits);

}  // namespace kdgrid
