#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <glm/ext/matrix_transform.hpp>

#include "cull/reference.hpp"
#include "geom/validate.hpp"
#include "scene/cull_case_io.hpp"
#include "scene/generators.hpp"
#include "scene/point_io.hpp"
#include "scene/scene_io.hpp"

namespace cullpipe {
namespace {

bool same_scene(const Scene& a, const Scene& b) {
  if (a.name != b.name || !(a.camera == b.camera) || a.objects.size() != b.objects.size()) return false;
  for (std::size_t i = 0; i < a.objects.size(); ++i)
    if (!(a.objects[i].local_bounds == b.objects[i].local_bounds) || a.objects[i].world != b.objects[i].world)
      return false;
  return true;
}

TEST(Generators, DeterministicPerSeedAndSized) {
  for (SceneKind kind : {SceneKind::Uniform, SceneKind::Clustered, SceneKind::City}) {
    for (std::size_t n : {0u, 1u, 7u, 1000u}) {
      const Scene a = generate_scene(kind, n, 9), b = generate_scene(kind, n, 9);
      EXPECT_EQ(a.objects.size(), n);
      EXPECT_TRUE(same_scene(a, b)) << to_string(kind) << ":" << n;
      EXPECT_NO_THROW(validate(a, "generated"));
    }
    const Scene c = generate_scene(kind, 100, 1), d = generate_scene(kind, 100, 2);
    EXPECT_FALSE(same_scene(c, d)) << "different seeds give different scenes";
  }
}

TEST(Generators, DefaultCameraSeesPartOfTheScene) {
  for (SceneKind kind : {SceneKind::Uniform, SceneKind::Clustered, SceneKind::City}) {
    const Scene s = generate_scene(kind, 2000, 1);
    const Frustum f = Frustum::from_view_proj(s.camera.view_proj());
    const auto boxes = world_aabbs(s);
    std::vector<Classification> out(boxes.size());
    const auto counts = reference::classify_all(boxes, f, out);
    EXPECT_GT(counts.visible, boxes.size() / 20) << to_string(kind);
    EXPECT_LT(counts.visible, boxes.size()) << to_string(kind);
    EXPECT_GT(counts.inside, 0u);
    EXPECT_GT(counts.intersecting, 0u);
  }
}

TEST(Generators, ParseSpec) {
  EXPECT_EQ(parse_generate_spec("city:2000"), std::make_pair(SceneKind::City, std::size_t(2000)));
  EXPECT_EQ(parse_generate_spec("uniform:1e6"), std::make_pair(SceneKind::Uniform, std::size_t(1000000)));
  EXPECT_THROW(parse_generate_spec("town:5"), InputError);
  EXPECT_THROW(parse_generate_spec("city"), InputError);
  EXPECT_THROW(parse_generate_spec("city:-1"), InputError);
  EXPECT_THROW(parse_generate_spec("city:1.5"), InputError);
  EXPECT_THROW(parse_generate_spec("city:abc"), InputError);
}

TEST(Camera, PathCirclesTheSceneAndKeepsTheLens) {
  Camera base;
  base.eye = {10, 5, 0};
  base.target = {0, 0, 0};
  const auto path = camera_path(base, Aabb{{-1, -1, -1}, {1, 1, 1}}, 4);
  ASSERT_EQ(path.size(), 4u);
  for (const Camera& c : path) {
    EXPECT_NEAR(glm::length(glm::vec2(c.eye.x, c.eye.z)), 10.0f, 1e-4f);
    EXPECT_EQ(c.eye.y, 5.0f);
    EXPECT_EQ(c.fov_y_degrees, base.fov_y_degrees);
  }
  EXPECT_NEAR(path[2].eye.x, -10.0f, 1e-4f);
  EXPECT_EQ(camera_path(base, Aabb{}, 1).front(), base);
}

// Enclosure with no slack: every corner transformed exactly (in double) is inside each
// world volume, also measured in double.
void expect_world_volumes_enclose(const Scene& s) {
  const auto aabbs = world_aabbs(s);
  const auto obbs = world_obbs(s);
  const auto spheres = world_spheres(s);
  for (std::size_t i = 0; i < s.objects.size(); ++i) {
    ASSERT_EQ(invalid_reason(obbs[i]), "");
    ASSERT_EQ(invalid_reason(spheres[i]), "");
    const glm::dmat4 m(s.objects[i].world);
    for (const glm::vec3& c : s.objects[i].local_bounds.corners()) {
      const glm::dvec3 p = glm::dvec3(m * glm::dvec4(glm::dvec3(c), 1.0));
      for (int k = 0; k < 3; ++k) {
        ASSERT_LE(double(aabbs[i].min[k]), p[k]) << "object " << i;
        ASSERT_GE(double(aabbs[i].max[k]), p[k]) << "object " << i;
        ASSERT_LE(std::abs(glm::dot(p - glm::dvec3(obbs[i].center), glm::dvec3(obbs[i].basis[k]))),
                  double(obbs[i].half_extents[k]))
            << "object " << i;
      }
      ASSERT_LE(glm::length(p - glm::dvec3(spheres[i].center)), double(spheres[i].radius)) << "object " << i;
    }
  }
}

TEST(Camera, EveryDepthConventionGivesTheSameFrustumShape) {
  Camera base;
  base.eye = {0, 0, 10};
  base.target = {0, 0, 0};
  base.fov_y_degrees = 90.0f;
  base.aspect = 2.0f;
  base.near_plane = 1.0f;
  base.far_plane = 100.0f;
  // (point, inside the finite frustum?) -- camera looks down -z from z = 10.
  const std::vector<std::pair<glm::vec3, bool>> points = {
      {{0, 0, 0}, true},     {{0, 0, 9.5f}, false},  {{0, 0, 8.5f}, true}, {{0, 9.5f, 0}, true}, {{0, 10.5f, 0}, false},
      {{19.5f, 0, 0}, true}, {{20.5f, 0, 0}, false}, {{0, 0, -89}, true},  {{0, 0, -91}, false}, {{0, 0, 20}, false}};
  for (int variant = 0; variant < 4; ++variant) {
    Camera c = base;
    c.reversed_z = variant & 1;
    c.infinite_far = variant & 2;
    const Frustum f = Frustum::from_view_proj(c.view_proj());
    for (const auto& [p, inside] : points) {
      bool in = true;
      for (const Plane& pl : f.active()) in &= pl.distance(p) >= 0.0f;
      const bool beyond_far = p.z < -90.0f;  // only the finite far plane cuts it
      EXPECT_EQ(in, inside || (c.infinite_far && beyond_far)) << "variant " << variant << " point " << p.z;
    }
  }
}

TEST(World, VolumesEncloseTheTransformedBoxExactly) {
  for (SceneKind kind : {SceneKind::Uniform, SceneKind::Clustered, SceneKind::City}) {
    Scene s = generate_scene(kind, 3000, 4);
    // Add translation far from the origin and non-uniform scale.
    for (std::size_t i = 0; i < s.objects.size(); i += 3) {
      s.objects[i].world = glm::scale(s.objects[i].world, glm::vec3(0.3f, 2.0f, 1.7f));
      s.objects[i].world[3] += glm::vec4(1e4f, -3e3f, 7e3f, 0.0f);
    }
    expect_world_volumes_enclose(s);
  }
}

TEST(World, HugeScaleObjectsGetValidVolumes) {
  // A scale whose squared column length overflows float: volumes are built in double.
  Scene s;
  SceneObject o;
  o.local_bounds = {{-0.5f, -0.5f, -0.5f}, {0.5f, 0.5f, 0.5f}};
  o.world = glm::scale(glm::mat4(1.0f), glm::vec3(1e20f));
  o.world[3] = glm::vec4(2.5e20f, 0.0f, -1.5e20f, 1.0f);
  s.objects.push_back(o);
  EXPECT_NO_THROW(validate(s, "huge"));
  expect_world_volumes_enclose(s);
  const Obb b = world_obbs(s)[0];
  EXPECT_NEAR(b.half_extents.x, 0.5e20f, 1e14f);
  // Seen from the origin looking down -z, the object crosses the view: never OUTSIDE.
  Camera cam;
  cam.eye = glm::vec3(0);
  cam.target = glm::vec3(0, 0, -1);
  cam.far_plane = 1e30f;
  const Frustum f = Frustum::from_view_proj(cam.view_proj());
  EXPECT_NE(reference::classify(b, f), Classification::Outside);
  EXPECT_NE(reference::classify(world_aabbs(s)[0], f), Classification::Outside);
  EXPECT_NE(reference::classify(world_spheres(s)[0], f), Classification::Outside);
}

TEST(SceneIo, RoundTripsBitExact) {
  const Scene s = generate_scene(SceneKind::City, 50, 3);
  const Scene back = parse_scene(scene_to_json(s), "memory");
  EXPECT_TRUE(same_scene(s, back));
}

TEST(SceneIo, ErrorsNameTheFileAndElement) {
  auto error_of = [](const std::string& text) {
    try {
      parse_scene(text, "bad.json");
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(error_of("{").find("bad.json: invalid JSON"), std::string::npos);
  EXPECT_EQ(error_of(R"({"format":"x","version":1,"objects":[]})"), "bad.json: format: expected \"cullpipe-scene\"");
  EXPECT_NE(error_of(R"({"format":"cullpipe-scene","version":2,"objects":[]})").find("unsupported version 2"),
            std::string::npos);
  EXPECT_EQ(error_of(R"({"format":"cullpipe-scene","version":1,"objects":[{"min":[0,0],"max":[1,1,1]}]})"),
            "bad.json: objects[0].min: expected 3 numbers, got 2");
  EXPECT_EQ(error_of(R"({"format":"cullpipe-scene","version":1,"objects":[{"min":[0,0,0],"max":[1,1e39,1]}]})"),
            "bad.json: objects[0].max[1]: number out of float range");
  EXPECT_NE(error_of(R"({"format":"cullpipe-scene","version":1,"objects":[{"min":[0,0,0],"max":[1,1e999,1]}]})")
                .find("bad.json: invalid JSON: [json.exception.out_of_range.406] number overflow"),
            std::string::npos);
  EXPECT_EQ(error_of(R"({"format":"cullpipe-scene","version":1,"objects":[{"min":[0,0,0],"max":[1,"a",1]}]})"),
            "bad.json: objects[0].max[1]: expected a number, got string");
  EXPECT_EQ(error_of(R"({"format":"cullpipe-scene","version":1,"objects":[{"min":[2,0,0],"max":[1,1,1]}]})"),
            "bad.json: objects[0]: min.x > max.x");
  EXPECT_EQ(error_of(R"({"format":"cullpipe-scene","version":1,"objects":[{"min":[0,0,0],"max":[1,1,1],
              "world":[0,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]}]})"),
            "bad.json: objects[0]: world transform is singular");
  EXPECT_EQ(error_of(R"({"format":"cullpipe-scene","version":1,"objects":[{"min":[0,0,0],"max":[1,1,1],
              "world":[1e38,0,0,0, 0,1,0,0, 0,0,1,0, 3e38,0,0,1]}]})"),
            "bad.json: objects[0]: world-space bounds: max.x is infinite");
  EXPECT_EQ(
      error_of(
          R"({"format":"cullpipe-scene","version":1,"camera":{"eye":[0,0,1],"target":[0,0,0],"near":-1},"objects":[]})"),
      "bad.json: camera.near: must be positive");
  EXPECT_EQ(
      error_of(
          R"({"format":"cullpipe-scene","version":1,"camera":{"eye":[0,0,1],"target":[0,0,0],"reversed_z":"yes"},"objects":[]})"),
      "bad.json: camera.reversed_z: expected true or false, got string");
  EXPECT_THROW(load_scene("/nonexistent/scene.json"), InputError);
}

