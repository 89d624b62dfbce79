// The strongest test of culling: the image drawn from the culling pass's indirect draws equals
// the image drawn from every object, pixel for pixel, and the GPU issued exactly the visible
// objects' draws. Vulkan validation (with synchronization validation) is on; any message fails.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <glm/ext/matrix_double3x3.hpp>
#include <glm/ext/matrix_transform.hpp>
#include <glm/geometric.hpp>
#include <glm/matrix.hpp>
#include <map>
#include <memory>
#include <optional>

#include "cullpipe/bounds/mesh_bounds.hpp"
#include "cullpipe/bounds/sphere_fit.hpp"
#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/cull/occlusion.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/cull/software_depth.hpp"
#include "cullpipe/gpu/depth_pyramid_pass.hpp"
#include "cullpipe/render/image.hpp"
#include "cullpipe/render/renderer.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/gltf_scene.hpp"
#include "cullpipe/scene/scene_io.hpp"
#include "test_util.hpp"

namespace cullpipe {
namespace {

class RenderEnvironment : public ::testing::Environment {
 public:
  static inline std::unique_ptr<vulkan::Context> context;
  void SetUp() override {
    vulkan::ContextOptions options;
    options.validation = true;
    options.on_message = [](std::string_view m) { ADD_FAILURE() << m; };
    context = std::make_unique<vulkan::Context>(options);
  }
  void TearDown() override { context.reset(); }
};
const auto* const kEnv = ::testing::AddGlobalTestEnvironment(new RenderEnvironment);

const std::filesystem::path kScenes = std::filesystem::path(CULLPIPE_SHARED_DIR) / "scenes";

// `camera` moved towards its target to `factor` of its distance (an orbit closer than the
// framing camera leaves part of the model outside the view), its near plane brought in.
Camera closer(Camera camera, float factor) {
  camera.eye = camera.target + (camera.eye - camera.target) * factor;
  camera.near_plane *= 0.2f;
  return camera;
}

// The scene's world volumes of the kind the renderer's culling pass tests.
struct WorldVolumes {
  std::vector<Aabb> aabbs;
  std::vector<Obb> obbs;
  std::vector<Sphere> spheres;
  BvKind bv;
  WorldVolumes(const Scene& scene, BvKind kind) : bv(kind) {
    if (bv == BvKind::Aabb) aabbs = world_aabbs(scene);
    if (bv == BvKind::Obb) obbs = world_obbs(scene);
    if (bv == BvKind::Sphere) spheres = world_spheres(scene);
  }
  /// classify(span of the volumes), whatever their kind.
  template <class Classify>
  reference::CullCounts apply(Classify&& classify) const {
    if (bv == BvKind::Obb) return classify(std::span<const Obb>(obbs));
    if (bv == BvKind::Sphere) return classify(std::span<const Sphere>(spheres));
    return classify(std::span<const Aabb>(aabbs));
  }
};

// For each camera: culled image == unculled image; draws issued == visible objects by the CPU
// reference; triangles drawn == the visible objects' triangles. Returns the total number of
// (visible, culled) objects over the cameras, so callers can check the views were not trivial.
std::pair<std::size_t, std::size_t> expect_culling_invisible(const Scene& scene, const std::vector<Camera>& cameras,
                                                             BvKind bv, std::uint32_t width = 320,
                                                             std::uint32_t height = 200) {
  render::RendererConfig config;
  config.width = width;
  config.height = height;
  config.bv = bv;
  render::Renderer renderer(*RenderEnvironment::context, scene, config);
  const WorldVolumes volumes(scene, bv);
  std::size_t visible_total = 0, culled_total = 0;
  for (std::size_t v = 0; v < cameras.size(); ++v) {
    SCOPED_TRACE("camera " + std::to_string(v));
    render::FrameStats culled_stats, all_stats;
    const render::Image culled = renderer.render(cameras[v], true, &culled_stats);
    const render::Image all = renderer.render(cameras[v], false, &all_stats);
    EXPECT_EQ(render::count_different_pixels(culled, all), 0u);
    // The CPU reference's visible set.
    const Frustum f = Frustum::from_view_proj(cameras[v].view_proj());
    std::vector<Classification> cpu(scene.objects.size());
    const reference::CullCounts counts =
        volumes.apply([&](auto span) { return reference::classify_all(span, f, cpu); });
    EXPECT_EQ(culled_stats.classes, cpu);
    EXPECT_EQ(culled_stats.draws, counts.visible);
    EXPECT_EQ(all_stats.draws, scene.objects.size());
    if (culled_stats.primitives_counted) {
      std::uint64_t visible_triangles = 0, all_triangles = 0;
      for (std::size_t i = 0; i < cpu.size(); ++i) {
        all_triangles += renderer.triangles(i);
        if (cpu[i] != Classification::Outside) visible_triangles += renderer.triangles(i);
      }
      EXPECT_EQ(culled_stats.primitives, visible_triangles);
      EXPECT_EQ(all_stats.primitives, all_triangles);
    }
    visible_total += counts.visible;
    culled_total += scene.objects.size() - counts.visible;
    // Something is drawn.
    std::size_t background = 0;
    for (std::size_t p = 0; p < all.rgba.size(); p += 4)
      background += all.rgba[p] == all.rgba[0] && all.rgba[p + 1] == all.rgba[1];
    if (counts.visible > 0) {
      EXPECT_LT(background, all.rgba.size() / 4);
    }
  }
  return {visible_total, culled_total};
}

TEST(Render, GeneratedCityCulledEqualsUnculledForEveryVolume) {
  const Scene city = generate_scene(SceneKind::City, 3000, 4);
  const std::vector<Camera> cameras = camera_path(city.camera, city.bounds(), 4);
  for (BvKind bv : {BvKind::Aabb, BvKind::Obb, BvKind::Sphere}) {
    SCOPED_TRACE(std::string(to_string(bv)));
    const auto [visible, culled] = expect_culling_invisible(city, cameras, bv);
    EXPECT_GT(visible, 100u);
    EXPECT_GT(culled, 1000u);  // the test is not trivial: culling removed many draws
  }
}

// `base` with reversed Z, then also an infinite far plane, then an infinite far plane alone,
// and an orthographic view of the given half height.
std::vector<Camera> depth_conventions(const Camera& base, float ortho_half_height) {
  std::vector<Camera> cameras;
  Camera c = base;
  c.reversed_z = true;
  cameras.push_back(c);
  c.infinite_far = true;
  cameras.push_back(c);
  c.reversed_z = false;
  cameras.push_back(c);
  Camera ortho = base;
  ortho.orthographic = true;
  ortho.ortho_half_height = ortho_half_height;
  cameras.push_back(ortho);
  return cameras;
}

TEST(Render, DepthConventionsAndCamerasInsideTheScene) {
  const Scene scene = generate_scene(SceneKind::Uniform, 2000, 11);
  std::vector<Camera> cameras = depth_conventions(scene.camera, 20.0f);
  cameras.insert(cameras.begin(), scene.camera);
  expect_culling_invisible(scene, cameras, BvKind::Aabb);
}

TEST(Render, GltfScenesCulledEqualsUnculled) {
  if (!std::filesystem::exists(kScenes)) GTEST_SKIP() << kScenes << " not present";
  std::size_t files = 0;
  for (const char* name :
       {"VC/VC.gltf", "2CylinderEngine/2CylinderEngine.gltf", "NegativeScaleTest/NegativeScaleTest.gltf",
        "ReciprocatingSaw/ReciprocatingSaw.gltf", "CesiumMilkTruck/CesiumMilkTruck.gltf"}) {
    const std::filesystem::path path = kScenes / name;
    if (!std::filesystem::exists(path)) continue;
    SCOPED_TRACE(path.string());
    ++files;
    const GltfScene g = load_gltf_scene(path.string());
    std::vector<Camera> cameras = camera_path(closer(g.scene.camera, 0.45f), g.scene.bounds(), 4);
    for (std::size_t c = 0; c < g.cameras.size() && c < 3; ++c) {
      if (g.cameras[c].node < 0) continue;
      GltfSceneOptions o;
      o.camera = std::to_string(c);
      cameras.push_back(load_gltf_scene(path.string(), o).scene.camera);
    }
    expect_culling_invisible(g.scene, cameras, BvKind::Sphere);
    expect_culling_invisible(g.scene, cameras, BvKind::Obb);
  }
  EXPECT_EQ(files, 5u);
}

// Occlusion frames along a camera path (two phases, the visibility carried frame to frame): each
// image equals the unculled one pixel for pixel, and each frame's classes equal
// occlusion::classify_all's on the pyramid the frame built. Returns the occluded total.
std::size_t expect_occlusion_invisible(const Scene& scene, const std::vector<Camera>& cameras, BvKind bv,
                                       std::uint32_t width = 320, std::uint32_t height = 200,
                                       std::uint32_t texels_per_axis = 4) {
  render::RendererConfig config;
  config.width = width;
  config.height = height;
  config.bv = bv;
  config.occlusion.texels_per_axis = texels_per_axis;
  render::Renderer renderer(*RenderEnvironment::context, scene, config);
  const WorldVolumes volumes(scene, bv);
  std::size_t occluded_total = 0;
  for (std::size_t v = 0; v < cameras.size(); ++v) {
    SCOPED_TRACE("frame " + std::to_string(v));
    render::FrameStats stats, all_stats;
    const render::Image culled = renderer.render(cameras[v], render::CullMode::Occlusion, &stats);
    EXPECT_NE(renderer.pyramid(), nullptr);
    if (!renderer.pyramid()) return occluded_total;
    const occlusion::DepthPyramid pyramid = renderer.pyramid()->read();
    const render::Image all = renderer.render(cameras[v], render::CullMode::None, &all_stats);
    EXPECT_EQ(render::count_different_pixels(culled, all), 0u) << stats.occluded << " occluded";
    if (v == 0) {
      EXPECT_EQ(stats.first_phase_draws, 0u);  // nothing visible before the first frame
    }
    const glm::mat4 vp = cameras[v].view_proj();
    const Frustum f = Frustum::from_view_proj(vp);
    const occlusion::OcclusionView view{vp, width, height, cameras[v].reversed_z};
    std::vector<Classification> cpu(scene.objects.size());
    const reference::CullCounts counts = volumes.apply(
        [&](auto span) { return occlusion::classify_all(span, f, view, pyramid, config.occlusion, cpu); });
    EXPECT_EQ(stats.draws, counts.visible);
    EXPECT_EQ(stats.occluded, counts.occluded);
    // The contract itself: every object owning a pixel of the unculled image is drawn.
    const std::vector<bool> owners = renderer.pixel_owners(cameras[v]);
    std::size_t owning = 0;
    for (std::size_t i = 0; i < owners.size(); ++i) {
      if (!owners[i]) continue;
      ++owning;
      EXPECT_TRUE(is_visible(stats.classes[i]))
          << "object " << i << " owns a pixel but is " << to_string(stats.classes[i]);
    }
    occluded_total += counts.occluded;
    std::printf("  frame %zu: %zu drawn first, %zu kept by the frustum, %zu occluded, %zu drawn, %zu own a pixel\n", v,
                stats.first_phase_draws, counts.visible + counts.occluded, counts.occluded, stats.draws, owning);
  }
  return occluded_total;
}

TEST(Render, OcclusionFramesEqualUnculledAlongAPath) {
  const Scene city = load_scene(std::string(CULLPIPE_SOURCE_DIR) + "/scenes/default.json");
  std::vector<Camera> path = camera_path(city.camera, city.bounds(), 6);
  path.insert(path.begin(), city.camera);
  for (BvKind bv : {BvKind::Aabb, BvKind::Obb, BvKind::Sphere}) {
    SCOPED_TRACE(std::string(to_string(bv)));
    EXPECT_GT(expect_occlusion_invisible(city, path, bv), 200u);  // the test is not trivial
  }
  // Reversed Z, an infinite far plane, an orthographic view, 2 and 16 texels per axis.
  const std::vector<Camera> cameras = depth_conventions(city.camera, 60.0f);
  for (const std::uint32_t texels : {2u, 16u})
    expect_occlusion_invisible(city, cameras, BvKind::Aabb, 333, 187, texels);
}

// Boxes flush with walls: each pair shares a front face, drawn by two different box models, so
// their depths there differ by roundings only and the first drawn (the small box) wins the
// ties. Without the depth-side margins (the clip error and the depth margin, each alone enough
// here), or with no margins and a non-strict comparison, the test culls small boxes that own
// pixels and this fails.
TEST(Render, OcclusionKeepsBoxesFlushWithTheWallsBehindThem) {
  Scene scene;
  test::Rng rng(31);
  for (int k = 0; k < 40; ++k) {
    const glm::vec3 centre((k % 8) * 9.0f - 31.5f, (k / 8) * 9.0f - 18.0f, rng.uniform(-20.0f, 0.0f));
    glm::mat4 world = glm::translate(glm::mat4(1.0f), centre);
    // Half face the cameras (a face of one depth: the tie is everywhere), half are turned.
    if (k % 2)
      world =
          glm::rotate(world, rng.uniform(-0.6f, 0.6f), glm::normalize(rng.vec3(-1.0f, 1.0f) + glm::vec3(0, 0, 0.01f)));
    SceneObject small, wall;
    small.local_bounds = {{-1.0f, -1.0f, -0.5f}, {1.0f, 1.0f, 0.0f}};
    wall.local_bounds = {{-3.5f, -3.5f, -1.0f}, {3.5f, 3.5f, 0.0f}};
    small.world = wall.world = world;
    scene.objects.push_back(small);  // first: it wins the ties
    scene.objects.push_back(wall);
  }
  std::vector<Camera> cameras;
  for (int f = 0; f < 6; ++f) {
    Camera c;
    // Looking straight down -z (the unturned faces at one depth each), from places along a path.
    c.eye = {std::sin(f * 0.5f) * 8.0f, std::cos(f * 0.7f) * 5.0f, 60.0f};
    c.target = {c.eye.x, c.eye.y, -10.0f};
    c.aspect = 1.6f;
    c.near_plane = 1.0f;
    c.far_plane = 200.0f;
    c.reversed_z = f >= 3;
    cameras.push_back(c);
  }
  for (BvKind bv : {BvKind::Aabb, BvKind::Obb, BvKind::Sphere}) {
    SCOPED_TRACE(std::string(to_string(bv)));
    expect_occlusion_invisible(scene, cameras, bv, 480, 300);
  }
}

// `scene` with every other box object mirrored in x about its own centre: the same boxes, drawn
// through transforms with a negative determinant.
Scene mirror_every_other(Scene scene) {
  for (std::size_t i = 0; i < scene.objects.size(); i += 2) {
    SceneObject& o = scene.objects[i];
    const glm::vec3 c = (o.local_bounds.min + o.local_bounds.max) * 0.5f;
    o.world = glm::translate(glm::scale(glm::translate(o.world, c), glm::vec3(-1.0f, 1.0f, 1.0f)), -c);
  }
  return scene;
}

// Back faces culled as glTF asks change next to nothing on closed meshes seen from outside,
// mirrored or not: each image is the one with every face drawn but for a few pixels where
// touching buildings have coplanar faces, whose depth ties the first drawn face wins (with back
// faces culled, that may be another one). With the winding of a mirroring instance not flipped,
// or the front face the wrong way round, insides would show: 16,000 pixels of 64,000 here.
TEST(Render, BackFaceCullingKeepsClosedMeshesWhole) {
  const Scene city = generate_scene(SceneKind::City, 400, 7);
  std::vector<Scene> scenes = {city, mirror_every_other(city)};
  if (std::filesystem::exists(kScenes / "Box/Box.gltf"))
    scenes.push_back(load_gltf_scene((kScenes / "Box/Box.gltf").string()).scene);
  for (std::size_t k = 0; k < scenes.size(); ++k) {
    SCOPED_TRACE("scene " + std::to_string(k));
    render::RendererConfig config;
    config.width = 320;
    config.height = 200;
    render::Renderer culling(*RenderEnvironment::context, scenes[k], config);
    config.cull_back_faces = false;
    render::Renderer all(*RenderEnvironment::context, scenes[k], config);
    for (const Camera& camera : camera_path(scenes[k].camera, scenes[k].bounds(), 3)) {
      const render::Image a = culling.render(camera, render::CullMode::None),
                          b = all.render(camera, render::CullMode::None);
      EXPECT_LE(render::count_different_pixels(a, b), a.rgba.size() / 4 / 1000);
      std::size_t background = 0;
      for (std::size_t p = 0; p < a.rgba.size(); p += 4)
        background += a.rgba[p] == a.rgba[0] && a.rgba[p + 1] == a.rgba[1];
      EXPECT_LT(background, a.rgba.size() / 4 * 99 / 100);  // something is drawn
    }
  }
}

// What a run of cluster frames found, summed.
struct ClusterTotals {
  std::size_t frames = 0;
  std::array<std::size_t, 6> classes{};
  std::uint64_t cluster_triangles = 0, object_triangles = 0, visible_triangles = 0;
  std::size_t mirrored_back_facing = 0;  // back-facing clusters of mirroring objects
};

// Cluster frames along `cameras`, by the frustum and then with occlusion in two phases: each
// image equals the unculled image pixel for pixel; the triangles submitted are counted against
// object-level culling's in the same mode.
ClusterTotals expect_clusters_invisible(const Scene& scene, const std::vector<Camera>& cameras,
                                        std::uint32_t width = 320, std::uint32_t height = 200) {
  render::RendererConfig config;
  config.width = width;
  config.height = height;
  config.clusters = true;
  render::Renderer renderer(*RenderEnvironment::context, scene, config);
  EXPECT_TRUE(renderer.cluster_fallbacks().empty()) << renderer.cluster_fallbacks().front();
  config.clusters = false;
  render::Renderer objects(*RenderEnvironment::context, scene, config);
  ClusterTotals totals;
  for (const render::CullMode mode : {render::CullMode::Frustum, render::CullMode::Occlusion}) {
    for (std::size_t v = 0; v < cameras.size(); ++v) {
      SCOPED_TRACE(std::string(mode == render::CullMode::Frustum ? "frustum" : "occlusion") + " frame " +
                   std::to_string(v));
      render::FrameStats stats, object_stats;
      const render::Image culled = renderer.render(cameras[v], mode, &stats);
      const render::Image all = renderer.render(cameras[v], render::CullMode::None);
      EXPECT_EQ(render::count_different_pixels(culled, all), 0u)
          << stats.clusters_drawn << " of " << stats.clusters << " clusters drawn";
      objects.render(cameras[v], mode, &object_stats);
      EXPECT_EQ(stats.clusters_drawn, stats.cluster_classes[std::size_t(clusters::ClusterClass::Drawn)]);
      std::size_t sum = 0;
      for (std::size_t c = 0; c < stats.cluster_classes.size(); ++c) {
        totals.classes[c] += stats.cluster_classes[c];
        sum += stats.cluster_classes[c];
      }
      EXPECT_EQ(sum, stats.clusters);
      totals.cluster_triangles += stats.primitives;
      totals.object_triangles += object_stats.primitives;
      std::size_t p = 0;
      for (const gpu::ClusterInstance& in : renderer.cluster_instances()) {
        const glm::dmat3 linear(in.transform.to_mat4());
        for (std::uint32_t k = 0; k < in.cluster_count; ++k, ++p)
          totals.mirrored_back_facing += glm::determinant(linear) < 0.0 && p < stats.cluster_pair_classes.size() &&
                                         stats.cluster_pair_classes[p] == clusters::ClusterClass::BackFacing;
      }
      if (const std::optional<std::uint64_t> visible = renderer.visible_triangles(cameras[v])) {
        // Every triangle owning a pixel is among those submitted (the images are equal).
        if (stats.primitives_counted) {
          EXPECT_LE(*visible, stats.primitives);
        }
        totals.visible_triangles += *visible;
      }
      ++totals.frames;
    }
  }
  return totals;
}

TEST(Render, ClusterFramesEqualUnculled) {
  if (!std::filesystem::exists(kScenes)) GTEST_SKIP() << kScenes << " not present";
  ClusterTotals all;
  std::size_t files = 0;
  for (const char* name :
       {"FlightHelmet/FlightHelmet.gltf", "2CylinderEngine/2CylinderEngine.gltf",
        "ReciprocatingSaw/ReciprocatingSaw.gltf", "VC/VC.gltf", "NegativeScaleTest/NegativeScaleTest.gltf",
        "Lantern/Lantern.gltf", "Duck/Duck.gltf", "CesiumMilkTruck/CesiumMilkTruck.gltf",
        "OrientationTest/OrientationTest.gltf", "Box/Box.gltf"}) {
    const std::filesystem::path path = kScenes / name;
    if (!std::filesystem::exists(path)) continue;
    SCOPED_TRACE(path.string());
    ++files;
    const GltfScene g = load_gltf_scene(path.string());
    const ClusterTotals t =
        expect_clusters_invisible(g.scene, camera_path(closer(g.scene.camera, 0.6f), g.scene.bounds(), 4));
    std::printf(
        "%s: %llu triangles submitted with clusters, %llu by objects, %llu own a pixel; clusters outside %zu, "
        "back-facing %zu, occluded %zu, of culled objects %zu, drawn %zu\n",
        name, static_cast<unsigned long long>(t.cluster_triangles), static_cast<unsigned long long>(t.object_triangles),
        static_cast<unsigned long long>(t.visible_triangles), t.classes[0], t.classes[4], t.classes[3], t.classes[5],
        t.classes[1]);
    EXPECT_LE(t.cluster_triangles, t.object_triangles);
    for (std::size_t c = 0; c < all.classes.size(); ++c) all.classes[c] += t.classes[c];
  }
  EXPECT_EQ(files, 10u);
  for (const clusters::ClusterClass c : {clusters::ClusterClass::Outside, clusters::ClusterClass::BackFacing,
                                         clusters::ClusterClass::Occluded, clusters::ClusterClass::Drawn})
    EXPECT_GT(all.classes[std::size_t(c)], 100u) << "too few clusters " << to_string(c) << " to test the images";
}

// Instances of one mesh, a quarter of them mirrored, their clusters culled as facing away too.
TEST(Render, ClusterFramesOfMirroredMeshesEqualUnculled) {
  const Scene meshes = generate_scene(SceneKind::Meshes, 300, 5);
  std::vector<Camera> path = camera_path(meshes.camera, meshes.bounds(), 3);
  path.insert(path.begin(), meshes.camera);
  const ClusterTotals t = expect_clusters_invisible(meshes, path);
  EXPECT_GT(t.mirrored_back_facing, 100u);
  EXPECT_LT(t.cluster_triangles, t.object_triangles * 3 / 4);
}

// The same instances with a double-sided mesh: each cluster is drawn twice, the second time
// reversed, and each copy is culled by its own cone (the first where the eye is behind the
// mesh's triangles, the second where it is in front), mirrored instances too.
TEST(Render, ClusterFramesOfDoubleSidedMeshesEqualUnculled) {
  Scene meshes = generate_scene(SceneKind::Meshes, 300, 5);
  std::map<const TriangleMesh*, std::shared_ptr<const TriangleMesh>> double_sided;
  for (SceneObject& o : meshes.objects) {
    if (!o.triangles) continue;
    auto& copy = double_sided[o.triangles.get()];
    if (!copy) {
      auto mesh = std::make_shared<TriangleMesh>(*o.triangles);
      mesh->double_sided = true;
      copy = std::move(mesh);
    }
    o.triangles = copy;
  }
  std::vector<Camera> path = camera_path(meshes.camera, meshes.bounds(), 3);
  path.insert(path.begin(), meshes.camera);
  const ClusterTotals t = expect_clusters_invisible(meshes, path);
  EXPECT_GT(t.classes[std::size_t(clusters::ClusterClass::BackFacing)], 1000u);
  EXPECT_GT(t.mirrored_back_facing, 100u);
  EXPECT_LT(t.cluster_triangles, t.object_triangles * 3 / 4);
}

// Open double-sided sheets (a wavy grid, nothing behind it), tilted, some mirrored, seen from
// above and from below: each winding's clusters are culled by their own cone, and a cone that
// culled a winding the eye sees would show in the image.
TEST(Render, ClusterFramesOfOpenDoubleSidedSheetsEqualUnculled) {
  auto sheet = std::make_shared<TriangleMesh>();
  const int n = 40;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) {
      const float x = -5.0f + 10.0f * float(i) / n, z = -5.0f + 10.0f * float(j) / n;
      sheet->positions.emplace_back(x, 0.3f * std::sin(x) * std::cos(z), z);
    }
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const std::uint32_t a = std::uint32_t(j * (n + 1) + i), b = a + 1, c = a + std::uint32_t(n + 1), d = c + 1;
      sheet->indices.insert(sheet->indices.end(), {a, c, b, b, c, d});
    }
  sheet->double_sided = true;
  auto bounds = std::make_shared<const bounds::MeshBounds>(sheet->positions);
  Scene scene;
  for (int k = 0; k < 6; ++k) {
    SceneObject o;
    o.local_bounds = bounds::aabb_of_points(sheet->positions);
    o.world = glm::rotate(
        glm::translate(glm::mat4(1.0f), glm::vec3(12.0f * float(k % 3) - 12.0f, 0.0f, 12.0f * float(k / 3) - 6.0f)),
        0.3f * float(k), glm::vec3(1, 0, 0));
    if (k % 3 == 1) o.world = glm::scale(o.world, glm::vec3(-1.0f, 1.0f, 1.0f));  // mirrored
    o.mesh = bounds;
    o.triangles = sheet;
    scene.objects.push_back(o);
  }
  Camera above;
  above.eye = glm::vec3(4.0f, 22.0f, 18.0f);
  above.target = glm::vec3(0.0f);
  above.near_plane = 0.5f;
  above.far_plane = 200.0f;
  Camera below = above;
  below.eye = glm::vec3(-4.0f, -22.0f, -18.0f);
  Camera grazing = above;
  grazing.eye = glm::vec3(30.0f, 2.0f, 3.0f);
  const ClusterTotals t = expect_clusters_invisible(scene, {above, below, grazing, above});
  EXPECT_GT(t.classes[std::size_t(clusters::ClusterClass::BackFacing)], 100u);
}

