#include "cullpipe/scene/camera.hpp"

#include <algorithm>
#include <cmath>
#include <glm/common.hpp>
#include <glm/ext/matrix_clip_space.hpp>
#include <glm/ext/matrix_transform.hpp>
#include <glm/geometric.hpp>
#include <glm/trigonometric.hpp>

#include "cullpipe/scene/scene.hpp"

namespace cullpipe {

glm::mat4 Camera::view() const { return glm::lookAtRH(eye, target, up); }
glm::mat4 Camera::view_proj() const { return projection() * view(); }

glm::mat4 Camera::projection() const {
  if (orthographic) {
    // x' = x / (aspect h), y' = -y / h, w' = 1; depth linear in -z from near to far.
    glm::mat4 p(0.0f);
    p[0][0] = 1.0f / (aspect * ortho_half_height);
    p[1][1] = -1.0f / ortho_half_height;
    p[3][3] = 1.0f;
    const float n = near_plane, fa = far_plane;
    if (!reversed_z) {  // z' = 0 at -z = n, 1 at -z = far
      p[2][2] = 1.0f / (n - fa);
      p[3][2] = n / (n - fa);
    } else {
      p[2][2] = 1.0f / (fa - n);
      p[3][2] = fa / (fa - n);
    }
    return p;
  }
  const float f = 1.0f / std::tan(glm::radians(fov_y_degrees) * 0.5f);
  // Right-handed view space (looking down -z) to Vulkan clip space, written out so every
  // variant is explicit: x' = f/aspect x, y' = -f y (Vulkan's y points down), w' = -z.
  glm::mat4 p(0.0f);
  p[0][0] = f / aspect;
  p[1][1] = -f;
  p[2][3] = -1.0f;
  const float n = near_plane, fa = far_plane;
  if (!reversed_z && !infinite_far) {  // z' = 0 at near, w' at far
    p[2][2] = fa / (n - fa);
    p[3][2] = fa * n / (n - fa);
  } else if (!reversed_z) {  // far -> infinity
    p[2][2] = -1.0f;
    p[3][2] = -n;
  } else if (!infinite_far) {  // reversed: z' = w' at near, 0 at far
    p[2][2] = n / (fa - n);
    p[3][2] = fa * n / (fa - n);
  } else {  // reversed and infinite: depth = n / -z
    p[2][2] = 0.0f;
    p[3][2] = n;
  }
  return p;
}

Camera framing_camera(const Aabb& bounds) {
  Camera cam;
  const glm::vec3 c = bounds.center();
  const float r = std::max(0.5f * glm::length(bounds.max - bounds.min), 1e-3f * std::max(glm::length(c), 1.0f));
  const float dist = r / std::sin(glm::radians(cam.fov_y_degrees) * 0.5f) * 1.05f;
  cam.target = c;
  cam.eye = c + glm::normalize(glm::vec3(0.6f, 0.45f, 1.0f)) * dist;
  cam.near_plane = std::max((dist - r) * 0.5f, dist * 1e-4f);
  cam.far_plane = (dist + r) * 1.5f;
  return cam;
}

std::vector<Camera> camera_path(const Camera& base, const Aabb& bounds, std::size_t count) {
  if (count <= 1) return std::vector<Camera>(count, base);
  const glm::vec3 center = bounds.center();
  const glm::vec3 offset = base.eye - base.target;
  const float height = offset.y;
  const float radius = std::max(std::sqrt(offset.x * offset.x + offset.z * offset.z), 1e-3f);
  const float start = std::atan2(offset.z, offset.x);
  std::vector<Camera> path(count, base);
  for (std::size_t i = 0; i < count; ++i) {
    const float angle = start + 2.0f * 3.14159265358979f * float(i) / float(count);
    path[i].target = center;
    path[i].eye = center + glm::vec3(radius * std::cos(angle), height, radius * std::sin(angle));
  }
  return path;
}

std::vector<Camera> scene_camera_path(const Scene& scene, std::size_t count) {
  const std::vector<Camera>& keys = scene.path;
  if (keys.empty()) return camera_path(scene.camera, scene.bounds(), count);
  if (count <= 1) return std::vector<Camera>(count, scene.camera);
  if (keys.size() == 1) return std::vector<Camera>(count, keys.front());
  // Cumulative arc length of the eye polyline, in double so long paths keep their spacing.
  // When every eye is the same, each keyframe step counts as one unit instead.
  std::vector<double> at(keys.size(), 0.0);
  for (std::size_t k = 1; k < keys.size(); ++k)
    at[k] = at[k - 1] + glm::length(glm::dvec3(keys[k].eye) - glm::dvec3(keys[k - 1].eye));
  if (!(at.back() > 0.0))
    for (std::size_t k = 1; k < keys.size(); ++k) at[k] = double(k);
  const double total = at.back();
  // A closed path (ending where it starts) is a loop: spacing total / count, so cycling
  // through the frames never shows the start twice.
  const bool closed = keys.back().eye == keys.front().eye && keys.back().target == keys.front().target;
  const double step = total / double(closed ? count : count - 1);
  std::vector<Camera> out;
  out.reserve(count);
  std::size_t k = 0;  // segment keys[k] -> keys[k + 1]
  for (std::size_t i = 0; i < count; ++i) {
    const double s = std::min(step * double(i), total);
    while (k + 2 < keys.size() && at[k + 1] <= s) ++k;
    const double length = at[k + 1] - at[k];
    const float t = length > 0.0 ? float(std::clamp((s - at[k]) / length, 0.0, 1.0)) : 1.0f;
    Camera c = t < 1.0f ? keys[k] : keys[k + 1];
    c.eye = glm::mix(keys[k].eye, keys[k + 1].eye, t);
    c.target = glm::mix(keys[k].target, keys[k + 1].target, t);
    out.push_back(c);
  }
  return out;
}

}  // namespace cullpipe
