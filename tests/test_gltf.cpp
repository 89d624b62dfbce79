// glTF scenes: node hierarchies, instancing, cameras and malformed files (src/cullpipe/scene/gltf_scene).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <glm/geometric.hpp>
#include <glm/gtc/quaternion.hpp>
#include <nlohmann/json.hpp>

#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/validate.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/gltf_points.hpp"
#include "cullpipe/scene/gltf_scene.hpp"

namespace cullpipe {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;

const fs::path kScenes = fs::path(CULLPIPE_SHARED_DIR) / "scenes";

bool in_frustum(const Frustum& f, const glm::vec3& p) {
  for (const Plane& plane : f.active())
    if (plane.distance(p) < 0.0f) return false;
  return true;
}

bool box_contains(const Aabb& b, const glm::vec3& p) {
  return glm::all(glm::lessThanEqual(b.min, p)) && glm::all(glm::lessThanEqual(p, b.max));
}

// ---- an independent reading of the node graph (nlohmann, recursion), for the real scenes ----

glm::dmat4 node_matrix(const json& node) {
  glm::dmat4 m(1.0);
  if (node.contains("matrix")) {
    for (int i = 0; i < 16; ++i) m[i / 4][i % 4] = node["matrix"][std::size_t(i)].get<double>();
    return m;
  }
  glm::dmat4 t(1.0), r(1.0), s(1.0);
  if (node.contains("translation"))
    for (int k = 0; k < 3; ++k) t[3][k] = node["translation"][std::size_t(k)].get<double>();
  if (node.contains("rotation")) {
    const json& q = node["rotation"];
    r = glm::dmat4(glm::mat3_cast(
        glm::normalize(glm::dquat(q[3].get<double>(), q[0].get<double>(), q[1].get<double>(), q[2].get<double>()))));
  }
  if (node.contains("scale"))
    for (int k = 0; k < 3; ++k) s[k][k] = node["scale"][std::size_t(k)].get<double>();
  return t * r * s;
}

struct Instance {
  int node, mesh, primitive;
  glm::dmat4 world;
};

void collect(const json& doc, int n, const glm::dmat4& parent, std::vector<Instance>& out) {
  const json& node = doc["nodes"][std::size_t(n)];
  const glm::dmat4 world = parent * node_matrix(node);
  if (node.contains("mesh")) {
    const int m = node["mesh"].get<int>();
    for (std::size_t p = 0; p < doc["meshes"][std::size_t(m)]["primitives"].size(); ++p)
      out.push_back({n, m, int(p), world});
  }
  if (node.contains("children"))
    for (const json& c : node["children"]) collect(doc, c.get<int>(), world, out);
}

double max_abs(const glm::dmat4& a) {
  double m = 0.0;
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r) m = std::max(m, std::abs(a[c][r]));
  return m;
}

