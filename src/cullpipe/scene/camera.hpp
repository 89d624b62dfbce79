#pragma once
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>
#include <vector>

#include "cullpipe/geom/aabb.hpp"

namespace cullpipe {

struct Scene;

/// A perspective (or orthographic) camera producing Vulkan clip space (y down, depth 0..1).
struct Camera {
  glm::vec3 eye{0.0f, 10.0f, 30.0f};
  glm::vec3 target{0.0f};
  glm::vec3 up{0.0f, 1.0f, 0.0f};
  float fov_y_degrees = 60.0f;
  float aspect = 16.0f / 9.0f;
  float near_plane = 0.1f;
  float far_plane = 1000.0f;  ///< ignored when infinite_far
  bool reversed_z = false;    ///< depth 1 at the near plane, 0 at the far plane
  bool infinite_far = false;  ///< far plane at infinity
  /// Orthographic projection: the view is 2 * ortho_half_height high and aspect times as
  /// wide; fov_y_degrees is ignored and infinite_far is not allowed.
  bool orthographic = false;
  float ortho_half_height = 1.0f;

  glm::mat4 view() const;
  glm::mat4 projection() const;
  glm::mat4 view_proj() const;  ///< projection() * view(), computed inside the library

  bool operator==(const Camera&) const = default;
};

/// A 60-degree camera looking at the centre of `bounds` from above and to the side, far
/// enough that the bounding sphere of `bounds` fits the view, near and far planes around it.
Camera framing_camera(const Aabb& bounds);

/// `count` cameras on a circle around `bounds`, looking at its centre from above at
/// `base`'s height angle, evenly spaced in angle; each keeps `base`'s lens settings.
/// For count == 1 the result is `base` itself.
std::vector<Camera> camera_path(const Camera& base, const Aabb& bounds, std::size_t count);

/// `count` cameras for `scene`. With a `scene.path`: evenly spaced by arc length along the
/// polyline of the keyframe eyes, starting at the first keyframe, eye and target interpolated
/// linearly between the two keyframes around each point, the other lens settings from the
/// earlier one. An open path ends at the last keyframe; a closed one (last keyframe's eye and
/// target equal to the first's) is sampled as a loop, spacing length / count, so the cameras
/// repeat seamlessly. Keyframes all at one eye are spaced by index instead. count == 1 gives
/// `scene.camera`. Without a path: the orbit `camera_path(scene.camera, scene.bounds(), count)`.
std::vector<Camera> scene_camera_path(const Scene& scene, std::size_t count);

}  // namespace cullpipe
