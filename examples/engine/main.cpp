// engine_example [SCENE.gltf|.glb] [OUT.png]
//
// What an engine does with cullpipe: it owns the Vulkan instance, device and queue; cullpipe
// borrows them (vulkan::ExternalDevice), records its culling pass into the engine's command
// buffer, and the engine draws from the draw and count buffers the pass wrote. Here the
// "engine" also checks the GPU's answers against the CPU reference and draws the culled scene
// with cullpipe's renderer into a PNG. Then it runs a frame loop: two frames in flight over one
// scene of instances, a tenth of them moving each frame, only their transforms sent, every
// frame checked against the CPU reference.
#include <vulkan/vulkan.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <cullpipe/cull/instances.hpp>
#include <cullpipe/cull/reference.hpp>
#include <cullpipe/gpu/gpu_culler.hpp>
#include <cullpipe/render/image.hpp>
#include <cullpipe/render/renderer.hpp>
#include <cullpipe/scene/generators.hpp>
#include <cullpipe/scene/gltf_scene.hpp>
#include <cullpipe/vulkan/context.hpp>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

void check(VkResult r, const char* what) {
  if (r != VK_SUCCESS) throw std::runtime_error(std::string(what) + " failed (VkResult " + std::to_string(r) + ")");
}

// The engine's own device: the first one with a graphics + compute queue, with the features
// indirect-count drawing needs.
struct EngineDevice {
  VkInstance instance = VK_NULL_HANDLE;
  VkPhysicalDevice physical = VK_NULL_HANDLE;
  VkDevice device = VK_NULL_HANDLE;
  VkQueue queue = VK_NULL_HANDLE;
  std::uint32_t family = 0;

  EngineDevice() {
    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    app.pApplicationName = "engine_example";
    app.apiVersion = VK_API_VERSION_1_2;
    VkInstanceCreateInfo ii{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    ii.pApplicationInfo = &app;
    check(vkCreateInstance(&ii, nullptr, &instance), "vkCreateInstance");
    std::uint32_t n = 0;
    vkEnumeratePhysicalDevices(instance, &n, nullptr);
    std::vector<VkPhysicalDevice> devices(n);
    vkEnumeratePhysicalDevices(instance, &n, devices.data());
    for (VkPhysicalDevice pd : devices) {
      std::uint32_t nf = 0;
      vkGetPhysicalDeviceQueueFamilyProperties(pd, &nf, nullptr);
      std::vector<VkQueueFamilyProperties> families(nf);
      vkGetPhysicalDeviceQueueFamilyProperties(pd, &nf, families.data());
      for (std::uint32_t f = 0; f < nf && !physical; ++f)
        if ((families[f].queueFlags & VK_QUEUE_GRAPHICS_BIT) && (families[f].queueFlags & VK_QUEUE_COMPUTE_BIT))
          physical = pd, family = f;
      if (physical) break;
    }
    if (!physical) {
      vkDestroyInstance(instance, nullptr);
      throw std::runtime_error("no Vulkan device with a graphics + compute queue");
    }
    VkPhysicalDeviceVulkan12Features f12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES};
    f12.drawIndirectCount = VK_TRUE;
    VkPhysicalDeviceFeatures2 f2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &f12, {}};
    f2.features.multiDrawIndirect = VK_TRUE;
    f2.features.drawIndirectFirstInstance = VK_TRUE;  // draws carry the object id as firstInstance
    const float priority = 1.0f;
    VkDeviceQueueCreateInfo qi{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    qi.queueFamilyIndex = family;
    qi.queueCount = 1;
    qi.pQueuePriorities = &priority;
    VkDeviceCreateInfo di{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO};
    di.pNext = &f2;
    di.queueCreateInfoCount = 1;
    di.pQueueCreateInfos = &qi;
    if (vkCreateDevice(physical, &di, nullptr, &device) != VK_SUCCESS) {
      vkDestroyInstance(instance, nullptr);  // the destructor does not run for a failed constructor
      throw std::runtime_error("vkCreateDevice failed");
    }
    vkGetDeviceQueue(device, family, 0, &queue);
  }
  ~EngineDevice() {
    if (device) vkDestroyDevice(device, nullptr);
    if (instance) vkDestroyInstance(instance, nullptr);
  }
};

