// Instances on the GPU: meshes' local volumes and per-object transforms uploaded, objects placed
// by the GPU, and every pass's classes equal to the reference's on the CPU's placed volumes
// (InstanceSet::world_volumes), object by object, over frames of moving, added and removed
// objects. Validation layers on; any message fails.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <glm/ext/matrix_transform.hpp>
#include <glm/gtc/quaternion.hpp>
#include <random>
#include <sstream>
#include <stdexcept>

#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/cull/compare.hpp"
#include "cullpipe/cull/instances.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/gpu/bvh_culler.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/vulkan/context.hpp"
#include "gpu_test_env.hpp"
#include "test_util.hpp"

namespace cullpipe {
namespace {

using GpuEnvironment = test::GpuTestEnvironment<gpu::GpuCuller>;
const auto* const kEnvironment = ::testing::AddGlobalTestEnvironment(new GpuEnvironment);
using GpuInstances = test::GpuTest<gpu::GpuCuller>;

float uniform(std::mt19937& rng, float lo, float hi) { return std::uniform_real_distribution<float>(lo, hi)(rng); }

// Placements around the origin: rotations, non-uniform and mirrored scales, flattened objects.
Transform3x4 random_placement(std::mt19937& rng, float spread) {
  const glm::quat q =
      glm::normalize(glm::quat(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)));
  glm::vec3 scale(uniform(rng, 0.2f, 3.0f), uniform(rng, 0.2f, 3.0f), uniform(rng, 0.2f, 3.0f));
  if (rng() % 8 == 0) scale.x = -scale.x;
  if (rng() % 16 == 0) scale.z = 0.0f;
  const glm::vec3 t(uniform(rng, -spread, spread), uniform(rng, -spread, spread), uniform(rng, -spread, spread) - 5.0f);
  return Transform3x4::from_mat4(glm::translate(glm::mat4(1.0f), t) * glm::mat4_cast(q) *
                                 glm::scale(glm::mat4(1.0f), scale));
}

std::vector<Aabb> box_meshes(std::mt19937& rng, std::size_t n) {
  std::vector<Aabb> meshes;
  for (std::size_t i = 0; i < n; ++i) {
    const glm::vec3 c(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1));
    const glm::vec3 h(uniform(rng, 0, 1.5f), uniform(rng, 0, 1.5f), uniform(rng, 0, 1.5f));
    meshes.push_back({c - h, c + h});
  }
  return meshes;
}

std::vector<Obb> obb_meshes(std::mt19937& rng, std::size_t n) {
  std::vector<Obb> meshes;
  for (std::size_t i = 0; i < n; ++i) {
    const glm::quat q =
        glm::normalize(glm::quat(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)));
    meshes.push_back({glm::vec3(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)), glm::mat3_cast(q),
                      glm::vec3(uniform(rng, 0, 1.5f), uniform(rng, 0, 1.5f), uniform(rng, 0, 1.5f))});
  }
  return meshes;
}

std::vector<Sphere> sphere_meshes(std::mt19937& rng, std::size_t n) {
  std::vector<Sphere> meshes;
  for (std::size_t i = 0; i < n; ++i)
    meshes.push_back({glm::vec3(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)), uniform(rng, 0, 2)});
  return meshes;
}

Aabb random_box_near(std::mt19937& rng) {
  const glm::vec3 c(uniform(rng, -15, 15), uniform(rng, -15, 15), uniform(rng, -20, 10));
  const glm::vec3 h(uniform(rng, 0, 2), uniform(rng, 0, 2), uniform(rng, 0, 2));
  return {c - h, c + h};
}

std::string describe(const Transform3x4& t) {
  std::ostringstream s;
  s.precision(9);
  for (const glm::vec4& r : t.rows) s << "(" << r.x << ", " << r.y << ", " << r.z << ", " << r.w << ") ";
  return s.str();
}