TEST(GltfScene, RealScenesMatchAnIndependentReadingOfTheirNodes) {
  if (!fs::exists(kScenes)) GTEST_SKIP() << kScenes << " not present";
  std::size_t files = 0, objects = 0, mirrored = 0;
  for (const auto& dir : fs::directory_iterator(kScenes)) {
    if (!dir.is_directory()) continue;
    for (const auto& file : fs::directory_iterator(dir.path())) {
      if (file.path().extension() != ".gltf") continue;
      SCOPED_TRACE(file.path().string());
      ++files;
      const json doc = json::parse(std::ifstream(file.path()));
      std::vector<Instance> expected;
      const int s = doc.value("scene", 0);
      for (const json& r : doc["scenes"][std::size_t(s)]["nodes"])
        collect(doc, r.get<int>(), glm::dmat4(1.0), expected);

      const GltfScene g = load_gltf_scene(file.path().string());
      ASSERT_EQ(g.scene.objects.size(), expected.size());
      EXPECT_EQ(g.cameras.size(), doc.contains("cameras") ? doc["cameras"].size() : 0u);
      const std::vector<Aabb> exact = world_aabbs(g.scene, bounds::AabbUpdate::Recompute);
      std::vector<std::vector<Aabb>> by_method;
      for (bounds::AabbUpdate m :
           {bounds::AabbUpdate::HullRecompute, bounds::AabbUpdate::TransformBox, bounds::AabbUpdate::HillClimb})
        by_method.push_back(world_aabbs(g.scene, m));
      const std::vector<Obb> obbs = world_obbs(g.scene);
      const std::vector<Sphere> spheres = world_spheres(g.scene);
      for (std::size_t i = 0; i < expected.size(); ++i) {
        const SceneObject& o = g.scene.objects[i];
        const Instance& e = expected[i];
        SCOPED_TRACE("object " + std::to_string(i) + " node " + std::to_string(e.node));
        ASSERT_EQ(o.origin, (ObjectOrigin{e.node, e.mesh, e.primitive, 0}));
        ASSERT_TRUE(o.mesh);
        // The transform composed down the hierarchy.
        EXPECT_LE(max_abs(glm::dmat4(o.world) - e.world), 1e-6 * std::max(max_abs(e.world), 1.0));
        if (glm::determinant(glm::dmat3(e.world)) < 0.0) ++mirrored;
        // The local box is the accessor's declared min/max (exporters print in decimal).
        const json& acc =
            doc["accessors"]
               [doc["meshes"][std::size_t(e.mesh)]["primitives"][std::size_t(e.primitive)]["attributes"]["POSITION"]
                    .get<std::size_t>()];
        const float scale = glm::length(o.local_bounds.extent()) + 1e-30f;
        for (int k = 0; k < 3; ++k) {
          EXPECT_NEAR(o.local_bounds.min[k], acc["min"][std::size_t(k)].get<double>(), 1e-6 * scale);
          EXPECT_NEAR(o.local_bounds.max[k], acc["max"][std::size_t(k)].get<double>(), 1e-6 * scale);
        }
        // World AABB from the points lies inside the declared box carried by the expected
        // transform, and every update method encloses it.
        Aabb declared_world{glm::vec3(INFINITY), glm::vec3(-INFINITY)};
        for (int c = 0; c < 8; ++c) {
          glm::dvec3 p;
          for (int k = 0; k < 3; ++k) p[k] = acc[(c >> k) & 1 ? "max" : "min"][std::size_t(k)].get<double>();
          const glm::vec3 w(e.world * glm::dvec4(p, 1.0));
          declared_world.min = glm::min(declared_world.min, w);
          declared_world.max = glm::max(declared_world.max, w);
        }
        const float wscale =
            glm::length(declared_world.extent()) + glm::length(declared_world.center()) * 1e-3f + 1e-30f;
        for (int k = 0; k < 3; ++k) {
          EXPECT_GE(exact[i].min[k], declared_world.min[k] - 1e-5f * wscale);
          EXPECT_LE(exact[i].max[k], declared_world.max[k] + 1e-5f * wscale);
          // Each method evaluates the transform in double in its own order: they agree to
          // double rounding of the terms, which shows near zero (the documented relative
          // tolerance of every volume).
          const float slack = 1e-9f * wscale;
          for (const auto& m : by_method) {
            EXPECT_LE(m[i].min[k], exact[i].min[k] + slack);
            EXPECT_GE(m[i].max[k], exact[i].max[k] - slack);
          }
        }
        EXPECT_EQ(invalid_reason(obbs[i]), "");
        EXPECT_EQ(invalid_reason(spheres[i]), "");
        // The OBB and the sphere enclose every transformed hull vertex.
        for (const glm::vec3& v : o.mesh->hull().vertices) {
          const glm::dvec3 w = glm::dvec3(glm::dmat4(o.world) * glm::dvec4(glm::dvec3(v), 1.0));
          const double tol = 1e-5 * (double(glm::length(declared_world.extent())) + 1e-30) + 1e-6 * glm::length(w);
          EXPECT_LE(glm::length(w - glm::dvec3(spheres[i].center)), double(spheres[i].radius) + tol);
          for (int k = 0; k < 3; ++k)
            EXPECT_LE(std::abs(glm::dot(w - glm::dvec3(obbs[i].center), glm::dvec3(obbs[i].basis[k]))),
                      double(obbs[i].half_extents[k]) + tol);
        }
      }
      objects += expected.size();
    }
  }
  EXPECT_EQ(files, 10u);
  EXPECT_GE(objects, 400u);
  EXPECT_GE(mirrored, 4u);  // NegativeScaleTest's mirrored instances (VC has more)
}

