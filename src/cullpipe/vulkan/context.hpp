#pragma once
#include <vulkan/vulkan.h>

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

namespace cullpipe::vulkan {

/// How to create a Context.
/// Memory for one buffer, as an engine's allocator hands it out: a block of device memory, the
/// offset of the buffer's range in it (a multiple of the buffer's alignment), and the host
/// address of that offset, or nullptr for memory the host cannot map (device-local scene
/// buffers on a device with separate memory, written through a staging copy).
struct Allocation {
  VkDeviceMemory memory = VK_NULL_HANDLE;
  VkDeviceSize offset = 0;
  void* mapped = nullptr;
  void* user = nullptr;  ///< the allocator's own handle for it (a VmaAllocation, say)
};

/// An engine's allocator (over VMA, say): set on a Context (Context::set_allocator), it supplies
/// the memory of every buffer cullpipe creates there instead of vkAllocateMemory, and gets it
/// back when the buffer goes. Called from the thread that creates or destroys the buffer.
class Allocator {
 public:
  virtual ~Allocator() = default;
  /// Memory meeting `requirements` (size, alignment, memory type bits) of a type with every
  /// `required` flag, preferably also `preferred`: host-visible and coherent required, mapped,
  /// for what the host writes each frame or reads back (preferring device-local); device-local
  /// required for scene buffers (preferring host-visible and coherent, then mapped; otherwise
  /// `mapped` may be nullptr). Return `mapped` only for host-coherent memory: cullpipe writes
  /// through it without flushing, and writes scene buffers without a mapping through a staging
  /// copy. `what` names the buffer ("bounds buffer"). Throws on failure (any exception; the
  /// buffer is not created).
  virtual Allocation allocate(const VkMemoryRequirements& requirements, VkMemoryPropertyFlags required,
                              VkMemoryPropertyFlags preferred, const char* what) = 0;
  /// Takes back what allocate() gave; the buffer bound to it is already destroyed.
  virtual void free(const Allocation& allocation) noexcept = 0;
};

struct ContextOptions {
  /// Enable VK_LAYER_KHRONOS_validation with synchronization validation. Every message it
  /// reports is counted and passed to `on_message`.
  bool validation = false;
  /// Pick the first device whose name contains this substring (case-insensitive). Empty: use
  /// the CULLPIPE_DEVICE environment variable, else the first discrete or integrated GPU,
  /// else the first CPU device (lavapipe).
  std::string device_filter;
  /// Receives every validation message; default prints it to stderr.
  std::function<void(std::string_view)> on_message;
  /// The most device memory cullpipe may hold at once through this context, in bytes; 0: no
  /// limit beyond the device's. An allocation past it fails as the device would when out of
  /// memory (vulkan::Error with VK_ERROR_OUT_OF_DEVICE_MEMORY), naming the budget. See
  /// Context::set_memory_budget.
  VkDeviceSize memory_budget = 0;
  /// Map device-local scene buffers when their memory is host-visible too (unified memory, as
  /// on lavapipe and integrated GPUs), writing uploads straight into them. false writes every
  /// upload through a staging buffer and a copy, as on a device whose device-local memory the
  /// host cannot map; tests use it to cover that path on any device.
  bool map_device_memory = true;
};

/// Handles of a device the caller already has (an engine's own device). The Context borrows
/// them: it never destroys them, and creates only its own command pool and fence on them.
/// The queue family must support compute; for draws from the culling output on the same
/// queue, it should also support graphics.
struct ExternalDevice {
  VkInstance instance = VK_NULL_HANDLE;
  VkPhysicalDevice physical_device = VK_NULL_HANDLE;
  VkDevice device = VK_NULL_HANDLE;
  VkQueue queue = VK_NULL_HANDLE;
  std::uint32_t queue_family = 0;
  /// The caller enabled drawIndirectCount, multiDrawIndirect and drawIndirectFirstInstance
  /// (needed by render::Renderer, whose draws carry the object id as firstInstance).
  bool draw_indirect_count = false;
  /// The caller enabled pipelineStatisticsQuery (the renderer then counts triangles drawn).
  bool pipeline_statistics = false;
  /// The caller enabled geometryShader (fragment shaders may read gl_PrimitiveID: the renderer
  /// then counts the triangles owning a pixel).
  bool primitive_ids = false;
};

/// A physical device as listed by list_devices().
struct DeviceInfo {
  std::string name;
  std::string type;    ///< "discrete", "integrated", "virtual", "cpu" or "other"
  std::string driver;  ///< driver name and info, e.g. "llvmpipe Mesa 22.3.6"
  std::uint32_t api_version = 0;
};

/// The Vulkan devices this machine offers. Throws vulkan::Error when Vulkan cannot be loaded.
std::vector<DeviceInfo> list_devices();

/// Owns a VkInstance, the chosen VkPhysicalDevice, a VkDevice and one queue (compute, and
/// graphics when the device has a family with both), plus a command pool for one-shot
/// submissions; or borrows an ExternalDevice. Move-free and copy-free: create it once, pass by
/// reference. Throws vulkan::Error with a clear message when there is no usable device.
class Context {
 public:
  explicit Context(const ContextOptions& options = {});
  /// Borrows the caller's device and queue (validation is the caller's business then).
  explicit Context(const ExternalDevice& external);
  ~Context();
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;

