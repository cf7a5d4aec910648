#include "render/camera.h"

#include <cmath>

namespace kdgrid {

CameraFrame CameraFrame::make(const Camera& cam, int width, int height) {
  CameraFrame f;
  f.eye = cam.eye;
  f.fwd = normalize(cam.target - cam.eye);
  f.right = normalize(cross(f.fwd, cam.up));
  f.up = cross(f.right, f.fwd);
  f.tan_half_fov = std::tan(cam.fov_deg * 0.5f * 3.14159265358979f / 180.0f);
  f.width = width;
  f.height = height;
  return f;
}

Ray CameraFrame::ray(float x, float y) const {
  const float aspect = float(width) / float(height);
  const float u = (x / width * 2.0f - 1.0f) * tan_half_fov * aspect;
  const float v = (1.0f - y / height * 2.0f) * tan_half_fov;
  return {eye, 0.0f, normalize(fwd + right * u + up * v), kInf};
}

}  // namespace kdgrid
