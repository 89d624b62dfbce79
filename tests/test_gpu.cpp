// GPU vs CPU, bit for bit, on the Vulkan device chosen by CULLPIPE_DEVICE (lavapipe in CI),
// with validation layers (including synchronization validation) on: any message fails.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>

#include "cullpipe/cull/compare.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/gpu/layout.hpp"
#include "cullpipe/gpu/pass_support.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/gltf_scene.hpp"
#include "cullpipe/vulkan/check.hpp"
#include "cullpipe/vulkan/compute_pipeline.hpp"
#include "edge_sets.hpp"
#include "gpu_test_env.hpp"
#include "test_util.hpp"

namespace cullpipe {
namespace {

using GpuEnvironment = test::GpuTestEnvironment<gpu::GpuCuller>;
const auto* const kEnvironment = ::testing::AddGlobalTestEnvironment(new GpuEnvironment);
using Gpu = test::GpuTest<gpu::GpuCuller>;

// Culls `volumes` against `frusta` on the GPU and the CPU; every classification, every
// counter and the visible-id list must agree (cull/compare.hpp). Returns the CPU classes of
// view 0.
template <class Volume>
std::vector<Classification> expect_agreement(gpu::GpuCuller& culler, const std::vector<Volume>& volumes,
                                             const std::vector<Frustum>& frusta, const gpu::CullOptions& options = {}) {
  culler.upload(std::span<const Volume>(volumes));
  const gpu::CullResult result = culler.cull(frusta, options);
  EXPECT_EQ(result.views.size(), frusta.size());
  const std::size_t capacity = options.visible_capacity ? options.visible_capacity : volumes.size();
  std::vector<Classification> first;
  for (std::size_t v = 0; v < frusta.size() && v < result.views.size(); ++v) {
    std::vector<Classification> cpu(volumes.size());
    const reference::CullCounts counts = reference::classify_all(std::span<const Volume>(volumes), frusta[v], cpu);
    const gpu::ViewResult& g = result.views[v];
    // Without classes the counters and the list are checked (and no classes come back).
    const std::span<const Classification> gpu_classes =
        options.classes ? std::span<const Classification>(g.classes) : cpu;
    if (!options.classes) {
      EXPECT_TRUE(g.classes.empty()) << "view " << v;
    }
    const Agreement a =
        check_agreement<Volume>(volumes, frusta[v], cpu, counts, gpu_classes, g.counts, g.visible_ids, capacity);
    EXPECT_TRUE(a.ok()) << a.mismatches << " mismatches in view " << v
                        << "; first: " << (a.reports.empty() ? "" : a.reports[0]);
    EXPECT_EQ(g.overflow, counts.visible > capacity) << "view " << v;
    if (v == 0) first = cpu;
  }
  return first;
}

std::vector<Frustum> test_frusta() {
  return {Frustum::from_view_proj(test::test_view_proj()), Frustum::from_view_proj(test::test_view_proj(100.0f, 0.5f))};
}

TEST_F(Gpu, EdgeCountsAroundTheWorkgroupSize) {
  test::Rng rng{100};
  for (std::size_t n : {0u, 1u, 63u, 64u, 65u, 255u, 256u, 257u, 1000u}) {
    std::vector<Aabb> boxes;
    std::vector<Obb> obbs;
    std::vector<Sphere> spheres;
    for (std::size_t i = 0; i < n; ++i) {
      boxes.push_back(test::random_aabb(rng, 30.0f, 5.0f));
      obbs.push_back(test::random_obb(rng, 30.0f, 5.0f));
      spheres.push_back(test::random_sphere(rng, 30.0f, 5.0f));
    }
    SCOPED_TRACE("n = " + std::to_string(n));
    expect_agreement(culler(), boxes, test_frusta());
    expect_agreement(culler(), obbs, test_frusta());
    expect_agreement(culler(), spheres, test_frusta());
  }
}

TEST_F(Gpu, OneMillionObjects) {
  test::Rng rng{101};
  std::vector<Aabb> boxes(1000000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 60.0f, 3.0f);
  const auto classes = expect_agreement(culler(), boxes, test_frusta());
  const auto visible = std::count_if(classes.begin(), classes.end(), is_visible);
  EXPECT_GT(visible, 10000);
  EXPECT_LT(visible, 990000);
  std::vector<Sphere> spheres(1000000);
  for (Sphere& s : spheres) s = test::random_sphere(rng, 60.0f, 3.0f);
  expect_agreement(culler(), spheres, test_frusta());
}

// Uploads are written in chunks of 16384 objects on a pool of upload threads: on the calling
// thread alone and on more threads than cores, a count that ends mid-chunk, every kind, and
// a smaller scene after a larger one on the same culler (its buffers reused).
TEST_F(Gpu, UploadsOnOneOrManyThreadsAgree) {
  test::Rng rng{102};
  std::vector<Aabb> boxes(70001);
  std::vector<Obb> obbs(boxes.size());
  std::vector<Sphere> spheres(boxes.size());
  for (std::size_t i = 0; i < boxes.size(); ++i) {
    boxes[i] = test::random_aabb(rng, 40.0f, 3.0f);
    obbs[i] = test::random_obb(rng, 40.0f, 3.0f);
    spheres[i] = test::random_sphere(rng, 40.0f, 3.0f);
  }
  for (unsigned threads : {1u, 3u}) {
    SCOPED_TRACE("upload threads " + std::to_string(threads));
    gpu::GpuCullerConfig config;
    config.upload_threads = threads;
    gpu::GpuCuller culler(*GpuEnvironment::context, config);
    expect_agreement(culler, boxes, test_frusta());
    expect_agreement(culler, obbs, test_frusta());
    expect_agreement(culler, spheres, test_frusta());
    expect_agreement(culler, std::vector<Aabb>(boxes.begin(), boxes.begin() + 16385), test_frusta());
    expect_agreement(culler, std::vector<Obb>(obbs.begin(), obbs.begin() + 999), test_frusta());
  }
}

TEST_F(Gpu, GeneratedScenesManyViews) {
  for (SceneKind kind : {SceneKind::Uniform, SceneKind::Clustered, SceneKind::City}) {
    const Scene scene = generate_scene(kind, 20000, 5);
    std::vector<Frustum> frusta;
    for (const Camera& c : camera_path(scene.camera, scene.bounds(), 6))
      frusta.push_back(Frustum::from_view_proj(c.view_proj()));
    SCOPED_TRACE(std::string(to_string(kind)));
    expect_agreement(culler(), world_aabbs(scene), frusta);
    expect_agreement(culler(), world_obbs(scene), frusta);
    expect_agreement(culler(), world_spheres(scene), frusta);
  }
}

// The real glTF scenes, every AABB update method, their own cameras where they have them,
// and a repeated model large enough for many workgroups.
TEST_F(Gpu, GltfScenesAgree) {
  const std::filesystem::path dir = std::filesystem::path(CULLPIPE_SHARED_DIR) / "scenes";
  if (!std::filesystem::exists(dir)) GTEST_SKIP() << dir << " not present";
  std::size_t files = 0;
  for (const auto& sub : std::filesystem::directory_iterator(dir)) {
    if (!sub.is_directory()) continue;
    for (const auto& file : std::filesystem::directory_iterator(sub.path())) {
      if (file.path().extension() != ".gltf") continue;
      SCOPED_TRACE(file.path().string());
      ++files;
      const GltfScene g = load_gltf_scene(file.path().string());
      std::vector<Frustum> frusta;
      for (const Camera& c : camera_path(g.scene.camera, g.scene.bounds(), 8))
        frusta.push_back(Frustum::from_view_proj(c.view_proj()));
      for (std::size_t c = 0; c < g.cameras.size(); ++c) {
        if (g.cameras[c].node < 0) continue;
        GltfSceneOptions o;
        o.camera = std::to_string(c);
        frusta.push_back(Frustum::from_view_proj(load_gltf_scene(file.path().string(), o).scene.camera.view_proj()));
      }
      for (bounds::AabbUpdate m :
           {bounds::AabbUpdate::Recompute, bounds::AabbUpdate::TransformBox, bounds::AabbUpdate::HillClimb})
        expect_agreement(culler(), world_aabbs(g.scene, m), frusta);
      expect_agreement(culler(), world_obbs(g.scene), frusta);
      expect_agreement(culler(), world_spheres(g.scene), frusta);
      if (file.path().filename() == "VC.gltf") {  // 167 objects x 300 = 50,100
        const Scene big = replicate_scene(g.scene, 300, InstanceLayout::Random, 3);
        std::vector<Frustum> views;
        for (const Camera& c : camera_path(big.camera, big.bounds(), 4))
          views.push_back(Frustum::from_view_proj(c.view_proj()));
        expect_agreement(culler(), world_aabbs(big), views);
        expect_agreement(culler(), world_spheres(big), views);
      }
    }
  }
  EXPECT_EQ(files, 10u);
}

TEST_F(Gpu, ReversedZAndInfiniteProjections) {
  const Scene scene = generate_scene(SceneKind::Uniform, 5000, 6);
  for (int variant = 0; variant < 3; ++variant) {
    Camera cam = scene.camera;
    cam.reversed_z = variant != 1;
    cam.infinite_far = variant != 0;
    const std::vector<Frustum> frusta = {Frustum::from_view_proj(cam.view_proj())};
    EXPECT_EQ(frusta[0].plane_count, cam.infinite_far ? 5u : 6u);
    expect_agreement(culler(), world_aabbs(scene), frusta);
    expect_agreement(culler(), world_obbs(scene), frusta);
    expect_agreement(culler(), world_spheres(scene), frusta);
  }
}

// Volumes placed so that a plane distance is within a few float steps of zero (or of +-r):
// the only cases where a fused multiply-add or a reordered sum changes the answer.
struct NearPlaneSet {
  std::vector<Aabb> boxes;
  std::vector<Sphere> spheres;
  std::vector<Obb> obbs;
};

NearPlaneSet near_plane_set(const Frustum& f, std::size_t per_plane) {
  test::Rng rng{77};
  NearPlaneSet set;
  for (const Plane& plane : f.active())
    for (std::size_t i = 0; i < per_plane; ++i) {
      const glm::vec3 n = plane.normal;
      const int steps = int(i % 9) - 4;  // -4..4 float steps
      // AABB: move the box along n so its p-vertex (or n-vertex) lies on the plane.
      Aabb b = test::random_aabb(rng, 20.0f, 3.0f);
      const glm::vec3 pv(n.x >= 0 ? b.max.x : b.min.x, n.y >= 0 ? b.max.y : b.min.y, n.z >= 0 ? b.max.z : b.min.z);
      const glm::vec3 nv(n.x >= 0 ? b.min.x : b.max.x, n.y >= 0 ? b.min.y : b.max.y, n.z >= 0 ? b.min.z : b.max.z);
      const float s = plane.distance(i % 2 ? pv : nv);
      glm::vec3 shift = -s * n;
      for (int k = 0; k < 3; ++k) {  // then nudge each coordinate by a few ulps
        float v = b.min[k] + shift[k];
        for (int st = 0; st < std::abs(steps); ++st) v = std::nextafter(v, steps > 0 ? 1e30f : -1e30f);
        shift[k] = v - b.min[k];
      }
      set.boxes.push_back({b.min + shift, b.max + shift});
      // Sphere: centre at distance +-r from the plane, nudged.
      Sphere sp = test::random_sphere(rng, 20.0f, 3.0f);
      const float target = (i % 2 ? -1.0f : 1.0f) * sp.radius;
      sp.center += (target - plane.distance(sp.center)) * n;
      for (int st = 0; st < std::abs(steps); ++st)
        sp.center.x = std::nextafter(sp.center.x, steps > 0 ? 1e30f : -1e30f);
      set.spheres.push_back(sp);
      // OBB: centre at distance +-r (projected radius) from the plane, nudged.
      Obb ob = test::random_obb(rng, 20.0f, 3.0f);
      float r = 0.0f;
      for (int k = 0; k < 3; ++k) r += std::abs(glm::dot(n, ob.basis[k])) * ob.half_extents[k];
      ob.center += ((i % 2 ? -r : r) - plane.distance(ob.center)) * n;
      for (int st = 0; st < std::abs(steps); ++st)
        ob.center.y = std::nextafter(ob.center.y, steps > 0 ? 1e30f : -1e30f);
      set.obbs.push_back(ob);
    }
  return set;
}

// The same p/n-vertex test with every plane distance fused (fma), as a GPU that contracts
// would compute it. Used to show the near-plane set can tell the difference.
Classification classify_pn_fused(const Aabb& box, const Frustum& f) {
  bool crossing = false;
  for (const Plane& p : f.active()) {
    const glm::vec3& n = p.normal;
    auto dist = [&](glm::vec3 v) { return std::fma(n.z, v.z, std::fma(n.y, v.y, std::fma(n.x, v.x, p.d))); };
    const glm::vec3 pv(n.x >= 0 ? box.max.x : box.min.x, n.y >= 0 ? box.max.y : box.min.y,
                       n.z >= 0 ? box.max.z : box.min.z);
    const glm::vec3 nv(n.x >= 0 ? box.min.x : box.max.x, n.y >= 0 ? box.min.y : box.max.y,
                       n.z >= 0 ? box.min.z : box.max.z);
    if (dist(pv) < 0.0f) return Classification::Outside;
    if (dist(nv) < 0.0f) crossing = true;
  }
  return crossing ? Classification::Intersecting : Classification::Inside;
}

TEST_F(Gpu, VolumesWithinFloatStepsOfThePlanes) {
  for (const Frustum& f : test_frusta()) {
    const NearPlaneSet set = near_plane_set(f, 3000);
    const auto classes = expect_agreement(culler(), set.boxes, {f});
    expect_agreement(culler(), set.spheres, {f});
    expect_agreement(culler(), set.obbs, {f});
    // The set is sharp: all three answers occur, and fused arithmetic would change some.
    EXPECT_GT(std::count(classes.begin(), classes.end(), Classification::Outside), 100);
    EXPECT_GT(std::count(classes.begin(), classes.end(), Classification::Intersecting), 100);
    std::size_t fused_differs = 0;
    for (std::size_t i = 0; i < set.boxes.size(); ++i)
      fused_differs += classify_pn_fused(set.boxes[i], f) != classes[i];
    EXPECT_GT(fused_differs, 0u) << "the near-plane set would not catch contraction";
  }
}

// The box passes settle most boxes by their centre distance against a bound (docs/numerics.md,
// Settling bounds); boxes at the edge of those bounds, huge and non-finite ones, and planes
// whose normals are too long for them (nothing may be settled) must still get the reference's
// answers, in one pass of every view and in the object-order pass (which tests every box in
// full). `mixed` is a view where all three answers occur.
template <class Volume>
void expect_edge_set_agreement(gpu::GpuCuller& culler, const test::EdgeSet<Volume>& set, std::size_t mixed) {
  const auto classes = expect_agreement(culler, set.volumes, {set.views[mixed]});
  for (Classification c : {Classification::Outside, Classification::Intersecting, Classification::Inside})
    EXPECT_GT(std::count(classes.begin(), classes.end(), c), 100) << "the edge set is mixed: " << to_string(c);
  expect_agreement(culler, set.volumes, set.views);
  gpu::CullOptions ordered;
  ordered.ordered = true;
  expect_agreement(culler, set.volumes, set.views, ordered);
}

TEST_F(Gpu, BoxesAtTheEdgeOfTheirCentreBound) {
  expect_edge_set_agreement(culler(), test::aabb_edge_set(), 1);
  expect_edge_set_agreement(culler(), test::obb_edge_set(), 0);
  expect_edge_set_agreement(culler(), test::sphere_edge_set(), 1);  // (the GPU tests spheres in full)
}

TEST_F(Gpu, DegenerateBehindCameraHugeAndTiny) {
  const Frustum f = Frustum::from_view_proj(test::test_view_proj());
  std::vector<Aabb> boxes = {
      {{0, 0, 0}, {0, 0, 0}},                                   // point box at the target
      {{-1, 0, -1}, {1, 0, 1}},                                 // flat box
      {{0, 0, 11}, {1, 1, 12}},                                 // behind the camera (camera at z = 10)
      {{-1, -1, 5}, {1, 1, 30}},                                // from behind the camera through the near plane
      {{-1e30f, -1e30f, -1e30f}, {1e30f, 1e30f, 1e30f}},        // huge: encloses everything
      {{1e30f, 0, 0}, {1.0001e30f, 1, 1}},                      // huge and far away
      {{1e-30f, 1e-30f, 1e-30f}, {2e-30f, 2e-30f, 2e-30f}},     // tiny, at the origin
      {{-1e-38f, -1e-38f, -1e-38f}, {1e-38f, 1e-38f, 1e-38f}},  // near the denormal range
  };
  const auto classes = expect_agreement(culler(), boxes, {f});
  EXPECT_EQ(classes[0], Classification::Inside);
  EXPECT_EQ(classes[2], Classification::Outside);
  EXPECT_EQ(classes[3], Classification::Intersecting);
  EXPECT_EQ(classes[4], Classification::Intersecting);
  EXPECT_EQ(classes[5], Classification::Outside);
  EXPECT_EQ(classes[6], Classification::Inside);
  std::vector<Sphere> spheres = {
      {{0, 0, 0}, 0}, {{0, 0, 20}, 1}, {{0, 0, 0}, 1e30f}, {{1e30f, 0, 0}, 1}, {{0, 0, 0}, 1e-30f}};
  const auto sphere_classes = expect_agreement(culler(), spheres, {f});
  EXPECT_EQ(sphere_classes[1], Classification::Outside);
  EXPECT_EQ(sphere_classes[2], Classification::Intersecting);
  std::vector<Obb> obbs(3);
  obbs[1].center = {0, 0, 20};
  obbs[1].half_extents = {1, 1, 1};
  obbs[2].half_extents = {1e30f, 0, 1e30f};
  expect_agreement(culler(), obbs, {f});
}

// Frusta of fewer than six planes against large, negative and infinite radii, infinite and NaN
// coordinates: the planes past a view's count decide nothing, whatever the shader keeps there.
TEST_F(Gpu, FrustaOfFewerPlanesWithExtremeVolumes) {
  const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<Sphere> spheres = {{{0.5f, 0.5f, 0}, 5},  {{0.5f, 0.5f, 0}, 1e30f},  {{0.5f, 0.5f, 0}, inf},
                                 {{0.5f, 0.5f, 0}, -2}, {{0.5f, 0.5f, 0}, -inf},   {{inf, 0.5f, 0}, 1},
                                 {{0.5f, -inf, 0}, 1},  {{nan, 0.5f, 0}, 1},       {{0.5f, 0.5f, 0}, nan},
                                 {{10, 10, 0}, 5},      {{0.5f, 0.5f, inf}, 0.25f}};
  std::vector<Aabb> boxes = {{{0.25f, 0.25f, -1}, {0.75f, 0.75f, 1}}, {{0.25f, 0.25f, -inf}, {0.75f, 0.75f, inf}},
                             {{-inf, -inf, -inf}, {inf, inf, inf}},   {{0.25f, 0.25f, nan}, {0.75f, 0.75f, 1}},
                             {{0.75f, 0.75f, 1}, {0.25f, 0.25f, -1}}, {{0.25f, 0.25f, -1e30f}, {0.75f, 0.75f, 1e30f}}};
  std::vector<Obb> obbs(5);
  for (Obb& o : obbs) o.center = {0.5f, 0.5f, 0};
  obbs[1].half_extents = {0.25f, 0.25f, inf};
  obbs[2].half_extents = {0.25f, 0.25f, 1e30f};
  obbs[3].center.z = inf;
  obbs[4].basis[2] = {0, 0, nan};
  const glm::vec4 all[5] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {-1, 0, 0, 1}, {0, -1, 0, 1}, {0, 0, -1, 10}};
  for (std::size_t count : {1u, 2u, 5u}) {
    const Frustum f = Frustum::from_planes(std::span(all, count));
    ASSERT_EQ(f.plane_count, count);
    const auto sphere_classes = expect_agreement(culler(), spheres, {f});
    // Inside the first two planes; a stale or filler plane such as (0, 0, 0, 1) would make it
    // INTERSECTING.
    EXPECT_EQ(sphere_classes[9], count <= 2 ? Classification::Inside : Classification::Outside);
    expect_agreement(culler(), boxes, {f});
    expect_agreement(culler(), obbs, {f});
  }
}

// Subnormal inputs and results: Vulkan lets a device flush them to zero unless the shader
// asks to preserve them (shaderDenormPreserveFloat32). This documents what the device does.
TEST_F(Gpu, SubnormalCoordinatesAgree) {
  const glm::vec4 planes[2] = {{1, 0, 0, 0}, {0, 1, 0, 0}};  // x >= 0, y >= 0
  const Frustum f = Frustum::from_planes(planes);
  const float tiny = 1e-40f;  // subnormal
  ASSERT_LT(tiny, std::numeric_limits<float>::min());
  std::vector<Aabb> boxes = {
      {{-2 * tiny, 0, 0}, {-tiny, 1, 1}},  // just behind x = 0 by a subnormal: OUTSIDE
      {{-tiny, 0, 0}, {tiny, 1, 1}},       // straddles x = 0: INTERSECTING
      {{tiny, tiny, 0}, {1, 1, 1}},        // inside by a subnormal: INSIDE
  };
  const auto classes = expect_agreement(culler(), boxes, {f});
  EXPECT_EQ(classes, (std::vector<Classification>{Classification::Outside, Classification::Intersecting,
                                                  Classification::Inside}));
  std::vector<Sphere> spheres = {{{-2 * tiny, 1, 1}, tiny}, {{tiny, 1, 1}, 0.5f}};
  expect_agreement(culler(), spheres, {f});
}

TEST_F(Gpu, ManyViewsInOnePass) {
  const Scene scene = generate_scene(SceneKind::Clustered, 3000, 8);
  std::vector<Frustum> frusta;
  for (const Camera& c : camera_path(scene.camera, scene.bounds(), 64))
    frusta.push_back(Frustum::from_view_proj(c.view_proj()));
  expect_agreement(culler(), world_obbs(scene), frusta);
}

TEST_F(Gpu, RepeatedCullsReuseBuffersAndStayCorrect) {
  test::Rng rng{9};
  for (int round = 0; round < 20; ++round) {
    std::vector<Sphere> spheres(std::size_t(rng.next() % 5000));
    for (Sphere& s : spheres) s = test::random_sphere(rng, 30.0f, 4.0f);
    expect_agreement(culler(), spheres, test_frusta());
  }
}

TEST_F(Gpu, ScenesLargerThanAStorageBufferAreCulledInSegments) {
  // More OBBs than one storage buffer range holds (2.1 million on lavapipe's 128 MiB). The
  // volumes are read through a texel buffer view, which covers them whole; 17 views make the
  // per-object classes outgrow one storage buffer, so the pass is split into segments and
  // must still agree object by object, ids included.
  const VkPhysicalDeviceLimits& limits = GpuEnvironment::context->properties().limits;
  const VkDeviceSize range = limits.maxStorageBufferRange;
  const std::size_t count = std::size_t(range / sizeof(gpu::GpuObb)) + 1000;
  if (count > 5'000'000) GTEST_SKIP() << "device storage range too large to test cheaply";
  test::Rng rng{77};
  std::vector<Obb> obbs(count);
  const std::vector<Obb> pool = [&] {
    std::vector<Obb> p(4096);
    for (Obb& b : p) b = test::random_obb(rng, 40.0f, 3.0f);
    return p;
  }();
  for (std::size_t i = 0; i < count; ++i) {  // varied positions without a rotation per object
    obbs[i] = pool[i % pool.size()];
    obbs[i].center += glm::vec3(float(i % 97) * 0.5f - 24.0f, float(i % 89) * 0.5f - 22.0f, 0.0f);
  }
  constexpr std::size_t kViews = 17;
  std::vector<Frustum> frusta;
  for (std::size_t v = 0; v < kViews; ++v) frusta.push_back(test_frusta()[v % test_frusta().size()]);
  // What the limits allow per segment: the classes (4 bytes per object and view) and the
  // texel view of the volumes, in multiples of 256 objects.
  const std::size_t by_classes = std::size_t(range / (sizeof(std::uint32_t) * kViews));
  const std::size_t by_texels =
      std::size_t(std::min<VkDeviceSize>(limits.maxTexelBufferElements, 0x7fffffffu) * 16 / sizeof(gpu::GpuObb));
  const std::size_t per_segment = std::min(by_classes, by_texels) / 256 * 256;
  const std::size_t segments = (count + per_segment - 1) / per_segment;
  ASSERT_GE(segments, 2u);
  gpu::CullOptions options;
  options.visible_capacity = by_classes;  // the visible lists must fit one storage buffer too
  expect_agreement(culler(), obbs, frusta, options);
  EXPECT_EQ(culler().last_segment_count(), segments);
  // One view: the classes fit, and the texel view holds more than a storage buffer could.
  expect_agreement(culler(), obbs, std::vector<Frustum>{frusta[0]});
  EXPECT_EQ(culler().last_segment_count(), count <= by_texels ? 1u : 2u);
}

TEST_F(Gpu, SegmentedPassesAgreeForEveryKindAndOutput) {
  // Segments of 256 objects: every kind, several views, draws, an overflowing list, and the
  // engine's record path.
  gpu::GpuCullerConfig config;
  config.max_segment_objects = 300;  // rounded down to 256
  gpu::GpuCuller segmented(*GpuEnvironment::context, config);
  test::Rng rng{21};
  std::vector<Aabb> boxes(5000);
  std::vector<Obb> obbs(1234);
  std::vector<Sphere> spheres(2600);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 3.0f);
  for (Obb& b : obbs) b = test::random_obb(rng, 30.0f, 3.0f);
  for (Sphere& b : spheres) b = test::random_sphere(rng, 30.0f, 3.0f);
  expect_agreement(segmented, boxes, test_frusta());
  EXPECT_EQ(segmented.last_segment_count(), (5000u + 255u) / 256u);
  expect_agreement(segmented, obbs, test_frusta());
  expect_agreement(segmented, spheres, test_frusta(), gpu::CullOptions{true, true, 100});
  // Draws: one template per object, object ids global across segments.
  std::vector<gpu::DrawCommand> templates(boxes.size());
  for (std::uint32_t i = 0; i < templates.size(); ++i) templates[i] = {36, 1, i * 36, 0, 0, 0};
  segmented.upload(std::span<const Aabb>(boxes));
  segmented.upload_draws(templates);
  gpu::CullOptions draws;
  draws.draws = true;
  const gpu::CullResult r = segmented.cull(test_frusta(), draws);
  for (const gpu::ViewResult& view : r.views) {
    ASSERT_EQ(view.draws.size(), view.visible_ids.size());
    for (std::size_t k = 0; k < view.draws.size(); ++k) {
      const std::uint32_t id = view.visible_ids[k];
      EXPECT_EQ(view.draws[k].object_id, id);
      EXPECT_EQ(view.draws[k].first_index, id * 36) << "segment " << id / 256 << " read another segment's template";
    }
  }
  // Object order cannot span segments: a clear error, not a wrong answer.
  gpu::CullOptions ordered;
  ordered.ordered = true;
  try {
    segmented.cull(test_frusta(), ordered);
    FAIL() << "expected std::length_error";
  } catch (const std::length_error& e) {
    EXPECT_NE(std::string(e.what()).find("limited to one storage buffer"), std::string::npos) << e.what();
  }
  // And one segment again: a small upload on the same culler.
  std::vector<Aabb> few(boxes.begin(), boxes.begin() + 200);
  expect_agreement(segmented, few, test_frusta(), ordered);
  EXPECT_EQ(segmented.last_segment_count(), 1u);
}

