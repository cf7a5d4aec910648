// Pinhole camera rays with exactly the pixel mapping of docs/RAYSETS.md, shared by the
// renderer, the primary ray set, the viewer's picking and `kdgrid trace`.
#pragma once

#include <string>

#include "math/ray.h"
#include "scene/scene.h"

namespace kdgrid {

struct CameraFrame {
  Vec3 eye, fwd, right, up;
  float tan_half_fov = 0.414f;  ///< tan(vertical fov / 2)
  int width = 1, height = 1;

  /// fwd = normalize(target - eye), right = camera_right(fwd, world_up) (docs/RAYSETS.md's
  /// normalize(cross(fwd, world_up)) unless the view is parallel to world_up),
  /// up = cross(right, fwd).
  static CameraFrame make(const Camera& cam, int width, int height);

  /// Ray through image position (x, y) in pixels, (0, 0) the top-left corner of the image:
  /// pixel (i, j)'s centre is (i + 0.5, j + 0.5). Direction normalized, tmin 0, tmax inf.
  Ray ray(float x, float y) const;
};

/// The unit vector to the right of the unit view direction fwd for the world up vector `up`:
/// normalize(cross(fwd, up)). When the view is parallel to up (a camera looking straight down
/// or up) or up is zero, that cross product vanishes; the world axis least aligned with fwd
/// (z first on ties), signed so that looking down along -up puts +x on the right for a y-up
/// world, stands in for up instead, so the frame stays orthonormal.
Vec3 camera_right(const Vec3& fwd, const Vec3& up);

/// Throws ParamError unless `cam` gives a usable frame: eye and target finite, apart, and
/// within kMaxRayCoordinate (rays from farther away are invalid for every structure), and
/// fov_deg in (0, 180). `what` names where the camera came from in the message.
void check_camera(const Camera& cam, const std::string& what);

}  // namespace kdgrid
