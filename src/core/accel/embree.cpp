#include "accel/embree.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <mutex>
#include <string>
#include <utility>

#include "accel/guards.h"
#include "accel/triangle.h"
#include "util/cancel.h"
#include "util/error.h"

namespace kdgrid {

namespace {

/// What Embree's memory monitor sees (its callback may run on several threads at once).
struct MemoryWatch {
  /// Bytes Embree holds, as reported by its memory monitor (allocations minus frees).
  std::atomic<int64_t> bytes{0};
  /// Highest value of `bytes` during the build (its peak, temporaries included).
  std::atomic<int64_t> peak{0};
  /// Allocations that would take `bytes` above this are refused (0 = no limit), so a build
  /// the estimate let through still stops at the memory budget instead of exhausting RAM.
  int64_t limit = 0;
  std::atomic<bool> over_limit{false};
};

}  // namespace

struct EmbreeAccel::State {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  MemoryWatch memory;
  std::string error;  ///< last message of Embree's error callback
};

namespace {

/// Embree's rule (rtcSetDeviceMemoryMonitorFunction): a refused allocation announced before
/// it happens (post == false) is not counted; one refused after it happened is, and is freed
/// later. Refusing makes the current call fail with RTC_ERROR_OUT_OF_MEMORY.
bool memory_monitor(void* user, ssize_t bytes, bool post) {
  auto* st = static_cast<MemoryWatch*>(user);
  const int64_t now = st->bytes.fetch_add(int64_t(bytes), std::memory_order_relaxed) + bytes;
  if (bytes > 0 && st->limit > 0 && now > st->limit) {
    st->over_limit.store(true);
    if (!post) st->bytes.fetch_sub(int64_t(bytes), std::memory_order_relaxed);
    return false;
  }
  int64_t peak = st->peak.load(std::memory_order_relaxed);
  while (now > peak && !st->peak.compare_exchange_weak(peak, now, std::memory_order_relaxed)) {
  }
  return true;
}

void error_callback(void* user, RTCError code, const char* str) {
  auto* msg = static_cast<std::string*>(user);
  *msg = std::string("Embree error ") + std::to_string(int(code)) + ": " + (str ? str : "");
}

/// Embree calls this during the commit; returning false stops the build (RTC_ERROR_CANCELLED).
bool keep_building(void* token, double /*progress*/) {
  return !static_cast<const CancelToken*>(token)->cancelled();
}

RTCBuildQuality parse_quality(const std::string& q) {
  if (q == "low") return RTC_BUILD_QUALITY_LOW;
  if (q == "medium") return RTC_BUILD_QUALITY_MEDIUM;
  if (q == "high") return RTC_BUILD_QUALITY_HIGH;
  throw ParamError("embree: unknown build quality '" + q +
                   "' (--embree-quality): use low, medium (default) or high");
}

/// Converts a kdgrid ray to Embree's, returning the t shift applied for a negative tmin.
float to_rtc(const Ray& r, RTCRay& out) {
  float shift = 0.0f;
  Vec3 org = r.org;
  if (r.tmin < 0.0f) {
    shift = r.tmin;
    org = r.org + r.dir * r.tmin;
  }
  out.org_x = org.x;
  out.org_y = org.y;
  out.org_z = org.z;
  out.dir_x = r.dir.x;
  out.dir_y = r.dir.y;
  out.dir_z = r.dir.z;
  out.tnear = r.tmin - shift;
  // [tmin, tmax) -> [tnear, tfar]: the float just below tmax (infinity stays infinity).
  out.tfar = (r.tmax == kInf ? kInf : next_float_down(r.tmax)) - shift;
  if (out.tfar < out.tnear) out.tfar = out.tnear;
  out.time = 0.0f;
  out.mask = 0xFFFFFFFFu;
  out.id = 0;
  out.flags = 0;
  return shift;
}

}  // namespace

const std::vector<EmbreeConfig>& embree_configs() {
  static const std::vector<EmbreeConfig> configs = {
      {"embree", false, ""}, {"embree-robust", true, ""}, {"embree-high", false, "high"}};
  return configs;
}

const EmbreeConfig* embree_config(const std::string& name) {
  for (const EmbreeConfig& c : embree_configs())
    if (c.name == name) return &c;
  return nullptr;
}

const char* embree_isa_names() {
  return "sse4.2, avx, avx2, avx512";
}

namespace {

/// A restriction's name in reports, and whether this CPU runs it (Embree's AVX-512 kernels
/// need F, CD, DQ, BW and VL); nullptr for a name Embree's "isa=" does not take here.
const char* restricted_isa_name(const std::string& isa, bool& cpu_has) {
  __builtin_cpu_init();
  if (isa == "sse4.2") return cpu_has = __builtin_cpu_supports("sse4.2"), "SSE4.2";
  if (isa == "avx") return cpu_has = __builtin_cpu_supports("avx"), "AVX";
  if (isa == "avx2") return cpu_has = __builtin_cpu_supports("avx2"), "AVX2";
  if (isa == "avx512")
    return cpu_has = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512cd") &&
                     __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512bw") &&
                     __builtin_cpu_supports("avx512vl"),
           "AVX-512";
  return nullptr;
}

/// rtcNewDevice's configuration: the build threads (0 = Embree's default) and the ISA.
std::string device_config(int threads, const std::string& isa) {
  std::string c = threads > 0 ? "threads=" + std::to_string(threads) : std::string();
  if (!isa.empty()) c += (c.empty() ? "isa=" : ",isa=") + isa;
  return c;
}

/// What device d (nullptr: none could be created) runs, created with the restriction `isa`.
EmbreeIsa device_isa(RTCDevice d, const std::string& isa) {
  EmbreeIsa out;
  out.isa = "unknown";
  out.config = isa;
  if (!d) return out;
  const ssize_t v = rtcGetDeviceProperty(d, RTC_DEVICE_PROPERTY_VERSION);  // 31305 = 3.13.5
  out.version = std::to_string(v / 10000) + "." + std::to_string(v / 100 % 100) + "." +
                std::to_string(v % 100);
  if (rtcGetDeviceProperty(d, RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED)) {
    out.isa = "AVX-512";
    out.native_packet = 16;
  } else if (rtcGetDeviceProperty(d, RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED)) {
    out.isa = "AVX or AVX2";
    out.native_packet = 8;
  } else if (rtcGetDeviceProperty(d, RTC_DEVICE_PROPERTY_NATIVE_RAY4_SUPPORTED)) {
    out.isa = "SSE";
    out.native_packet = 4;
  }
  // A restriction names its ISA where the device's packets are that ISA's (AVX and AVX2 both
  // run packets of 8).
  const int packet = isa == "avx512" ? 16 : isa == "avx" || isa == "avx2" ? 8 : 4;
  bool cpu_has = false;
  if (!isa.empty() && out.native_packet == packet) out.isa = restricted_isa_name(isa, cpu_has);
  return out;
}

}  // namespace

void check_embree_isa(const std::string& isa) {
  if (isa.empty()) return;
  bool cpu_has = false;
  const char* name = restricted_isa_name(isa, cpu_has);
  if (!name)
    throw ParamError("--embree-isa '" + isa + "' is not an ISA Embree can be restricted to: use " +
                     embree_isa_names() + " or native");
  if (!cpu_has)
    throw ParamError("--embree-isa " + isa + ": this CPU does not run " + name +
                     " instructions; use an older ISA or native");
}

const EmbreeIsa& embree_isa(const std::string& isa) {
  check_embree_isa(isa);
  static std::mutex mutex;
  static std::map<std::string, EmbreeIsa> cache;
  const std::lock_guard<std::mutex> lock(mutex);
  const auto found = cache.find(isa);
  if (found != cache.end()) return found->second;
  const std::string config = device_config(0, isa);
  RTCDevice d = rtcNewDevice(config.empty() ? nullptr : config.c_str());
  EmbreeIsa& out = cache[isa] = device_isa(d, isa);
  if (d) rtcReleaseDevice(d);
  return out;
}

EmbreeAccel::EmbreeAccel(EmbreeConfig config)
    : config_(std::move(config)), isa_(embree_isa()), state_(std::make_unique<State>()) {}
EmbreeAccel::~EmbreeAccel() {
  release();
}

void EmbreeAccel::release() {
  if (state_->scene) rtcReleaseScene(state_->scene);
  if (state_->device) rtcReleaseDevice(state_->device);
  state_->scene = nullptr;
  state_->device = nullptr;
  state_->memory.bytes = 0;
  state_->memory.peak = 0;
  state_->memory.over_limit = false;
}

BuildStats EmbreeAccel::build(const Mesh& mesh, const BuildParams& params) {
  if (params.triangle_test == TriangleTestKind::None)
    throw ParamError(
        "embree: its traversal cannot run without its own triangle tests, so it has "
        "no traversal-only timing; drop --traversal-only or choose another --accel");
  const std::string quality_name =
      config_.quality.empty() ? params.embree_quality : config_.quality;
  const RTCBuildQuality quality = parse_quality(quality_name);
  const auto t_start = std::chrono::steady_clock::now();
  // Memory guard before anything is allocated: the padded vertex copy plus what Embree's
  // own allocations reach at their peak, with a margin (docs/LIMITS.md, "The guards'
  // constants").
  // The memory monitor enforces the budget during the build as well.
  const double copy_estimate = (3.0 * double(mesh.num_vertices()) + 1.0) * sizeof(float);
  const uint64_t estimate =
      check_memory_budget("embree", mesh.num_triangles(),
                          {{"vertex copy", copy_estimate},
                           {"Embree BVH and build temporaries (~110 bytes per triangle, measured)",
                            110.0 * double(mesh.num_triangles())}},
                          params, "Embree's memory grows with the triangle count: split the scene");
  release();
  stats_ = {};
  quality_.clear();
  check_embree_isa(params.embree_isa);
  mesh_ = &mesh;

  const std::string config = device_config(params.threads, params.embree_isa);
  State& st = *state_;
  st.error.clear();
  st.device = rtcNewDevice(config.empty() ? nullptr : config.c_str());
  if (!st.device)
    throw Error("embree: cannot create a device (" +
                std::to_string(int(rtcGetDeviceError(nullptr))) +
                "); is libembree3 installed for this CPU?");
  // The ISA is this device's: a restriction Embree did not apply would show here.
  isa_ = device_isa(st.device, params.embree_isa);
  rtcSetDeviceErrorFunction(st.device, error_callback, &st.error);
  const uint64_t budget = effective_memory_budget(params);
  st.memory.limit = int64_t(std::max(1.0, double(budget) - copy_estimate));
  rtcSetDeviceMemoryMonitorFunction(st.device, memory_monitor, &st.memory);

  st.scene = rtcNewScene(st.device);
  // Robust mode avoids Embree's fast-path shortcuts that can miss hits on edges (at some
  // speed); the default flags are what a user of Embree gets (see embree.h).
  rtcSetSceneFlags(st.scene, config_.robust ? RTC_SCENE_FLAG_ROBUST : RTC_SCENE_FLAG_NONE);
  rtcSetSceneBuildQuality(st.scene, quality);
  if (params.cancel)
    rtcSetSceneProgressMonitorFunction(st.scene, keep_building,
                                       const_cast<CancelToken*>(params.cancel));

  const size_t nv = mesh.num_vertices(), nt = mesh.num_triangles();
  if (nt > 0) {
    vertices_.assign(nv * 3 + 1, 0.0f);
    for (size_t i = 0; i < nv; ++i) {
      vertices_[3 * i + 0] = mesh.positions[i].x;
      vertices_[3 * i + 1] = mesh.positions[i].y;
      vertices_[3 * i + 2] = mesh.positions[i].z;
    }
    RTCGeometry geom = rtcNewGeometry(st.device, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(geom, quality);
    rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, vertices_.data(),
                               0, 3 * sizeof(float), nv);
    rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                               mesh.triangles.data(), 0, 3 * sizeof(uint32_t), nt);
    rtcCommitGeometry(geom);
    rtcAttachGeometry(st.scene, geom);
    rtcReleaseGeometry(geom);
  }
  rtcCommitScene(st.scene);
  const RTCError err = rtcGetDeviceError(st.device);
  if (params.cancel && params.cancel->cancelled()) {
    release();
    vertices_ = {};
    throw BuildCancelled();
  }
  if (st.memory.over_limit.load()) {
    const double held = double(std::max<int64_t>(0, st.memory.peak.load()));
    release();
    vertices_ = {};
    throw ParamError("embree: the build asked for more than the memory budget of " +
                     format_bytes_iec(double(budget)) + " (Embree held " + format_bytes_iec(held) +
                     " plus the " + format_bytes_iec(copy_estimate) +
                     " vertex copy when it was stopped, building over " +
                     std::to_string(mesh.num_triangles()) +
                     " triangles); split the scene, or raise --memory-budget-mb (0 = half of "
                     "physical memory) if the machine has the memory");
  }
  if (err != RTC_ERROR_NONE || !st.error.empty())
    throw Error("embree: building the scene failed: " +
                (st.error.empty() ? std::string("unknown error") : st.error));