TEST(Render, ClusterFramesOfBoxesEqualUnculled) {
  const Scene city = load_scene(std::string(CULLPIPE_SOURCE_DIR) + "/scenes/default.json");
  std::vector<Camera> path = camera_path(city.camera, city.bounds(), 3);
  path.insert(path.begin(), city.camera);
  const ClusterTotals t = expect_clusters_invisible(mirror_every_other(city), path);
  EXPECT_GT(t.classes[std::size_t(clusters::ClusterClass::ObjectCulled)], 100u);
}

// The CPU occlusion path against the GPU's render: every pixel of a software depth buffer (at the
// viewport's size and smaller) holds a depth no nearer than the render's depth at every pixel
// centre it covers, with the scene's boxes as occluders; objects it finds occluded own no pixel
// of the unculled image; and it culls a good part of what the GPU path culls on the same frame.
void expect_software_depth_conservative(const Scene& scene, const std::vector<Camera>& cameras, std::uint32_t width,
                                        std::uint32_t height) {
  render::RendererConfig config;
  config.width = width;
  config.height = height;
  render::Renderer renderer(*RenderEnvironment::context, scene, config);
  gpu::DepthPyramidPass pass(*RenderEnvironment::context);
  ThreadPool pool(2);
  const std::vector<occlusion::OccluderBox> occluders = render::box_occluders(scene);
  const std::vector<Aabb> boxes = world_aabbs(scene);
  std::size_t covered = 0, occluded = 0, gpu_occluded = 0;
  for (std::size_t v = 0; v < cameras.size(); ++v) {
    const Camera& camera = cameras[v];
    const occlusion::OcclusionView view{camera.view_proj(), width, height, camera.reversed_z};
    const Frustum frustum = Frustum::from_view_proj(camera.view_proj());
    renderer.render(camera, render::CullMode::None);
    const occlusion::DepthPyramid full = pass.build(renderer.depth_source(), camera.reversed_z);
    for (const auto& [w, h] :
         {std::pair{width, height}, std::pair{width / 4, height / 4}, std::pair{width / 3 + 1, height / 5 + 1}}) {
      const occlusion::SoftwareDepth soft = occlusion::rasterise_occluders(occluders, view, w, h, &pool);
      const float clear = camera.reversed_z ? 0.0f : 1.0f;
      for (std::uint32_t y = 0; y < height; ++y)
        for (std::uint32_t x = 0; x < width; ++x) {
          const std::uint32_t px = std::uint32_t((x + 0.5) * w / width), py = std::uint32_t((y + 0.5) * h / height);
          const float cpu = soft.depth[std::size_t(py) * w + px], gpu = full.at(0, x, y);
          ASSERT_TRUE(camera.reversed_z ? cpu <= gpu : cpu >= gpu)
              << "camera " << v << (camera.reversed_z ? " (reversed Z)" : "") << ", " << w << "x" << h
              << " buffer: pixel " << x << "," << y << " (buffer pixel " << px << "," << py << ") rendered at depth "
              << gpu << ", software depth " << cpu;
        }
      std::size_t written = 0;
      for (float d : soft.depth) written += d != clear;
      EXPECT_GT(written, 0u) << "camera " << v << ", " << w << "x" << h << " buffer: nothing written";
      covered += written;
    }
    // End to end at a quarter of the size, against the objects owning a pixel.
    std::vector<Classification> classes(boxes.size());
    const reference::CullCounts counts = occlusion::cull_with_software_depth(
        std::span<const Aabb>(boxes), std::span<const occlusion::OccluderBox>(occluders), frustum, view, width / 4,
        height / 4, {}, std::span<Classification>(classes), &pool);
    const std::vector<bool> owners = renderer.pixel_owners(camera);
    for (std::size_t i = 0; i < boxes.size(); ++i)
      ASSERT_FALSE(owners[i] && classes[i] == Classification::Occluded)
          << "camera " << v << ": object " << i << " owns a pixel, the software depth hid it";
    occluded += counts.occluded;
    // The GPU path on the render's full depth, for comparison.
    std::vector<Classification> gpu_classes(boxes.size());
    gpu_occluded +=
        occlusion::classify_all(std::span<const Aabb>(boxes), frustum, view, full, {}, gpu_classes).occluded;
  }
  EXPECT_GT(covered, 0u);
  EXPECT_GT(occluded, gpu_occluded / 4) << "software depth " << occluded << ", full depth " << gpu_occluded;
  std::printf("software depth: %zu occluded, the render's own depth: %zu\n", occluded, gpu_occluded);
}