TEST(CullCaseIo, ParsesEveryVolumeFormAndRoundTrips) {
  const std::string text = R"({
    "frustum": {"planes": [[1,0,0,1],[-1,0,0,1],[0,1,0,1],[0,-1,0,1],[0,0,1,1],[0,0,-1,1]]},
    "volumes": [
      {"aabb": {"min": [-0.5,-0.5,-0.5], "max": [0.5,0.5,0.5]}},
      {"aabb": {"center": [2,0,0], "half_extents": [0.5,0.5,0.5]}},
      {"sphere": {"center": [1,0,0], "radius": 0.5}},
      {"obb": {"center": [0,0,0], "half_extents": [1,2,3], "axes": [[0,1,0],[-1,0,0],[0,0,1]]}}
    ]})";
  const CullCase c = parse_cull_case(text, "case.json");
  ASSERT_EQ(c.volumes.size(), 4u);
  EXPECT_EQ(std::get<Aabb>(c.volumes[1]), (Aabb{{1.5f, -0.5f, -0.5f}, {2.5f, 0.5f, 0.5f}}));
  EXPECT_EQ(std::get<Sphere>(c.volumes[2]).radius, 0.5f);
  EXPECT_EQ(std::get<Obb>(c.volumes[3]).basis[1], glm::vec3(-1, 0, 0));
  const std::vector<std::vector<Classification>> classes = {
      {Classification::Inside, Classification::Outside, Classification::Intersecting, Classification::Intersecting}};
  const std::string dumped = cull_case_to_json(c, &classes);
  EXPECT_NE(dumped.find("\"class\": \"outside\""), std::string::npos);
  const CullCase back = parse_cull_case(dumped, "dump.json");
  EXPECT_EQ(back.frusta, c.frusta);
  EXPECT_EQ(back.volumes, c.volumes);
}

