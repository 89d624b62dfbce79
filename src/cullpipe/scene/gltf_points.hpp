#pragma once
#include <optional>
#include <string>
#include <vector>

#include "cullpipe/geom/aabb.hpp"

namespace cullpipe {

/// The vertex positions of one glTF mesh, in the mesh's own space (no node transforms).
struct GltfMeshPoints {
  std::string name;                  ///< the mesh's name, or "mesh N"
  int mesh = 0;                      ///< index in the file's meshes[]
  std::vector<glm::vec3> positions;  ///< POSITION of every primitive, concatenated
  /// The union of the POSITION accessors' declared min/max, when every accessor has them
  /// (the glTF spec requires them; an independent check of the data).
  std::optional<Aabb> declared_bounds;
};

/// Reads every mesh's positions from a .gltf or .glb file with tinygltf. External images are
/// not loaded (missing images are not an error). Every accessor and buffer view is range
/// checked; throws InputError naming the file and the element (e.g. "meshes[2].primitives[0]:
/// POSITION accessor 7 reads past its buffer view") for malformed files, unsupported
/// encodings (sparse or quantized positions) and NaN/Inf coordinates.
std::vector<GltfMeshPoints> load_gltf_mesh_points(const std::string& path);

}  // namespace cullpipe
