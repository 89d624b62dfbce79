#pragma once
// Internal to src/cullpipe/scene: tinygltf loading and range-checked accessor reads shared by the
// glTF readers (gltf_points.cpp, gltf_scene.cpp). Not a public header.
#include <tiny_gltf.h>

#include <glm/vec3.hpp>
#include <optional>
#include <string>
#include <vector>

#include "cullpipe/geom/aabb.hpp"

namespace cullpipe::gltf {

/// True when `path` ends with `suffix` (lower case, e.g. ".glb"), ignoring case.
bool ends_with_ci(const std::string& path, const char* suffix);

/// Loads a .gltf or .glb (chosen by extension) without decoding images; throws InputError
/// naming the file when tinygltf cannot read it.
tinygltf::Model load_model(const std::string& path);

/// A primitive's POSITION data, every element range checked and finite.
struct Positions {
  std::vector<glm::vec3> points;
  std::optional<Aabb> declared;  ///< the accessor's min/max, when present
};

/// Reads meshes[mesh].primitives[primitive]'s POSITION accessor. `where` prefixes every error
/// ("FILE: meshes[2].primitives[0]: "). Throws InputError for a missing, sparse, non-VEC3 or
/// non-FLOAT accessor, a read past its buffer view or buffer, an empty accessor, or a NaN or
/// infinite coordinate.
Positions read_positions(const tinygltf::Model& model, std::size_t mesh, std::size_t primitive,
                         const std::string& where);

/// Reads the primitive's index accessor, if any: a scalar of UNSIGNED_BYTE/SHORT/INT, within
/// its buffer view, and every index below `vertex_count` (InputError otherwise). Without an
/// index accessor: 0, 1, ..., vertex_count - 1.
std::vector<std::uint32_t> read_indices(const tinygltf::Model& model, const tinygltf::Primitive& primitive,
                                        std::size_t vertex_count, const std::string& where);

/// The primitive's triangles as a list (three indices each) from its mode: TRIANGLES as is
/// (a trailing partial triangle dropped), TRIANGLE_STRIP and TRIANGLE_FAN unrolled (winding
/// kept), POINTS and LINES* give none.
std::vector<std::uint32_t> triangle_list(int mode, const std::vector<std::uint32_t>& indices);

}  // namespace cullpipe::gltf