TEST_F(Gpu, OutOfDeviceMemoryIsAClearErrorAndTheCullerStaysUsable) {
  vulkan::Context& ctx = *GpuEnvironment::context;
  struct BudgetReset {  // the shared context must not keep a budget, whatever happens here
    vulkan::Context& c;
    ~BudgetReset() { c.set_memory_budget(0); }
  } reset{ctx};
  gpu::GpuCuller culler_under_budget(ctx);
  test::Rng rng{41};
  std::vector<Aabb> boxes(100000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 3.0f);
  // Room for 1 MiB more than is held now: 100,000 boxes (3.2 MB of bounds) do not fit.
  ctx.set_memory_budget(ctx.memory_in_use() + (1u << 20));
  try {
    culler_under_budget.upload(std::span<const Aabb>(boxes));
    FAIL() << "expected vulkan::Error";
  } catch (const vulkan::Error& e) {
    EXPECT_EQ(e.result(), VK_ERROR_OUT_OF_DEVICE_MEMORY);
    // The first of the upload's buffers: boxes' centre bounds (1.6 MB), then their records.
    EXPECT_NE(std::string(e.what()).find("centre bound buffer"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("memory budget"), std::string::npos) << e.what();
  }
  EXPECT_EQ(culler_under_budget.object_count(), 0u) << "a failed upload leaves no half-uploaded scene";
  // A scene that fits, on the same culler: exact as ever.
  std::vector<Aabb> few(boxes.begin(), boxes.begin() + 2000);
  expect_agreement(culler_under_budget, few, test_frusta());
  // Outputs that do not fit fail the same way, and the culler recovers once memory is there.
  ctx.set_memory_budget(ctx.memory_in_use() + 1024);
  culler_under_budget.upload(std::span<const Aabb>(few));  // reuses the bounds buffer
  std::vector<Frustum> many_views(64, test_frusta()[0]);
  EXPECT_THROW(culler_under_budget.cull(many_views), vulkan::Error);
  ctx.set_memory_budget(0);
  expect_agreement(culler_under_budget, few, many_views);
  const VkDeviceSize held = ctx.memory_in_use();
  { gpu::GpuCuller temporary(ctx); }
  EXPECT_EQ(ctx.memory_in_use(), held) << "buffers give their memory back to the budget";
}

TEST_F(Gpu, AMissingDeviceFeatureIsAClearError) {
  // What the cullers need is there; a feature this device lacks is named in the error. (lavapipe
  // has no clustered subgroup operations; on a device that has them the check passes.)
  const vulkan::Context& ctx = *GpuEnvironment::context;
  EXPECT_NO_THROW(gpu::detail::check_subgroup_operations(
      ctx, VK_SUBGROUP_FEATURE_BASIC_BIT | VK_SUBGROUP_FEATURE_BALLOT_BIT, "flat culling"));
  VkPhysicalDeviceSubgroupProperties subgroup{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES};
  VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &subgroup, {}};
  vkGetPhysicalDeviceProperties2(ctx.physical_device(), &properties);
  if (subgroup.supportedOperations & VK_SUBGROUP_FEATURE_CLUSTERED_BIT)
    GTEST_SKIP() << "this device has clustered operations";
  try {
    gpu::detail::check_subgroup_operations(ctx, VK_SUBGROUP_FEATURE_BASIC_BIT | VK_SUBGROUP_FEATURE_CLUSTERED_BIT,
                                           "a test pass");
    FAIL() << "expected vulkan::Error";
  } catch (const vulkan::Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("a test pass needs subgroup operations"), std::string::npos) << what;
    EXPECT_NE(what.find("lacks: clustered"), std::string::npos) << what;
  }
}