// Views that cut through the scene: cameras around it, and one whose planes each touch a placed
// volume exactly (its p-vertex on the plane), where a placement off by one bit changes a class.
template <class Volume>
std::vector<Frustum> views_for(std::mt19937& rng, std::span<const Volume> world) {
  std::vector<Frustum> views;
  for (int v = 0; v < 3; ++v) {
    glm::mat4 proj = glm::perspectiveRH_ZO(glm::radians(uniform(rng, 30, 90)), 1.5f, 0.5f, 60.0f);
    proj[1][1] *= -1.0f;
    const glm::vec3 eye(uniform(rng, -20, 20), uniform(rng, -5, 5), uniform(rng, 5, 25));
    views.push_back(
        Frustum::from_view_proj(proj * glm::lookAtRH(eye, glm::vec3(uniform(rng, -5, 5), 0, -5), glm::vec3(0, 1, 0))));
  }
  if (!world.empty()) {
    std::vector<glm::vec4> planes;
    for (int k = 0; k < 6; ++k) {
      const Volume& w = world[rng() % world.size()];
      glm::vec3 n = glm::normalize(glm::vec3(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)));
      const Plane unit = Frustum::from_planes(std::vector<glm::vec4>{glm::vec4(n, 0.0f)}).planes[0];
      n = unit.normal;
      glm::vec3 touch;
      if constexpr (std::is_same_v<Volume, Aabb>) {
        touch = {n.x >= 0 ? w.max.x : w.min.x, n.y >= 0 ? w.max.y : w.min.y, n.z >= 0 ? w.max.z : w.min.z};
      } else if constexpr (std::is_same_v<Volume, Obb>) {
        touch = w.center;
        for (int a = 0; a < 3; ++a)
          touch += w.basis[a] * (glm::dot(n, w.basis[a]) >= 0 ? w.half_extents[a] : -w.half_extents[a]);
      } else {
        touch = w.center + n * w.radius;
      }
      const Plane through{n, 0.0f};
      planes.push_back(glm::vec4(n, -through.distance(touch)));
    }
    views.push_back(Frustum::from_planes(planes));
  }
  return views;
}

// The GPU's last pass against the reference on the set's placed volumes, view by view; the
// first difference is reported with the object's id, mesh, local volume, transform and placed
// volume, and both answers.
template <class Volume>
void expect_reference(const InstanceSet<Volume>& set, const gpu::CullResult& result, std::span<const Frustum> views,
                      const std::string& when) {
  std::vector<Volume> world(set.size());
  set.world_volumes(world);
  ASSERT_EQ(result.views.size(), views.size()) << when;
  for (std::size_t v = 0; v < views.size(); ++v) {
    std::vector<Classification> cpu(world.size());
    const reference::CullCounts counts = reference::classify_all(std::span<const Volume>(world), views[v], cpu);
    const gpu::ViewResult& g = result.views[v];
    ASSERT_EQ(g.classes.size(), cpu.size()) << when << ", view " << v;
    const std::size_t s = first_mismatch(cpu, g.classes);
    ASSERT_EQ(s, npos) << when << ", view " << v << ": slot " << s << " (id " << set.ids()[s] << ", mesh "
                       << set.mesh_indices()[s] << ", local " << cullpipe::describe(set.meshes()[set.mesh_indices()[s]])
                       << ", transform " << describe(set.transforms()[s]) << ", placed " << cullpipe::describe(world[s])
                       << "): cpu says " << to_string(cpu[s]) << ", gpu says " << to_string(g.classes[s])
                       << "; frustum " << cullpipe::describe(views[v]);
    EXPECT_EQ(g.counts, counts) << when << ", view " << v;
    std::vector<std::uint32_t> ids = g.visible_ids;
    std::sort(ids.begin(), ids.end());
    std::vector<std::uint32_t> expected;
    for (std::size_t i = 0; i < cpu.size(); ++i)
      if (cpu[i] != Classification::Outside) expected.push_back(static_cast<std::uint32_t>(i));
    EXPECT_EQ(ids, expected) << when << ", view " << v;
  }
}