TEST(GltfScene, GlbAndGltfGiveTheSameScene) {
  if (!fs::exists(kScenes / "Duck" / "Duck.glb")) GTEST_SKIP() << "Duck not present";
  const GltfScene a = load_gltf_scene((kScenes / "Duck" / "Duck.gltf").string());
  const GltfScene b = load_gltf_scene((kScenes / "Duck" / "Duck.glb").string());
  ASSERT_EQ(a.scene.objects.size(), b.scene.objects.size());
  EXPECT_EQ(world_aabbs(a.scene), world_aabbs(b.scene));
  EXPECT_EQ(world_obbs(a.scene), world_obbs(b.scene));
  EXPECT_EQ(world_spheres(a.scene), world_spheres(b.scene));
}

TEST(GltfScene, CamerasComeFromTheirNodes) {
  if (!fs::exists(kScenes / "Duck" / "Duck.gltf")) GTEST_SKIP() << "Duck not present";
  const std::string path = (kScenes / "Duck" / "Duck.gltf").string();
  GltfSceneOptions o;
  o.camera = "0";
  const GltfScene g = load_gltf_scene(path, o);
  ASSERT_EQ(g.cameras.size(), 1u);
  // Independent: the camera node's translation/rotation from the JSON.
  const json doc = json::parse(std::ifstream(path));
  glm::dmat4 world(1.0);
  bool found = false;
  std::function<void(int, const glm::dmat4&)> find = [&](int n, const glm::dmat4& parent) {
    const json& node = doc["nodes"][std::size_t(n)];
    const glm::dmat4 w = parent * node_matrix(node);
    if (node.contains("camera") && !found) world = w, found = true;
    if (node.contains("children"))
      for (const json& c : node["children"]) find(c.get<int>(), w);
  };
  for (const json& r : doc["scenes"][0]["nodes"]) find(r.get<int>(), glm::dmat4(1.0));
  ASSERT_TRUE(found);
  const glm::dvec3 eye(world[3]);
  const glm::dvec3 forward = glm::normalize(glm::dvec3(-world[2]));
  EXPECT_LE(glm::length(glm::dvec3(g.scene.camera.eye) - eye), 1e-4 * glm::length(eye));
  EXPECT_LE(glm::length(glm::normalize(glm::dvec3(g.scene.camera.target - g.scene.camera.eye)) - forward), 1e-5);
  const json& p = doc["cameras"][0]["perspective"];
  EXPECT_NEAR(g.scene.camera.fov_y_degrees, p["yfov"].get<double>() * 180.0 / M_PI, 1e-4);
  EXPECT_FLOAT_EQ(g.scene.camera.near_plane, p["znear"].get<float>());
  // The duck is in view of its own camera.
  const Frustum f = Frustum::from_view_proj(g.scene.camera.view_proj());
  EXPECT_NE(reference::classify(world_aabbs(g.scene)[0], f), Classification::Outside);
  o.camera = "7";
  EXPECT_THROW(load_gltf_scene(path, o), InputError);
}

// ---- synthetic files ----

std::string base64(const std::vector<unsigned char>& data) {
  static const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  for (std::size_t i = 0; i < data.size(); i += 3) {
    const unsigned v = unsigned(data[i]) << 16 | (i + 1 < data.size() ? unsigned(data[i + 1]) << 8 : 0u) |
                       (i + 2 < data.size() ? unsigned(data[i + 2]) : 0u);
    out += k[(v >> 18) & 63];
    out += k[(v >> 12) & 63];
    out += i + 1 < data.size() ? k[(v >> 6) & 63] : '=';
    out += i + 2 < data.size() ? k[v & 63] : '=';
  }
  return out;
}

// A glTF with one mesh: a tetrahedron (4 positions, 12 uint16 indices), nodes as given.
json tetra_gltf(const json& nodes, const json& scene_nodes) {
  const float pos[12] = {0, 0, 0, 2, 0, 0, 0, 1, 0, 0, 0, 3};
  const std::uint16_t idx[12] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};
  std::vector<unsigned char> bin(48 + 24);
  std::memcpy(bin.data(), pos, 48);
  std::memcpy(bin.data() + 48, idx, 24);
  json j;
  j["asset"] = {{"version", "2.0"}};
  j["buffers"] =
      json::array({{{"byteLength", bin.size()}, {"uri", "data:application/octet-stream;base64," + base64(bin)}}});
  j["bufferViews"] =
      json::array({{{"buffer", 0}, {"byteLength", 48}}, {{"buffer", 0}, {"byteOffset", 48}, {"byteLength", 24}}});
  j["accessors"] = json::array({{{"bufferView", 0},
                                 {"componentType", 5126},
                                 {"count", 4},
                                 {"type", "VEC3"},
                                 {"min", {0, 0, 0}},
                                 {"max", {2, 1, 3}}},
                                {{"bufferView", 1}, {"componentType", 5123}, {"count", 12}, {"type", "SCALAR"}}});
  j["meshes"] = json::array({{{"primitives", json::array({{{"attributes", {{"POSITION", 0}}}, {"indices", 1}}})}}});
  j["nodes"] = nodes;
  j["scenes"] = json::array({{{"nodes", scene_nodes}}});
  j["scene"] = 0;
  return j;
}