TEST(Render, SoftwareDepthIsNeverNearerThanTheRender) {
  const Scene city = load_scene(std::string(CULLPIPE_SOURCE_DIR) + "/scenes/default.json");
  std::vector<Camera> cameras = depth_conventions(city.camera, 60.0f);
  cameras.insert(cameras.begin(), city.camera);
  expect_software_depth_conservative(city, cameras, 320, 180);
  const Scene streets = generate_scene(SceneKind::Streets, 3000, 2);
  expect_software_depth_conservative(streets, scene_camera_path(streets, 5), 333, 187);
}

// Which debug colour a shaded pixel of a class image was drawn with: the class colour nearest in
// direction (shading scales a colour by 0.35 to 1). Grey and dark grey share a direction: grey.
std::uint32_t class_color_of(const render::Image& img, std::size_t p) {
  const glm::vec3 c(img.rgba[p], img.rgba[p + 1], img.rgba[p + 2]);
  std::uint32_t best = 0;
  float best_cos = -1.0f;
  for (const std::uint32_t k : {render::kColorInside, render::kColorIntersecting, render::kColorOutside,
                                render::kColorOccluded, render::kColorBackFacing}) {
    const glm::vec3 d(float(k >> 24), float(k >> 16 & 255u), float(k >> 8 & 255u));
    const float cos = glm::dot(c, d) / (glm::length(c) * glm::length(d) + 1e-6f);
    if (cos > best_cos) best_cos = cos, best = k;
  }
  return best;
}

