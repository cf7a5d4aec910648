// Small fixed-size vector and box types used everywhere in kdgrid.
// Kept deliberately simple (no expression templates) so that hot loops compile to
// plain scalar/SSE code and so that the core library has no dependency on GLM.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>

namespace kdgrid {

struct Vec3 {
  float x = 0, y = 0, z = 0;

  constexpr Vec3() = default;
  constexpr Vec3(float x_, float y_, float z_) : x(x_), y(y_), z(z_) {}
  constexpr explicit Vec3(float s) : x(s), y(s), z(s) {}

  constexpr float operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  constexpr float& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }

  constexpr Vec3 operator+(const Vec3& o) const { return {x + o.x, y + o.y, z + o.z}; }
  constexpr Vec3 operator-(const Vec3& o) const { return {x - o.x, y - o.y, z - o.z}; }
  constexpr Vec3 operator*(const Vec3& o) const { return {x * o.x, y * o.y, z * o.z}; }
  constexpr Vec3 operator/(const Vec3& o) const { return {x / o.x, y / o.y, z / o.z}; }
  constexpr Vec3 operator*(float s) const { return {x * s, y * s, z * s}; }
  constexpr Vec3 operator/(float s) const { return {x / s, y / s, z / s}; }
  constexpr Vec3 operator-() const { return {-x, -y, -z}; }
  constexpr Vec3& operator+=(const Vec3& o) {
    x += o.x;
    y += o.y;
    z += o.z;
    return *this;
  }
  constexpr Vec3& operator-=(const Vec3& o) {
    x -= o.x;
    y -= o.y;
    z -= o.z;
    return *this;
  }
  constexpr Vec3& operator*=(float s) {
    x *= s;
    y *= s;
    z *= s;
    return *this;
  }
  constexpr Vec3& operator*=(const Vec3& o) {
    x *= o.x;
    y *= o.y;
    z *= o.z;
    return *this;
  }
  constexpr bool operator==(const Vec3& o) const { return x == o.x && y == o.y && z == o.z; }
  constexpr bool operator!=(const Vec3& o) const { return !(*this == o); }
};

constexpr Vec3 operator*(float s, const Vec3& v) {
  return v * s;
}
constexpr float dot(const Vec3& a, const Vec3& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
constexpr Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline float max_abs_component(const Vec3& v) {
  return std::max(std::fabs(v.x), std::max(std::fabs(v.y), std::fabs(v.z)));
}
/// |v| for any finite v: where the squared length would leave float's normal range (vectors
/// shorter than about 1e-18 or longer than 1e18) v is first divided by its largest
/// component, so the length does not underflow to 0 (or lose its bits in denormals) or
/// overflow; in range it is sqrt(dot(v, v)) bit for bit.
inline float length(const Vec3& v) {
  const float l2 = dot(v, v);
  if (l2 >= 1e-36f && l2 <= 1e36f) return std::sqrt(l2);
  const float m = max_abs_component(v);
  if (!(m > 0.0f) || !std::isfinite(m)) return std::sqrt(l2);
  const Vec3 w(v.x / m, v.y / m, v.z / m);
  return m * std::sqrt(dot(w, w));
}
/// v / |v|, scale invariant as length() is; a zero vector is returned unchanged.
inline Vec3 normalize(const Vec3& v) {
  const float l2 = dot(v, v);
  if (l2 >= 1e-36f && l2 <= 1e36f) return v / std::sqrt(l2);
  const float m = max_abs_component(v);
  if (!(m > 0.0f) || !std::isfinite(m)) {
    const float l = std::sqrt(l2);
    return l > 0 ? v / l : v;
  }
  const Vec3 w(v.x / m, v.y / m, v.z / m);
  return w / std::sqrt(dot(w, w));
}
inline Vec3 min(const Vec3& a, const Vec3& b) {
  return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)};
}
inline Vec3 max(const Vec3& a, const Vec3& b) {
  return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)};
}
inline Vec3 abs(const Vec3& v) {
  return {std::fabs(v.x), std::fabs(v.y), std::fabs(v.z)};
}
inline float max_component(const Vec3& v) {
  return std::max(v.x, std::max(v.y, v.z));
}
inline float min_component(const Vec3& v) {
  return std::min(v.x, std::min(v.y, v.z));
}
/// v's coordinate on axis k (0..2) for a k known only at run time, as one indexed load from
/// memory: its bytes are copied (a defined read of the object's representation; Vec3 is three
/// packed floats). Vec3::operator[] compiles to a chain of selects instead, which in the
/// watertight test and the kd traversals cost more than the arithmetic around it.
[[gnu::always_inline]] inline float component(const Vec3& v, int k) {
  static_assert(std::is_standard_layout_v<Vec3> && sizeof(Vec3) == 3 * sizeof(float));
  float f;
  std::memcpy(&f, reinterpret_cast<const unsigned char*>(&v) + sizeof(float) * unsigned(k),
              sizeof f);
  return f;
}
inline int max_dimension(const Vec3& v) {
  return (v.x > v.y) ? (v.x > v.z ? 0 : 2) : (v.y > v.z ? 1 : 2);
}
inline bool is_finite(const Vec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}
inline Vec3 lerp(const Vec3& a, const Vec3& b, float t) {
  return a * (1 - t) + b * t;
}
inline Vec3 reflect(const Vec3& d, const Vec3& n) {
  return d - n * (2 * dot(d, n));
}

