#pragma once
#include <vulkan/vulkan.h>

#include <cstddef>
#include <span>
#include <utility>

#include "cullpipe/vulkan/context.hpp"

namespace cullpipe::vulkan {

/// What a buffer's memory is for.
enum class MemoryUse {
  /// Written or read by the host every pass (views, placing lists, outputs): host-visible and
  /// coherent, persistently mapped, device-local where such memory is.
  Host,
  /// Scene data the GPU reads every pass and the host writes only at uploads: device-local.
  /// Mapped when that memory is host-visible too (and ContextOptions::map_device_memory);
  /// otherwise data() is null and uploads go through a staging copy (write_through_staging).
  Device,
};

/// A VkBuffer with its own host-visible, coherent memory, persistently mapped. Prefers memory
/// that is also device-local (integrated GPUs, lavapipe, resizable BAR); falls back to plain
/// host memory that the device reads over the bus. The memory comes from the context's
/// Allocator when one is set, else from vkAllocateMemory. Move-only.
class Buffer {
 public:
  Buffer() = default;
  /// Throws vulkan::Error on failure, naming `what` (e.g. "bounds buffer") and the size.
  Buffer(const Context& ctx, VkDeviceSize size, VkBufferUsageFlags usage, const char* what,
         MemoryUse use = MemoryUse::Host);
  /// A buffer someone else owns (an engine's), `size` bytes from its start, mapped at `mapped`
  /// or not at all (nullptr): used as it is, never destroyed here.
  static Buffer borrow(VkBuffer handle, VkDeviceSize size, void* mapped = nullptr);
  bool borrowed() const { return borrowed_; }
  ~Buffer() { reset(); }
  Buffer(Buffer&& o) noexcept { *this = std::move(o); }
  Buffer& operator=(Buffer&& o) noexcept;
  Buffer(const Buffer&) = delete;
  Buffer& operator=(const Buffer&) = delete;

  VkBuffer handle() const { return buffer_; }
  VkDeviceSize size() const { return size_; }
  void* data() const { return mapped_; }
  template <class T>
  std::span<T> as() const {
    return {static_cast<T*>(mapped_), static_cast<std::size_t>(size_ / sizeof(T))};
  }
  explicit operator bool() const { return buffer_ != VK_NULL_HANDLE; }
  /// Whether the host writes it directly (data() is its memory).
  bool mapped() const { return mapped_ != nullptr; }
  void reset();

 private:
  const Context* ctx_ = nullptr;  // for the memory budget
  VkDeviceSize reserved_ = 0;     // bytes counted against it
  VkDevice device_ = VK_NULL_HANDLE;
  VkBuffer buffer_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  VkDeviceSize size_ = 0;
  void* mapped_ = nullptr;
  Allocator* allocator_ = nullptr;  // where memory_ came from (null: vkAllocateMemory)
  bool borrowed_ = false;           // buffer_ is someone else's
  Allocation allocation_;
};

/// Copies `bytes` from the start of `src` to the start of `dst` and waits (write_through_staging).
void copy_buffer(const Context& ctx, const Buffer& src, const Buffer& dst, VkDeviceSize bytes);

/// Writes `bytes` bytes into `dst` from its start: `fill(host)` writes them at `host`, dst's own
/// mapping when it has one, else a staging buffer that is then copied into dst (one submission,
/// waited for, ending with a barrier that makes the copy visible to later shaders and transfers).
/// dst needs VK_BUFFER_USAGE_TRANSFER_DST_BIT when it is not mapped.
template <class Fill>
void write_through_staging(const Context& ctx, const Buffer& dst, VkDeviceSize bytes, Fill&& fill) {
  if (bytes == 0) return;
  if (dst.mapped()) {
    fill(dst.data());
    return;
  }
  Buffer staging(ctx, bytes, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, "staging buffer");
  fill(staging.data());
  copy_buffer(ctx, staging, dst, bytes);
}

}  // namespace cullpipe::vulkan
