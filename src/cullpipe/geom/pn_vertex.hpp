#pragma once
#include <glm/vec3.hpp>

#include "cullpipe/geom/aabb.hpp"

namespace cullpipe {

/// The corners of `box` farthest along a plane normal (p-vertex) and against it (n-vertex),
/// chosen per axis by the normal's sign (a zero or -0 component counts as positive). The one
/// definition the scalar reference and the hierarchical cull share; the shader mirrors it.
struct PnVertices {
  glm::vec3 p;
  glm::vec3 n;
};

inline PnVertices pn_vertices(const glm::vec3& normal, const Aabb& box) {
  return {{normal.x >= 0.0f ? box.max.x : box.min.x, normal.y >= 0.0f ? box.max.y : box.min.y,
           normal.z >= 0.0f ? box.max.z : box.min.z},
          {normal.x >= 0.0f ? box.min.x : box.max.x, normal.y >= 0.0f ? box.min.y : box.max.y,
           normal.z >= 0.0f ? box.min.z : box.max.z}};
}

}  // namespace cullpipe
