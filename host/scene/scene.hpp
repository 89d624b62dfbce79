#pragma once
#include <cstdint>
#include <glm/mat4x4.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "geom/aabb.hpp"
#include "geom/obb.hpp"
#include "geom/sphere.hpp"
#include "scene/camera.hpp"

namespace cullpipe {

/// Bad input from outside (a file, a command line value): the message names the source and
/// what is wrong, e.g. "scenes/x.json: objects[3].min[1] is NaN".
class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// One cullable object: its bounds in its own space and where the world puts it.
struct SceneObject {
  Aabb local_bounds;
  glm::mat4 world{1.0f};  ///< affine object-to-world transform
};

/// A scene: objects plus the camera it is meant to be seen from.
struct Scene {
  std::string name;
  std::vector<SceneObject> objects;
  Camera camera;

  /// The world-space AABB around every object (empty box at the origin for no objects).
  Aabb bounds() const;
};

/// World-space volumes of every object, in object order. The AABB is the AABB of the
/// transformed local box; the OBB is the transformed local box; the sphere is centred on the
/// transformed box centre with the distance to its farthest transformed corner as radius.
std::vector<Aabb> world_aabbs(const Scene& scene);
std::vector<Obb> world_obbs(const Scene& scene);
std::vector<Sphere> world_spheres(const Scene& scene);

/// Throws InputError("<source>: objects[i]...") for the first object with a non-finite value,
/// min > max, or a singular transform.
void validate(const Scene& scene, const std::string& source);

}  // namespace cullpipe