TEST_F(Gpu, CorruptShadersAreRefusedBeforeTheDriverSeesThem) {
  // A minimal sound module: header, then OpCapability Shader (2 words) and OpMemoryModel
  // Logical GLSL450 (3 words).
  const std::vector<std::uint32_t> sound = {0x07230203u, 0x00010300u, 0, 8, 0, 2u << 16 | 17u, 1, 3u << 16 | 14u, 0, 1};
  EXPECT_EQ(vulkan::spirv_problem(sound), "");
  std::vector<std::uint32_t> bad = sound;
  bad[0] = 0x03022307u;  // byte-swapped magic
  EXPECT_NE(vulkan::spirv_problem(bad).find("magic"), std::string::npos);
  bad = sound;
  bad.pop_back();  // truncated
  EXPECT_NE(vulkan::spirv_problem(bad).find("past the end"), std::string::npos);
  bad = sound;
  bad[5] = 0;  // zero word count
  EXPECT_NE(vulkan::spirv_problem(bad).find("word count of 0"), std::string::npos);
  EXPECT_NE(vulkan::spirv_problem(std::span(sound).first(3)).find("header"), std::string::npos);
  bad = sound;
  bad[1] = 0x00020000u;
  EXPECT_NE(vulkan::spirv_problem(bad).find("version"), std::string::npos);
  for (const std::vector<std::uint32_t>& words :
       {std::vector<std::uint32_t>{}, std::vector<std::uint32_t>(sound.begin(), sound.end() - 1)}) {
    try {
      vulkan::ComputePipeline pipe(*GpuEnvironment::context,
                                   vulkan::ComputePipelineDesc{words, 1, 0, {}, "test pipeline"});
      FAIL() << "expected vulkan::Error";
    } catch (const vulkan::Error& e) {
      EXPECT_NE(std::string(e.what()).find("test pipeline: SPIR-V is corrupt"), std::string::npos) << e.what();
    }
  }
}

