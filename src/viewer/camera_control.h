// Interactive camera: fly (WASD/QE + right-mouse look) and orbit (left drag about a target).
// Works on kdgrid::Camera directly so that what the user sees is exactly what `kdgrid
// render --eye --target --fov` reproduces.
#pragma once

#include <string>

#include "scene/scene.h"

namespace kdgrid::viewer {

enum class CameraMode { Fly, Orbit };

class CameraControl {
 public:
  /// Sets the camera and the scene size that scales movement speeds.
  void reset(const Camera& cam, const Box3& scene_bounds);
  /// Frames the whole scene (the canonical camera of docs/RAYSETS.md) keeping the fov.
  void frame_scene();

  const Camera& camera() const { return cam_; }
  void set_camera(const Camera& cam) { cam_ = cam; }
  CameraMode mode() const { return mode_; }
  void toggle_mode() { mode_ = mode_ == CameraMode::Fly ? CameraMode::Orbit : CameraMode::Fly; }

  /// Units per second of fly motion: a fraction of the scene radius times speed_scale().
  float speed() const { return radius_ * 0.5f * speed_scale_; }
  float speed_scale() const { return speed_scale_; }
  void scale_speed(float factor);

  /// Moves along (right, up, forward) by the given amounts in seconds of travel. In orbit
  /// mode forward dollies towards the target and right/up orbit about it.
  void move(float right, float up, float forward, float seconds);
  /// Turns the view direction about the eye (fly look), in radians.
  void look(float yaw, float pitch);
  /// Rotates the eye about the target (orbit), in radians.
  void orbit(float yaw, float pitch);
  /// Moves towards the target by `steps` wheel notches (each 10% of the distance, never
  /// passing the target).
  void dolly(float steps);

  /// The camera as CLI flags: --eye x,y,z --target x,y,z --fov f, with enough digits that
  /// the floats read back bit for bit (so `kdgrid trace --pixel` traces the same ray).
  std::string cli_flags() const;

 private:
  Camera cam_;
  Box3 bounds_;
  float radius_ = 1.0f;
  float speed_scale_ = 1.0f;
  CameraMode mode_ = CameraMode::Orbit;
};

}  // namespace kdgrid::viewer