TEST(CullCaseIo, RejectsBadInputNamingTheElement) {
  auto error_of = [](const std::string& volumes, const std::string& frustum = R"({"planes": [[1,0,0,1]]})") {
    try {
      parse_cull_case(R"({"frustum": )" + frustum + R"(, "volumes": )" + volumes + "}", "in.json");
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_EQ(error_of(R"([{"sphere": {"center": [0,0,0], "radius": -1}}])"),
            "in.json: volumes[0].sphere: radius is negative");
  EXPECT_EQ(error_of(R"([{"aabb": {"center": [0,0,0], "half_extents": [1,-1,1]}}])"),
            "in.json: volumes[0].aabb.half_extents: negative extent");
  EXPECT_EQ(error_of(R"([{"aabb": {"min": [0,0,0], "max": [-1,1,1]}}])"), "in.json: volumes[0].aabb: min.x > max.x");
  EXPECT_EQ(error_of(R"([{"cone": {}}])"), "in.json: volumes[0]: expected \"aabb\", \"obb\" or \"sphere\"");
  EXPECT_EQ(error_of(R"([{"obb": {"center": [0,0,0], "half_extents": [1,1,1], "axes": [[1,0,0],[1,0,0],[0,0,1]]}}])"),
            "in.json: volumes[0].obb: axes[0] and axes[1] are not orthogonal");
  EXPECT_EQ(error_of("[]", R"({"view_proj": [0,0,0,0, 0,0,0,0, 0,0,0,0, 0,0,0,0]})"),
            "in.json: frustum: view-projection matrix is singular (determinant 0)");
  EXPECT_EQ(error_of("[]", R"({"planes": [[0,0,0,1]]})"), "in.json: frustum: plane 0 has a zero normal");
  EXPECT_EQ(error_of("[]", R"({"planes": [[1,0,0,-1e39]]})"),
            "in.json: frustum.planes[0][3]: number out of float range");
  EXPECT_EQ(error_of("[]", R"({"nothing": 1})"), "in.json: frustum: expected \"planes\" or \"view_proj\"");
  EXPECT_NE(error_of("[", "").find("in.json: invalid JSON"), std::string::npos);
  EXPECT_EQ(error_of("{}"), "in.json: volumes: expected an array");
  EXPECT_EQ(error_of(R"([{"sphere": {"center": [0,0,0], "radius": 1}, "aabb": {"min": [0,0,0], "max": [1,1,1]}}])"),
            "in.json: volumes[0]: more than one of \"aabb\", \"obb\", \"sphere\" in one volume");
}

}  // namespace
}  // namespace cullpipe