// Writing classes or not is a pipeline of its own (WRITE_CLASSES in cull_flat.comp): without
// them the counters and the list still equal the reference's, and a pass asking for classes
// after one that did not gets this pass's classes (each kind's upload changes them).
TEST_F(Gpu, TheListIsTheSameWithAndWithoutClasses) {
  test::Rng rng{22};
  const test::RandomVolumes v = test::random_volumes(rng, 3000, 30.0f, 3.0f);
  for (bool ordered : {false, true}) {
    for (bool classes : {false, true, false, true}) {
      SCOPED_TRACE(std::string(ordered ? "ordered" : "arrival order") + (classes ? ", classes" : ", no classes"));
      gpu::CullOptions options;
      options.classes = classes;
      options.ordered = ordered;
      expect_agreement(culler(), v.aabbs, test_frusta(), options);
      expect_agreement(culler(), v.obbs, test_frusta(), options);
      expect_agreement(culler(), v.spheres, test_frusta(), options);
    }
  }
}

TEST_F(Gpu, VisibleListOverflowIsReportedNotSilent) {
  test::Rng rng{12};
  std::vector<Sphere> spheres(5000);
  for (Sphere& sp : spheres) sp = test::random_sphere(rng, 30.0f, 4.0f);
  // A list with room for 100 ids per view: the counters still count everything, the list
  // holds 100 distinct visible ids, and overflow is flagged.
  expect_agreement(culler(), spheres, test_frusta(), gpu::CullOptions{true, true, 100});
  culler().upload(std::span<const Sphere>(spheres));
  const auto r = culler().cull(test_frusta(), gpu::CullOptions{false, true, 100});
  EXPECT_TRUE(r.views[0].overflow);
  EXPECT_EQ(r.views[0].visible_ids.size(), 100u);
  EXPECT_GT(r.views[0].counts.visible, 100u);
  EXPECT_TRUE(r.views[0].classes.empty()) << "classes not read back when not asked for";
}

