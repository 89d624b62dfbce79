#pragma once
#include <vulkan/vulkan.h>

#include <cstddef>
#include <span>
#include <utility>

#include "cullpipe/vulkan/context.hpp"

namespace cullpipe::vulkan {

/// A VkBuffer with its own host-visible, coherent memory, persistently mapped. Prefers memory
/// that is also device-local (integrated GPUs, lavapipe, resizable BAR); falls back to plain
/// host memory that the device reads over the bus. The memory comes from the context's
/// Allocator when one is set, else from vkAllocateMemory. Move-only.
class Buffer {
 public:
  Buffer() = default;
  /// Throws vulkan::Error on failure, naming `what` (e.g. "bounds buffer") and the size.
  Buffer(const Context& ctx, VkDeviceSize size, VkBufferUsageFlags usage, const char* what);
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

}  // namespace cullpipe::vulkan
