// Clusters of a mesh (scene/clusters): meshoptimizer's meshlets as index ranges into the mesh's
// own vertices, every triangle once with its winding, and bounds that enclose every vertex;
// bad meshes refused with the mesh named. The shared glTF scenes' meshes when present.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <glm/ext/matrix_double3x3.hpp>
#include <glm/ext/vector_double3.hpp>
#include <glm/geometric.hpp>
#include <glm/matrix.hpp>
#include <limits>
#include <map>
#include <stdexcept>

#include "cullpipe/bounds/obb_fit.hpp"
#include "cullpipe/geom/cone.hpp"
#include "cullpipe/scene/clusters.hpp"
#include "cullpipe/scene/gltf_scene.hpp"
#include "mesh_test_util.hpp"

namespace cullpipe {
namespace {

namespace fs = std::filesystem;
using test::random_transform;
using test::uv_sphere;
const fs::path kScenes = fs::path(CULLPIPE_SHARED_DIR) / "scenes";

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
    std::size_t with_obb = 0;
    for (const Cluster& cl : c.clusters) {
      EXPECT_TRUE(cl.cone.cutoff <= 1.0f) << cl.cone.cutoff;
      for (int a = 0; a < 3; ++a) EXPECT_LE(cl.box.max[a] - cl.box.min[a], 2.0f * cl.sphere.radius * 1.0001f);
      if (!cl.obb) continue;
      ++with_obb;  // kept only where it is under 3/4 of the box's volume
      const glm::dvec3 size = glm::dvec3(cl.box.max) - glm::dvec3(cl.box.min);
      EXPECT_LT(bounds::volume(*cl.obb), 0.75 * size.x * size.y * size.z);
    }
    // A sphere's patches are tilted against the axes: most clusters away from the axes get one.
    EXPECT_GT(with_obb, c.clusters.size() / 4);
    ClusterOptions boxes_only = options;
    boxes_only.obbs = false;
    const MeshClusters plain = build_clusters(mesh, boxes_only, "sphere");
    EXPECT_TRUE(std::none_of(plain.clusters.begin(), plain.clusters.end(), [](const Cluster& cl) { return cl.obb; }));
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
  // An OBB: the cluster's box as one encloses its vertices; shrunk by a tenth it does not.
  MeshClusters with_obb = good;
  const Aabb box = good.clusters[0].box;
  Obb obb;
  obb.center = (box.min + box.max) * 0.5f;
  obb.half_extents = (box.max - box.min) * 0.5f * 1.001f;
  with_obb.clusters[0].obb = obb;
  EXPECT_EQ(check_clusters(with_obb, mesh), "");
  with_obb.clusters[0].obb->half_extents *= 0.9f;
  EXPECT_NE(check_clusters(with_obb, mesh).find("OBB does not enclose"), std::string::npos);
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

// Whether every triangle of cluster `cl` with an area faces away from `eye` (world), in double:
// the eye brought into the mesh's space by the transform's inverse, then the side of each
// triangle's plane (counter-clockwise front faces in the mesh's space; a mirrored instance's
// winding is flipped when drawn, which keeps that side).
bool all_face_away(const TriangleMesh& mesh, const MeshClusters& c, const Cluster& cl, const Transform3x4& t,
                   const glm::dvec3& eye) {
  glm::dmat3 m;
  for (int row = 0; row < 3; ++row)
    for (int col = 0; col < 3; ++col) m[col][row] = t.rows[std::size_t(row)][col];
  const glm::dvec3 translation(t.rows[0].w, t.rows[1].w, t.rows[2].w);
  const glm::dvec3 local = glm::inverse(m) * (eye - translation);
  for (std::uint32_t k = cl.first_index; k < cl.first_index + cl.index_count; k += 3) {
    const glm::dvec3 a(mesh.positions[c.indices[k]]), b(mesh.positions[c.indices[k + 1]]),
        d(mesh.positions[c.indices[k + 2]]);
    const glm::dvec3 n = glm::cross(b - a, d - a);
    if (glm::length(n) == 0.0) continue;
    if (!(glm::dot(n, local - a) < 0.0)) return false;
  }
  return true;
}

TEST(ClusterCones, InverseFramesBringTheEyeHome) {
  test::Rng rng(5);
  for (int i = 0; i < 200; ++i) {
    const Transform3x4 t = random_transform(rng);
    const InverseFrame f = inverse_frame(t);
    ASSERT_TRUE(f.usable);
    const glm::vec3 p(1.5f, -2.0f, 0.25f);
    glm::vec3 world, back;
    for (int r = 0; r < 3; ++r) world[r] = glm::dot(glm::vec3(t.rows[std::size_t(r)]), p) + t.rows[std::size_t(r)].w;
    for (int r = 0; r < 3; ++r)
      back[r] = glm::dot(glm::vec3(f.inverse.rows[std::size_t(r)]), world) + f.inverse.rows[std::size_t(r)].w;
    EXPECT_LT(glm::length(back - p), 1e-3f);
  }
  Transform3x4 flat;
  flat.rows[2] = glm::vec4(0.0f, 0.0f, 0.0f, 1.0f);  // z squashed to a plane
  EXPECT_FALSE(inverse_frame(flat).usable);
  Transform3x4 nan;
  nan.rows[1].w = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(inverse_frame(nan).usable);
  Transform3x4 thin;  // two rows 10^-6 apart: the determinant's terms cancel to 2^-20 of themselves
  thin.rows[0] = glm::vec4(1.0f, 1.0f, 0.0f, 0.0f);
  thin.rows[1] = glm::vec4(1.0f, 1.000001f, 0.0f, 0.0f);
  EXPECT_FALSE(inverse_frame(thin).usable);
  Transform3x4 scaled;  // a scale of 10^-7 on one axis: an exact inverse, so usable
  scaled.rows[2] = glm::vec4(0.0f, 0.0f, 1e-7f, 0.0f);
  EXPECT_TRUE(inverse_frame(scaled).usable);
}

// The cone test culls a cluster only when every one of its triangles faces away, under
// rotated, non-uniformly scaled and mirrored instances and from eyes all around; and it culls
// a good share of a closed mesh seen from outside (about half of it faces away).
TEST(ClusterCones, BackFacingClustersHaveNoFrontFace) {
  const TriangleMesh mesh = uv_sphere(40, 64, 2.0f);
  const MeshClusters c = build_clusters(mesh, {}, "sphere");
  std::size_t usable = 0;
  for (const Cluster& cl : c.clusters) usable += cl.cone.usable() ? 1 : 0;
  EXPECT_GT(usable, c.clusters.size() * 9 / 10);
  test::Rng rng(11);
  std::size_t tests = 0, culled = 0;
  for (int i = 0; i < 60; ++i) {
    const Transform3x4 t = random_transform(rng);
    const InverseFrame f = inverse_frame(t);
    const glm::dvec3 centre(t.rows[0].w, t.rows[1].w, t.rows[2].w);
    for (int e = 0; e < 8; ++e) {
      // Eyes from just outside the sphere to far away.
      const glm::dvec3 dir = glm::normalize(glm::dvec3(rng.vec3(-1.0f, 1.0f)) + glm::dvec3(1e-3, 0.0, 0.0));
      const glm::dvec3 eye = centre + dir * (12.0 * std::pow(10.0, 2.0 * double(rng.uniform(0.0f, 2.0f))));
      for (const Cluster& cl : c.clusters) {
        ++tests;
        if (!facing_away(cl.cone, f, glm::vec3(eye))) continue;
        ++culled;
        ASSERT_TRUE(all_face_away(mesh, c, cl, t, glm::dvec3(glm::vec3(eye))))
            << "transform " << i << " eye " << e << " cluster at " << cl.first_index;
      }
    }
  }
  std::printf("%zu of %zu cluster tests found the cluster facing away\n", culled, tests);
  EXPECT_GT(culled, tests / 5);
}

// Eyes on the edge of each cone: at angles from the axis within 2^-4 to 2^-30 of the cutoff's
// (inside and outside), from 2^-20 to 2^20 times the cluster's size away, under transforms that
// scale by 2^-10 to 2^10 per axis, mirror, and translate by up to 2^15. Every cluster the float
// test culls has every triangle facing away in double.
TEST(ClusterCones, EyesOnTheConesEdgeNeverCullAFrontFace) {
  const TriangleMesh mesh = uv_sphere(24, 32, 1.0f);
  const MeshClusters c = build_clusters(mesh, {}, "sphere");
  test::Rng rng(23);
  std::size_t tests = 0, culled = 0;
  for (int t = 0; t < 40; ++t) {
    const glm::mat3 r = rng.rotation();
    glm::vec3 k(std::exp2(rng.uniform(-10.0f, 10.0f)), std::exp2(rng.uniform(-10.0f, 10.0f)),
                std::exp2(rng.uniform(-10.0f, 10.0f)));
    if (t % 2) k.y = -k.y;
    Transform3x4 tr;
    for (int row = 0; row < 3; ++row)
      tr.rows[std::size_t(row)] =
          glm::vec4(r[0][row] * k.x, r[1][row] * k.y, r[2][row] * k.z, rng.uniform(-32768.0f, 32768.0f));
    const InverseFrame f = inverse_frame(tr);
    if (!f.usable) continue;
    glm::dmat3 m;
    for (int row = 0; row < 3; ++row)
      for (int col = 0; col < 3; ++col) m[col][row] = tr.rows[std::size_t(row)][col];
    const glm::dvec3 translation(tr.rows[0].w, tr.rows[1].w, tr.rows[2].w);
    for (const Cluster& cl : c.clusters) {
      if (!cl.cone.usable()) continue;
      const glm::dvec3 axis = glm::normalize(glm::dvec3(cl.cone.axis)), apex(cl.cone.apex);
      const glm::dvec3 side =
          glm::normalize(glm::cross(axis, std::abs(axis.x) < 0.9 ? glm::dvec3(1, 0, 0) : glm::dvec3(0, 1, 0)));
      const glm::dvec3 up = glm::cross(axis, side);
      const double size = glm::length(glm::dvec3(cl.box.max - cl.box.min));
      const double edge = std::acos(double(cl.cone.cutoff));
      for (int e = 0; e < 24; ++e) {
        const double angle = edge * (1.0 + (e % 2 ? 1.0 : -1.0) * std::exp2(-double(rng.uniform(4.0f, 30.0f))));
        const double turn = double(rng.uniform(0.0f, 6.2831853f));
        const glm::dvec3 u = std::cos(angle) * axis + std::sin(angle) * (std::cos(turn) * side + std::sin(turn) * up);
        const glm::dvec3 local = apex - u * (size * std::exp2(double(rng.uniform(-20.0f, 20.0f))));
        const glm::vec3 eye(m * local + translation);
        ++tests;
        if (!facing_away(cl.cone, f, eye)) continue;
        ++culled;
        ASSERT_TRUE(all_face_away(mesh, c, cl, tr, glm::dvec3(eye)))
            << "transform " << t << " cluster at " << cl.first_index << " angle " << angle << " against " << edge;
      }
    }
  }
  std::printf("%zu of %zu eyes on the cones' edges found the cluster facing away\n", culled, tests);
  EXPECT_GT(culled, 200u);  // eyes near enough to the cone's axis to be culled despite the margins
}

// Clusters 2^-40 to 2^-140 across, and eyes in front of a triangle: no underflow lets the test
// cull (its margin and its squared bound carry an absolute 2^-100; without it, squared distances
// of 2^-150 and less flush to 0, and 0 >= 0 culled).
TEST(ClusterCones, TinyClustersAreNotCulledByUnderflow) {
  for (int e = 40; e <= 140; e += 4) {
    const float s = std::exp2(-float(e));
    // A roof: two triangles at +-45 degrees about +y, its ridge at y = s.
    TriangleMesh roof;
    roof.positions = {{-s, 0, -s}, {s, 0, -s}, {0, s, -s}, {-s, 0, s}, {s, 0, s}, {0, s, s}};
    roof.indices = {0, 3, 2, 3, 5, 2, 1, 2, 4, 2, 5, 4};  // facing up and out
    const MeshClusters c = build_clusters(roof, {}, "roof");
    ASSERT_EQ(c.clusters.size(), 1u);
    ASSERT_TRUE(c.clusters[0].cone.usable());
    ASSERT_GT(c.clusters[0].cone.axis.y, 0.99f);
    const InverseFrame f = inverse_frame(Transform3x4{});
    // In front of the +x face (its normal is (1, 1, 0) / sqrt 2), below the ridge, along +y (the
    // cone's axis) beyond the apex, but far outside the cone.
    const glm::vec3 eye = glm::vec3(3.0f, 0.0f, 0.0f) * s;
    ASSERT_FALSE(all_face_away(roof, c, c.clusters[0], Transform3x4{}, glm::dvec3(eye)));
    EXPECT_FALSE(facing_away(c.clusters[0].cone, f, eye)) << "size 2^-" << e;
  }
}

// Every mesh primitive of the shared scenes, split with the default options.
TEST(Clusters, SharedScenesSplitIntoValidClusters) {
  if (!fs::exists(kScenes)) GTEST_SKIP() << kScenes << " not present";
  std::size_t meshes = 0, triangles = 0, clusters = 0, cones = 0;
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
        for (const Cluster& cl : c.clusters) cones += cl.cone.usable() ? 1 : 0;
      }
    }
  }
  std::printf("%zu meshes, %zu triangles in %zu clusters, %zu with a back-face cone\n", meshes, triangles, clusters,
              cones);
  EXPECT_GT(meshes, 0u);
}

}  // namespace
}  // namespace cullpipe
