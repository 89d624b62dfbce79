// Clusters of a mesh (scene/clusters): meshoptimizer's meshlets as index ranges into the mesh's
// own vertices, every triangle once with its winding, and bounds that enclose every vertex;
// bad meshes refused with the mesh named. The shared glTF scenes' meshes when present.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <map>
#include <stdexcept>

#include "cullpipe/scene/clusters.hpp"
#include "cullpipe/scene/gltf_scene.hpp"

namespace cullpipe {
namespace {

namespace fs = std::filesystem;
const fs::path kScenes = fs::path(CULLPIPE_SHARED_DIR) / "scenes";

// A latitude-longitude sphere of radius r: 2 x rings x segments triangles, wound outwards.
TriangleMesh uv_sphere(int rings, int segments, float r) {
  TriangleMesh m;
  for (int i = 0; i <= rings; ++i)
    for (int j = 0; j < segments; ++j) {
      const float theta = float(i) / float(rings) * 3.14159265f, phi = float(j) / float(segments) * 6.2831853f;
      m.positions.push_back(
          r * glm::vec3(std::sin(theta) * std::cos(phi), std::cos(theta), std::sin(theta) * std::sin(phi)));
    }
  auto at = [&](int i, int j) { return std::uint32_t(i * segments + (j % segments)); };
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      m.indices.insert(m.indices.end(), {at(i, j), at(i, j + 1), at(i + 1, j)});
      m.indices.insert(m.indices.end(), {at(i, j + 1), at(i + 1, j + 1), at(i + 1, j)});
    }
  return m;
}

TEST(Clusters, ASphereSplitsIntoValidClusters) {
  const TriangleMesh mesh = uv_sphere(60, 80, 3.0f);  // 9,600 triangles, the poles degenerate
  for (const ClusterOptions options : {ClusterOptions{}, ClusterOptions{.max_vertices = 255, .max_triangles = 512},
                                       ClusterOptions{.max_vertices = 3, .max_triangles = 4, .cone_weight = 0.0f}}) {
    SCOPED_TRACE(std::to_string(options.max_vertices) + "/" + std::to_string(options.max_triangles));
    const MeshClusters c = build_clusters(mesh, options, "sphere");
    EXPECT_EQ(check_clusters(c, mesh), "");
    // Near the limits: no more clusters than twice the fewest the triangle limit allows (with 3
    // vertices a cluster holds one triangle).
    const std::size_t per = options.max_vertices == 3 ? 1 : options.max_triangles;
    const std::size_t fewest = (mesh.indices.size() / 3 + per - 1) / per;
    EXPECT_GE(c.clusters.size(), fewest);
    EXPECT_LE(c.clusters.size(), 2 * fewest + 2);
    for (const Cluster& cl : c.clusters) {
      EXPECT_LE(cl.cone_cutoff, 1.0f);
      for (int a = 0; a < 3; ++a) EXPECT_LE(cl.box.max[a] - cl.box.min[a], 2.0f * cl.sphere.radius * 1.0001f);
    }
  }
}

TEST(Clusters, ChecksFindBrokenClusters) {
  const TriangleMesh mesh = uv_sphere(10, 12, 1.0f);
  const MeshClusters good = build_clusters(mesh);
  ASSERT_EQ(check_clusters(good, mesh), "");
  MeshClusters flipped = good;
  std::swap(flipped.indices[0], flipped.indices[1]);  // one triangle's winding reversed
  EXPECT_NE(check_clusters(flipped, mesh), "");
  MeshClusters small = good;
  small.clusters[0].sphere.radius *= 0.5f;
  EXPECT_NE(check_clusters(small, mesh), "");
  MeshClusters shifted = good;
  shifted.clusters[0].box.max.x = shifted.clusters[0].box.min.x;
  EXPECT_NE(check_clusters(shifted, mesh), "");
}

TEST(Clusters, BadMeshesAreRefusedByName) {
  auto message = [](const TriangleMesh& m, const ClusterOptions& o = {}) {
    try {
      build_clusters(m, o, "wheel");
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  TriangleMesh m = uv_sphere(4, 6, 1.0f);
  EXPECT_NE(message(TriangleMesh{}).find("wheel: has no triangles"), std::string::npos);
  TriangleMesh past = m;
  past.indices[7] = std::uint32_t(past.positions.size());
  EXPECT_NE(message(past).find("wheel: index 7"), std::string::npos);
  TriangleMesh nan = m;
  nan.positions[3].y = std::numeric_limits<float>::quiet_NaN();
  EXPECT_NE(message(nan).find("wheel: vertex 3 is not finite"), std::string::npos);
  TriangleMesh ragged = m;
  ragged.indices.pop_back();
  EXPECT_NE(message(ragged).find("not a multiple of 3"), std::string::npos);
  EXPECT_NE(message(m, {.max_vertices = 256}).find("max_vertices"), std::string::npos);
  EXPECT_NE(message(m, {.max_triangles = 126}).find("max_triangles"), std::string::npos);
  EXPECT_NE(message(m, {.cone_weight = 2.0f}).find("cone_weight"), std::string::npos);
}

// Every mesh primitive of the shared scenes, split with the default options.
TEST(Clusters, SharedScenesSplitIntoValidClusters) {
  if (!fs::exists(kScenes)) GTEST_SKIP() << kScenes << " not present";
  std::size_t meshes = 0, triangles = 0, clusters = 0;
  for (const auto& dir : fs::directory_iterator(kScenes)) {
    if (!dir.is_directory()) continue;
    for (const auto& file : fs::directory_iterator(dir.path())) {
      if (file.path().extension() != ".gltf") continue;
      SCOPED_TRACE(file.path().string());
      const GltfScene g = load_gltf_scene(file.path().string());
      std::map<const TriangleMesh*, bool> seen;
      for (const SceneObject& o : g.scene.objects) {
        if (!o.triangles || seen[o.triangles.get()]) continue;
        seen[o.triangles.get()] = true;
        const std::string name =
            "mesh " + std::to_string(o.origin.mesh) + " primitive " + std::to_string(o.origin.primitive);
        const MeshClusters c = build_clusters(*o.triangles, {}, name);
        ASSERT_EQ(check_clusters(c, *o.triangles), "") << name;
        ++meshes;
        triangles += o.triangles->indices.size() / 3;
        clusters += c.clusters.size();
      }
    }
  }
  std::printf("%zu meshes, %zu triangles in %zu clusters\n", meshes, triangles, clusters);
  EXPECT_GT(meshes, 0u);
}

}  // namespace
}  // namespace cullpipe