std::string write_temp(const std::string& name, const std::string& text) {
  const auto path = fs::temp_directory_path() / ("cullpipe_gltf_" + std::to_string(::getpid()) + "_" + name);
  std::ofstream(path) << text;
  return path.string();
}

std::string load_error(const std::string& name, const json& j, const GltfSceneOptions& o = {}) {
  try {
    load_gltf_scene(write_temp(name, j.dump()), o);
  } catch (const InputError& e) {
    const std::string m = e.what();
    const auto at = m.find(name);
    return at == std::string::npos ? "message without the file name: " + m : m.substr(at);
  }
  return "no error";
}

TEST(GltfScene, HierarchyMirroringAndSharedMeshes) {
  // Root: translate (10,0,0), rotate 90 degrees about +y; children: the mesh mirrored in x and
  // scaled non-uniformly, and the same mesh plain. Node 3 has scale 0 (draws nothing).
  const double s = std::sqrt(0.5);
  const json nodes = json::array({{{"translation", {10, 0, 0}}, {"rotation", {0, s, 0, s}}, {"children", {1, 2, 3}}},
                                  {{"mesh", 0}, {"scale", {-1, 2, 1}}},
                                  {{"mesh", 0}, {"matrix", {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 5, 0, 1}}},
                                  {{"mesh", 0}, {"scale", {0, 0, 0}}}});
  const std::string path = write_temp("tree.gltf", tetra_gltf(nodes, {0}).dump());
  const GltfScene g = load_gltf_scene(path);
  ASSERT_EQ(g.scene.objects.size(), 2u);
  EXPECT_EQ(g.zero_scale_instances, 1u);
  EXPECT_EQ(g.scene.objects[0].mesh, g.scene.objects[1].mesh);  // one MeshBounds for both
  EXPECT_EQ(g.scene.objects[0].origin, (ObjectOrigin{1, 0, 0, 0}));
  EXPECT_EQ(g.scene.objects[1].origin, (ObjectOrigin{2, 0, 0, 0}));
  // Known answers. Rotation of 90 degrees about y maps (x,y,z) to (z,y,-x).
  // Object 0: local (x,y,z) -> scaled (-x, 2y, z) -> rotated (z, 2y, x) -> +(10,0,0).
  // Vertices (0,0,0) (2,0,0) (0,1,0) (0,0,3) -> (10,0,0) (10,0,2) (10,2,0) (13,0,0).
  // (The quaternion's matrix has 1e-16 where 0 is exact: compare to 1e-6.)
  auto near = [](const glm::vec3& a, const glm::vec3& b) { return glm::length(a - b) < 1e-6f; };
  const Aabb a0 = world_aabbs(g.scene, bounds::AabbUpdate::Recompute)[0];
  EXPECT_TRUE(near(a0.min, glm::vec3(10, 0, 0)) && near(a0.max, glm::vec3(13, 2, 2))) << a0.min.z << " " << a0.max.x;
  // Object 1: local + (0,5,0) -> rotated (z, y+5, -x) -> +(10,0,0): (10,5,0) (10,5,-2) (10,6,0) (13,5,0).
  const Aabb a1 = world_aabbs(g.scene, bounds::AabbUpdate::Recompute)[1];
  EXPECT_TRUE(near(a1.min, glm::vec3(10, 5, -2)) && near(a1.max, glm::vec3(13, 6, 0)));
  EXPECT_LT(glm::determinant(glm::mat3(g.scene.objects[0].world)), 0.0f);
  // Every method and volume encloses the known world vertices.
  const std::vector<std::vector<glm::vec3>> verts = {{{10, 0, 0}, {10, 0, 2}, {10, 2, 0}, {13, 0, 0}},
                                                     {{10, 5, 0}, {10, 5, -2}, {10, 6, 0}, {13, 5, 0}}};
  for (bounds::AabbUpdate m : {bounds::AabbUpdate::Recompute, bounds::AabbUpdate::HullRecompute,
                               bounds::AabbUpdate::TransformBox, bounds::AabbUpdate::HillClimb}) {
    const std::vector<Aabb> boxes = world_aabbs(g.scene, m);
    for (std::size_t i = 0; i < 2; ++i)
      for (const glm::vec3& v : verts[i]) EXPECT_TRUE(box_contains(boxes[i], v)) << bounds::to_string(m) << " " << i;
  }
  const std::vector<Obb> obbs = world_obbs(g.scene);
  const std::vector<Sphere> spheres = world_spheres(g.scene);
  for (std::size_t i = 0; i < 2; ++i)
    for (const glm::vec3& v : verts[i]) {
      EXPECT_LE(glm::length(glm::dvec3(v) - glm::dvec3(spheres[i].center)), double(spheres[i].radius) * (1 + 1e-6));
      for (int k = 0; k < 3; ++k)
        EXPECT_LE(std::abs(glm::dot(glm::dvec3(v) - glm::dvec3(obbs[i].center), glm::dvec3(obbs[i].basis[k]))),
                  double(obbs[i].half_extents[k]) * (1 + 1e-6) + 1e-6);
    }
}

