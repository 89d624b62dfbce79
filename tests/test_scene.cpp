#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <glm/ext/matrix_transform.hpp>

#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/validate.hpp"
#include "cullpipe/scene/cull_case_io.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/point_io.hpp"
#include "cullpipe/scene/scene_io.hpp"

namespace cullpipe {
namespace {

bool same_scene(const Scene& a, const Scene& b) {
  if (a.name != b.name || !(a.camera == b.camera) || a.path != b.path || a.objects.size() != b.objects.size())
    return false;
  for (std::size_t i = 0; i < a.objects.size(); ++i)
    if (!(a.objects[i].local_bounds == b.objects[i].local_bounds) || a.objects[i].world != b.objects[i].world)
      return false;
  return true;
}

TEST(Generators, DeterministicPerSeedAndSized) {
  for (SceneKind kind : {SceneKind::Uniform, SceneKind::Clustered, SceneKind::City, SceneKind::Streets}) {
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
  for (SceneKind kind : {SceneKind::Uniform, SceneKind::Clustered, SceneKind::City, SceneKind::Streets}) {
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
  EXPECT_EQ(parse_generate_spec("streets:10000"), std::make_pair(SceneKind::Streets, std::size_t(10000)));
}

// Distance in x-z from `p` to the footprint of `box`.
float ground_distance(const glm::vec3& p, const Aabb& box) {
  const float dx = std::max({box.min.x - p.x, 0.0f, p.x - box.max.x});
  const float dz = std::max({box.min.z - p.z, 0.0f, p.z - box.max.z});
  return std::sqrt(dx * dx + dz * dz);
}

// Does the segment from `from` along unit `dir` for `length` enter `box`? (slab test)
bool segment_hits(const glm::vec3& from, const glm::vec3& dir, float length, const Aabb& box) {
  float t0 = 0.0f, t1 = length;
  for (int k = 0; k < 3; ++k) {
    if (dir[k] == 0.0f) {
      if (from[k] < box.min[k] || from[k] > box.max[k]) return false;
      continue;
    }
    float a = (box.min[k] - from[k]) / dir[k], b = (box.max[k] - from[k]) / dir[k];
    if (a > b) std::swap(a, b);
    t0 = std::max(t0, a);
    t1 = std::min(t1, b);
  }
  return t0 <= t1;
}

TEST(Generators, StreetsHaveExactlyNBuildingsOnLots) {
  for (std::size_t n : {0u, 1u, 2u, 7u, 8u, 9u, 100u, 1000u, 12345u}) {
    const Scene s = generate_scene(SceneKind::Streets, n, 5);
    EXPECT_EQ(s.objects.size(), n);
    EXPECT_EQ(street_lots(n).size(), n);
    EXPECT_FALSE(s.path.empty()) << n;
  }
  // The city is about as wide as deep and grows with N at constant density.
  for (std::size_t n : {1000u, 100000u}) {
    const glm::vec3 e = generate_scene(SceneKind::Streets, n, 1).bounds().extent();
    EXPECT_GT(e.x / e.z, 0.75f) << n;
    EXPECT_LT(e.x / e.z, 1.33f) << n;
    EXPECT_NEAR(e.x * e.z / float(n), 300.0f, 60.0f) << n;
  }
}

TEST(Generators, StreetBuildingsStayInTheirLotsWithoutOverlap) {
  for (std::uint64_t seed : {1u, 2u}) {
    const std::size_t n = 5000;
    const Scene s = generate_scene(SceneKind::Streets, n, seed);
    const std::vector<Aabb> boxes = world_aabbs(s), lots = street_lots(n);
    std::size_t turned = 0, towers = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const Aabb& b = boxes[i];
      EXPECT_GE(b.min.x, lots[i].min.x + 0.2f) << i;
      EXPECT_LE(b.max.x, lots[i].max.x - 0.2f) << i;
      EXPECT_GE(b.min.z, lots[i].min.z + 0.2f) << i;
      EXPECT_LE(b.max.z, lots[i].max.z - 0.2f) << i;
      EXPECT_EQ(b.min.y, 0.0f) << i;
      EXPECT_GE(b.max.y, 8.0f) << i;
      EXPECT_LE(b.max.y, 120.0f) << i;
      turned += s.objects[i].world[0][2] != 0.0f;
      towers += b.max.y > 40.0f;
    }
    EXPECT_GT(turned, n / 50);
    EXPECT_LT(turned, n / 5);
    EXPECT_GT(towers, n / 100);
    EXPECT_LT(towers, n / 10);
    // Footprints pairwise disjoint, lots too: sweep along x.
    for (const std::vector<Aabb>* set : {&boxes, &lots}) {
      std::vector<std::size_t> order(n);
      for (std::size_t i = 0; i < n; ++i) order[i] = i;
      std::sort(order.begin(), order.end(),
                [&](std::size_t a, std::size_t b) { return (*set)[a].min.x < (*set)[b].min.x; });
      std::size_t overlaps = 0;
      for (std::size_t a = 0; a < n; ++a) {
        const Aabb& p = (*set)[order[a]];
        for (std::size_t b = a + 1; b < n && (*set)[order[b]].min.x < p.max.x; ++b) {
          const Aabb& q = (*set)[order[b]];
          overlaps += q.min.z < p.max.z && p.min.z < q.max.z;
        }
      }
      EXPECT_EQ(overlaps, 0u) << (set == &boxes ? "buildings" : "lots");
    }
  }
}

TEST(Generators, StreetCamerasStandInTheStreets) {
  for (std::size_t n : {0u, 1u, 30u, 5000u}) {
    const Scene s = generate_scene(SceneKind::Streets, n, 3);
    const std::vector<Aabb> boxes = world_aabbs(s), lots = street_lots(n);
    ASSERT_GE(s.path.size(), 2u);
    EXPECT_EQ(s.camera, s.path.front());
    EXPECT_EQ(s.path.front(), s.path.back()) << "a closed loop";
    EXPECT_LE(s.camera.near_plane, 0.1f);
    EXPECT_GE(s.camera.far_plane, glm::length(glm::vec2(s.bounds().extent().x, s.bounds().extent().z)));
    std::vector<Camera> cameras = s.path;
    const std::vector<Camera> sampled = scene_camera_path(s, 50);
    ASSERT_EQ(sampled.size(), 50u);
    cameras.insert(cameras.end(), sampled.begin(), sampled.end());
    for (const Camera& c : cameras) {
      EXPECT_NEAR(c.eye.y, 1.8f, 1e-5f);
      EXPECT_NEAR(c.target.y, 1.8f, 1e-5f);
      for (std::size_t i = 0; i < lots.size(); ++i) {
        ASSERT_GE(ground_distance(c.eye, lots[i]), 2.0f) << "lot " << i;
        ASSERT_GE(ground_distance(c.eye, boxes[i]), 2.0f) << "building " << i;
      }
      // No wall right ahead.
      const glm::vec3 dir = glm::normalize(c.target - c.eye);
      for (const Aabb& b : boxes) ASSERT_FALSE(segment_hits(c.eye, dir, 8.0f, b));
    }
    // The default camera looks along an open street.
    const glm::vec3 ahead = glm::normalize(s.camera.target - s.camera.eye);
    EXPECT_TRUE(ahead.x == 0.0f || ahead.z == 0.0f) << "along x or z";
    for (const Aabb& b : boxes) ASSERT_FALSE(segment_hits(s.camera.eye, ahead, 50.0f, b));
  }
}

TEST(Generators, StreetPathTurnsThroughCorners) {
  const Scene s = generate_scene(SceneKind::Streets, 10000, 1);
  const std::vector<Camera> walk = scene_camera_path(s, 1000);
  const float step = [&] {
    double length = 0.0;
    for (std::size_t k = 1; k < s.path.size(); ++k) length += glm::length(s.path[k].eye - s.path[k - 1].eye);
    return float(length / 1000.0);
  }();
  float most_turn = 0.0f, total_turn = 0.0f;
  for (std::size_t i = 0; i < walk.size(); ++i) {
    const Camera& a = walk[i];
    const Camera& b = walk[(i + 1) % walk.size()];
    EXPECT_LE(glm::length(b.eye - a.eye), step * 1.001f) << i;
    EXPECT_GE(glm::length(b.eye - a.eye), step * 0.7f) << i;
    const glm::vec3 da = glm::normalize(a.target - a.eye), db = glm::normalize(b.target - b.eye);
    const float turn = std::atan2(glm::length(glm::cross(da, db)), glm::dot(da, db));  // exact near 0
    most_turn = std::max(most_turn, turn);
    total_turn += turn;
  }
  EXPECT_LT(most_turn, glm::radians(6.0f)) << "the view turns gradually, never snaps";
  EXPECT_NEAR(total_turn, glm::radians(360.0f), glm::radians(1.0f)) << "one loop";
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

TEST(Camera, ScenePathWithoutKeyframesOrbits) {
  const Scene s = generate_scene(SceneKind::City, 300, 2);
  ASSERT_TRUE(s.path.empty());
  EXPECT_EQ(scene_camera_path(s, 7), camera_path(s.camera, s.bounds(), 7));
  EXPECT_EQ(scene_camera_path(s, 1), std::vector<Camera>{s.camera});
  EXPECT_TRUE(scene_camera_path(s, 0).empty());
}

TEST(Camera, ScenePathIsEvenByArcLength) {
  Scene s;
  s.camera.eye = {5, 5, 5};
  Camera k;
  k.eye = {0, 0, 0};
  k.target = {1, 0, 0};
  s.path = {k, k, k};
  s.path[1].eye = {10, 0, 0};
  s.path[1].target = {10, 0, 1};
  s.path[1].fov_y_degrees = 40.0f;
  s.path[2].eye = {10, 0, 30};
  s.path[2].target = {10, 0, 31};
  s.path[2].fov_y_degrees = 20.0f;
  EXPECT_EQ(scene_camera_path(s, 1), std::vector<Camera>{s.camera});
  // Open: 40 units in 4 steps of 10, ending on the last keyframe.
  const std::vector<Camera> open = scene_camera_path(s, 5);
  ASSERT_EQ(open.size(), 5u);
  EXPECT_EQ(open[0], s.path[0]);
  EXPECT_EQ(open[1].eye, glm::vec3(10, 0, 0));
  EXPECT_EQ(open[1].fov_y_degrees, 40.0f);
  EXPECT_EQ(open[2].eye, glm::vec3(10, 0, 10));
  EXPECT_NEAR(open[2].target.z, 11.0f, 1e-5f);
  EXPECT_EQ(open[2].fov_y_degrees, 40.0f) << "the lens of the keyframe before";
  EXPECT_EQ(open[4], s.path[2]);
  // Between keyframes, eye and target move linearly.
  const std::vector<Camera> fine = scene_camera_path(s, 9);
  EXPECT_EQ(fine[1].eye, glm::vec3(5, 0, 0));
  EXPECT_EQ(fine[1].target, glm::vec3(5.5f, 0, 0.5f));
  // Closed: back to the start, which is not repeated.
  s.path.push_back(s.path[0]);
  const std::vector<Camera> loop = scene_camera_path(s, 4);
  const float length = 10.0f + 30.0f + glm::length(glm::vec3(10, 0, 30));
  EXPECT_EQ(loop[0], s.path[0]);
  for (std::size_t i = 1; i < 4; ++i) {
    float along = 0.0f;  // the arc length of loop[i] from its segment's start
    if (loop[i].eye.z == 0.0f)
      along = loop[i].eye.x;
    else if (loop[i].eye.x == 10.0f)
      along = 10.0f + loop[i].eye.z;
    else
      along = 40.0f + glm::length(loop[i].eye - glm::vec3(10, 0, 30));
    EXPECT_NEAR(along, length * float(i) / 4.0f, 1e-3f) << i;
  }
  // Keyframes at one eye (turning on the spot) are spaced by index.
  Scene spot;
  spot.path = {k, k, k};
  spot.path[1].target = {0, 0, 1};
  spot.path[2].target = {-1, 0, 0};
  const std::vector<Camera> turn = scene_camera_path(spot, 5);
  EXPECT_EQ(turn[2], spot.path[1]);
  EXPECT_EQ(turn[4], spot.path[2]);
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
  for (SceneKind kind : {SceneKind::Uniform, SceneKind::Clustered, SceneKind::City, SceneKind::Streets}) {
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
  EXPECT_EQ(scene_to_json(s).find("\"path\""), std::string::npos) << "no path, no \"path\"";
}

TEST(SceneIo, KeepsTheCameraPath) {
  const Scene s = generate_scene(SceneKind::Streets, 200, 3);
  ASSERT_FALSE(s.path.empty());
  const Scene back = parse_scene(scene_to_json(s), "memory");
  EXPECT_EQ(back.path, s.path);
  EXPECT_TRUE(same_scene(s, back));
}

TEST(Generators, ReplicatingDropsThePath) {
  const Scene s = generate_scene(SceneKind::Streets, 100, 1);
  EXPECT_EQ(replicate_scene(s, 1, InstanceLayout::Grid, 1).path, s.path);
  const Scene many = replicate_scene(s, 4, InstanceLayout::Grid, 1);
  EXPECT_TRUE(many.path.empty());
  EXPECT_NE(many.camera, s.camera);
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
  const std::string camera = R"({"eye":[0,0,1],"target":[0,0,0]})";
  EXPECT_EQ(error_of(R"({"format":"cullpipe-scene","version":1,"path":{},"objects":[]})"),
            "bad.json: path: expected an array of cameras");
  EXPECT_EQ(error_of(R"({"format":"cullpipe-scene","version":1,"path":[)" + camera +
                     R"(,{"eye":[0,0],"target":[0,0,0]}],"objects":[]})"),
            "bad.json: path[1].eye: expected 3 numbers, got 2");
  EXPECT_EQ(error_of(R"({"format":"cullpipe-scene","version":1,"path":[)" + camera + "," + camera +
                     R"(,{"eye":[0,"NaN",1],"target":[0,0,0]}],"objects":[]})"),
            "bad.json: path[2].eye[1]: expected a number, got string");
  EXPECT_EQ(error_of(R"({"format":"cullpipe-scene","version":1,"path":[{"eye":[0,0,1]}],"objects":[]})"),
            "bad.json: path[0]: missing \"target\"");
  EXPECT_EQ(
      error_of(
          R"({"format":"cullpipe-scene","version":1,"path":[{"eye":[0,0,1],"target":[0,0,0],"far":0.01}],"objects":[]})"),
      "bad.json: path[0].far: must be greater than near");
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

#include "cullpipe/bounds/sphere_fit.hpp"
#include "cullpipe/scene/gltf_points.hpp"

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