/// Double-precision vector, used by reference computations and camera set-up.
struct Vec3d {
  double x = 0, y = 0, z = 0;
  constexpr Vec3d() = default;
  constexpr Vec3d(double x_, double y_, double z_) : x(x_), y(y_), z(z_) {}
  constexpr explicit Vec3d(const Vec3& v) : x(v.x), y(v.y), z(v.z) {}
  constexpr double operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  constexpr Vec3d operator+(const Vec3d& o) const { return {x + o.x, y + o.y, z + o.z}; }
  constexpr Vec3d operator-(const Vec3d& o) const { return {x - o.x, y - o.y, z - o.z}; }
  constexpr Vec3d operator*(double s) const { return {x * s, y * s, z * s}; }
  constexpr Vec3 to_float() const { return {float(x), float(y), float(z)}; }
};
constexpr double dot(const Vec3d& a, const Vec3d& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
constexpr Vec3d cross(const Vec3d& a, const Vec3d& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}

/// Axis-aligned box. An empty box has lo = +inf, hi = -inf so that growing it works.
struct Box3 {
  Vec3 lo{std::numeric_limits<float>::infinity()};
  Vec3 hi{-std::numeric_limits<float>::infinity()};

  constexpr Box3() = default;
  constexpr Box3(const Vec3& lo_, const Vec3& hi_) : lo(lo_), hi(hi_) {}

  void grow(const Vec3& p) {
    lo = min(lo, p);
    hi = max(hi, p);
  }
  void grow(const Box3& b) {
    lo = min(lo, b.lo);
    hi = max(hi, b.hi);
  }
  bool empty() const { return lo.x > hi.x || lo.y > hi.y || lo.z > hi.z; }
  Vec3 extent() const { return hi - lo; }
  Vec3 center() const { return (lo + hi) * 0.5f; }
  /// Surface area; 0 for an empty box.
  float area() const {
    if (empty()) return 0.0f;
    const Vec3 e = extent();
    return 2.0f * (e.x * e.y + e.y * e.z + e.z * e.x);
  }
  bool contains(const Vec3& p) const {
    return p.x >= lo.x && p.x <= hi.x && p.y >= lo.y && p.y <= hi.y && p.z >= lo.z && p.z <= hi.z;
  }
  Box3 intersect(const Box3& b) const { return {max(lo, b.lo), min(hi, b.hi)}; }
  bool operator==(const Box3& b) const { return lo == b.lo && hi == b.hi; }
};

inline Box3 merge(Box3 a, const Box3& b) {
  a.grow(b);
  return a;
}

constexpr float kInf = std::numeric_limits<float>::infinity();

/// Next representable float towards +inf / -inf (used to widen intervals conservatively).
inline float next_float_up(float v) {
  return std::nextafter(v, kInf);
}
inline float next_float_down(float v) {
  return std::nextafter(v, -kInf);
}

}  // namespace kdgrid