TEST(GltfScene, SphereTransformIsTightForUniformScaleAndEnclosesForNonUniform) {
  const Sphere s{{1, 2, 3}, 2.0f};
  glm::mat4 m(3.0f);  // uniform scale 3
  m[3] = glm::vec4(1, 1, 1, 1);
  const Sphere t = bounds::transform_sphere(s, m);
  EXPECT_EQ(t.center, glm::vec3(4, 7, 10));
  EXPECT_GE(t.radius, 6.0f);
  EXPECT_LE(t.radius, 6.0f * (1 + 2e-6f));
  // Non-uniform: the longest axis wins, whatever the rotation.
  glm::mat4 n =
      glm::mat4(glm::mat3_cast(glm::angleAxis(0.7f, glm::normalize(glm::vec3(1, 2, 3))))) *
      glm::mat4(glm::vec4(1, 0, 0, 0), glm::vec4(0, 5, 0, 0), glm::vec4(0, 0, 0.5f, 0), glm::vec4(0, 0, 0, 1));
  const Sphere u = bounds::transform_sphere(s, n);
  EXPECT_GE(u.radius, 10.0f);
  EXPECT_LE(u.radius, 10.0f * (1 + 2e-6f));
}

TEST(GltfScene, MalformedFilesNameTheFileAndTheElement) {
  const json ok_nodes = json::array({{{"mesh", 0}}});
  json j = tetra_gltf(ok_nodes, {0});
  EXPECT_EQ(load_error("ok.gltf", j), "no error");

  json cycle = tetra_gltf(json::array({{{"mesh", 0}, {"children", {1}}}, {{"children", {0}}}}), {0});
  EXPECT_EQ(load_error("cycle.gltf", cycle), "cycle.gltf: nodes[0] is its own ancestor (a cycle in the node graph)");
  json self = tetra_gltf(json::array({{{"mesh", 0}, {"children", {0}}}}), {0});
  EXPECT_EQ(load_error("self.gltf", self), "self.gltf: nodes[0] is its own child (a cycle in the node graph)");
  json two = tetra_gltf(json::array({{{"children", {2}}}, {{"children", {2}}}, {{"mesh", 0}}}), {0, 1});
  EXPECT_EQ(load_error("two.gltf", two), "two.gltf: nodes[2] has two parents: nodes[0] and nodes[1]");
  json child = tetra_gltf(json::array({{{"children", {1}}}, {{"mesh", 0}}}), {0, 1});
  EXPECT_EQ(load_error("child.gltf", child),
            "child.gltf: scenes[0].nodes: nodes[1] is not a root (it is a child of nodes[0])");
  json missing_child = tetra_gltf(json::array({{{"children", {5}}}}), {0});
  EXPECT_EQ(load_error("kid.gltf", missing_child), "kid.gltf: nodes[0].children lists node 5, which does not exist");

  json bad_index = tetra_gltf(ok_nodes, {0});
  {  // index 12 > 3 vertices: rewrite the buffer with a bad index
    const float pos[12] = {0, 0, 0, 2, 0, 0, 0, 1, 0, 0, 0, 3};
    const std::uint16_t idx[12] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 12};
    std::vector<unsigned char> bin(72);
    std::memcpy(bin.data(), pos, 48);
    std::memcpy(bin.data() + 48, idx, 24);
    bad_index["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64(bin);
  }
  EXPECT_EQ(load_error("idx.gltf", bad_index),
            "idx.gltf: meshes[0].primitives[0]: index accessor 1 element 11 is 12, past the 4 vertices");
  json float_index = j;
  float_index["accessors"][1]["componentType"] = 5126;
  EXPECT_EQ(load_error("fidx.gltf", float_index),
            "fidx.gltf: meshes[0].primitives[0]: index accessor 1 has component type 5126, not UNSIGNED_BYTE, "
            "UNSIGNED_SHORT or UNSIGNED_INT");
  json short_pos = j;
  short_pos["accessors"][0]["componentType"] = 5123;
  EXPECT_NE(load_error("spos.gltf", short_pos)
                .find("spos.gltf: meshes[0].primitives[0]: POSITION accessor 0 has component type 5123"),
            std::string::npos);
  json absurd = j;
  absurd["accessors"][0]["count"] = 4000000000u;
  EXPECT_EQ(load_error("absurd.gltf", absurd),
            "absurd.gltf: meshes[0].primitives[0]: POSITION accessor 0 reads past its buffer view");
  json past = j;
  past["accessors"][1]["count"] = 13;
  EXPECT_EQ(load_error("past.gltf", past),
            "past.gltf: meshes[0].primitives[0]: index accessor 1 reads past its buffer view");
  json no_acc = j;
  no_acc["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = 9;
  EXPECT_NE(load_error("noacc.gltf", no_acc).find("noacc.gltf"), std::string::npos);
  json no_mesh = tetra_gltf(json::array({{{"mesh", 3}}}), {0});
  EXPECT_NE(load_error("nomesh.gltf", no_mesh).find("nomesh.gltf"), std::string::npos);
  json bad_matrix =
      tetra_gltf(json::array({{{"mesh", 0}, {"matrix", {1, 0, 0, 1, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1}}}}), {0});
  EXPECT_EQ(load_error("proj.gltf", bad_matrix),
            "proj.gltf: nodes[0]: matrix is not affine (its last row must be 0 0 0 1)");
  json zero_q = tetra_gltf(json::array({{{"mesh", 0}, {"rotation", {0, 0, 0, 0}}}}), {0});
  EXPECT_EQ(load_error("zq.gltf", zero_q), "zq.gltf: nodes[0]: rotation is the zero quaternion");
  json truncated = j;
  truncated["buffers"][0]["byteLength"] = 200;  // more than the data holds
  EXPECT_NE(load_error("trunc.gltf", truncated).find("trunc.gltf"), std::string::npos);
  json missing_bin = j;
  missing_bin["buffers"][0]["uri"] = "no-such-file.bin";
  EXPECT_NE(load_error("nobin.gltf", missing_bin).find("nobin.gltf"), std::string::npos);
  json draco = j;
  draco["extensionsRequired"] = {"KHR_draco_mesh_compression"};
  draco["extensionsUsed"] = {"KHR_draco_mesh_compression"};
  EXPECT_NE(load_error("draco.gltf", draco).find("draco.gltf: requires extension KHR_draco_mesh_compression"),
            std::string::npos);
  GltfSceneOptions o;
  o.scene = 3;
  EXPECT_EQ(load_error("scene.gltf", j, o), "scene.gltf: scene 3 does not exist (the file has 1 scenes)");
  o = {};
  o.camera = "front";
  EXPECT_EQ(load_error("cam.gltf", j, o), "cam.gltf: no camera \"front\"; the file has no cameras");
  json nan = j;
  {
    const float pos[12] = {0, 0, 0, NAN, 0, 0, 0, 1, 0, 0, 0, 3};
    const std::uint16_t idx[12] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};
    std::vector<unsigned char> bin(72);
    std::memcpy(bin.data(), pos, 48);
    std::memcpy(bin.data() + 48, idx, 24);
    nan["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64(bin);
  }
  EXPECT_EQ(load_error("nan.gltf", nan),
            "nan.gltf: meshes[0].primitives[0]: POSITION accessor 0 vertex 1 has a NaN or infinite coordinate");
  EXPECT_EQ(load_error("trunc2.gltf", json::parse(R"({"asset":{"version":"2.0"}})")), "no error");  // empty but valid
  EXPECT_THROW(load_gltf_scene("/nonexistent/scene.gltf"), InputError);
}

// A .glb file: header, the JSON chunk (padded with spaces) and a BIN chunk.
std::string glb_bytes(const json& j, const std::string& bin) {
  std::string text = j.dump();
  while (text.size() % 4) text += ' ';
  auto u32 = [](std::uint32_t v) {
    return std::string(reinterpret_cast<const char*>(&v), 4);
  };  // little endian (x86, arm64)
  const std::uint32_t total = std::uint32_t(12 + 8 + text.size() + 8 + bin.size());
  return "glTF" + u32(2) + u32(total) + u32(std::uint32_t(text.size())) + u32(0x4E4F534Au) + text +
         u32(std::uint32_t(bin.size())) + u32(0x004E4942u) + bin;
}

TEST(GltfScene, GlbWhoseBufferIsEmptyIsAnErrorNamingTheFile) {
  // A buffer of byteLength 0 with a BIN chunk: tinygltf's checks let it through and it then
  // indexes an empty vector (std::out_of_range); found by fuzz_gltf. Both readers must report
  // the file as unreadable.
  const std::string path = write_temp(
      "zerobuf.glb",
      glb_bytes(json::parse(R"({"asset":{"version":"2.0"},"buffers":[{"byteLength":0}]})"), std::string(4, '\0')));
  for (int reader = 0; reader < 2; ++reader) {
    try {
      if (reader == 0)
        load_gltf_scene(path);
      else
        load_gltf_mesh_points(path);
      ADD_FAILURE() << "no error from reader " << reader;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(path + ": not a readable glTF file"), std::string::npos) << e.what();
    }
  }
  // The same file with a buffer of the chunk's size loads.
  const std::string fine = write_temp(
      "fourbuf.glb",
      glb_bytes(json::parse(R"({"asset":{"version":"2.0"},"buffers":[{"byteLength":4}]})"), std::string(4, '\0')));
  EXPECT_NO_THROW(load_gltf_scene(fine));
}

