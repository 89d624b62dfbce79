// engine_example [SCENE.gltf|.glb] [OUT.png]
//
// What an engine does with cullpipe: it owns the Vulkan instance, device and queue; cullpipe
// borrows them (vulkan::ExternalDevice), records its culling pass into the engine's command
// buffer, and the engine draws from the draw and count buffers the pass wrote. Here the
// "engine" also checks the GPU's answers against the CPU reference and draws the culled scene
// with cullpipe's renderer into a PNG.
#include <vulkan/vulkan.h>

#include <cstdio>
#include <cstring>
#include <cullpipe/cull/reference.hpp>
#include <cullpipe/gpu/gpu_culler.hpp>
#include <cullpipe/render/image.hpp>
#include <cullpipe/render/renderer.hpp>
#include <cullpipe/scene/generators.hpp>
#include <cullpipe/scene/gltf_scene.hpp>
#include <cullpipe/vulkan/context.hpp>
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
  return stats.draws == counts.visible ? 0 : 1;
} catch (const std::exception& e) {
  std::fprintf(stderr, "engine_example: %s\n", e.what());
  return 2;
}