namespace cullpipe {
namespace {

std::string write_temp(const std::string& name, const std::string& text) {
  const auto path =
      std::filesystem::temp_directory_path() / ("cullpipe_points_" + std::to_string(::getpid()) + "_" + name);
  std::ofstream(path) << text;
  return path.string();
}

// The message from the part naming the file on (the temp directory prefix removed), or a
// marker when the message does not name the file at all.
std::string from_name(const std::string& message, const std::string& name) {
  const auto at = message.find(name);
  return at == std::string::npos ? "message without the file name: " + message : message.substr(at);
}

std::string points_error(const std::string& name, const std::string& text) {
  try {
    load_points(write_temp(name, text));
  } catch (const InputError& e) {
    return from_name(e.what(), name);
  }
  return "no error";
}

TEST(PointIo, ReadsTextOffAndObj) {
  const auto txt = load_points(write_temp("a.txt", "# comment\n1 2 3\n\n  -4.5 5e-1 6  \n7 8 9 # trailing\n"));
  EXPECT_EQ(txt, (std::vector<glm::vec3>{{1, 2, 3}, {-4.5f, 0.5f, 6}, {7, 8, 9}}));
  const auto off = load_points(write_temp("b.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"));
  EXPECT_EQ(off.size(), 3u);
  const auto obj = load_points(write_temp("c.obj", "# obj\no thing\nv 1 2 3\nvn 0 0 1\nv 4 5 6 1.0\nf 1 2 1\n"));
  EXPECT_EQ(obj, (std::vector<glm::vec3>{{1, 2, 3}, {4, 5, 6}}));
}

TEST(PointIo, BadFilesNameTheLine) {
  EXPECT_EQ(points_error("d.txt", "1 2 3\n1 2\n"), "d.txt:2: expected three coordinates");
  EXPECT_EQ(points_error("e.txt", "1 2 nan\n"), "e.txt:1: 'nan' is not finite");
  EXPECT_EQ(points_error("f.txt", "1 2 1e39\n"), "f.txt:1: '1e39' is out of float range");
  EXPECT_EQ(points_error("g.txt", "1 2 x\n"), "g.txt:1: 'x' is not a number");
  EXPECT_EQ(points_error("h.txt", "1 2 3 4\n"), "h.txt:1: more than three numbers on a line");
  EXPECT_EQ(points_error("i.txt", "# nothing\n\n"), "i.txt: no points");
  EXPECT_EQ(points_error("j.off", "OFF\n5 0 0\n0 0 0\n"), "j.off: file ends before all 5 vertices");
  EXPECT_EQ(points_error("k.off", "PLY\n"), "k.off:1: expected the OFF header");
  EXPECT_THROW(load_points("/nonexistent/points.txt"), InputError);
}

}  // namespace
}  // namespace cullpipe