TEST(GltfScene, OrthographicAndPerspectiveCameras) {
  json j = tetra_gltf(
      json::array(
          {{{"mesh", 0}}, {{"camera", 0}, {"translation", {0, 0, 10}}}, {{"camera", 1}, {"translation", {0, 0, 10}}}}),
      {0, 1, 2});
  j["cameras"] = json::array(
      {{{"type", "perspective"},
        {"name", "persp"},
        {"perspective", {{"yfov", 0.8}, {"znear", 0.5}, {"zfar", 100}, {"aspectRatio", 1.5}}}},
       {{"type", "orthographic"}, {"orthographic", {{"xmag", 4}, {"ymag", 2}, {"znear", 0}, {"zfar", 50}}}}});
  const std::string path = write_temp("cams.gltf", j.dump());
  GltfSceneOptions o;
  o.camera = "persp";
  const Camera p = load_gltf_scene(path, o).scene.camera;
  EXPECT_EQ(p.eye, glm::vec3(0, 0, 10));
  EXPECT_EQ(p.target, glm::vec3(0, 0, 9));
  EXPECT_FLOAT_EQ(p.aspect, 1.5f);
  EXPECT_FALSE(p.orthographic);
  o.camera = "1";
  const Camera q = load_gltf_scene(path, o).scene.camera;
  EXPECT_TRUE(q.orthographic);
  EXPECT_FLOAT_EQ(q.ortho_half_height, 2.0f);
  EXPECT_FLOAT_EQ(q.aspect, 2.0f);
  // The orthographic frustum is the box x in [-4, 4], y in [-2, 2], depth 0..50 in front of the eye.
  const Frustum f = Frustum::from_view_proj(q.view_proj());
  EXPECT_TRUE(in_frustum(f, glm::vec3(3.9f, 1.9f, 9.0f)));
  EXPECT_TRUE(in_frustum(f, glm::vec3(-3.9f, -1.9f, -39.0f)));
  EXPECT_FALSE(in_frustum(f, glm::vec3(4.1f, 0.0f, 0.0f)));
  EXPECT_FALSE(in_frustum(f, glm::vec3(0.0f, 2.1f, 0.0f)));
  EXPECT_FALSE(in_frustum(f, glm::vec3(0.0f, 0.0f, 10.5f)));
  EXPECT_FALSE(in_frustum(f, glm::vec3(0.0f, 0.0f, -40.5f)));
  json bad = j;
  bad["cameras"][0]["perspective"]["yfov"] = 4.0;
  o.camera = "persp";
  EXPECT_EQ(load_error("badcam.gltf", bad, o), "badcam.gltf: cameras[0] (\"persp\") yfov must be between 0 and pi");
}

