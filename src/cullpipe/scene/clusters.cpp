#include "cullpipe/scene/clusters.hpp"

#include <meshoptimizer.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <glm/ext/vector_double3.hpp>
#include <glm/geometric.hpp>
#include <limits>
#include <stdexcept>
#include <string>

#include "cullpipe/bounds/cone_fit.hpp"
#include "cullpipe/bounds/obb_fit.hpp"
#include "cullpipe/bounds/sphere_fit.hpp"

namespace cullpipe {

namespace {

std::string where(std::string_view name) { return "build_clusters: " + std::string(name) + ": "; }

}  // namespace

MeshClusters build_clusters(const TriangleMesh& mesh, const ClusterOptions& options, std::string_view name) {
  const std::size_t index_count = mesh.indices.size(), vertex_count = mesh.positions.size();
  if (options.max_vertices < 3 || options.max_vertices > 255)
    throw std::invalid_argument(where(name) + "max_vertices " + std::to_string(options.max_vertices) +
                                " is outside 3..255");
  if (options.max_triangles < 1 || options.max_triangles > 512 || options.max_triangles % 4 != 0)
    throw std::invalid_argument(where(name) + "max_triangles " + std::to_string(options.max_triangles) +
                                " is not a multiple of 4 in 4..512");
  if (!(options.cone_weight >= 0.0f && options.cone_weight <= 1.0f))
    throw std::invalid_argument(where(name) + "cone_weight " + std::to_string(options.cone_weight) +
                                " is outside 0..1");
  if (index_count == 0) throw std::invalid_argument(where(name) + "has no triangles");
  if (index_count % 3 != 0)
    throw std::invalid_argument(where(name) + std::to_string(index_count) + " indices, not a multiple of 3");
  if (index_count > std::numeric_limits<std::uint32_t>::max())
    throw std::invalid_argument(where(name) + std::to_string(index_count) + " indices, more than 2^32 - 1");
  for (std::size_t k = 0; k < index_count; ++k)
    if (mesh.indices[k] >= vertex_count)
      throw std::invalid_argument(where(name) + "index " + std::to_string(k) + " is " +
                                  std::to_string(mesh.indices[k]) + ", past its " + std::to_string(vertex_count) +
                                  " vertices");
  for (std::size_t v = 0; v < vertex_count; ++v)
    for (int a = 0; a < 3; ++a)
      if (!std::isfinite(mesh.positions[v][a]))
        throw std::invalid_argument(where(name) + "vertex " + std::to_string(v) + " is not finite");

  const float* positions = &mesh.positions[0].x;
  const std::size_t stride = sizeof(glm::vec3);
  const std::size_t bound = meshopt_buildMeshletsBound(index_count, options.max_vertices, options.max_triangles);
  std::vector<meshopt_Meshlet> meshlets(bound);
  std::vector<unsigned int> meshlet_vertices(bound * options.max_vertices);
  std::vector<unsigned char> meshlet_triangles(bound * options.max_triangles * 3);
  const std::size_t count = meshopt_buildMeshlets(meshlets.data(), meshlet_vertices.data(), meshlet_triangles.data(),
                                                  mesh.indices.data(), index_count, positions, vertex_count, stride,
                                                  options.max_vertices, options.max_triangles, options.cone_weight);

  MeshClusters out;
  out.options = options;
  out.clusters.reserve(count);
  out.indices.reserve(index_count);
  std::vector<glm::vec3> points;
  for (std::size_t m = 0; m < count; ++m) {
    const meshopt_Meshlet& ml = meshlets[m];
    const unsigned int* local = &meshlet_vertices[ml.vertex_offset];
    const unsigned char* tris = &meshlet_triangles[ml.triangle_offset];
    Cluster c;
    c.first_index = static_cast<std::uint32_t>(out.indices.size());
    c.index_count = ml.triangle_count * 3;
    c.vertex_count = ml.vertex_count;
    for (std::size_t k = 0; k < std::size_t(ml.triangle_count) * 3; ++k) out.indices.push_back(local[tris[k]]);
    points.clear();
    for (std::size_t v = 0; v < ml.vertex_count; ++v) points.push_back(mesh.positions[local[v]]);
    c.box = bounds::aabb_of_points(points);
    const meshopt_Bounds b =
        meshopt_computeMeshletBounds(local, tris, ml.triangle_count, positions, vertex_count, stride);
    // meshoptimizer's centre, with the radius that encloses every vertex as measured in double
    // (meshoptimizer computes its sphere in float and does not promise that to the last bit).
    c.sphere = bounds::enclosing_sphere(glm::dvec3(b.center[0], b.center[1], b.center[2]), points);
    // meshoptimizer's axis, with an apex and a cutoff that are proven (its float ones are not).
    c.cone = bounds::backface_cone(mesh.positions, std::span(out.indices).subspan(c.first_index, c.index_count),
                                   glm::vec3(b.cone_axis[0], b.cone_axis[1], b.cone_axis[2]));
    if (options.obbs) {
      // Both volumes are tested and either may cull, so an OBB is worth its test only where it
      // is clearly tighter (a strict test: flat clusters in an axis plane have two empty boxes).
      const Obb obb = bounds::hull_face_obb(points);
      const glm::dvec3 size = glm::dvec3(c.box.max) - glm::dvec3(c.box.min);
      if (bounds::volume(obb) < 0.75 * size.x * size.y * size.z) c.obb = obb;
    }
    out.clusters.push_back(c);
  }
  return out;
}

std::string check_clusters(const MeshClusters& clusters, const TriangleMesh& mesh) {
  const std::size_t triangles = mesh.indices.size() / 3;
  if (clusters.indices.size() != mesh.indices.size())
    return std::to_string(clusters.indices.size()) + " cluster indices for " + std::to_string(mesh.indices.size()) +
           " mesh indices";
  // Each triangle as its corners rotated to start at the smallest index (winding kept), sorted:
  // the clusters' triangles must be the mesh's, each once.
  auto canonical = [](std::span<const std::uint32_t> idx) {
    std::vector<std::array<std::uint32_t, 3>> t(idx.size() / 3);
    for (std::size_t k = 0; k < t.size(); ++k) {
      std::array<std::uint32_t, 3> a{idx[3 * k], idx[3 * k + 1], idx[3 * k + 2]};
      const std::size_t low = std::size_t(std::min_element(a.begin(), a.end()) - a.begin());
      std::rotate(a.begin(), a.begin() + std::ptrdiff_t(low), a.end());
      t[k] = a;
    }
    std::sort(t.begin(), t.end());
    return t;
  };
  if (canonical(clusters.indices) != canonical(mesh.indices))
    return "the clusters' triangles are not the mesh's " + std::to_string(triangles) + " triangles with their winding";
  std::uint32_t next = 0;
  for (std::size_t c = 0; c < clusters.clusters.size(); ++c) {
    const Cluster& cl = clusters.clusters[c];
    const std::string at = "cluster " + std::to_string(c) + ": ";
    if (cl.first_index != next || cl.index_count == 0 || cl.index_count % 3 != 0)
      return at + "index range " + std::to_string(cl.first_index) + "+" + std::to_string(cl.index_count) +
             " does not follow the one before";
    next += cl.index_count;
    if (next > clusters.indices.size()) return at + "index range past the indices";
    if (cl.index_count / 3 > clusters.options.max_triangles || cl.vertex_count > clusters.options.max_vertices)
      return at + std::to_string(cl.index_count / 3) + " triangles and " + std::to_string(cl.vertex_count) +
             " vertices, past the options";
    std::vector<std::uint32_t> used(clusters.indices.begin() + cl.first_index,
                                    clusters.indices.begin() + cl.first_index + cl.index_count);
    std::sort(used.begin(), used.end());
    used.erase(std::unique(used.begin(), used.end()), used.end());
    if (used.size() != cl.vertex_count)
      return at + std::to_string(used.size()) + " distinct vertices, " + std::to_string(cl.vertex_count) + " counted";
    for (const std::uint32_t v : used) {
      const glm::vec3& p = mesh.positions[v];
      for (int a = 0; a < 3; ++a)
        if (!(cl.box.min[a] <= p[a] && p[a] <= cl.box.max[a]))
          return at + "box does not enclose vertex " + std::to_string(v);
      const double dx = double(p.x) - cl.sphere.center.x, dy = double(p.y) - cl.sphere.center.y,
                   dz = double(p.z) - cl.sphere.center.z;
      if (!(std::sqrt(dx * dx + dy * dy + dz * dz) <= double(cl.sphere.radius)))
        return at + "sphere does not enclose vertex " + std::to_string(v);
      if (cl.obb) {
        const glm::dvec3 d = glm::dvec3(p) - glm::dvec3(cl.obb->center);
        for (int a = 0; a < 3; ++a)
          if (!(std::abs(glm::dot(d, glm::dvec3(cl.obb->basis[a]))) <= double(cl.obb->half_extents[a])))
            return at + "OBB does not enclose vertex " + std::to_string(v);
      }
    }
    if (cl.cone.usable()) {
      // Every triangle with an area within the cone's angle, and behind the apex (in double).
      const glm::dvec3 axis = glm::normalize(glm::dvec3(cl.cone.axis)), apex(cl.cone.apex);
      const double cutoff = cl.cone.cutoff, min_cos = std::sqrt(std::max(0.0, 1.0 - cutoff * cutoff));
      for (std::uint32_t k = cl.first_index; k < cl.first_index + cl.index_count; k += 3) {
        const glm::dvec3 a(mesh.positions[clusters.indices[k]]), b(mesh.positions[clusters.indices[k + 1]]),
            c3(mesh.positions[clusters.indices[k + 2]]);
        const glm::dvec3 n = glm::cross(b - a, c3 - a);
        if (!(glm::length(n) > 0.0)) continue;
        const glm::dvec3 u = n / glm::length(n);
        if (!(glm::dot(u, axis) >= min_cos) || !(glm::dot(u, apex - a) < 0.0))
          return at + "the cone does not hold triangle " + std::to_string((k - cl.first_index) / 3);
      }
    }
  }
  if (next != clusters.indices.size()) return "the clusters cover " + std::to_string(next) + " of the indices";
  return "";
}

}  // namespace cullpipe
