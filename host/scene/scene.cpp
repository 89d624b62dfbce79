#include "scene/scene.hpp"

#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>

#include "geom/validate.hpp"

namespace cullpipe {

Aabb Scene::bounds() const {
  if (objects.empty()) return {};
  Aabb b = objects.front().local_bounds.transformed(objects.front().world);
  for (const SceneObject& o : objects) {
    const Aabb w = o.local_bounds.transformed(o.world);
    b.min = glm::min(b.min, w.min);
    b.max = glm::max(b.max, w.max);
  }
  return b;
}

std::vector<Aabb> world_aabbs(const Scene& scene) {
  std::vector<Aabb> out;
  out.reserve(scene.objects.size());
  for (const SceneObject& o : scene.objects) out.push_back(o.local_bounds.transformed(o.world));
  return out;
}

std::vector<Obb> world_obbs(const Scene& scene) {
  std::vector<Obb> out;
  out.reserve(scene.objects.size());
  for (const SceneObject& o : scene.objects) out.push_back(Obb::from_transformed_aabb(o.local_bounds, o.world));
  return out;
}

std::vector<Sphere> world_spheres(const Scene& scene) {
  std::vector<Sphere> out;
  out.reserve(scene.objects.size());
  for (const SceneObject& o : scene.objects) {
    Sphere s;
    s.center = glm::vec3(o.world * glm::vec4(o.local_bounds.center(), 1.0f));
    for (const glm::vec3& corner : o.local_bounds.corners())
      s.radius = std::max(s.radius, glm::length(glm::vec3(o.world * glm::vec4(corner, 1.0f)) - s.center));
    out.push_back(s);
  }
  return out;
}

void validate(const Scene& scene, const std::string& source) {
  for (std::size_t i = 0; i < scene.objects.size(); ++i) {
    const SceneObject& o = scene.objects[i];
    const std::string where = source + ": objects[" + std::to_string(i) + "]: ";
    if (const std::string why = invalid_reason(o.local_bounds); !why.empty()) throw InputError(where + why);
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r)
        if (!std::isfinite(o.world[c][r])) throw InputError(where + "world transform has a NaN or infinite entry");
    if (o.world[0][3] != 0.0f || o.world[1][3] != 0.0f || o.world[2][3] != 0.0f || o.world[3][3] != 1.0f)
      throw InputError(where + "world transform is not affine (last row must be 0 0 0 1)");
    const double det = glm::determinant(glm::dmat3(glm::mat3(o.world)));
    if (!(std::abs(det) > 0.0f) || !std::isfinite(det)) throw InputError(where + "world transform is singular");
    // World-space volumes must be finite too (a huge scale can overflow float).
    const Aabb w = o.local_bounds.transformed(o.world);
    if (const std::string why = invalid_reason(w); !why.empty()) throw InputError(where + "world-space bounds: " + why);
  }
}

}  // namespace cullpipe