template <class Volume>
void run_frames(gpu::GpuCuller& culler, std::vector<Volume> meshes, std::size_t objects, std::uint32_t seed) {
  std::mt19937 rng(seed);
  InstanceSet<Volume> set(std::move(meshes));
  std::vector<InstanceId> live;
  for (std::size_t i = 0; i < objects; ++i)
    live.push_back(set.add(static_cast<std::uint32_t>(rng() % set.meshes().size()), random_placement(rng, 15.0f)));
  culler.upload(set);
  set.clear_changes();
  EXPECT_EQ(culler.pending_placements(), set.size());
  for (int frame = 0; frame < 12; ++frame) {
    std::vector<Volume> world(set.size());
    set.world_volumes(world);
    const std::vector<Frustum> views = views_for<Volume>(rng, world);
    const gpu::CullResult result = culler.cull(views);
    EXPECT_EQ(culler.pending_placements(), 0u);
    expect_reference(set, result, views, "frame " + std::to_string(frame));
    if (::testing::Test::HasFatalFailure()) return;
    // A tenth of the objects move; some come and go (on frame 5, twice as many come as were
    // there, past the buffers' room); on odd frames two updates reach one pass.
    const std::size_t moves = std::max<std::size_t>(1, live.size() / 10);
    for (std::size_t k = 0; k < moves && !live.empty(); ++k)
      set.set_transform(live[rng() % live.size()], random_placement(rng, 15.0f));
    if (frame % 2 == 1) {
      culler.update(set, set.changed_slots());
      set.clear_changes();
    }
    for (std::size_t k = 0; k < objects / 20 && !live.empty(); ++k) {
      const std::size_t r = rng() % live.size();
      set.remove(live[r]);
      live[r] = live.back();
      live.pop_back();
    }
    const std::size_t adds = frame == 5 ? 2 * objects + 300 : objects / 25;
    for (std::size_t k = 0; k < adds; ++k)
      live.push_back(set.add(static_cast<std::uint32_t>(rng() % set.meshes().size()), random_placement(rng, 15.0f)));
    culler.update(set, set.changed_slots());
    set.clear_changes();
    EXPECT_EQ(culler.object_count(), set.size());
  }
}

TEST_F(GpuInstances, BoxesAgreeWithTheReferenceOnEveryFrame) {
  std::mt19937 rng(1);
  for (const std::size_t n : {1u, 255u, 1000u, 20000u}) {
    SCOPED_TRACE(n);
    run_frames<Aabb>(culler(), box_meshes(rng, 7), n, static_cast<std::uint32_t>(n));
    if (HasFatalFailure()) return;
  }
}

// OBBs are placed on the host and sent: the same frames, the same contract.
TEST_F(GpuInstances, ObbsAgreeWithTheReferenceOnEveryFrame) {
  std::mt19937 rng(3);
  for (const std::size_t n : {1u, 300u, 20000u}) {
    SCOPED_TRACE(n);
    run_frames<Obb>(culler(), obb_meshes(rng, 5), n, static_cast<std::uint32_t>(n) + 11);
    if (HasFatalFailure()) return;
  }
}

TEST_F(GpuInstances, SpheresAgreeWithTheReferenceOnEveryFrame) {
  std::mt19937 rng(2);
  for (const std::size_t n : {1u, 256u, 20000u}) {
    SCOPED_TRACE(n);
    run_frames<Sphere>(culler(), sphere_meshes(rng, 5), n, static_cast<std::uint32_t>(n) + 7);
    if (HasFatalFailure()) return;
  }
}

// The node boxes the device holds against bvh::refit's on the CPU's placed volumes, bit for bit
// (a -0 where the CPU has +0 is a difference).
void expect_refit(const gpu::BvhCuller& culler, const bvh::FlatTree& tree, const std::string& when) {
  const std::vector<Aabb> gpu = culler.node_boxes();
  ASSERT_EQ(gpu.size(), tree.nodes.size()) << when;
  for (std::size_t i = 0; i < gpu.size(); ++i)
    ASSERT_TRUE(std::memcmp(&gpu[i], &tree.nodes[i].box, sizeof(Aabb)) == 0)
        << when << ": node " << i << " (" << (tree.nodes[i].leaf ? "leaf" : "inner") << ", objects "
        << tree.nodes[i].first << ".." << tree.nodes[i].first + tree.nodes[i].count << "): cpu refit "
        << cullpipe::describe(tree.nodes[i].box) << ", gpu refit " << cullpipe::describe(gpu[i]);
}

