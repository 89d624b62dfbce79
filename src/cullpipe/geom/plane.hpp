#pragma once
#include <glm/vec3.hpp>
#include <glm/vec4.hpp>

#include "cullpipe/geom/exact_fp.hpp"

CULLPIPE_EXACT_FP_BEGIN
namespace cullpipe {

/// A plane n.p + d = 0 with the normal pointing into the kept half space:
/// a point p is in front (inside) when n.p + d >= 0. Frustum planes are normalised (|n| = 1).
struct Plane {
  glm::vec3 normal{0.0f, 0.0f, 1.0f};
  float d = 0.0f;

  /// Signed distance (scaled by |n|), evaluated as ((n.x*p.x + n.y*p.y) + n.z*p.z) + d.
  /// This exact order is the one the shaders use; do not reorder.
  float distance(const glm::vec3& p) const { return normal.x * p.x + normal.y * p.y + normal.z * p.z + d; }

  glm::vec4 as_vec4() const { return {normal, d}; }
  static Plane from_vec4(const glm::vec4& v) { return {glm::vec3(v), v.w}; }

  bool operator==(const Plane&) const = default;
};

}  // namespace cullpipe
CULLPIPE_EXACT_FP_END
