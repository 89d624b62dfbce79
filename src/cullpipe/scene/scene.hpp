#pragma once
#include <cstdint>
#include <glm/mat4x4.hpp>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "cullpipe/bounds/aabb_update.hpp"
#include "cullpipe/bounds/mesh_bounds.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"
#include "cullpipe/scene/camera.hpp"

namespace cullpipe {

/// Bad input from outside (a file, a command line value): the message names the source and
/// what is wrong, e.g. "scenes/x.json: objects[3].min[1] is NaN".
class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Writes `bytes` to `path` atomically: into `path`.tmp beside it, then renamed over `path`,
/// so a reader never sees a half-written file and a failed write leaves an existing file
/// untouched (and no temporary behind). Throws InputError naming the path.
void write_file_atomic(const std::string& path, std::string_view bytes);

/// Where an object came from in a glTF file (-1: not from glTF).
struct ObjectOrigin {
  int node = -1;       ///< index in the file's nodes[]
  int mesh = -1;       ///< index in meshes[]
  int primitive = -1;  ///< index in that mesh's primitives[]
  int instance = 0;    ///< which copy, for scenes repeated with --instances
  bool operator==(const ObjectOrigin&) const = default;
};

/// Triangles of one mesh primitive, in its own space, for drawing (src/cullpipe/render).
struct TriangleMesh {
  std::vector<glm::vec3> positions;
  std::vector<std::uint32_t> indices;  ///< three per triangle, each < positions.size()
  /// Both faces are drawn (a glTF material's doubleSided); otherwise the triangles wound
  /// clockwise as seen are back faces, culled (counter-clockwise under a mirroring transform).
  bool double_sided = false;
};

/// One cullable object: its bounds in its own space and where the world puts it.
struct SceneObject {
  Aabb local_bounds;      ///< for a mesh object, the AABB of its vertices
  glm::mat4 world{1.0f};  ///< affine object-to-world transform
  /// The geometry's volumes (hull, OBB, sphere), shared by every instance of one mesh
  /// primitive; null for objects that are boxes (generated scenes, scene JSON files).
  std::shared_ptr<const bounds::MeshBounds> mesh;
  /// The triangles to draw (glTF objects); null for box objects, which are drawn as their box.
  std::shared_ptr<const TriangleMesh> triangles;
  ObjectOrigin origin;
};

/// A scene: objects plus the camera it is meant to be seen from.
struct Scene {
  std::string name;
  std::vector<SceneObject> objects;
  Camera camera;
  /// A natural camera path through the scene, in order; empty when the scene has none (then
  /// tools orbit: scene_camera_path).
  std::vector<Camera> path;

  /// The world-space AABB around every object (empty box at the origin for no objects).
  Aabb bounds() const;
};

/// World-space volumes of every object, in object order.
///
/// Objects with a mesh: the AABB by the chosen update method over the mesh's points (see
/// bounds::AabbUpdate; `climb_state`, when given, holds each object's hill-climbing extremes
/// from one call to the next, for objects that move between calls; it is resized to the
/// object count and started at the local extremes); the OBB is the mesh's OBB transformed; the
/// sphere is the mesh's sphere transformed (bounds::transform_sphere).
///
/// Box objects (no mesh): the AABB is the AABB of the transformed local box whatever the
/// method (the box is the geometry); the OBB is the transformed local box; the sphere is
/// centred on the transformed box centre with the distance to its farthest transformed
/// corner as radius.
std::vector<Aabb> world_aabbs(const Scene& scene, bounds::AabbUpdate method = bounds::AabbUpdate::HullRecompute,
                              std::vector<bounds::AabbTracker::Extremes>* climb_state = nullptr);
std::vector<Obb> world_obbs(const Scene& scene);
std::vector<Sphere> world_spheres(const Scene& scene);

/// Throws InputError("<source>: objects[i]...") for the first object with a non-finite value,
/// min > max, or a singular transform.
void validate(const Scene& scene, const std::string& source);

}  // namespace cullpipe