// The engine's frame loop: two frames in flight over one scene. Each distinct mesh's local box
// is uploaded once and every object is an instance of it; a tenth of the objects move each
// frame and only their transforms are sent, to that frame's culler, whose pass places them on
// the GPU and then culls. When a frame's fence signals, its answers are checked against the CPU
// reference on the volumes as placed for it.
int frame_loop(const EngineDevice& engine, const cullpipe::vulkan::Context& ctx, const cullpipe::Scene& scene) {
  using namespace cullpipe;
  constexpr int kFramesInFlight = 2, kFrames = 24;
  // Meshes: the objects' distinct local boxes (a glTF primitive drawn many times is one mesh).
  std::vector<Aabb> meshes;
  std::map<std::vector<float>, std::uint32_t> mesh_of_box;
  std::vector<std::uint32_t> mesh_index;
  for (const SceneObject& o : scene.objects) {
    const Aabb& b = o.local_bounds;
    const std::vector<float> key = {b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z};
    auto [it, added] = mesh_of_box.emplace(key, static_cast<std::uint32_t>(meshes.size()));
    if (added) meshes.push_back(b);
    mesh_index.push_back(it->second);
  }
  InstanceSet<Aabb> set(meshes);
  std::vector<InstanceId> ids;
  std::vector<glm::mat4> rest;  // each object's transform at rest
  for (std::size_t i = 0; i < scene.objects.size(); ++i) {
    rest.push_back(scene.objects[i].world);
    ids.push_back(set.add(mesh_index[i], Transform3x4::from_mat4(rest.back())));
  }

  // One culler per frame in flight, one scene: the second culls the first's buffers.
  gpu::GpuCuller cullers[kFramesInFlight] = {gpu::GpuCuller(ctx), gpu::GpuCuller(ctx)};
  cullers[1].share_scene(cullers[0]);
  cullers[0].upload(set);
  set.clear_changes();
  std::vector<gpu::DrawCommand> draws(set.size());
  for (std::uint32_t i = 0; i < draws.size(); ++i) draws[i] = {36, 1, 0, 0, i, 0};
  cullers[0].upload_draws(draws);
  gpu::CullOptions options;
  options.ordered = true;
  options.draws = true;
  for (gpu::GpuCuller& culler : cullers) culler.reserve_outputs(1, options);  // each frame's own outputs

  VkCommandPoolCreateInfo pi{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  pi.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
  pi.queueFamilyIndex = engine.family;
  VkCommandPool pool = VK_NULL_HANDLE;
  check(vkCreateCommandPool(engine.device, &pi, nullptr, &pool), "vkCreateCommandPool");
  VkCommandBufferAllocateInfo ai{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr, pool,
                                 VK_COMMAND_BUFFER_LEVEL_PRIMARY, kFramesInFlight};
  VkCommandBuffer cmds[kFramesInFlight] = {};
  check(vkAllocateCommandBuffers(engine.device, &ai, cmds), "vkAllocateCommandBuffers");
  VkFence fences[kFramesInFlight] = {};
  for (VkFence& fence : fences) {
    VkFenceCreateInfo fi{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    fi.flags = VK_FENCE_CREATE_SIGNALED_BIT;
    check(vkCreateFence(engine.device, &fi, nullptr, &fence), "vkCreateFence");
  }
  struct Frame {
    bool pending = false;
    int number = 0;
    Frustum view;
    std::vector<Aabb> placed;  // the world boxes as placed for this frame, for the check
  } frames[kFramesInFlight];
  int failures = 0;
  std::size_t visible_total = 0;
  auto finish = [&](int f) {
    Frame& frame = frames[f];
    if (!frame.pending) return;
    check(vkWaitForFences(engine.device, 1, &fences[f], VK_TRUE, UINT64_MAX), "vkWaitForFences");
    frame.pending = false;
    const gpu::ViewResult view = cullers[f].read_results().views.at(0);
    std::vector<Classification> cpu(frame.placed.size());
    const reference::CullCounts counts = reference::classify_all(std::span<const Aabb>(frame.placed), frame.view, cpu);
    visible_total += counts.visible;
    if (view.classes != cpu || view.draws.size() != counts.visible) {
      std::fprintf(stderr, "engine_example: frame %d: GPU and CPU disagree (%zu and %zu visible)\n", frame.number,
                   std::size_t(view.counts.visible), std::size_t(counts.visible));
      ++failures;
    }
  };
  const std::vector<Camera> path = scene_camera_path(scene, kFrames);
  std::vector<InstanceId> moving;
  std::vector<Transform3x4> moves;
  for (int number = 0; number < kFrames; ++number) {
    const int f = number % kFramesInFlight;
    finish(f);  // this culler's frame from kFramesInFlight frames ago
    // A tenth of the objects bob up and down.
    moving.clear();
    moves.clear();
    for (std::size_t k = static_cast<std::size_t>(number) % 10; k < ids.size(); k += 10) {
      moving.push_back(ids[k]);
      const float lift = 2.0f * std::sin(0.5f * static_cast<float>(number) + static_cast<float>(k));
      glm::mat4 m = rest[k];
      m[3].y += lift;
      moves.push_back(Transform3x4::from_mat4(m));
    }
    set.set_transforms(moving, moves);
    cullers[f].update(set, set.changed_slots());  // only what moved
    set.clear_changes();
    Frame& frame = frames[f];
    frame.number = number;
    frame.view = Frustum::from_view_proj(path[static_cast<std::size_t>(number)].view_proj());
    frame.placed.resize(set.size());
    set.world_volumes(frame.placed);
    check(vkResetFences(engine.device, 1, &fences[f]), "vkResetFences");
    check(vkResetCommandBuffer(cmds[f], 0), "vkResetCommandBuffer");
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    check(vkBeginCommandBuffer(cmds[f], &begin), "vkBeginCommandBuffer");
    cullers[f].record(cmds[f], std::span(&frame.view, 1), options);
    // ... the frame's render pass would draw from cullers[f].draw_buffer() here.
    check(vkEndCommandBuffer(cmds[f]), "vkEndCommandBuffer");
    VkSubmitInfo si{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    si.commandBufferCount = 1;
    si.pCommandBuffers = &cmds[f];
    check(vkQueueSubmit(engine.queue, 1, &si, fences[f]), "vkQueueSubmit");
    frame.pending = true;
  }
  for (int f = 0; f < kFramesInFlight; ++f) finish(f);
  check(vkDeviceWaitIdle(engine.device), "vkDeviceWaitIdle");
  for (VkFence fence : fences) vkDestroyFence(engine.device, fence, nullptr);
  vkDestroyCommandPool(engine.device, pool, nullptr);
  std::printf(
      "engine_example: %d frames, 2 in flight, %zu of %zu objects moving per frame, %zu meshes: "
      "%zu visible in all, every frame equal to the CPU reference%s\n",
      kFrames, moving.size(), set.size(), meshes.size(), visible_total, failures ? " EXCEPT the above" : "");
  return failures ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) try {
  using namespace cullpipe;
  EngineDevice engine;
  // cullpipe borrows the engine's device: it never destroys it.
  vulkan::Context ctx(vulkan::ExternalDevice{engine.instance, engine.physical, engine.device, engine.queue,
                                             engine.family,
                                             /*draw_indirect_count=*/true, /*pipeline_statistics=*/false});

  Scene scene = argc > 1 ? load_gltf_scene(argv[1]).scene : generate_scene(SceneKind::City, 2000, 1);
  const std::vector<Aabb> boxes = world_aabbs(scene);
  const Frustum frustum = Frustum::from_view_proj(scene.camera.view_proj());

  // Per object, the draw the engine wants issued when the object is visible.
  std::vector<gpu::DrawCommand> draws(boxes.size());
  for (std::uint32_t i = 0; i < draws.size(); ++i) draws[i] = {36, 1, 0, 0, i, 0};
  gpu::GpuCuller culler(ctx);
  culler.upload(std::span<const Aabb>(boxes));
  culler.upload_draws(draws);

  // The engine's frame: its command buffer, cullpipe's pass recorded into it.
  VkCommandPoolCreateInfo pi{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  pi.queueFamilyIndex = engine.family;
  VkCommandPool pool = VK_NULL_HANDLE;
  check(vkCreateCommandPool(engine.device, &pi, nullptr, &pool), "vkCreateCommandPool");
  VkCommandBufferAllocateInfo ai{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr, pool,
                                 VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
  VkCommandBuffer cmd = VK_NULL_HANDLE;
  check(vkAllocateCommandBuffers(engine.device, &ai, &cmd), "vkAllocateCommandBuffers");
  VkCommandBufferBeginInfo bi{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  check(vkBeginCommandBuffer(cmd, &bi), "vkBeginCommandBuffer");
  gpu::CullOptions options;
  options.ordered = true;  // draws in object order
  options.draws = true;
  culler.reserve_outputs(1, options);  // the draw and count buffers, made once (record never replaces them)
  culler.record(cmd, std::span(&frustum, 1), options);
  // ... here an engine would begin its render pass and call
  // vkCmdDrawIndexedIndirectCount(cmd, culler.draw_buffer().handle(), 0,
  //                               culler.counter_buffer().handle(), 0, capacity, sizeof(gpu::DrawCommand));
  check(vkEndCommandBuffer(cmd), "vkEndCommandBuffer");
  VkSubmitInfo si{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  si.commandBufferCount = 1;
  si.pCommandBuffers = &cmd;
  check(vkQueueSubmit(engine.queue, 1, &si, VK_NULL_HANDLE), "vkQueueSubmit");
  check(vkQueueWaitIdle(engine.queue), "vkQueueWaitIdle");
  vkDestroyCommandPool(engine.device, pool, nullptr);

  const gpu::CullResult result = culler.read_results();
  std::vector<Classification> cpu(boxes.size());
  const reference::CullCounts counts = reference::classify_all(std::span<const Aabb>(boxes), frustum, cpu);
  const gpu::ViewResult& view = result.views[0];
  std::printf("engine_example: %zu objects on %s; GPU: %zu visible, %zu draws; CPU reference: %zu visible\n",
              boxes.size(), ctx.info().name.c_str(), std::size_t(view.counts.visible), view.draws.size(),
              std::size_t(counts.visible));
  if (view.classes != cpu || view.draws.size() != counts.visible) {
    std::fprintf(stderr, "engine_example: GPU and CPU disagree\n");
    return 1;
  }

  // Draw the culled scene with cullpipe's renderer, on the engine's device.
  render::Renderer renderer(ctx, scene, render::RendererConfig{480, 270});
  render::FrameStats stats;
  const render::Image image = renderer.render(scene.camera, true, &stats);
  const std::string out = argc > 2 ? argv[2] : "engine_example.png";
  render::write_png(out, image);
  std::printf("engine_example: drew %zu of %zu objects into %s\n", stats.draws, stats.objects, out.c_str());
  if (stats.draws != counts.visible) return 1;
  return frame_loop(engine, ctx, scene);
} catch (const std::exception& e) {
  std::fprintf(stderr, "engine_example: %s\n", e.what());
  return 2;
}