// Moving objects: each frame's world AABBs by every update method enclose the exact ones, and
// hill climbing kept from frame to frame (climb_state) gives the same boxes as starting over.
TEST(GltfScene, MovingObjectsKeepTheirAabbsByTheChosenMethod) {
  if (!fs::exists(kScenes / "CesiumMilkTruck" / "CesiumMilkTruck.gltf")) GTEST_SKIP() << "CesiumMilkTruck not present";
  Scene scene = load_gltf_scene((kScenes / "CesiumMilkTruck" / "CesiumMilkTruck.gltf").string()).scene;
  const std::vector<glm::mat4> base = [&] {
    std::vector<glm::mat4> w;
    for (const SceneObject& o : scene.objects) w.push_back(o.world);
    return w;
  }();
  std::vector<bounds::AabbTracker::Extremes> climb_state;
  for (int frame = 0; frame < 40; ++frame) {
    const glm::mat4 spin =
        glm::mat4(glm::mat3_cast(glm::angleAxis(0.05f * float(frame), glm::normalize(glm::vec3(0.3f, 1.0f, 0.2f)))));
    for (std::size_t i = 0; i < scene.objects.size(); ++i) scene.objects[i].world = spin * base[i];
    const std::vector<Aabb> exact = world_aabbs(scene, bounds::AabbUpdate::Recompute);
    const std::vector<Aabb> kept = world_aabbs(scene, bounds::AabbUpdate::HillClimb, &climb_state);
    const std::vector<Aabb> fresh = world_aabbs(scene, bounds::AabbUpdate::HillClimb);
    const std::vector<Aabb> hull = world_aabbs(scene, bounds::AabbUpdate::HullRecompute);
    ASSERT_EQ(climb_state.size(), scene.objects.size());
    for (std::size_t i = 0; i < exact.size(); ++i) {
      EXPECT_EQ(kept[i], fresh[i]) << "frame " << frame << " object " << i;
      const float slack = 1e-9f * (glm::length(exact[i].extent()) + glm::length(exact[i].center()));
      for (int k = 0; k < 3; ++k) {
        EXPECT_LE(kept[i].min[k], exact[i].min[k] + slack);
        EXPECT_GE(kept[i].max[k], exact[i].max[k] - slack);
        EXPECT_LE(hull[i].min[k], exact[i].min[k] + slack);
        EXPECT_GE(hull[i].max[k], exact[i].max[k] - slack);
      }
    }
  }
}