#include "bounds/sphere_fit.hpp"
#include "scene/gltf_points.hpp"

namespace cullpipe {
namespace {

const std::filesystem::path kScenes = std::filesystem::path(CULLPIPE_SHARED_DIR) / "scenes";

TEST(GltfPoints, RealScenesMatchTheirDeclaredBounds) {
  if (!std::filesystem::exists(kScenes)) GTEST_SKIP() << kScenes << " not present";
  std::size_t meshes = 0;
  for (const auto& dir : std::filesystem::directory_iterator(kScenes)) {
    if (!dir.is_directory()) continue;
    for (const auto& file : std::filesystem::directory_iterator(dir.path())) {
      const std::string ext = file.path().extension().string();
      if (ext != ".gltf" && ext != ".glb") continue;
      SCOPED_TRACE(file.path().string());
      for (const GltfMeshPoints& m : load_gltf_mesh_points(file.path().string())) {
        ++meshes;
        ASSERT_FALSE(m.positions.empty());
        ASSERT_TRUE(m.declared_bounds.has_value());
        const Aabb b = bounds::aabb_of_points(m.positions);
        const float scale = glm::length(m.declared_bounds->extent()) + 1e-30f;
        for (int k = 0; k < 3; ++k) {  // exporters print min/max in decimal: 1e-6 relative
          EXPECT_NEAR(b.min[k], m.declared_bounds->min[k], 1e-6f * scale) << m.name;
          EXPECT_NEAR(b.max[k], m.declared_bounds->max[k], 1e-6f * scale) << m.name;
        }
      }
    }
  }
  EXPECT_GT(meshes, 200u);  // 263 meshes in the shipped set
}

std::string gltf_error(const std::string& name, const std::string& text) {
  try {
    load_gltf_mesh_points(write_temp(name, text));
  } catch (const InputError& e) {
    return from_name(e.what(), name);
  }
  return "no error";
}

// A one-triangle glTF with its buffer inline (base64 of three float3 positions: 36 bytes).
std::string triangle_gltf(const std::string& accessor_patch, std::size_t byte_length = 36) {
  // (0,0,0) (1,0,0) (0,1,0) as little-endian floats
  const std::string b64 = "AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA";
  return R"({"asset":{"version":"2.0"},"buffers":[{"byteLength":36,"uri":"data:application/octet-stream;base64,)" +
         b64 + R"("}],"bufferViews":[{"buffer":0,"byteLength":)" + std::to_string(byte_length) +
         R"(}],"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",)" + accessor_patch +
         R"("min":[0,0,0],"max":[1,1,0]}],"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}]})";
}