// A tree over moving boxes: built once on the host, then each frame some of the objects move
// (some far out, loosening the tree), the device places them and refits the tree above them,
// and the pass's classes and
// test counts equal bvh::cull_hierarchical's on the CPU-refitted tree, and its node boxes
// bvh::refit's. Some frames refit without culling first, some send two updates to one pass.
TEST_F(GpuInstances, TreesOverMovingBoxesAreRefittedOnTheDevice) {
  gpu::BvhCuller bvh_culler(*GpuEnvironment::context);
  std::mt19937 rng(11);
  for (const std::size_t n : {1u, 300u, 20000u}) {
    SCOPED_TRACE(n);
    InstanceSet<Aabb> set(box_meshes(rng, 6));
    std::vector<InstanceId> ids;
    for (std::size_t i = 0; i < n; ++i)
      ids.push_back(set.add(static_cast<std::uint32_t>(rng() % 6), random_placement(rng, 15.0f)));
    std::vector<Aabb> world(n);
    set.world_volumes(world);
    bvh::FlatTree tree = bvh::flatten(bvh::build_binned_sah(world));
    // Uploaded with looser boxes than a refit gives (as a tree refitted to older boxes has): the
    // device's boxes are still bvh::refit's, every frame, though only moved paths are refitted.
    bvh::FlatTree loose = tree;
    for (bvh::FlatNode& node : loose.nodes) node.box = {node.box.min - 1.0f, node.box.max + 1.0f};
    bvh_culler.upload(loose, set);
    bvh::refit(tree, world);
    expect_refit(bvh_culler, tree, "upload");
    set.clear_changes();
    EXPECT_EQ(bvh_culler.pending_placements(), 0u);  // uploaded as placed
    for (int frame = 0; frame < 8; ++frame) {
      const std::string when = "frame " + std::to_string(frame);
      // A tenth of the objects move; on frame 4 all of them (the whole tree refitted), on frame
      // 6 one (its leaf's path alone).
      const std::size_t moves = frame == 4 ? n : frame == 6 ? 1 : std::max<std::size_t>(1, n / 10);
      for (std::size_t k = 0; k < moves; ++k)
        set.set_transform(frame == 4 ? ids[k] : ids[rng() % n], random_placement(rng, frame % 3 == 2 ? 30.0f : 15.0f));
      bvh_culler.update(set, set.changed_slots());
      set.clear_changes();
      if (frame % 2 == 1) {  // the same objects again, and more, before any pass
        for (std::size_t k = 0; k < std::max<std::size_t>(1, n / 20); ++k)
          set.set_transform(ids[rng() % n], random_placement(rng, 15.0f));
        bvh_culler.update(set, set.changed_slots());
        set.clear_changes();
      }
      EXPECT_GT(bvh_culler.pending_placements(), 0u);
      set.world_volumes(world);
      bvh::refit(tree, world);
      if (frame % 3 == 0) {
        bvh_culler.refit();
        EXPECT_EQ(bvh_culler.pending_placements(), 0u);
        expect_refit(bvh_culler, tree, when + ", refit()");
        if (HasFatalFailure()) return;
      }
      const std::vector<Frustum> views = views_for<Aabb>(rng, world);
      gpu::CullOptions options;
      options.classes = true;
      const gpu::CullResult result = bvh_culler.cull(views, options);
      expect_refit(bvh_culler, tree, when);
      if (HasFatalFailure()) return;
      for (std::size_t v = 0; v < views.size(); ++v) {
        const bvh::HierarchicalResult cpu = bvh::cull_hierarchical(tree, std::span<const Aabb>(world), views[v]);
        const std::size_t s = first_mismatch(cpu.classes, result.views[v].classes);
        ASSERT_EQ(s, npos) << when << ", view " << v << ": slot " << s << " (transform "
                           << describe(set.transforms()[s]) << ", placed " << cullpipe::describe(world[s])
                           << "): cpu says " << to_string(cpu.classes[s]) << ", gpu says "
                           << to_string(result.views[v].classes[s]);
        EXPECT_EQ(result.views[v].node_tests, cpu.node_tests) << when << ", view " << v;
        EXPECT_EQ(result.views[v].object_tests, cpu.object_tests) << when << ", view " << v;
      }
      expect_reference(set, result, views, when);  // and flat culling's classes
      if (HasFatalFailure()) return;
    }
  }
}