TEST(Replicate, CopiesShareMeshesAndKeepTheirOrigin) {
  const json nodes = json::array({{{"mesh", 0}}});
  const GltfScene g = load_gltf_scene(write_temp("one.gltf", tetra_gltf(nodes, {0}).dump()));
  for (InstanceLayout layout : {InstanceLayout::Grid, InstanceLayout::Random}) {
    const Scene big = replicate_scene(g.scene, 1000, layout, 7);
    ASSERT_EQ(big.objects.size(), 1000u);
    EXPECT_EQ(big.objects[999].origin.instance, 999);
    EXPECT_EQ(big.objects[999].mesh, g.scene.objects[0].mesh);
    // Copies do not overlap: their world boxes are disjoint in the grid layout.
    const std::vector<Aabb> boxes = world_aabbs(big);
    if (layout == InstanceLayout::Grid)
      for (std::size_t i = 1; i < boxes.size(); ++i) {
        const Aabb& a = boxes[i - 1];
        const Aabb& b = boxes[i];
        EXPECT_TRUE(a.max.x < b.min.x || b.max.x < a.min.x || a.max.z < b.min.z || b.max.z < a.min.z) << i;
      }
    EXPECT_EQ(replicate_scene(g.scene, 1000, layout, 7).objects[500].world, big.objects[500].world);  // deterministic
  }
  EXPECT_THROW(replicate_scene(g.scene, kMaxSceneObjects + 1, InstanceLayout::Grid, 1), InputError);
}

}  // namespace
}  // namespace cullpipe