TEST(GltfPoints, ReadsAMinimalFileAndRejectsBrokenOnes) {
  const auto good = load_gltf_mesh_points(write_temp("ok.gltf", triangle_gltf("")));
  ASSERT_EQ(good.size(), 1u);
  EXPECT_EQ(good[0].positions, (std::vector<glm::vec3>{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}));
  EXPECT_NE(gltf_error("trunc.gltf", triangle_gltf("").substr(0, 100)).find("trunc.gltf: not a readable glTF file"),
            std::string::npos);
  EXPECT_NE(gltf_error("offset.gltf", triangle_gltf(R"("byteOffset":12,)"))
                .find("POSITION accessor 0 reads past its buffer view"),
            std::string::npos);
  EXPECT_NE(
      gltf_error("type.gltf", triangle_gltf("").replace(triangle_gltf("").find("5126"), 4, "5123")).find("not FLOAT"),
      std::string::npos);
  EXPECT_EQ(gltf_error("missing.gltf", "{}").find("missing.gltf"), 0u);
  // Offsets near 2^64 must not wrap the range checks into an out-of-bounds read.
  std::string wrap_view = triangle_gltf("");
  wrap_view.replace(wrap_view.find(R"("buffer":0,)"), 11, R"("buffer":0,"byteOffset":18446744073709551615,)");
  EXPECT_NE(gltf_error("wrap1.gltf", wrap_view).find("reads past"), std::string::npos)
      << gltf_error("wrap1.gltf", wrap_view);
  EXPECT_NE(gltf_error("wrap2.gltf", triangle_gltf(R"("byteOffset":18446744073709551604,)")).find("reads past"),
            std::string::npos);
  EXPECT_NE(
      gltf_error("count.gltf", triangle_gltf("").replace(triangle_gltf("").find(R"("count":3)"), 9, R"("count":4)"))
          .find("reads past"),
      std::string::npos);
  EXPECT_THROW(load_gltf_mesh_points("/nonexistent/model.gltf"), InputError);
}

}  // namespace
}  // namespace cullpipe
