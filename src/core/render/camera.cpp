#include "render/camera.h"

#include <cmath>
#include <cstdio>

#include "util/error.h"

namespace kdgrid {

CameraFrame CameraFrame::make(const Camera& cam, int width, int height) {
  CameraFrame f;
  f.eye = cam.eye;
  f.fwd = normalize(cam.target - cam.eye);
  f.right = camera_right(f.fwd, cam.up);
  f.up = cross(f.right, f.fwd);
  f.tan_half_fov = std::tan(cam.fov_deg * 0.5f * 3.14159265358979f / 180.0f);
  f.width = width;
  f.height = height;
  return f;
}

Vec3 camera_right(const Vec3& fwd, const Vec3& up) {
  const Vec3 c = cross(fwd, up);
  // Relative to |up|: below 1e-6 radians from parallel the cross product is mostly rounding.
  if (dot(c, c) > 1e-12f * dot(up, up)) return normalize(c);
  const Vec3 a = abs(fwd);
  Vec3 axis(0.0f);
  if (a.z <= a.x && a.z <= a.y)
    axis.z = 1.0f;
  else if (a.x <= a.y)
    axis.x = 1.0f;
  else
    axis.y = 1.0f;
  if (dot(fwd, up) < 0.0f) axis = -axis;
  return normalize(cross(fwd, axis));
}

void check_camera(const Camera& cam, const std::string& what) {
  auto point = [](const Vec3& v) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "%g,%g,%g", double(v.x), double(v.y), double(v.z));
    return std::string(buf);
  };
  char limit[32];
  std::snprintf(limit, sizeof limit, "%g", double(kMaxRayCoordinate));
  for (const auto& [name, v] : {std::pair{"eye", cam.eye}, std::pair{"target", cam.target}})
    if (!within(v, kMaxRayCoordinate))
      throw ParamError(what + ": camera " + name + " " + point(v) +
                       " is outside the supported coordinate range +-" + limit +
                       " (docs/LIMITS.md); move it closer to the scene");
  if (!(length(cam.target - cam.eye) > 0.0f))
    throw ParamError(what + ": camera eye and target are the same point (" + point(cam.eye) +
                     "): the camera has no view direction; give a target apart from the eye");
  if (!(cam.fov_deg > 0.0f && cam.fov_deg < 180.0f)) {
    char fov[32];
    std::snprintf(fov, sizeof fov, "%g", double(cam.fov_deg));
    throw ParamError(what + ": camera field of view " + fov +
                     " degrees is outside (0, 180): give e.g. --fov 45");
  }
}

Ray CameraFrame::ray(float x, float y) const {
  const float aspect = float(width) / float(height);
  const float u = (x / width * 2.0f - 1.0f) * tan_half_fov * aspect;
  const float v = (1.0f - y / height * 2.0f) * tan_half_fov;
  return {eye, 0.0f, normalize(fwd + right * u + up * v), kInf};
}

}  // namespace kdgrid