TEST_F(Gpu, PassesSplitIntoChunksAgree) {
  // At most 3 workgroups per dispatch: 10,000 objects take many chunked dispatches.
  gpu::GpuCuller chunked(*GpuEnvironment::context, gpu::GpuCullerConfig{64, 3});
  EXPECT_EQ(chunked.group_size(), 64u);
  test::Rng rng{13};
  std::vector<Obb> obbs(10000);
  for (Obb& b : obbs) b = test::random_obb(rng, 30.0f, 3.0f);
  expect_agreement(chunked, obbs, test_frusta());
  std::vector<Aabb> boxes(193);  // not a multiple of the chunk
  for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 3.0f);
  expect_agreement(chunked, boxes, test_frusta());
  // Objects per invocation of the arrival-order pass: one, an odd count, the most; with a
  // visible list too short to hold every id.
  for (std::uint32_t k : {1u, 3u, 32u}) {
    gpu::GpuCuller per_invocation(*GpuEnvironment::context, gpu::GpuCullerConfig{64, 3, k});
    EXPECT_EQ(per_invocation.objects_per_invocation(), k);
    expect_agreement(per_invocation, obbs, test_frusta());
    expect_agreement(per_invocation, boxes, test_frusta(), gpu::CullOptions{true, true, 50});
  }
}

