#include "viewer/camera_control.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "render/camera.h"

namespace kdgrid::viewer {

namespace {

/// Rotates v about the unit axis k by angle a (Rodrigues).
Vec3 rotate(const Vec3& v, const Vec3& k, float a) {
  const float c = std::cos(a), s = std::sin(a);
  return v * c + cross(k, v) * s + k * (dot(k, v) * (1 - c));
}

/// Keeps a direction away from the world up pole so the basis cross(fwd, up) never
/// degenerates: pitch is clamped to +-89 degrees.
Vec3 rotate_pitch_clamped(const Vec3& dir, const Vec3& up, float pitch) {
  const Vec3 d = normalize(dir);
  const Vec3 right = camera_right(d, up);
  const float cur = std::asin(std::clamp(dot(d, up), -1.0f, 1.0f));
  const float lim = 89.0f * 3.14159265f / 180.0f;
  const float next = std::clamp(cur + pitch, -lim, lim);
  return rotate(d, right, next - cur);
}

}  // namespace

void CameraControl::reset(const Camera& cam, const Box3& scene_bounds) {
  cam_ = cam;
  if (length(cam_.up) == 0.0f) cam_.up = {0, 1, 0};
  cam_.up = normalize(cam_.up);
  bounds_ = scene_bounds;
  radius_ = scene_bounds.empty() ? 1.0f : std::max(length(scene_bounds.extent()) * 0.5f, 1e-6f);
}

void CameraControl::frame_scene() {
  if (bounds_.empty()) return;
  const Camera c = canonical_camera(bounds_, cam_.fov_deg);
  cam_.eye = c.eye;
  cam_.target = c.target;
  cam_.up = c.up;
}

void CameraControl::scale_speed(float factor) {
  speed_scale_ = std::clamp(speed_scale_ * factor, 1e-3f, 1e3f);
}

void CameraControl::move(float right, float up, float forward, float seconds) {
  const float dist = speed() * seconds;
  const Vec3 fwd = normalize(cam_.target - cam_.eye);
  const Vec3 r = camera_right(fwd, cam_.up);
  if (mode_ == CameraMode::Fly) {
    const Vec3 delta = (r * right + cam_.up * up + fwd * forward) * dist;
    cam_.eye += delta;
    cam_.target += delta;
    return;
  }
  // Orbit: A/D and Q/E go round the target at one radian per second at speed scale 1.
  const float ang = seconds * speed_scale_;
  if (right != 0.0f || up != 0.0f) orbit(-right * ang, up * ang);
  if (forward != 0.0f) dolly(forward * seconds * 10.0f * speed_scale_);
}

void CameraControl::look(float yaw, float pitch) {
  const float dist = length(cam_.target - cam_.eye);
  Vec3 d = rotate(normalize(cam_.target - cam_.eye), cam_.up, yaw);
  d = rotate_pitch_clamped(d, cam_.up, pitch);
  cam_.target = cam_.eye + d * dist;
}

void CameraControl::orbit(float yaw, float pitch) {
  const Vec3 off = cam_.eye - cam_.target;
  const float dist = length(off);
  if (dist == 0.0f) return;
  Vec3 d = rotate(off / dist, cam_.up, yaw);
  // Pitching the eye up means the view direction (-d) pitches down.
  d = -rotate_pitch_clamped(-d, cam_.up, -pitch);
  cam_.eye = cam_.target + d * dist;
}

void CameraControl::dolly(float steps) {
  const Vec3 off = cam_.eye - cam_.target;
  const float dist = length(off);
  // Never reach the target (eye == target has no view direction); keep a floor relative to
  // the scene size.
  const float next = std::max(dist * std::pow(0.9f, steps), radius_ * 1e-4f);
  cam_.eye = cam_.target + off * (next / std::max(dist, 1e-30f));
}

std::string CameraControl::cli_flags() const {
  char buf[320];
  std::snprintf(buf, sizeof buf, "--eye %.9g,%.9g,%.9g --target %.9g,%.9g,%.9g --fov %.9g",
                cam_.eye.x, cam_.eye.y, cam_.eye.z, cam_.target.x, cam_.target.y, cam_.target.z,
                cam_.fov_deg);
  return buf;
}

}  // namespace kdgrid::viewer