TEST_F(GpuInstances, BadTreeUpdatesAreRefusedAndChangeNothing) {
  gpu::BvhCuller bvh_culler(*GpuEnvironment::context);
  std::mt19937 rng(12);
  InstanceSet<Aabb> set(box_meshes(rng, 3));
  for (int i = 0; i < 50; ++i) set.add(static_cast<std::uint32_t>(i % 3), random_placement(rng, 10.0f));
  std::vector<std::uint32_t> all(set.size());
  for (std::uint32_t i = 0; i < all.size(); ++i) all[i] = i;
  EXPECT_THROW(bvh_culler.update(set, all), std::invalid_argument);  // nothing uploaded
  std::vector<Aabb> world(set.size());
  set.world_volumes(world);
  const bvh::FlatTree tree = bvh::flatten(bvh::build_binned_sah(world));
  bvh_culler.upload(tree, set);
  const std::uint32_t backwards[2] = {5, 3};
  EXPECT_THROW(bvh_culler.update(set, backwards), std::invalid_argument);
  const std::uint32_t past[1] = {50};
  EXPECT_THROW(bvh_culler.update(set, past), std::invalid_argument);
  InstanceSet<Aabb> other_meshes(box_meshes(rng, 3));
  for (int i = 0; i < 50; ++i) other_meshes.add(0, random_placement(rng, 10.0f));
  EXPECT_THROW(bvh_culler.update(other_meshes, all), std::invalid_argument);
  set.add(0, random_placement(rng, 10.0f));  // 51 objects over a tree of 50
  EXPECT_THROW(bvh_culler.update(set, set.changed_slots()), std::invalid_argument);
  EXPECT_EQ(bvh_culler.pending_placements(), 0u);
  // A tree whose structure is not flatten's is refused (one id twice, one missing).
  set.remove(set.ids().back());
  bvh::FlatTree broken = tree;
  broken.objects[1] = broken.objects[0];
  EXPECT_THROW(bvh_culler.upload(broken, set), std::invalid_argument);
  EXPECT_EQ(bvh_culler.object_count(), 50u);  // the tree uploaded before stays
  const Frustum everything = Frustum::from_planes(std::vector<glm::vec4>{glm::vec4(1, 0, 0, 1e30f)});
  EXPECT_EQ(bvh_culler.cull(std::span<const Frustum>(&everything, 1)).views[0].counts.visible, 50u);
}

