#pragma once
// Clusters of a triangle mesh: the mesh split into meshlets of a few dozen vertices and about a
// hundred triangles by meshoptimizer (meshopt_buildMeshlets), each with its bounds, so that a
// pass can cull parts of a mesh rather than all or nothing. Each cluster's triangles are kept as
// a range of an index buffer into the mesh's own vertices, ready for an indexed draw of that
// range (no mesh shaders needed).
#include <cstddef>
#include <cstdint>
#include <glm/vec3.hpp>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/cone.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"
#include "cullpipe/scene/scene.hpp"

namespace cullpipe {

/// How a mesh is split (meshopt_buildMeshlets' settings).
struct ClusterOptions {
  std::uint32_t max_vertices = 64;    ///< per cluster, 3..255
  std::uint32_t max_triangles = 124;  ///< per cluster, 1..512, a multiple of 4 (meshoptimizer's limits)
  /// 0 builds clusters for size alone; towards 1 meshoptimizer trades size for narrower normal
  /// cones (more clusters culled as facing away).
  float cone_weight = 0.25f;
  /// An OBB per cluster too (bounds::hull_face_obb of its vertices), kept where its volume is
  /// under 3/4 of the box's: the cluster tests then cull what either volume proves culled.
  bool obbs = true;
  bool operator==(const ClusterOptions&) const = default;
};

/// One cluster: its triangles and its bounds in the mesh's own space.
struct Cluster {
  std::uint32_t first_index = 0;  ///< into MeshClusters::indices: three per triangle
  std::uint32_t index_count = 0;
  std::uint32_t vertex_count = 0;  ///< distinct vertices its triangles use
  /// The AABB of its vertices, exactly (a float box's bounds are the vertices' own floats).
  Aabb box;
  /// About the centre of meshoptimizer's bounding sphere (meshopt_computeMeshletBounds), the
  /// radius that encloses every vertex as measured in double (bounds::enclosing_sphere).
  Sphere sphere;
  /// The back-face cone about meshoptimizer's cone axis, with the apex and cutoff measured in
  /// double (bounds::backface_cone): the cluster faces away from every viewer the cone test
  /// (facing_away) passes. Unusable (cutoff 1) when the normals spread too far.
  BackfaceCone cone;
  /// With ClusterOptions::obbs, where it is under 3/4 of the box's volume: an OBB enclosing
  /// every vertex (each vertex's offset from the centre, projected on each axis in double, within
  /// the half extent), else none.
  std::optional<Obb> obb;
};

/// A mesh's clusters. `indices` hold every triangle of the mesh once (a permutation of its
/// triangles, each triangle's winding kept), cluster by cluster; they index the mesh's own
/// positions.
struct MeshClusters {
  std::vector<Cluster> clusters;
  std::vector<std::uint32_t> indices;
  ClusterOptions options;
};

/// Splits `mesh` into clusters. Throws std::invalid_argument naming `name` and what is wrong for
/// a mesh with no triangles, an index count that is not a multiple of 3, an index past the
/// vertices, a position that is not finite, or options past meshoptimizer's limits; the
/// caller's state is untouched. Degenerate triangles (repeated or collinear corners) are kept:
/// they draw nothing, and their cluster's bounds still enclose them. O(triangles).
MeshClusters build_clusters(const TriangleMesh& mesh, const ClusterOptions& options = {},
                            std::string_view name = "mesh");

/// "" when `clusters` are a valid split of `mesh`: every triangle of the mesh in exactly one
/// cluster with its winding, ranges contiguous and in bounds, at most the options' vertices and
/// triangles per cluster, every cluster's box and sphere enclosing its vertices, and its cone
/// (when usable) holding every triangle with an area, in double; else what is wrong and where.
std::string check_clusters(const MeshClusters& clusters, const TriangleMesh& mesh);

}  // namespace cullpipe