// Ordered compaction and draw output: the visible list in object order equals the CPU's
// visible objects in object order exactly, the draws are the templates of those objects with
// their ids, and in arrival order the draws follow the visible ids one for one.
template <class Volume>
void expect_draws(gpu::GpuCuller& c, const std::vector<Volume>& volumes, const std::vector<Frustum>& frusta,
                  std::uint64_t seed, std::size_t capacity = 0) {
  test::Rng rng{seed};
  std::vector<gpu::DrawCommand> templates(volumes.size());
  for (gpu::DrawCommand& d : templates)
    d = {std::uint32_t(rng.next() % 5000), 1 + std::uint32_t(rng.next() % 3), std::uint32_t(rng.next() % 100000),
         int(rng.next() % 2001) - 1000,    std::uint32_t(rng.next() % 70000), 0xdeadbeefu};
  c.upload(std::span<const Volume>(volumes));
  c.upload_draws(templates);
  std::vector<std::vector<std::uint32_t>> ordered_ids;
  for (bool ordered : {true, false})
    for (bool classes : {true, false}) {  // (without classes: pipelines of their own)
      SCOPED_TRACE(std::string(ordered ? "ordered" : "arrival order") + (classes ? ", classes" : ", no classes"));
      const gpu::CullResult r = c.cull(frusta, {classes, true, capacity, ordered, true});
      ASSERT_EQ(r.views.size(), frusta.size());
      if (ordered && classes)
        for (const gpu::ViewResult& view : r.views) ordered_ids.push_back(view.visible_ids);
      for (std::size_t v = 0; v < frusta.size(); ++v) {
        std::vector<Classification> cpu(volumes.size());
        const reference::CullCounts counts = reference::classify_all(std::span<const Volume>(volumes), frusta[v], cpu);
        const gpu::ViewResult& g = r.views[v];
        if (classes) {
          EXPECT_EQ(g.classes, cpu) << "view " << v;
        } else {
          EXPECT_TRUE(g.classes.empty()) << "view " << v;
        }
        EXPECT_EQ(g.counts.visible, counts.visible);
        EXPECT_EQ(g.counts.inside, counts.inside);
        const std::size_t cap = capacity ? capacity : volumes.size();
        EXPECT_EQ(g.overflow, counts.visible > cap);
        std::vector<std::uint32_t> expected;
        for (std::uint32_t i = 0; i < volumes.size(); ++i)
          if (cpu[i] != Classification::Outside) expected.push_back(i);
        if (expected.size() > cap) expected.resize(cap);
        ASSERT_EQ(g.visible_ids.size(), expected.size()) << "view " << v;
        ASSERT_EQ(g.draws.size(), expected.size()) << "view " << v;
        if (ordered) {
          EXPECT_EQ(g.visible_ids, expected) << "view " << v;
        } else if (!capacity) {
          std::vector<std::uint32_t> sorted = g.visible_ids;
          std::sort(sorted.begin(), sorted.end());
          EXPECT_EQ(sorted, expected) << "view " << v;
        }
        for (std::size_t k = 0; k < g.draws.size(); ++k) {
          const gpu::DrawCommand& d = g.draws[k];
          const std::uint32_t id = g.visible_ids[k];
          ASSERT_EQ(d.object_id, id) << "view " << v << " draw " << k;
          const gpu::DrawCommand& t = templates[id];
          ASSERT_TRUE(d.index_count == t.index_count && d.instance_count == t.instance_count &&
                      d.first_index == t.first_index && d.vertex_offset == t.vertex_offset &&
                      d.first_instance == t.first_instance)
              << "view " << v << " draw " << k;
        }
      }
    }
  // Object order without reading the classes back: the scatter pass must still get this
  // pass's classes (a pass over the views in reverse order leaves other classes behind).
  const std::vector<Frustum> reversed(frusta.rbegin(), frusta.rend());
  c.cull(reversed, {true, false, capacity, false, false});
  const gpu::CullResult lean = c.cull(frusta, {false, true, capacity, true, false});
  for (std::size_t v = 0; v < frusta.size(); ++v) EXPECT_EQ(lean.views[v].visible_ids, ordered_ids[v]) << "view " << v;
}

TEST_F(Gpu, OrderedCompactionAndDrawCommands) {
  test::Rng rng{21};
  for (std::size_t n : {0u, 1u, 255u, 256u, 257u, 5000u}) {
    SCOPED_TRACE("n = " + std::to_string(n));
    auto [boxes, obbs, spheres] = test::random_volumes(rng, n, 30.0f, 4.0f);
    expect_draws(culler(), boxes, test_frusta(), 1);
    expect_draws(culler(), obbs, test_frusta(), 2);
    expect_draws(culler(), spheres, test_frusta(), 3);
  }
  // Many workgroups and views; a capacity that overflows keeps the first objects in order.
  std::vector<Aabb> many(300000);
  for (Aabb& b : many) b = test::random_aabb(rng, 60.0f, 3.0f);
  const Scene city = generate_scene(SceneKind::City, 20000, 9);
  std::vector<Frustum> frusta;
  for (const Camera& c : camera_path(city.camera, city.bounds(), 5))
    frusta.push_back(Frustum::from_view_proj(c.view_proj()));
  expect_draws(culler(), many, test_frusta(), 4);
  expect_draws(culler(), world_aabbs(city), frusta, 5);
  expect_draws(culler(), world_spheres(city), frusta, 6, 100);
  // Chunked dispatches and a small group size; object counts not multiples of either.
  gpu::GpuCuller chunked(*GpuEnvironment::context, gpu::GpuCullerConfig{32, 5});
  std::vector<Aabb> some(many.begin(), many.begin() + 12345);
  expect_draws(chunked, some, test_frusta(), 7);
  expect_draws(chunked, some, test_frusta(), 8, 77);
  // Workgroup runs that are not a multiple of 32 objects (a partly filled last word of the
  // scatter pass's rank bitmask), words that span objects of two steps, one object per
  // invocation, and the largest run (every word of the shared arrays) where the device allows.
  const std::uint32_t max_group = std::min(GpuEnvironment::context->properties().limits.maxComputeWorkGroupSize[0],
                                           GpuEnvironment::context->properties().limits.maxComputeWorkGroupInvocations);
  for (const gpu::GpuCullerConfig config :
       {gpu::GpuCullerConfig{100}, gpu::GpuCullerConfig{100, 3, 3}, gpu::GpuCullerConfig{64, 3, 1}}) {
    SCOPED_TRACE("group size " + std::to_string(config.group_size) + ", " +
                 std::to_string(config.objects_per_invocation) + " per invocation");
    gpu::GpuCuller shaped(*GpuEnvironment::context, config);
    expect_draws(shaped, some, test_frusta(), 9);
  }
  gpu::GpuCuller largest(*GpuEnvironment::context,
                         gpu::GpuCullerConfig{std::min(max_group, gpu::MAX_CULL_GROUP_SIZE), 0, 32});
  expect_draws(largest, some, test_frusta(), 10, 5000);
}