// Two frames in flight over one scene: a culler per frame, sharing the placed volumes; each
// frame's moves go to that frame's culler, recorded into its own command buffer and submitted
// while the other frame may still run. Every frame's classes equal the reference's on the volumes
// as placed when it was recorded; synchronization validation watches the shared buffers.
TEST_F(GpuInstances, TwoFramesInFlightShareOneScene) {
  const vulkan::Context& ctx = *GpuEnvironment::context;
  std::mt19937 rng(12);
  InstanceSet<Aabb> set(box_meshes(rng, 9));
  std::vector<InstanceId> live;
  for (int i = 0; i < 5000; ++i)
    live.push_back(set.add(static_cast<std::uint32_t>(i % 9), random_placement(rng, 15.0f)));
  gpu::GpuCuller first(ctx), second(ctx);
  second.share_scene(first);
  first.upload(set);
  second.reserve_instances(set, 6000);  // room for the adds below: no update grows the buffers
  set.clear_changes();
  EXPECT_EQ(second.object_count(), set.size());
  EXPECT_EQ(first.instance_capacity(), 6000u);
  EXPECT_EQ(first.pending_placements(), set.size());  // queued on the scene, for whichever records first
  gpu::GpuCuller* cullers[2] = {&second, &first};     // the culler that did not upload records first
  for (gpu::GpuCuller* c : cullers) c->reserve_outputs(4, {}, 6000);  // views_for gives four views

  VkDevice dev = ctx.device();
  VkCommandPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  pool_info.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
  pool_info.queueFamilyIndex = ctx.queue_family();
  VkCommandPool pool = VK_NULL_HANDLE;
  VkFence fences[2] = {};
  struct Release {  // the engine's objects, gone however the test ends
    VkDevice dev;
    VkCommandPool& pool;
    VkFence* fences;
    ~Release() {
      vkDeviceWaitIdle(dev);
      for (int f = 0; f < 2; ++f)
        if (fences[f]) vkDestroyFence(dev, fences[f], nullptr);
      if (pool) vkDestroyCommandPool(dev, pool, nullptr);
    }
  } release{dev, pool, fences};
  ASSERT_EQ(vkCreateCommandPool(dev, &pool_info, nullptr, &pool), VK_SUCCESS);
  VkCommandBufferAllocateInfo alloc{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr, pool,
                                    VK_COMMAND_BUFFER_LEVEL_PRIMARY, 2};
  VkCommandBuffer cmds[2] = {};
  ASSERT_EQ(vkAllocateCommandBuffers(dev, &alloc, cmds), VK_SUCCESS);
  for (VkFence& f : fences) {
    VkFenceCreateInfo fence_info{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    fence_info.flags = VK_FENCE_CREATE_SIGNALED_BIT;
    ASSERT_EQ(vkCreateFence(dev, &fence_info, nullptr, &f), VK_SUCCESS);
  }
  struct InFlight {
    bool pending = false;
    std::vector<Aabb> world;  // the volumes as placed for this frame
    std::vector<Frustum> views;
    int frame = 0;
  } in_flight[2];
  auto check = [&](int f) {
    InFlight& slot = in_flight[f];
    if (!slot.pending) return;
    ASSERT_EQ(vkWaitForFences(dev, 1, &fences[f], VK_TRUE, UINT64_MAX), VK_SUCCESS);
    const gpu::CullResult result = cullers[f]->read_results();
    for (std::size_t v = 0; v < slot.views.size(); ++v) {
      std::vector<Classification> cpu(slot.world.size());
      reference::classify_all(std::span<const Aabb>(slot.world), slot.views[v], cpu);
      const std::size_t s = first_mismatch(cpu, result.views.at(v).classes);
      ASSERT_EQ(s, npos) << "frame " << slot.frame << ", view " << v << ": slot " << s << " placed "
                         << cullpipe::describe(slot.world[s]) << "; cpu says " << to_string(cpu[s]) << ", gpu says "
                         << to_string(result.views[v].classes[s]);
    }
    slot.pending = false;
  };
  for (int frame = 0; frame < 12; ++frame) {
    const int f = frame % 2;
    check(f);  // the frame that used this culler two frames ago
    if (HasFatalFailure()) break;
    for (int k = 0; k < 400; ++k) set.set_transform(live[rng() % live.size()], random_placement(rng, 15.0f));
    if (frame % 3 == 2) {
      for (int k = 0; k < 60; ++k) {
        const std::size_t r = rng() % live.size();
        set.remove(live[r]);
        live[r] = live.back();
        live.pop_back();
      }
      for (int k = 0; k < 90; ++k)
        live.push_back(set.add(static_cast<std::uint32_t>(k % 9), random_placement(rng, 15.0f)));
    }
    ASSERT_LE(set.size(), first.instance_capacity());
    cullers[f]->update(set, set.changed_slots());
    set.clear_changes();
    InFlight& slot = in_flight[f];
    slot.world.resize(set.size());
    set.world_volumes(slot.world);
    slot.views = views_for<Aabb>(rng, slot.world);
    slot.frame = frame;
    ASSERT_EQ(vkResetFences(dev, 1, &fences[f]), VK_SUCCESS);
    ASSERT_EQ(vkResetCommandBuffer(cmds[f], 0), VK_SUCCESS);
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    ASSERT_EQ(vkBeginCommandBuffer(cmds[f], &begin), VK_SUCCESS);
    cullers[f]->record(cmds[f], slot.views);
    ASSERT_EQ(vkEndCommandBuffer(cmds[f]), VK_SUCCESS);
    VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &cmds[f];
    ASSERT_EQ(vkQueueSubmit(ctx.queue(), 1, &submit, fences[f]), VK_SUCCESS);
    slot.pending = true;
  }
  check(0);
  check(1);
}

// Placements queued through one culler belong to the scene: another upload through a sharer
// drops them, so a pass never places objects of a scene that is gone over the new volumes.
TEST_F(GpuInstances, AnUploadThroughASharerDropsQueuedPlacements) {
  const vulkan::Context& ctx = *GpuEnvironment::context;
  std::mt19937 rng(17);
  InstanceSet<Aabb> set(box_meshes(rng, 3));
  for (int i = 0; i < 3000; ++i) set.add(static_cast<std::uint32_t>(i % 3), random_placement(rng, 15.0f));
  gpu::GpuCuller a(ctx), b(ctx);
  b.share_scene(a);
  a.upload(set);
  const std::vector<Frustum> views = views_for<Aabb>(rng, std::vector<Aabb>{set.world_volume(0)});
  expect_reference(set, b.cull(views), views, "after the upload through the other culler");
  set.clear_changes();
  for (int k = 0; k < 300; ++k)
    set.set_transform(set.ids()[static_cast<std::size_t>(k) * 7], random_placement(rng, 15.0f));
  b.update(set, set.changed_slots());  // queued, not yet placed
  std::vector<Aabb> boxes(2000);
  for (Aabb& box : boxes) box = random_box_near(rng);
  a.upload(std::span<const Aabb>(boxes));
  EXPECT_EQ(b.pending_placements(), 0u);
  const gpu::CullResult r = b.cull(views);
  std::vector<Classification> cpu(boxes.size());
  reference::classify_all(std::span<const Aabb>(boxes), views[0], cpu);
  EXPECT_EQ(r.views.at(0).classes, cpu);
}

TEST_F(GpuInstances, AnEmptySetCullsNothing) {
  InstanceSet<Aabb> set({Aabb{glm::vec3(-1), glm::vec3(1)}});
  culler().upload(set);
  const std::vector<Frustum> views = {Frustum::from_view_proj(test::test_view_proj())};
  const gpu::CullResult result = culler().cull(views);
  EXPECT_TRUE(result.views.at(0).classes.empty());
  EXPECT_EQ(result.views.at(0).counts.visible, 0u);
}

TEST_F(GpuInstances, BadUpdatesAreRefusedAndChangeNothing) {
  std::mt19937 rng(4);
  InstanceSet<Aabb> set(box_meshes(rng, 3));
  for (int i = 0; i < 500; ++i) set.add(static_cast<std::uint32_t>(i % 3), random_placement(rng, 10.0f));
  set.clear_changes();
  InstanceSet<Sphere> spheres(sphere_meshes(rng, 2));
  spheres.add(0, random_placement(rng, 1.0f));
  culler().upload(std::span<const Aabb>());  // world volumes: no instances to update
  const std::uint32_t none[1] = {0};
  EXPECT_THROW(culler().update(set, none), std::invalid_argument);
  culler().upload(set);
  const std::vector<Frustum> views = views_for<Aabb>(rng, std::vector<Aabb>{set.world_volume(0)});
  expect_reference(set, culler().cull(views), views, "after upload");
  const auto expect_error = [&](auto&& call, const std::string& words) {
    try {
      call();
      ADD_FAILURE() << "accepted; expected an error with \"" << words << "\"";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
    }
  };
  const std::uint32_t out_of_range[2] = {3, 500};
  const std::uint32_t descending[2] = {7, 3};
  expect_error([&] { culler().update(set, out_of_range); }, "slot 500 is out of range");
  expect_error([&] { culler().update(set, descending); }, "not ascending");
  expect_error([&] { culler().update(spheres, none); }, "no sphere instances were uploaded");
  InstanceSet<Aabb> other(box_meshes(rng, 3));
  other.add(0, random_placement(rng, 1.0f));
  expect_error([&] { culler().update(other, none); }, "meshes are not the ones uploaded");
  // The refused updates sent nothing: a move made after them is still the only one placed.
  set.set_transform(set.ids()[9], random_placement(rng, 10.0f));
  culler().update(set, set.changed_slots());
  EXPECT_EQ(culler().pending_placements(), 1u);
  expect_reference(set, culler().cull(views), views, "after the refused updates");
}

// On a device whose device-local memory the host cannot map, every upload goes through a
// staging copy (forced here with map_device_memory = false): world volumes of every kind, draw
// templates and instances reach the GPU intact, and the answers are the reference's.
TEST(GpuStaging, UploadsThroughStagingGiveTheReferenceAnswers) {
  vulkan::ContextOptions options;
  options.validation = true;
  options.on_message = [](std::string_view m) { ADD_FAILURE() << m; };
  options.map_device_memory = false;
  vulkan::Context ctx(options);
  gpu::GpuCuller culler(ctx);
  std::mt19937 rng(21);
  test::Rng trng(21);
  std::vector<Aabb> boxes(3000);
  for (Aabb& b : boxes) b = test::random_aabb(trng, 30.0f, 2.0f);
  std::vector<Sphere> spheres(3000);
  for (Sphere& sp : spheres) sp = test::random_sphere(trng, 30.0f, 2.0f);
  std::vector<Obb> obbs;
  for (const Aabb& b : boxes)
    obbs.push_back(Obb::from_transformed_aabb(b, glm::rotate(glm::mat4(1.0f), 0.3f, glm::vec3(0, 1, 0))));
  const std::vector<Frustum> views = {Frustum::from_view_proj(test::test_view_proj())};
  auto expect_reference = [&](const auto& volumes, const gpu::CullResult& r, const char* what) {
    using Volume = typename std::decay_t<decltype(volumes)>::value_type;
    std::vector<Classification> cpu(volumes.size());
    reference::classify_all(std::span<const Volume>(volumes), views[0], cpu);
    EXPECT_EQ(r.views.at(0).classes, cpu) << what;
  };
  culler.upload(std::span<const Aabb>(boxes));
  std::vector<gpu::DrawCommand> templates(boxes.size());
  for (std::uint32_t i = 0; i < templates.size(); ++i) templates[i] = {36, 1, 0, 0, i, 0};
  culler.upload_draws(templates);
  const gpu::CullResult r = culler.cull(views, {true, true, 0, true, true});
  expect_reference(boxes, r, "boxes");
  for (const gpu::DrawCommand& d : r.views[0].draws) EXPECT_EQ(d.index_count, 36u);  // templates arrived
  const VkDeviceSize staged = ctx.staged_bytes();
  EXPECT_GE(staged, boxes.size() * (sizeof(gpu::GpuAabb) + 16 + sizeof(gpu::DrawCommand)));
  culler.upload(std::span<const Obb>(obbs));
  expect_reference(obbs, culler.cull(views), "OBBs");
  culler.upload(std::span<const Sphere>(spheres));
  expect_reference(spheres, culler.cull(views), "spheres");
  InstanceSet<Aabb> set(box_meshes(rng, 4));
  for (int i = 0; i < 2000; ++i) set.add(static_cast<std::uint32_t>(i % 4), random_placement(rng, 15.0f));
  culler.upload(set);
  set.clear_changes();
  for (int frame = 0; frame < 3; ++frame) {
    std::vector<Aabb> world(set.size());
    set.world_volumes(world);
    expect_reference(world, culler.cull(views), "instances");
    for (int k = 0; k < 200; ++k)
      set.set_transform(set.ids()[static_cast<std::size_t>(rng() % set.size())], random_placement(rng, 15.0f));
    culler.update(set, set.changed_slots());
    set.clear_changes();
  }
  EXPECT_GT(ctx.staged_bytes(), staged);  // the meshes went through staging too
  EXPECT_EQ(ctx.validation_message_count(), 0u);
}

}  // namespace
}  // namespace cullpipe