  VkInstance instance() const { return instance_; }
  VkPhysicalDevice physical_device() const { return physical_device_; }
  VkDevice device() const { return device_; }
  VkQueue queue() const { return queue_; }
  std::uint32_t queue_family() const { return queue_family_; }
  VkCommandPool command_pool() const { return command_pool_; }
  const VkPhysicalDeviceProperties& properties() const { return properties_; }
  const DeviceInfo& info() const { return info_; }
  /// Nanoseconds per timestamp tick; 0 when the compute queue has no timestamps.
  double timestamp_period_ns() const { return timestamp_period_ns_; }
  /// Valid bits of the compute queue's timestamps (0: none).
  std::uint32_t timestamp_valid_bits() const { return timestamp_valid_bits_; }

  /// The queue family's flags (VK_QUEUE_GRAPHICS_BIT etc.).
  VkQueueFlags queue_flags() const { return queue_flags_; }
  /// drawIndirectCount, multiDrawIndirect and drawIndirectFirstInstance are enabled (own
  /// devices that support them).
  bool draw_indirect_count() const { return draw_indirect_count_; }
  /// pipelineStatisticsQuery is enabled (own devices that support it).
  bool pipeline_statistics() const { return pipeline_statistics_; }
  /// geometryShader is enabled, so fragment shaders may read gl_PrimitiveID (own devices that
  /// support it).
  bool primitive_ids() const { return primitive_ids_; }
  /// Whether this context created (and will destroy) the device.
  bool owns_device() const { return owns_device_; }
  /// Validation messages reported so far (0 when validation is off).
  std::size_t validation_message_count() const { return message_count_.load(); }
  /// The validation messages reported so far, removed from the context.
  std::vector<std::string> take_validation_messages();

  /// Index of a memory type allowed by `type_bits` with all of `required` flags, preferring
  /// one that also has `preferred`. Throws vulkan::Error if none.
  std::uint32_t find_memory_type(std::uint32_t type_bits, VkMemoryPropertyFlags required,
                                 VkMemoryPropertyFlags preferred) const;

  /// Submits one recorded command buffer to the queue and waits for it to finish.
  void submit_and_wait(VkCommandBuffer cmd) const;

  /// Device memory budget (ContextOptions::memory_budget; also for borrowed devices, e.g. an
  /// engine's share of its GPU). 0: none. Lowering it below what is held frees nothing; later
  /// allocations fail until enough is released.
  void set_memory_budget(VkDeviceSize bytes) { memory_budget_ = bytes; }
  VkDeviceSize memory_budget() const { return memory_budget_.load(); }
  /// Device memory held by buffers of this context now, in bytes.
  VkDeviceSize memory_in_use() const { return memory_in_use_.load(); }
  /// Counts `bytes` against the budget before they are allocated; throws vulkan::Error
  /// (VK_ERROR_OUT_OF_DEVICE_MEMORY) naming `what` when they do not fit. Used by vulkan::Buffer.
  void reserve_memory(VkDeviceSize bytes, const std::string& what) const;
  void release_memory(VkDeviceSize bytes) const { memory_in_use_ -= bytes; }

  /// The allocator buffers created from now on take their memory from (nullptr: cullpipe
  /// allocates it). Not owned: it must outlive every buffer it allocated for (each buffer
  /// returns its memory to the allocator it came from, whatever is set later).
  void set_allocator(Allocator* allocator) { allocator_ = allocator; }
  bool map_device_memory() const { return map_device_memory_; }
  /// Bytes uploads have copied through staging buffers so far (vulkan::copy_buffer).
  VkDeviceSize staged_bytes() const { return staged_bytes_.load(); }
  void count_staged(VkDeviceSize bytes) const { staged_bytes_ += bytes; }
  /// The property flags of memory type `index`.
  VkMemoryPropertyFlags memory_type_flags(std::uint32_t index) const {
    return memory_properties_.memoryTypes[index].propertyFlags;
  }
  Allocator* allocator() const { return allocator_; }

 private:
  static VKAPI_ATTR VkBool32 VKAPI_CALL debug_callback(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                                       VkDebugUtilsMessageTypeFlagsEXT types,
                                                       const VkDebugUtilsMessengerCallbackDataEXT* data, void* user);
  void destroy();
  void read_device_properties();
  void create_pool_and_fence();

  VkInstance instance_ = VK_NULL_HANDLE;
  VkDebugUtilsMessengerEXT messenger_ = VK_NULL_HANDLE;
  VkPhysicalDevice physical_device_ = VK_NULL_HANDLE;
  VkDevice device_ = VK_NULL_HANDLE;
  VkQueue queue_ = VK_NULL_HANDLE;
  VkCommandPool command_pool_ = VK_NULL_HANDLE;
  VkFence fence_ = VK_NULL_HANDLE;
  std::uint32_t queue_family_ = 0;
  VkPhysicalDeviceProperties properties_{};
  VkPhysicalDeviceMemoryProperties memory_properties_{};
  DeviceInfo info_;
  double timestamp_period_ns_ = 0.0;
  std::uint32_t timestamp_valid_bits_ = 0;
  VkQueueFlags queue_flags_ = 0;
  bool draw_indirect_count_ = false;
  bool pipeline_statistics_ = false;
  bool primitive_ids_ = false;
  bool owns_device_ = true;

  std::function<void(std::string_view)> on_message_;
  std::atomic<std::size_t> message_count_{0};
  Allocator* allocator_ = nullptr;
  bool map_device_memory_ = true;
  mutable std::atomic<VkDeviceSize> staged_bytes_{0};
  std::atomic<VkDeviceSize> memory_budget_{0};
  mutable std::atomic<VkDeviceSize> memory_in_use_{0};
  std::mutex messages_mutex_;
  std::vector<std::string> messages_;
};

}  // namespace cullpipe::vulkan