// Pixels of `classes` (a class image) per debug colour, over the pixels an object covers: those
// where `reference`, the unculled image from the same camera, differs (the two share only the
// background, as no object's colour is a class colour).
std::map<std::uint32_t, std::size_t> class_pixels(const render::Image& classes, const render::Image& reference) {
  std::map<std::uint32_t, std::size_t> count;
  for (std::size_t p = 0; p < classes.rgba.size(); p += 4)
    if (!std::equal(classes.rgba.begin() + std::ptrdiff_t(p), classes.rgba.begin() + std::ptrdiff_t(p + 4),
                    reference.rgba.begin() + std::ptrdiff_t(p)))
      ++count[class_color_of(classes, p)];
  return count;
}

// Class images: from the frame's own camera only drawn colours show (nothing culled owns a
// pixel); from the far side of the target the clusters facing away from the camera show blue.
TEST(Render, ClassImagesShowWhatEachTestCulled) {
  const Scene meshes = generate_scene(SceneKind::Meshes, 300, 5);
  render::RendererConfig config;
  config.width = 320;
  config.height = 200;
  config.clusters = true;
  render::Renderer clusters(*RenderEnvironment::context, meshes, config);
  const Camera camera = meshes.camera;
  render::FrameStats stats;
  clusters.render(camera, render::CullMode::Occlusion, &stats);
  clusters.render(camera, render::CullMode::Occlusion, &stats);  // with the first frame's visibility
  ASSERT_GT(stats.cluster_classes[std::size_t(clusters::ClusterClass::BackFacing)], 0u);
  const render::Image all = clusters.render(camera, render::CullMode::None);
  std::map<std::uint32_t, std::size_t> seen = class_pixels(clusters.class_image(camera, stats), all);
  EXPECT_GT(seen[render::kColorInside], 1000u);
  for (const auto& [color, pixels] : seen)
    EXPECT_TRUE(color == render::kColorInside || pixels == 0) << pixels << " pixels of colour " << std::hex << color;

  Camera behind = camera;
  behind.eye = 2.0f * camera.target - camera.eye;
  behind.eye.y = camera.eye.y;
  seen = class_pixels(clusters.class_image(behind, stats), clusters.render(behind, render::CullMode::None));
  EXPECT_GT(seen[render::kColorBackFacing], 50u);  // (~150 of 57,000 pixels; most show culled objects)
  EXPECT_GT(seen[render::kColorOutside], 10000u);

  // Objects: the city's, inside or intersecting from the camera; the front view shows the rest.
  const Scene city = load_scene(std::string(CULLPIPE_SOURCE_DIR) + "/scenes/default.json");
  config.clusters = false;
  render::Renderer objects(*RenderEnvironment::context, city, config);
  render::FrameStats object_stats;
  objects.render(city.camera, render::CullMode::Occlusion, &object_stats);
  objects.render(city.camera, render::CullMode::Occlusion, &object_stats);
  ASSERT_GT(object_stats.occluded, 0u);
  seen =
      class_pixels(objects.class_image(city.camera, object_stats), objects.render(city.camera, render::CullMode::None));
  EXPECT_GT(seen[render::kColorInside] + seen[render::kColorIntersecting], 1000u);
  for (const auto& [color, pixels] : seen)
    EXPECT_TRUE(color == render::kColorInside || color == render::kColorIntersecting || pixels == 0)
        << pixels << " pixels of colour " << std::hex << color;
  const Camera front = render::front_view_camera(city.bounds(), city.camera, 320.0f / 200.0f);
  render::Image view = objects.class_image(front, object_stats);
  seen = class_pixels(view, objects.render(front, render::CullMode::None));
  EXPECT_GT(seen[render::kColorOutside], 100u);
  EXPECT_GT(seen[render::kColorOccluded], 10u);
  const render::Image plain = view;
  render::draw_frustum(view, front, city.camera, 1e4f);
  std::size_t white = 0;
  for (std::size_t p = 0; p < view.rgba.size(); p += 4)
    white += view.rgba[p] == 255 && view.rgba[p + 1] == 255 && view.rgba[p + 2] == 255;
  EXPECT_GT(white, 100u);  // the frustum's edges
  EXPECT_LT(render::count_different_pixels(view, plain), view.rgba.size() / 16);

  EXPECT_THROW(objects.class_image(front, render::FrameStats{}), std::invalid_argument);
  EXPECT_THROW(clusters.class_image(front, object_stats), std::invalid_argument);
}

