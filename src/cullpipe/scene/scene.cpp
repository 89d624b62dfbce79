#include "cullpipe/scene/scene.hpp"

#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>

#include "cullpipe/geom/rounding.hpp"
#include "cullpipe/geom/validate.hpp"

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

std::vector<Aabb> world_aabbs(const Scene& scene, bounds::AabbUpdate method,
                              std::vector<bounds::AabbTracker::Extremes>* climb_state) {
  std::vector<Aabb> out;
  out.reserve(scene.objects.size());
  if (climb_state && climb_state->size() != scene.objects.size()) {
    climb_state->resize(scene.objects.size());
    for (std::size_t i = 0; i < scene.objects.size(); ++i)
      if (scene.objects[i].mesh) (*climb_state)[i] = scene.objects[i].mesh->tracker().initial_extremes();
  }
  for (std::size_t i = 0; i < scene.objects.size(); ++i) {
    const SceneObject& o = scene.objects[i];
    if (!o.mesh) {
      out.push_back(o.local_bounds.transformed(o.world));
    } else if (climb_state) {
      out.push_back(o.mesh->world_aabb(o.world, method, (*climb_state)[i]));
    } else {
      bounds::AabbTracker::Extremes start = o.mesh->tracker().initial_extremes();
      out.push_back(o.mesh->world_aabb(o.world, method, start));
    }
  }
  return out;
}

std::vector<Obb> world_obbs(const Scene& scene) {
  std::vector<Obb> out;
  out.reserve(scene.objects.size());
  for (const SceneObject& o : scene.objects)
    out.push_back(o.mesh ? o.mesh->world_obb(o.world) : Obb::from_transformed_aabb(o.local_bounds, o.world));
  return out;
}

std::vector<Sphere> world_spheres(const Scene& scene) {
  std::vector<Sphere> out;
  out.reserve(scene.objects.size());
  for (const SceneObject& o : scene.objects) {
    if (o.mesh) {
      out.push_back(o.mesh->world_sphere(o.world));
      continue;
    }
    // In double: centre = transformed box centre; radius = farthest transformed corner,
    // measured from the stored float centre and rounded up, so the sphere encloses the box
    // (docs/numerics.md, World-space volumes).
    const glm::dmat4 m(o.world);
    const glm::dvec3 local_c = (glm::dvec3(o.local_bounds.min) + glm::dvec3(o.local_bounds.max)) * 0.5;
    Sphere s;
    s.center = glm::vec3(m * glm::dvec4(local_c, 1.0));
    double r = 0.0;
    for (const glm::vec3& corner : o.local_bounds.corners())
      r = std::max(r, glm::length(glm::dvec3(m * glm::dvec4(glm::dvec3(corner), 1.0)) - glm::dvec3(s.center)));
    s.radius = round_up(r);
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
    const Obb ob = o.mesh ? o.mesh->world_obb(o.world) : Obb::from_transformed_aabb(o.local_bounds, o.world);
    if (const std::string why = invalid_reason(ob); !why.empty()) throw InputError(where + "world-space OBB: " + why);
    if (o.mesh) {
      const Sphere s = o.mesh->world_sphere(o.world);
      if (const std::string why = invalid_reason(s); !why.empty())
        throw InputError(where + "world-space sphere: " + why);
    }
    // The world sphere's radius is at most the world AABB's diagonal.
    if (!std::isfinite(float(glm::length(glm::dvec3(w.max) - glm::dvec3(w.min)))))
      throw InputError(where + "world-space bounding sphere: radius is infinite");
  }
}

}  // namespace cullpipe