  quality_ = quality_name;
  stats_.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  const uint64_t embree_bytes = uint64_t(std::max<int64_t>(0, st.memory.bytes.load()));
  const uint64_t copy_bytes = vertices_.size() * sizeof(float);
  stats_.bytes = embree_bytes + copy_bytes;
  stats_.bytes_by_part = {{"embree", embree_bytes}, {"vertex_copy", copy_bytes}};
  stats_.references = nt;
  stats_.extra = {
      {"quality", quality_name},
      {"flags", robust() ? "robust" : "default"},
      {"isa", isa_.isa},
      {"embree build peak", format_bytes_iec(double(std::max<int64_t>(0, st.memory.peak.load())))}};
  // Embree's allocations are its own: no bound below the budget is known before building, and
  // the memory monitor stops the build at the budget.
  stats_.peak_estimate = build_peak_bound(kInf, estimate, params);
  stats_.peak_expected = estimate;
  stats_.peak_accounted = uint64_t(std::max<int64_t>(0, st.memory.peak.load())) + copy_bytes;
  return stats_;
}

bool EmbreeAccel::robust() const {
  if (!state_->scene) return config_.robust;
  return (rtcGetSceneFlags(state_->scene) & RTC_SCENE_FLAG_ROBUST) != 0;
}

namespace {

/// Embree's hit (tfar, primID, u, v, in the ray as to_rtc shifted it) as kdgrid's; false when
/// the double-precision fallback puts it outside [tmin, tmax).
bool to_hit(const Mesh& mesh, const Ray& ray, float tfar, float shift, uint32_t prim, float u,
            float v, Hit& hit) {
  Hit h{tfar + shift, prim, u, v};
  if (!std::isfinite(h.t) || !std::isfinite(h.u) || !std::isfinite(h.v)) {
    // Embree's float test overflows from coordinates of about 1e13 on and reports the hit at
    // infinity: t and the barycentrics come from the hit triangle in double instead.
    const auto c = mesh.corners(prim);
    double t = 0, du = 0, dv = 0;
    if (!intersect_triangle_double(ray, c[0], c[1], c[2], ray.tmin, ray.tmax, t, du, dv)) {
      // Embree saw the hit on an edge the double test puts outside: the plane's distance.
      const Vec3d o(ray.org), d(ray.dir), v0(c[0]);
      const Vec3d n = cross(Vec3d(c[1]) - v0, Vec3d(c[2]) - v0);
      t = dot(n, v0 - o) / dot(n, d);
    }
    h = {float(t), prim, float(du), float(dv)};
    if (!(h.t >= ray.tmin && h.t < ray.tmax)) return false;
  }
  hit = h;
  return true;
}

/// Embree's packet types and calls by width K (rtcIntersect4/8/16, rtcOccluded4/8/16).
template <class RayHitK, class RaysK, auto kIntersect, auto kOccluded>
struct EmbreePacketOf {
  using RayHit = RayHitK;
  using Rays = RaysK;
  static void intersect(const int* valid, RTCScene s, RTCIntersectContext* c, RayHit* r) {
    kIntersect(valid, s, c, r);
  }
  static void occluded(const int* valid, RTCScene s, RTCIntersectContext* c, Rays* r) {
    kOccluded(valid, s, c, r);
  }
};
template <int K>
struct EmbreePacket;
template <>
struct EmbreePacket<4> : EmbreePacketOf<RTCRayHit4, RTCRay4, rtcIntersect4, rtcOccluded4> {};
template <>
struct EmbreePacket<8> : EmbreePacketOf<RTCRayHit8, RTCRay8, rtcIntersect8, rtcOccluded8> {};
template <>
struct EmbreePacket<16> : EmbreePacketOf<RTCRayHit16, RTCRay16, rtcIntersect16, rtcOccluded16> {};

/// Lane i of a packet's rays (RTCRay4/8/16, structures of arrays) set from one ray.
template <class RaysK>
void set_lane(RaysK& k, int i, const RTCRay& r) {
  k.org_x[i] = r.org_x;
  k.org_y[i] = r.org_y;
  k.org_z[i] = r.org_z;
  k.dir_x[i] = r.dir_x;
  k.dir_y[i] = r.dir_y;
  k.dir_z[i] = r.dir_z;
  k.tnear[i] = r.tnear;
  k.tfar[i] = r.tfar;
  k.time[i] = r.time;
  k.mask[i] = r.mask;
  k.id[i] = r.id;
  k.flags[i] = r.flags;
}

/// The K lanes of a packet's rays set from rays[0, m), 0 < m <= K: lanes past m repeat the last
/// ray. valid[i] turns off those lanes and rays Embree must not see (ray_is_valid); shift[i]
/// is what to_rtc moved lane i's ray by.
template <int K, class RaysK>
void set_lanes(RaysK& k, const Ray* rays, int m, int (&valid)[K], float (&shift)[K]) {
  for (int i = 0; i < K; ++i) {
    RTCRay one;
    const Ray& r = rays[std::min(i, m - 1)];
    shift[i] = to_rtc(r, one);
    valid[i] = i < m && ray_is_valid(r) ? -1 : 0;
    set_lane(k, i, one);
  }
}

/// The coherent context: Embree's packet kernels may then trace the lanes together.
RTCIntersectContext coherent_context() {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  return ctx;
}

}  // namespace