// The engine path: a context borrowing the caller's device, the pass recorded into the
// caller's command buffer and submitted by the caller; results identical to cull().
TEST_F(Gpu, RecordsIntoTheCallersCommandBufferOnABorrowedDevice) {
  const vulkan::Context& owner = *GpuEnvironment::context;
  vulkan::Context borrowed(vulkan::ExternalDevice{owner.instance(), owner.physical_device(), owner.device(),
                                                  owner.queue(), owner.queue_family()});
  EXPECT_FALSE(borrowed.owns_device());
  gpu::GpuCuller engine_culler(borrowed);

  test::Rng rng{31};
  std::vector<Sphere> spheres(20000);
  for (Sphere& sp : spheres) sp = test::random_sphere(rng, 40.0f, 3.0f);
  std::vector<gpu::DrawCommand> templates(spheres.size());
  for (std::uint32_t i = 0; i < templates.size(); ++i) templates[i] = {36, 1, 36 * i, 0, i, 0};
  engine_culler.upload(std::span<const Sphere>(spheres));
  engine_culler.upload_draws(templates);

  // The "engine": its own pool, command buffer and fence on its device.
  VkDevice dev = owner.device();
  VkCommandPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  pool_info.queueFamilyIndex = owner.queue_family();
  VkCommandPool pool = VK_NULL_HANDLE;
  ASSERT_EQ(vkCreateCommandPool(dev, &pool_info, nullptr, &pool), VK_SUCCESS);
  VkCommandBufferAllocateInfo alloc{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr, pool,
                                    VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
  VkCommandBuffer cmd = VK_NULL_HANDLE;
  ASSERT_EQ(vkAllocateCommandBuffers(dev, &alloc, &cmd), VK_SUCCESS);
  VkFenceCreateInfo fence_info{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
  VkFence fence = VK_NULL_HANDLE;
  ASSERT_EQ(vkCreateFence(dev, &fence_info, nullptr, &fence), VK_SUCCESS);

  const std::vector<Frustum> frusta = test_frusta();
  const gpu::CullOptions options{true, true, 0, true, true};
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  ASSERT_EQ(vkBeginCommandBuffer(cmd, &begin), VK_SUCCESS);
  // record() never makes room for its outputs: it says what to reserve, and changes nothing.
  try {
    engine_culler.record(cmd, frusta, options);
    ADD_FAILURE() << "record made room for its outputs";
  } catch (const std::logic_error& e) {
    EXPECT_NE(std::string(e.what()).find("reserve_outputs(2, options)"), std::string::npos) << e.what();
  }
  engine_culler.reserve_outputs(frusta.size(), options);
  const VkBuffer draw_handle = engine_culler.draw_buffer().handle(),
                 counter_handle = engine_culler.counter_buffer().handle();
  engine_culler.record(cmd, frusta, options);
  EXPECT_EQ(engine_culler.draw_buffer().handle(), draw_handle);  // what the engine binds stays
  EXPECT_EQ(engine_culler.counter_buffer().handle(), counter_handle);
  ASSERT_EQ(vkEndCommandBuffer(cmd), VK_SUCCESS);
  VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &cmd;
  ASSERT_EQ(vkQueueSubmit(owner.queue(), 1, &submit, fence), VK_SUCCESS);
  ASSERT_EQ(vkWaitForFences(dev, 1, &fence, VK_TRUE, UINT64_MAX), VK_SUCCESS);
  const gpu::CullResult engine = engine_culler.read_results();

  culler().upload(std::span<const Sphere>(spheres));
  culler().upload_draws(templates);
  const gpu::CullResult own = culler().cull(frusta, options);
  ASSERT_EQ(engine.views.size(), frusta.size());
  for (std::size_t v = 0; v < frusta.size(); ++v) {
    std::vector<Classification> cpu(spheres.size());
    reference::classify_all(std::span<const Sphere>(spheres), frusta[v], cpu);
    EXPECT_EQ(engine.views[v].classes, cpu);
    EXPECT_EQ(engine.views[v].visible_ids, own.views[v].visible_ids);  // ordered: deterministic
    ASSERT_EQ(engine.views[v].draws.size(), own.views[v].draws.size());
    for (std::size_t k = 0; k < engine.views[v].draws.size(); ++k)
      ASSERT_EQ(std::memcmp(&engine.views[v].draws[k], &own.views[v].draws[k], sizeof(gpu::DrawCommand)), 0) << k;
  }
  EXPECT_TRUE(engine_culler.draw_buffer().handle() != VK_NULL_HANDLE);
  vkDestroyFence(dev, fence, nullptr);
  vkDestroyCommandPool(dev, pool, nullptr);
  EXPECT_THROW(vulkan::Context(vulkan::ExternalDevice{}), vulkan::Error);
}

TEST_F(Gpu, DrawsNeedTemplatesForEveryObject) {
  std::vector<Aabb> boxes(10, Aabb{glm::vec3(-1), glm::vec3(1)});
  culler().upload(std::span<const Aabb>(boxes));
  culler().upload_draws(std::vector<gpu::DrawCommand>(9));
  EXPECT_THROW(culler().cull(test_frusta(), {true, true, 0, false, true}), std::invalid_argument);
  culler().upload_draws(std::vector<gpu::DrawCommand>(10));
  EXPECT_NO_THROW(culler().cull(test_frusta(), {true, true, 0, false, true}));
}

TEST_F(Gpu, TimestampsAreReported) {
  std::vector<Aabb> boxes(10000);
  test::Rng rng{4};
  for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 2.0f);
  culler().upload(std::span<const Aabb>(boxes));
  const auto r = culler().cull(test_frusta());
  if (GpuEnvironment::context->timestamp_period_ns() > 0) {
    EXPECT_GT(r.timings.gpu_ns, 0.0);
  }
  EXPECT_GE(r.timings.wall_ns, r.timings.gpu_ns);
}

TEST(GpuDevice, UnknownDeviceNameIsAClearError) {
  vulkan::ContextOptions options;
  options.device_filter = "no-such-device-xyz";
  try {
    vulkan::Context ctx(options);
    FAIL() << "expected vulkan::Error";
  } catch (const vulkan::Error& e) {
    EXPECT_NE(std::string(e.what()).find("no usable Vulkan device matching 'no-such-device-xyz'"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace cullpipe

namespace cullpipe {
namespace {

// The validation layer is really on: an invalid call is reported (and counted), so the
// "no validation message" checks above can fail.
TEST(GpuValidation, InvalidCallIsReported) {
  std::vector<std::string> seen;
  vulkan::ContextOptions options;
  options.validation = true;
  options.on_message = [&](std::string_view m) { seen.emplace_back(m); };
  vulkan::Context ctx(options);
  VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
  info.size = 16;
  info.usage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
  info.sharingMode = VK_SHARING_MODE_CONCURRENT;  // invalid: needs at least two queue families
  VkBuffer buffer = VK_NULL_HANDLE;
  vkCreateBuffer(ctx.device(), &info, nullptr, &buffer);
  if (buffer) vkDestroyBuffer(ctx.device(), buffer, nullptr);
  EXPECT_GT(ctx.validation_message_count(), 0u);
  ASSERT_FALSE(seen.empty());
  EXPECT_NE(seen.front().find("VkBufferCreateInfo"), std::string::npos) << seen.front();
}

}  // namespace
}  // namespace cullpipe

namespace cullpipe {
namespace {

// An engine's allocator, as a test needs it: one mapped block of device memory handed out from
// the front, counting what is outstanding.
class BlockAllocator final : public vulkan::Allocator {
 public:
  BlockAllocator(const vulkan::Context& ctx, VkDeviceSize size) : device_(ctx.device()), size_(size) {
    VkMemoryAllocateInfo info{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
    info.allocationSize = size;
    info.memoryTypeIndex =
        ctx.find_memory_type(~0u, VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT, 0);
    vulkan::check(vkAllocateMemory(device_, &info, nullptr, &block_), "test block");
    vulkan::check(vkMapMemory(device_, block_, 0, VK_WHOLE_SIZE, 0, &mapped_), "test block map");
  }
  ~BlockAllocator() override {
    vkUnmapMemory(device_, block_);
    vkFreeMemory(device_, block_, nullptr);
  }
  vulkan::Allocation allocate(const VkMemoryRequirements& req, VkMemoryPropertyFlags, VkMemoryPropertyFlags,
                              const char* what) override {
    const VkDeviceSize offset = (next_ + req.alignment - 1) / req.alignment * req.alignment;
    if (offset + req.size > size_) throw std::runtime_error(std::string("test block is full: ") + what);
    next_ = offset + req.size;
    ++allocated_;
    ++outstanding_;
    return {block_, offset, static_cast<char*>(mapped_) + offset, nullptr};
  }
  void free(const vulkan::Allocation& a) noexcept override {
    if (a.memory == block_) --outstanding_;
  }
  int allocated() const { return allocated_; }
  int outstanding() const { return outstanding_; }

 private:
  VkDevice device_;
  VkDeviceSize size_, next_ = 0;
  VkDeviceMemory block_ = VK_NULL_HANDLE;
  void* mapped_ = nullptr;
  int allocated_ = 0, outstanding_ = 0;
};

// With an engine's allocator set, every buffer of a culler takes its memory from it and gives
// it back, and the answers are the reference's; an allocator that fails fails the upload with its
// error, and the culler stays usable.
TEST_F(Gpu, BuffersTakeTheirMemoryFromTheEngineAllocator) {
  vulkan::Context& ctx = *GpuEnvironment::context;
  BlockAllocator block(ctx, 64u << 20);
  ctx.set_allocator(&block);
  struct Unset {
    vulkan::Context& ctx;
    ~Unset() { ctx.set_allocator(nullptr); }
  } unset{ctx};
  {
    gpu::GpuCuller culler(ctx);
    test::Rng rng(5);
    std::vector<Aabb> boxes(20000);
    for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 2.0f);
    expect_agreement(culler, boxes, test_frusta());
    EXPECT_GT(block.allocated(), 5);
    EXPECT_GT(block.outstanding(), 5);                                         // the culler's buffers, held
    std::vector<Aabb> too_many(2'000'000, Aabb{glm::vec3(-1), glm::vec3(1)});  // 96 MB: past the block
    try {
      culler.upload(std::span<const Aabb>(too_many));
      ADD_FAILURE() << "an upload past the allocator's block succeeded";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("test block is full"), std::string::npos) << e.what();
    }
    ctx.set_allocator(nullptr);  // the culler goes on with its own memory
    expect_agreement(culler, boxes, test_frusta());
  }
  EXPECT_EQ(block.outstanding(), 0) << "buffers not given back to the allocator";
}

// The pass writes its draws, counters and visible ids into buffers the engine owns: the same
// answers as into its own, draw_buffer() names the engine's buffer, one too small is refused
// with the size it needs, and the culler's own buffers come back on request.
TEST_F(Gpu, OutputsGoIntoTheEnginesBuffers) {
  const vulkan::Context& ctx = *GpuEnvironment::context;
  test::Rng rng(8);
  std::vector<Aabb> boxes(5000);
  for (Aabb& b : boxes) b = test::random_aabb(rng, 30.0f, 2.0f);
  std::vector<gpu::DrawCommand> templates(boxes.size());
  for (std::uint32_t i = 0; i < templates.size(); ++i) templates[i] = {36, 1, 0, 0, i, 0};
  const std::vector<Frustum> frusta = test_frusta();
  const gpu::CullOptions options{true, true, 0, true, true};
  gpu::GpuCuller& c = culler();
  c.upload(std::span<const Aabb>(boxes));
  c.upload_draws(templates);
  const gpu::CullResult own = c.cull(frusta, options);

  constexpr VkBufferUsageFlags storage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
  const std::size_t per_view = boxes.size();
  vulkan::Buffer draws(ctx, frusta.size() * per_view * sizeof(gpu::DrawCommand),
                       storage | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT, "engine draws");
  vulkan::Buffer counters(ctx, frusta.size() * sizeof(gpu::ViewCounters),
                          storage | VK_BUFFER_USAGE_TRANSFER_DST_BIT | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT,
                          "engine counters");
  vulkan::Buffer visible(ctx, frusta.size() * per_view * sizeof(std::uint32_t), storage, "engine visible ids");
  gpu::EngineOutputs outputs{draws.handle(),  draws.size(),     draws.data(),   counters.handle(), counters.size(),
                             counters.data(), visible.handle(), visible.size(), visible.data()};
  struct OwnAgain {  // the shared culler never keeps this test's buffers, however it ends
    gpu::GpuCuller& c;
    ~OwnAgain() { c.use_own_outputs(); }
  } own_again{c};
  c.use_engine_outputs(outputs);
  EXPECT_EQ(c.draw_buffer().handle(), draws.handle());
  EXPECT_EQ(c.counter_buffer().handle(), counters.handle());
  const gpu::CullResult engine = c.cull(frusta, options);
  for (std::size_t v = 0; v < frusta.size(); ++v) {
    EXPECT_EQ(engine.views[v].classes, own.views[v].classes) << "view " << v;
    EXPECT_EQ(engine.views[v].visible_ids, own.views[v].visible_ids) << "view " << v;
    EXPECT_EQ(engine.views[v].counts, own.views[v].counts) << "view " << v;
    EXPECT_EQ(counters.as<const gpu::ViewCounters>()[v].visible_count, own.views[v].counts.visible);
    ASSERT_EQ(engine.views[v].draws.size(), own.views[v].draws.size());
    EXPECT_EQ(std::memcmp(engine.views[v].draws.data(), own.views[v].draws.data(),
                          engine.views[v].draws.size() * sizeof(gpu::DrawCommand)),
              0);
  }
  // Too small for the pass: refused with the size it needs, never replaced.
  outputs.draws_size = 100 * sizeof(gpu::DrawCommand);
  c.use_engine_outputs(outputs);
  try {
    c.cull(frusta, options);
    ADD_FAILURE() << "a pass wrote past the engine's draw buffer";
  } catch (const std::length_error& e) {
    EXPECT_NE(std::string(e.what()).find("engine's draw buffer"), std::string::npos) << e.what();
  }
  EXPECT_EQ(c.draw_buffer().handle(), draws.handle());
  // Without host addresses the results stay on the engine's side.
  c.use_engine_outputs({draws.handle(), draws.size(), nullptr, counters.handle(), counters.size(), nullptr});
  EXPECT_THROW(c.cull(frusta, options), std::logic_error);
  c.use_own_outputs();
  EXPECT_NE(c.draw_buffer().handle(), draws.handle());
  const gpu::CullResult back = c.cull(frusta, options);
  EXPECT_EQ(back.views[0].visible_ids, own.views[0].visible_ids);
}

}  // namespace
}  // namespace cullpipe
