// Pinhole camera rays with exactly the pixel mapping of docs/RAYSETS.md, shared by the
// renderer, the primary ray set, the viewer's picking and `kdgrid trace`.
#pragma once

#include "math/ray.h"
#include "scene/scene.h"

namespace kdgrid {

struct CameraFrame {
  Vec3 eye, fwd, right, up;
  float tan_half_fov = 0.414f;  ///< tan(vertical fov / 2)
  int width = 1, height = 1;

  /// fwd = normalize(target - eye), right = normalize(cross(fwd, world_up)),
  /// up = cross(right, fwd) (docs/RAYSETS.md).
  static CameraFrame make(const Camera& cam, int width, int height);

  /// Ray through image position (x, y) in pixels, (0, 0) the top-left corner of the image:
  /// pixel (i, j)'s centre is (i + 0.5, j + 0.5). Direction normalized, tmin 0, tmax inf.
  Ray ray(float x, float y) const;
};

}  // namespace kdgrid