bool EmbreeAccel::intersect(const Ray& ray, Hit& hit) const {
  if (!state_->scene || !ray_is_valid(ray)) return false;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh;
  const float shift = to_rtc(ray, rh.ray);
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(state_->scene, &ctx, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  return to_hit(*mesh_, ray, rh.ray.tfar, shift, rh.hit.primID, rh.hit.u, rh.hit.v, hit);
}

int EmbreeAccel::packet_width() const {
  const int k = isa_.native_packet;
  return k == 16 || k == 8 || k == 4 ? k : 1;
}

template <int K>
void EmbreeAccel::intersect_k(const Ray* rays, int n, Hit* hits, bool* found) const {
  using P = EmbreePacket<K>;
  RTCIntersectContext ctx = coherent_context();
  for (int base = 0; base < n; base += K) {
    const int m = std::min(K, n - base);
    alignas(64) int valid[K];
    alignas(64) typename P::RayHit rh;
    float shift[K];
    set_lanes(rh.ray, rays + base, m, valid, shift);
    for (int i = 0; i < K; ++i) {
      rh.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
      rh.hit.primID[i] = RTC_INVALID_GEOMETRY_ID;
      rh.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
    }
    P::intersect(valid, state_->scene, &ctx, &rh);
    for (int i = 0; i < m; ++i) {
      bool f = valid[i] && rh.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID;
      if (f)
        f = to_hit(*mesh_, rays[base + i], rh.ray.tfar[i], shift[i], rh.hit.primID[i], rh.hit.u[i],
                   rh.hit.v[i], hits[base + i]);
      found[base + i] = f;
    }
  }
}

template <int K>
void EmbreeAccel::occluded_k(const Ray* rays, int n, bool* occluded_out) const {
  using P = EmbreePacket<K>;
  RTCIntersectContext ctx = coherent_context();
  for (int base = 0; base < n; base += K) {
    const int m = std::min(K, n - base);
    alignas(64) int valid[K];
    alignas(64) typename P::Rays rk;
    float shift[K];  // unused: an occlusion answer has no t to shift back
    set_lanes(rk, rays + base, m, valid, shift);
    P::occluded(valid, state_->scene, &ctx, &rk);
    for (int i = 0; i < m; ++i) occluded_out[base + i] = valid[i] && rk.tfar[i] == -kInf;
  }
}

void EmbreeAccel::intersect_packet(const Ray* rays, int n, Hit* hits, bool* found) const {
  if (!state_->scene) {
    for (int i = 0; i < n; ++i) found[i] = false;
    return;
  }
  switch (packet_width()) {
    case 16:
      return intersect_k<16>(rays, n, hits, found);
    case 8:
      return intersect_k<8>(rays, n, hits, found);
    case 4:
      return intersect_k<4>(rays, n, hits, found);
    default:
      return Accelerator::intersect_packet(rays, n, hits, found);
  }
}

void EmbreeAccel::occluded_packet(const Ray* rays, int n, bool* occluded_out) const {
  if (!state_->scene) {
    for (int i = 0; i < n; ++i) occluded_out[i] = false;
    return;
  }
  switch (packet_width()) {
    case 16:
      return occluded_k<16>(rays, n, occluded_out);
    case 8:
      return occluded_k<8>(rays, n, occluded_out);
    case 4:
      return occluded_k<4>(rays, n, occluded_out);
    default:
      return Accelerator::occluded_packet(rays, n, occluded_out);
  }
}

bool EmbreeAccel::occluded(const Ray& ray) const {
  if (!state_->scene || !ray_is_valid(ray)) return false;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRay r;
  to_rtc(ray, r);
  rtcOccluded1(state_->scene, &ctx, &r);
  return r.tfar == -kInf;
}

Trace EmbreeAccel::trace(const Ray& ray) const {
  Trace t;
  Hit h;
  if (intersect(ray, h)) t.hit = h;
  return t;
}

}  // namespace kdgrid
