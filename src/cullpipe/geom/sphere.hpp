#pragma once
#include <glm/vec3.hpp>

namespace cullpipe {

/// Sphere: all points within `radius` of `center`. radius >= 0.
struct Sphere {
  glm::vec3 center{0.0f};
  float radius = 0.0f;
  bool operator==(const Sphere&) const = default;
};

}  // namespace cullpipe