TEST(Render, TopDownImageAndPng) {
  const Scene city = generate_scene(SceneKind::City, 500, 2);
  const std::vector<Aabb> boxes = world_aabbs(city);
  std::vector<Classification> classes(boxes.size());
  reference::classify_all(std::span<const Aabb>(boxes), Frustum::from_view_proj(city.camera.view_proj()), classes);
  const render::Image img = render::top_down_image(boxes, classes, city.camera, 400);
  EXPECT_GE(std::max(img.width, img.height), 399u);
  EXPECT_LE(std::max(img.width, img.height), 420u);
  std::size_t inside = 0, outside = 0, white = 0;
  for (std::size_t p = 0; p < img.rgba.size(); p += 4) {
    const std::uint32_t c = std::uint32_t(img.rgba[p]) << 24 | std::uint32_t(img.rgba[p + 1]) << 16 |
                            std::uint32_t(img.rgba[p + 2]) << 8 | img.rgba[p + 3];
    inside += c == render::kColorInside;
    outside += c == render::kColorOutside;
    white += c == 0xffffffffu;
  }
  EXPECT_GT(inside, 100u);
  EXPECT_GT(outside, 100u);
  EXPECT_GT(white, 100u);  // the frustum's edges
  const auto path = std::filesystem::temp_directory_path() / "cullpipe_top_down_test.png";
  render::write_png(path.string(), img);
  EXPECT_GT(std::filesystem::file_size(path), 1000u);
  std::filesystem::remove(path);
  EXPECT_THROW(render::write_png("/nonexistent-dir/x.png", img), InputError);
  // Atomic: a failed write leaves the earlier file whole and no temporary behind.
  const auto dir = std::filesystem::temp_directory_path() / "cullpipe_png_atomic";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const auto kept = dir / "kept.png";
  render::write_png(kept.string(), img);
  const auto size = std::filesystem::file_size(kept);
  std::filesystem::create_directory(dir / "blocker.png.tmp");  // the temporary cannot be created
  EXPECT_THROW(render::write_png((dir / "blocker.png").string(), img), InputError);
  EXPECT_FALSE(std::filesystem::exists(dir / "blocker.png"));
  EXPECT_EQ(std::filesystem::file_size(kept), size);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace cullpipe
